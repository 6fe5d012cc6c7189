#include "slproto/status.hpp"

#include "slproto/handshake.hpp"

namespace slproto {

Result<pb::StatusReply> request_status(Connection& connection, const pb::HelloReply& hello_reply,
                                       std::chrono::milliseconds timeout) {
  if (hello_reply.protocol_version() < status_protocol_version) {
    const std::uint32_t board_max = hello_reply.protocol_version();
    const std::uint32_t board_min =
        hello_reply.min_protocol_version() != 0 ? hello_reply.min_protocol_version() : board_max;
    return make_error(Errc::wrong_version,
                      "board '" + hello_reply.board_name() + "' (" + hello_reply.software_version() +
                          ") speaks slproto " + std::to_string(board_min) + ".." + std::to_string(board_max) +
                          "; status needs slproto >= " + std::to_string(status_protocol_version) +
                          ": upgrade slscand on the board to >= " + first_release_speaking(status_protocol_version));
  }
  if (Status sent = connection.send(pb::StatusRequest{}, timeout); !sent) return sent.error();
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  for (;;) {
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now());
    if (left <= std::chrono::milliseconds(0))
      return make_error(Errc::timeout, "no status reply from " + connection.peer_address() + " within " +
                                           std::to_string(timeout.count()) + " ms");
    Result<Message> message = connection.receive(left);
    if (!message) return std::move(message).error();
    if (const auto* reply = message->get<pb::StatusReply>()) return *reply;
    if (const auto* error = message->get<pb::Error>()) return from_proto(*error);
    // Progress, frames and ScanDone of a running scan on this connection are not ours.
  }
}

}  // namespace slproto
