#include "slscan/session/scanner_connection.hpp"

#include "slproto/handshake.hpp"
#include "slscan/session/session_log.hpp"

#ifndef SLSCAN_VERSION
#define SLSCAN_VERSION "unknown"
#endif

namespace slscan::session {

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
