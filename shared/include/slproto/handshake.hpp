// The hello exchange that opens every connection: the host (client) sends Hello, the board
// (server) answers HelloReply and, if it rejects the hello, closes the connection.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>

#include "slproto/result.hpp"
#include "slproto/transport.hpp"

namespace slproto {

inline constexpr std::chrono::milliseconds default_handshake_timeout{3000};

// A Hello carrying this build's protocol versions.
pb::Hello make_hello(std::string client_name, std::string software_version, std::uint64_t capabilities = 0,
                     std::string auth_token = {}, std::string expected_board = {});

// Client side: sends `hello`, waits for the reply. Fails with the server's error code/text
// if it rejected us (e.g. Errc::unauthorized, Errc::wrong_version), with Errc::wrong_version
// if the reply names a version we do not speak, Errc::unsupported if hello.board_name is set
// and the server is a different board.
Result<pb::HelloReply> client_handshake(Connection& connection, const pb::Hello& hello,
                                        std::chrono::milliseconds timeout = default_handshake_timeout);

struct ServerIdentity {
  std::string board_name;
  std::string software_version;
  std::uint64_t capabilities = 0;
  pb::CameraInfo camera;
  std::uint32_t projector_count = 0;
  std::string auth_token;  // "" = no token required
};

// Server side: waits for Hello, checks the version range and the token (constant-time
// compare), answers. On acceptance returns the client's Hello; on rejection sends the reply
// with the reason, closes the connection and returns the reason as the error.
Result<pb::Hello> server_handshake(Connection& connection, const ServerIdentity& identity,
                                   std::chrono::milliseconds timeout = default_handshake_timeout);

}  // namespace slproto
