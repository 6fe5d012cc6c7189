// slscan status / discover: what a scanner on the network is, runs and did last.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "run.hpp"
#include "slproto/mdns.hpp"
#include "slproto/slproto.pb.h"

namespace slscan::app {

// The port every packaged board file listens on ([network] port).
inline constexpr std::uint16_t default_scanner_port = 7878;

// "HOST", "HOST:PORT", "[IPV6]:PORT" or a bare IPv6 literal -> host and port (default 7878).
// Throws std::invalid_argument naming the text for an empty host or a bad port.
std::pair<std::string, std::uint16_t> parse_scanner_address(const std::string& text);

// The token a host presents: the first line of `path`, or of $SLSCAN_TOKEN_FILE when `path` is
// empty, "" when neither is set. Never from the command line, where any user of the machine
// could read it in ps. Throws io::IoError naming the file if it cannot be read or is empty.
std::string read_token_file(const std::string& path);

struct StatusCommand {
  std::string address;     // HOST[:PORT]
  std::string token_file;  // "" = no token
  bool json = false;
};
int run_status(const StatusCommand& command, const Console& console);

// The human-readable report `slscan status` prints (one "key: value" line each).
std::string format_status(const slproto::pb::StatusReply& status, const std::string& address, std::int64_t now_unix_ns);

struct DiscoverCommand {
  double wait_s = 3.0;  // how long to listen for answers
  bool json = false;
};
int run_discover(const DiscoverCommand& command, const Console& console);

// One line per scanner: "NAME  HOST:PORT  board B, slscand V, slproto A..B[, token][, simulated]"
// plus what to upgrade when its protocol range and this host's do not meet.
std::string format_discovered(const std::vector<slproto::DiscoveredScanner>& scanners);

}  // namespace slscan::app
