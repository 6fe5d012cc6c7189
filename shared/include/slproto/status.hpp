// Status (protocol >= 2): the host asks a board what it is and what it did last, on a connection
// that finished its hello exchange.
#pragma once

#include <chrono>

#include "slproto/result.hpp"
#include "slproto/transport.hpp"

namespace slproto {

// Sends StatusRequest and waits for StatusReply, skipping Progress records of a scan the same
// connection may be running. A board that negotiated a version before status existed is not
// asked (it would reject the unknown record and close): Errc::wrong_version naming the board's
// versions and the release to upgrade slscand to.
Result<pb::StatusReply> request_status(Connection& connection, const pb::HelloReply& hello_reply,
                                       std::chrono::milliseconds timeout = std::chrono::seconds(3));

}  // namespace slproto
