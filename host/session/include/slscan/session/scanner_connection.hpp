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

// Connects and says hello as `client_name`; throws DeviceError naming the address and why
// (no route, refused, wrong token, a protocol version we do not speak).
ScannerConnection connect_to_scanner(const ScannerAddress& address, const std::string& client_name,
                                     std::chrono::milliseconds timeout = std::chrono::seconds(3));

}  // namespace slscan::session
