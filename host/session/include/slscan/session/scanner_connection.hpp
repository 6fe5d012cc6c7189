// A connection to a scanner (slscand, on a board or on the sim board), handshake done.
#pragma once

#include <chrono>
#include <cstdint>
#include <string>

#include "slproto/messages.hpp"
#include "slproto/transport.hpp"

namespace slscan::session {

struct ScannerAddress {
  std::string host = "127.0.0.1";
  std::uint16_t port = 7878;
  std::string token;  // the board's shared secret ("" where it needs none)
};

struct ScannerConnection {
  slproto::Connection connection;
  slproto::pb::HelloReply board;  // name, software and protocol version, capabilities
};

// The exposure and pattern period a scan asks for: the user's where given (non-zero), else the
// board's (its HelloReply: the board file's [timing]), else a DLP4500's 8-bit pattern (8333 us
// in a 10000 us period) from a board too old to say.
struct PatternTiming {
  std::uint32_t exposure_us = 0, period_us = 0;
};
PatternTiming pattern_timing(std::uint32_t exposure_us, std::uint32_t period_us, const slproto::pb::HelloReply& board);

// Connects and says hello as `client_name`; throws DeviceError naming the address and why
// (no route, refused, wrong token, a protocol version we do not speak).
ScannerConnection connect_to_scanner(const ScannerAddress& address, const std::string& client_name,
                                     std::chrono::milliseconds timeout = std::chrono::seconds(3));

}  // namespace slscan::session
