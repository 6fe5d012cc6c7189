// TCP transport: the board (slscand) runs a Server, the host connects with connect().
// Both ends then hold a Connection that sends and receives framed records.
//
// Liveness: each Connection runs a small heartbeat thread that sends a Heartbeat record when
// nothing else was sent for `heartbeat_interval`. receive() reports Errc::disconnected when
// no byte at all arrived for `peer_timeout` (the peer vanished without closing: power loss,
// cable pulled, process frozen); a send that makes no progress for `peer_timeout` reports
// Errc::disconnected too (peer neither reading nor sending) -- a peer that reads nothing but
// whose heartbeats still arrive is busy, not gone, and the send waits for it up to its timeout
// (back-pressure). A peer that closes or crashes is seen at once. TCP_USER_TIMEOUT (the larger
// of peer_timeout and default_send_timeout) is the kernel's backstop.
//
// Threads: one thread may send while another receives; sends are serialised internally;
// receive() must not be called from two threads at once. close() may be called from any
// thread (it wakes a receive() blocked in another, which then reports Errc::disconnected);
// destroy the Connection only once no other thread uses it.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <span>
#include <string>

#include "slproto/framing.hpp"
#include "slproto/messages.hpp"
#include "slproto/result.hpp"

namespace slproto {

class CaptureWriter;

struct ConnectionOptions {
  std::chrono::milliseconds heartbeat_interval{200};
  std::chrono::milliseconds peer_timeout{800};  // must exceed heartbeat_interval
  int socket_buffer_bytes = 8 << 20;            // SO_SNDBUF / SO_RCVBUF request
  DecoderLimits limits;
  // Deliver received Heartbeat records from receive() (normally they are consumed silently).
  bool deliver_heartbeats = false;
};

struct ConnectionStats {
  std::uint64_t bytes_sent = 0;
  std::uint64_t bytes_received = 0;
  std::uint64_t messages_sent = 0;
  std::uint64_t messages_received = 0;
  std::uint64_t heartbeats_sent = 0;
  std::uint64_t heartbeats_received = 0;
};

inline constexpr std::chrono::milliseconds default_send_timeout{10000};

class Connection {
 public:
  Connection();  // not connected: every call returns Errc::disconnected
  ~Connection();
  Connection(Connection&&) noexcept;
  Connection& operator=(Connection&&) noexcept;
  Connection(const Connection&) = delete;
  Connection& operator=(const Connection&) = delete;

  // Takes ownership of a connected TCP socket (tests, custom set-ups).
  static Result<Connection> adopt(int socket_fd, ConnectionOptions options = {});

  // Sends one control message (no payload). `timeout` bounds the whole send.
  template <ControlMessage T>
  Status send(const T& message, std::chrono::milliseconds timeout = default_send_timeout) {
    return send_record(message_type_v<T>, message, {}, timeout);
  }
  Status send(const Body& body, std::chrono::milliseconds timeout = default_send_timeout);

  // Sends a frame: header then the payload straight from `payload` (writev, no copy).
  // Checks the geometry (check_frame_geometry) and sets header.payload_crc32c from the payload
  // (a copy of the header is sent; the caller's stays unchanged).
  Status send_frame(const pb::FrameHeader& header, std::span<const std::byte> payload,
                    std::chrono::milliseconds timeout = default_send_timeout);

  // Any record type with an optional payload (the payload is only legal for frames).
  Status send_record(MessageType type, const google::protobuf::MessageLite& control, std::span<const std::byte> payload,
                     std::chrono::milliseconds timeout);

  // Waits up to `timeout` for the next record. Errors: timeout (nothing complete in time, the
  // connection stays usable), disconnected (peer closed, reset or silent for peer_timeout),
  // and the decoder's malformed / wrong_version / oversized / bad_checksum (the connection is
  // closed: framing is lost). The message's payload lives in a buffer reused by the next
  // receive(). timeout = 0 polls without blocking.
  Result<Message> receive(std::chrono::milliseconds timeout);

  // Receives until a record of type T arrives; other record types are an Errc::malformed
  // error naming what came instead, except pb::Error which is returned as its code + text.
  template <ControlMessage T>
  Result<T> receive_as(std::chrono::milliseconds timeout);

  // Every complete record received from now on (including heartbeats) is appended to
  // `capture` exactly as received, before receive() returns it. nullptr stops recording.
  // A capture write error is returned by receive() (Errc::io_error) and stops recording.
  void record_to(CaptureWriter* capture);

  // Stops the heartbeat thread, shuts the socket down for writing (the peer reads a clean
  // end of stream after the last record) and closes it. Idempotent.
  void close();
  // Safe from another thread while this one is in receive() or send(): shuts the socket down
  // both ways, so they return Errc::disconnected at once (a server dropping a connection that
  // is served elsewhere). The owner still calls close(); the object must outlive the call.
  void interrupt() noexcept;
  bool is_open() const noexcept;
  std::string peer_address() const;
  ConnectionStats stats() const;
  const ConnectionOptions& options() const;

 private:
  struct Impl;
  explicit Connection(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

struct ServerOptions {
  ConnectionOptions connection;
  int backlog = 4;
};

class Server {
 public:
  Server();
  ~Server();
  Server(Server&&) noexcept;
  Server& operator=(Server&&) noexcept;
  Server(const Server&) = delete;
  Server& operator=(const Server&) = delete;

  // Binds and listens. address: an IPv4/IPv6 literal or host name ("0.0.0.0", "::",
  // "127.0.0.1", "localhost"); port 0 picks a free port (see port()).
  static Result<Server> listen(const std::string& address, std::uint16_t port, ServerOptions options = {});
  std::uint16_t port() const noexcept;
  // Waits up to `timeout` for a client; Errc::timeout if none came.
  Result<Connection> accept(std::chrono::milliseconds timeout);
  void close();

 private:
  int fd_ = -1;
  std::uint16_t port_ = 0;
  ServerOptions options_;
};

// Connects to host:port within `timeout` (name resolution included).
Result<Connection> connect(const std::string& host, std::uint16_t port, std::chrono::milliseconds timeout,
                           ConnectionOptions options = {});

// ---- implementation of the template

template <ControlMessage T>
Result<T> Connection::receive_as(std::chrono::milliseconds timeout) {
  Result<Message> message = receive(timeout);
  if (!message) return std::move(message).error();
  if (const T* wanted = message->template get<T>()) return *wanted;
  if (const pb::Error* error = message->template get<pb::Error>()) return from_proto(*error);
  return make_error(Errc::malformed, std::string("expected a ") + message_type_name(message_type_v<T>) +
                                         " record, got " + message_type_name(message->type()) + " at stream offset " +
                                         std::to_string(message->stream_offset));
}

}  // namespace slproto
