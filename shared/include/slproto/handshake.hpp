// The hello exchange that opens every connection: the host (client) sends Hello, the board
// (server) answers HelloReply and, if it rejects the hello, closes the connection.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <string_view>

#include "slproto/messages.hpp"
#include "slproto/result.hpp"
#include "slproto/transport.hpp"

namespace slproto {

inline constexpr std::chrono::milliseconds default_handshake_timeout{3000};

// A range of protocol versions a peer speaks (Hello.min_protocol_version..protocol_version).
struct VersionRange {
  std::uint32_t min = min_protocol_version;
  std::uint32_t max = protocol_version;
};

// The first slscan/slscand release that speaks protocol version `version`; "" for a version
// newer than this build (it cannot know which release will bring it).
std::string first_release_speaking(std::uint32_t version);

// The refusal text for a host and a board without a common protocol version: names both ranges
// (and the software when known) and what to upgrade on which side, e.g. "board 'rpi' (slscand
// 0.1.0) speaks slproto 1..1, the host (slscan 0.2.0) speaks 2..2: upgrade slscand on the board
// to >= 0.2.0". Empty if the ranges overlap.
std::string version_skew_message(VersionRange host, std::string_view host_software, VersionRange board,
                                 std::string_view board_name, std::string_view board_software);

// A Hello carrying this build's protocol versions.
pb::Hello make_hello(std::string client_name, std::string software_version, std::uint64_t capabilities = 0,
                     std::string auth_token = {}, std::string expected_board = {});

// Client side: sends `hello`, waits for the reply. Fails with the server's error code/text
// if it rejected us (e.g. Errc::unauthorized; Errc::wrong_version with version_skew_message's
// text), with Errc::wrong_version if the reply names a version outside the hello's range, Errc::unsupported if
// hello.board_name is set and the server is a different board.
Result<pb::HelloReply> client_handshake(Connection& connection, const pb::Hello& hello,
                                        std::chrono::milliseconds timeout = default_handshake_timeout);

struct ServerIdentity {
  std::string board_name;
  std::string software_version;
  std::uint64_t capabilities = 0;
  pb::CameraInfo camera;
  std::uint32_t projector_count = 0;
  std::string auth_token;  // "" = no token required
  VersionRange versions;   // what this server speaks (tests play other builds with it)
  std::uint32_t pattern_exposure_us = 0, pattern_period_us = 0;  // the board file's timing
};

// Server side: waits for Hello, checks the version range and the token (constant-time
// compare), answers. On acceptance returns the client's Hello; on rejection sends the reply
// with the reason, closes the connection and returns the reason as the error. `admit`, when
// given, is asked last, before the accepting reply goes out: a server's own limits (e.g. the
// connections it serves) refuse the hello with its error instead of accepting it first.
Result<pb::Hello> server_handshake(Connection& connection, const ServerIdentity& identity,
                                   std::chrono::milliseconds timeout = default_handshake_timeout,
                                   const std::function<Status()>& admit = {});

}  // namespace slproto
