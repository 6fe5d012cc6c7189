#include "slscan/session/scanner_connection.hpp"

#include "slproto/handshake.hpp"
#include "slscan/session/session_log.hpp"

#ifndef SLSCAN_VERSION
#define SLSCAN_VERSION "unknown"
#endif

namespace slscan::session {

PatternTiming pattern_timing(std::uint32_t exposure_us, std::uint32_t period_us, const slproto::pb::HelloReply& board) {
  const bool board_says = board.pattern_exposure_us() != 0 && board.pattern_period_us() != 0;
  PatternTiming timing;
  timing.exposure_us = exposure_us != 0 ? exposure_us : (board_says ? board.pattern_exposure_us() : 8333);
  timing.period_us = period_us != 0 ? period_us : (board_says ? board.pattern_period_us() : 10000);
  return timing;
}

ScannerConnection connect_to_scanner(const ScannerAddress& address, const std::string& client_name,
                                     std::chrono::milliseconds timeout) {
  auto connection = slproto::connect(address.host, address.port, timeout);
  if (!connection)
    throw DeviceError("cannot connect to " + address.host + ":" + std::to_string(address.port) + ": " +
                      connection.error().message);
  auto reply = slproto::client_handshake(*connection,
                                         slproto::make_hello(client_name, "slscan " SLSCAN_VERSION, 0, address.token));
  if (!reply) throw DeviceError("the scanner refused the connection: " + reply.error().message);
  return {std::move(*connection), std::move(*reply)};
}

}  // namespace slscan::session
