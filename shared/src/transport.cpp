#include "slproto/transport.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/uio.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <condition_variable>
#include <cstring>
#include <mutex>
#include <thread>

#include "slproto/capture.hpp"
#include "slproto/crc32c.hpp"
#include "slproto/file_util.hpp"

namespace slproto {
namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

std::uint64_t monotonic_ns() {
  return static_cast<std::uint64_t>(
      std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch()).count());
}

int remaining_ms(Clock::time_point deadline) {
  const auto left = std::chrono::duration_cast<milliseconds>(deadline - Clock::now()).count() + 1;
  return static_cast<int>(std::clamp<long long>(left, 0, 1 << 30));
}

std::string format_address(const sockaddr* address) {
  char host[INET6_ADDRSTRLEN] = "?";
  std::uint16_t port = 0;
  if (address->sa_family == AF_INET) {
    const auto* in = reinterpret_cast<const sockaddr_in*>(address);
    inet_ntop(AF_INET, &in->sin_addr, host, sizeof host);
    port = ntohs(in->sin_port);
    return std::string(host) + ":" + std::to_string(port);
  }
  if (address->sa_family == AF_INET6) {
    const auto* in6 = reinterpret_cast<const sockaddr_in6*>(address);
    inet_ntop(AF_INET6, &in6->sin6_addr, host, sizeof host);
    port = ntohs(in6->sin6_port);
    // Appended piece by piece: `"[" + std::string(...)` trips GCC 12's -Wrestrict false
    // positive (GCC PR 105329) in the -O2 cross builds.
    std::string text = "[";
    text += host;
    text += "]:";
    text += std::to_string(port);
    return text;
  }
  return "unknown address";
}

Status set_nonblocking(int fd) {
  const int flags = fcntl(fd, F_GETFL, 0);
  if (flags < 0 || fcntl(fd, F_SETFL, flags | O_NONBLOCK) < 0)
    return make_error(Errc::io_error, "fcntl(O_NONBLOCK): " + errno_text(errno));
  return Ok{};
}

void tune_socket(int fd, const ConnectionOptions& options) {
  const int one = 1;
  setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  // The FORCE variants exceed net.core.{r,w}mem_max when we may (root on the board); if not,
  // leave the kernel's autotuning alone: a capped explicit size would switch it off.
  if (options.socket_buffer_bytes > 0) {
    setsockopt(fd, SOL_SOCKET, SO_SNDBUFFORCE, &options.socket_buffer_bytes, sizeof options.socket_buffer_bytes);
    setsockopt(fd, SOL_SOCKET, SO_RCVBUFFORCE, &options.socket_buffer_bytes, sizeof options.socket_buffer_bytes);
  }
  // The kernel's backstop only: on Linux 6.1 a zero receive window (a live peer that is busy and
  // reads nothing for a while) counts against TCP_USER_TIMEOUT too, so at peer_timeout it would
  // cut a connection that is merely back-pressured. Our own checks tell the two apart (a stalled
  // send asks whether the peer still sends, receive() watches its heartbeats) within
  // peer_timeout; the kernel steps in only after a whole send timeout.
  const unsigned user_timeout =
      static_cast<unsigned>(std::max<long long>({options.peer_timeout.count(), default_send_timeout.count(), 1}));
  setsockopt(fd, IPPROTO_TCP, TCP_USER_TIMEOUT, &user_timeout, sizeof user_timeout);
}

Result<addrinfo*> resolve(const std::string& host, std::uint16_t port, bool passive) {
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = passive ? AI_PASSIVE : 0;
  addrinfo* list = nullptr;
  const std::string service = std::to_string(port);
  const int rc = getaddrinfo(host.empty() ? nullptr : host.c_str(), service.c_str(), &hints, &list);
  if (rc != 0 || list == nullptr)
    return make_error(Errc::invalid_argument, "cannot resolve \"" + host + "\": " + gai_strerror(rc));
  return list;
}

}  // namespace

struct Connection::Impl {
  int fd = -1;
  ConnectionOptions options;
  std::string peer;

  std::mutex send_mutex;
  std::vector<std::byte> send_prefix;  // guarded by send_mutex
  std::atomic<std::uint64_t> last_send_ns{0};
  std::atomic<std::uint64_t> heartbeat_sequence{0};

  std::mutex receive_mutex;
  StreamDecoder decoder;
  // Written by the receiving thread, read by a sending one (a stalled send asks whether the peer
  // is still alive).
  std::atomic<std::uint64_t> last_receive_ns{0};
  CaptureWriter* capture = nullptr;

  std::mutex heartbeat_mutex;
  std::condition_variable heartbeat_wake;
  bool stopping = false;  // guarded by heartbeat_mutex
  std::thread heartbeat_thread;

  std::atomic<bool> open{false};
  std::atomic<std::uint64_t> bytes_sent{0}, bytes_received{0}, messages_sent{0}, messages_received{0},
      heartbeats_sent{0}, heartbeats_received{0};

  Impl(int socket_fd, ConnectionOptions opts) : fd(socket_fd), options(opts), decoder(opts.limits) {}

  ~Impl() {
    stop_heartbeats();
    if (fd >= 0) ::close(fd);
  }

  void stop_heartbeats() {
    {
      std::lock_guard lock(heartbeat_mutex);
      stopping = true;
    }
    heartbeat_wake.notify_all();
    if (heartbeat_thread.joinable() && heartbeat_thread.get_id() != std::this_thread::get_id()) heartbeat_thread.join();
  }

  void start_heartbeats() {
    heartbeat_thread = std::thread([this] { heartbeat_loop(); });
  }

  void heartbeat_loop() {
    const auto interval = options.heartbeat_interval;
    std::unique_lock lock(heartbeat_mutex);
    while (!stopping) {
      heartbeat_wake.wait_for(lock, interval / 4);
      if (stopping) break;
      const std::uint64_t now = monotonic_ns();
      const auto interval_ns = static_cast<std::uint64_t>(std::chrono::nanoseconds(interval).count());
      if (now - last_send_ns.load() < interval_ns) continue;
      // A send in progress is itself a sign of life; never queue behind it.
      std::unique_lock send_lock(send_mutex, std::try_to_lock);
      if (!send_lock.owns_lock()) continue;
      lock.unlock();
      pb::Heartbeat heartbeat;
      heartbeat.set_sequence(heartbeat_sequence++);
      heartbeat.set_monotonic_ns(now);
      const Status status = send_locked(MessageType::heartbeat, heartbeat, {}, 0, options.peer_timeout);
      send_lock.unlock();
      lock.lock();
      if (!status) break;  // the connection is gone; receive() and send() report it
      ++heartbeats_sent;
    }
  }

  // Sends header + control + payload; caller holds send_mutex. A failure part-way leaves the
  // stream without framing, so it shuts the socket down.
  Status send_locked(MessageType type, const google::protobuf::MessageLite& control, std::span<const std::byte> payload,
                     std::uint32_t payload_crc, milliseconds timeout) {
    if (!open.load()) return make_error(Errc::disconnected, "connection to " + peer + " is closed");
    send_prefix.clear();
    if (Status status =
            encode_prefix(type, control, static_cast<std::uint32_t>(payload.size()), payload_crc, send_prefix);
        !status)
      return status;
    iovec iov[2];
    iov[0].iov_base = send_prefix.data();
    iov[0].iov_len = send_prefix.size();
    iov[1].iov_base = const_cast<std::byte*>(payload.data());  // sendmsg does not write through it
    iov[1].iov_len = payload.size();
    int iov_count = payload.empty() ? 1 : 2;
    iovec* next = iov;
    const std::size_t total = send_prefix.size() + payload.size();
    std::size_t sent = 0;
    const auto deadline = Clock::now() + timeout;
    auto last_progress = Clock::now();
    while (sent < total) {
      msghdr message{};
      message.msg_iov = next;
      message.msg_iovlen = static_cast<std::size_t>(iov_count);
      const ssize_t n = ::sendmsg(fd, &message, MSG_NOSIGNAL | MSG_DONTWAIT);
      if (n > 0) {
        sent += static_cast<std::size_t>(n);
        bytes_sent += static_cast<std::uint64_t>(n);
        last_progress = Clock::now();
        auto left = static_cast<std::size_t>(n);
        while (iov_count > 0 && left >= next->iov_len) {
          left -= next->iov_len;
          ++next;
          --iov_count;
        }
        if (iov_count > 0) {
          next->iov_base = static_cast<char*>(next->iov_base) + left;
          next->iov_len -= left;
        }
        continue;
      }
      if (n < 0 && errno == EINTR) continue;
      if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK) {
        const int error = errno;
        return broken(make_error(Errc::disconnected, std::string("sending ") + message_type_name(type) + " to " + peer +
                                                         ": " + errno_text(error)),
                      sent);
      }
      // A peer that reads nothing but still sends (its heartbeats arrive) is alive and busy:
      // that is back-pressure, and the send waits for it up to `timeout`. Only a peer that
      // neither reads nor sends for peer_timeout is gone.
      const auto stall_deadline = last_progress + options.peer_timeout;
      const auto now = Clock::now();
      if (now >= deadline)
        return broken(make_error(Errc::timeout, std::string("sending ") + message_type_name(type) + " to " + peer +
                                                    ": not done after " + std::to_string(timeout.count()) +
                                                    " ms (the peer is alive but reads too slowly)"),
                      sent);
      const std::uint64_t now_ns = monotonic_ns();
      const std::uint64_t heard_ns = last_receive_ns.load();
      const bool peer_silent = now_ns - std::min(now_ns, heard_ns) >=
                               static_cast<std::uint64_t>(std::chrono::nanoseconds(options.peer_timeout).count());
      if (now >= stall_deadline && peer_silent)
        return broken(make_error(Errc::disconnected, std::string("sending ") + message_type_name(type) + " to " + peer +
                                                         ": the peer accepted no data and sent none for " +
                                                         std::to_string(options.peer_timeout.count()) + " ms"),
                      sent);
      pollfd waiter{fd, POLLOUT, 0};
      ::poll(&waiter, 1, std::min({remaining_ms(deadline), std::max(remaining_ms(stall_deadline), 1), 50}));
    }
    last_send_ns = monotonic_ns();
    ++messages_sent;
    return Ok{};
  }

  Status broken(Error error, std::size_t sent_of_record) {
    // Nothing of the record went out: the stream is still framed and usable (a plain timeout).
    if (sent_of_record == 0 && error.code == Errc::timeout) return error;
    open = false;
    ::shutdown(fd, SHUT_RDWR);
    return error;
  }

  Status send(MessageType type, const google::protobuf::MessageLite& control, std::span<const std::byte> payload,
              std::uint32_t payload_crc, milliseconds timeout) {
    std::unique_lock lock(send_mutex, std::defer_lock);
    // A bounded wait for a concurrent sender (e.g. a heartbeat) keeps the timeout honest.
    const auto deadline = Clock::now() + timeout;
    while (!lock.try_lock()) {
      if (Clock::now() >= deadline)
        return make_error(Errc::timeout, std::string("sending ") + message_type_name(type) +
                                             ": another send held the connection for " +
                                             std::to_string(timeout.count()) + " ms");
      std::this_thread::sleep_for(std::chrono::microseconds(200));
    }
    const auto left = std::chrono::duration_cast<milliseconds>(deadline - Clock::now());
    return send_locked(type, control, payload, payload_crc, std::max(left, milliseconds{0}));
  }

  Result<Message> receive(milliseconds timeout) {
    std::lock_guard lock(receive_mutex);
    decoder.next();
    const auto deadline = Clock::now() + timeout;
    const auto peer_timeout_ns = static_cast<std::uint64_t>(std::chrono::nanoseconds(options.peer_timeout).count());
    while (true) {
      if (decoder.failed()) return make_error(Errc::disconnected, "connection to " + peer + " lost its framing");
      if (!open.load()) return make_error(Errc::disconnected, "connection to " + peer + " is closed");
      // Chunks that fit in L2: the CRC reads the bytes while recv() has just left them in cache.
      const std::span<std::byte> window = decoder.window(std::size_t{256} << 10);
      const ssize_t n = ::recv(fd, window.data(), window.size(), MSG_DONTWAIT);
      if (n > 0) {
        last_receive_ns = monotonic_ns();
        bytes_received += static_cast<std::uint64_t>(n);
        if (Status status = decoder.commit(static_cast<std::size_t>(n)); !status) {
          open = false;
          ::shutdown(fd, SHUT_RDWR);
          return make_error(status.error().code, "from " + peer + ": " + status.error().message);
        }
        if (!decoder.message_ready()) continue;
        const Message& message = decoder.message();
        if (capture != nullptr) {
          if (Status status = capture->append(message); !status) {
            capture = nullptr;
            return make_error(Errc::io_error, "recording the stream: " + status.error().message);
          }
        }
        if (message.type() == MessageType::heartbeat) {
          ++heartbeats_received;
          if (!options.deliver_heartbeats) {
            decoder.next();
            continue;
          }
        }
        ++messages_received;
        return message;
      }
      if (n == 0) {
        open = false;
        if (decoder.at_boundary()) return make_error(Errc::disconnected, peer + " closed the connection");
        return make_error(Errc::disconnected,
                          peer + " closed the connection in the middle of a record at stream offset " +
                              std::to_string(decoder.record_offset()) + " (" + decoder.describe_partial() + ")");
      }
      if (errno == EINTR) continue;
      if (errno != EAGAIN && errno != EWOULDBLOCK) {
        const int error = errno;
        open = false;
        return make_error(Errc::disconnected, "receiving from " + peer + ": " + errno_text(error));
      }
      const std::uint64_t now = monotonic_ns();
      const std::uint64_t silent_ns = now - std::min(now, last_receive_ns.load());
      if (silent_ns >= peer_timeout_ns) {
        open = false;
        ::shutdown(fd, SHUT_RDWR);
        return make_error(Errc::disconnected, "no data from " + peer + " for " + std::to_string(silent_ns / 1000000) +
                                                  " ms (peer gone: heartbeats stopped)");
      }
      if (Clock::now() >= deadline) {
        if (timeout.count() == 0) return make_error(Errc::timeout, "no complete record from " + peer + " yet");
        return make_error(Errc::timeout,
                          "no complete record from " + peer + " within " + std::to_string(timeout.count()) + " ms");
      }
      const int silence_left_ms = static_cast<int>((peer_timeout_ns - silent_ns) / 1000000 + 1);
      pollfd waiter{fd, POLLIN, 0};
      ::poll(&waiter, 1, std::min(remaining_ms(deadline), silence_left_ms));
    }
  }

  void close() {
    stop_heartbeats();
    if (!open.exchange(false)) return;
    std::unique_lock send_lock(send_mutex, std::try_to_lock);
    if (!send_lock.owns_lock()) {
      // A send is mid-record: the peer will see a truncated record either way.
      ::shutdown(fd, SHUT_RDWR);
      return;
    }
    // Clean end: FIN after our last complete record, then wait (bounded) for the peer's FIN
    // so unread data on our side does not turn the close into a reset that could discard
    // what the peer has not read yet.
    ::shutdown(fd, SHUT_WR);
    std::unique_lock receive_lock(receive_mutex, std::try_to_lock);
    if (receive_lock.owns_lock()) {
      // Bounded so close() stays quick when the peer is slow to close its side.
      const auto deadline = Clock::now() + std::min(options.peer_timeout, milliseconds{250});
      std::byte sink[4096];
      while (Clock::now() < deadline) {
        pollfd waiter{fd, POLLIN, 0};
        if (::poll(&waiter, 1, remaining_ms(deadline)) <= 0) break;
        const ssize_t n = ::recv(fd, sink, sizeof sink, MSG_DONTWAIT);
        if (n == 0 || (n < 0 && errno != EINTR && errno != EAGAIN)) break;
      }
    }
    ::shutdown(fd, SHUT_RDWR);
  }
};

Connection::Connection() = default;
Connection::~Connection() {
  if (impl_) impl_->close();
}
Connection::Connection(Connection&&) noexcept = default;
Connection& Connection::operator=(Connection&& other) noexcept {
  if (this != &other) {
    if (impl_) impl_->close();
    impl_ = std::move(other.impl_);
  }
  return *this;
}
Connection::Connection(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

Result<Connection> Connection::adopt(int socket_fd, ConnectionOptions options) {
  if (socket_fd < 0) return make_error(Errc::invalid_argument, "adopt: invalid socket");
  if (options.heartbeat_interval.count() <= 0 || options.peer_timeout <= options.heartbeat_interval) {
    ::close(socket_fd);
    return make_error(Errc::invalid_argument, "connection options: need 0 < heartbeat_interval (" +
                                                  std::to_string(options.heartbeat_interval.count()) +
                                                  " ms) < peer_timeout (" +
                                                  std::to_string(options.peer_timeout.count()) + " ms)");
  }
  if (Status status = set_nonblocking(socket_fd); !status) {
    ::close(socket_fd);
    return status.error();
  }
  tune_socket(socket_fd, options);
  auto impl = std::make_unique<Impl>(socket_fd, options);
  sockaddr_storage address{};
  socklen_t length = sizeof address;
  impl->peer = getpeername(socket_fd, reinterpret_cast<sockaddr*>(&address), &length) == 0
                   ? format_address(reinterpret_cast<sockaddr*>(&address))
                   : std::string("unconnected peer");
  impl->open = true;
  impl->last_receive_ns = monotonic_ns();
  impl->last_send_ns = monotonic_ns();
  impl->start_heartbeats();
  return Connection(std::move(impl));
}

Status Connection::send(const Body& body, std::chrono::milliseconds timeout) {
  if (const auto* frame = std::get_if<pb::FrameHeader>(&body))
    return make_error(Errc::invalid_argument, "send: use send_frame() for frame " + std::to_string(frame->sequence()));
  return send_record(type_of(body), as_message_lite(body), {}, timeout);
}

Status Connection::send_frame(const pb::FrameHeader& header, std::span<const std::byte> payload,
                              std::chrono::milliseconds timeout) {
  if (!impl_) return make_error(Errc::disconnected, "send_frame: not connected");
  if (Status status = check_frame_geometry(header, payload.size()); !status)
    return make_error(status.error().code, "send_frame: " + status.error().message);
  const std::uint32_t payload_crc = crc32c(payload);
  pb::FrameHeader stamped = header;
  stamped.set_payload_crc32c(payload_crc);
  return impl_->send(MessageType::frame, stamped, payload, payload_crc, timeout);
}

Status Connection::send_record(MessageType type, const google::protobuf::MessageLite& control,
                               std::span<const std::byte> payload, std::chrono::milliseconds timeout) {
  if (!impl_) return make_error(Errc::disconnected, "send: not connected");
  if (type == MessageType::frame) {
    const auto* frame = dynamic_cast<const pb::FrameHeader*>(&control);
    if (frame == nullptr) return make_error(Errc::invalid_argument, "send_record: a frame record needs a FrameHeader");
    return send_frame(*frame, payload, timeout);
  }
  if (!payload.empty())
    return make_error(Errc::invalid_argument,
                      std::string("send: a ") + message_type_name(type) + " record cannot carry a payload");
  return impl_->send(type, control, {}, 0, timeout);
}

Result<Message> Connection::receive(std::chrono::milliseconds timeout) {
  if (!impl_) return make_error(Errc::disconnected, "receive: not connected");
  return impl_->receive(timeout);
}

void Connection::record_to(CaptureWriter* capture) {
  if (!impl_) return;
  std::lock_guard lock(impl_->receive_mutex);
  impl_->capture = capture;
}

void Connection::interrupt() noexcept {
  // The descriptor is closed only by ~Impl, so it cannot have been reused meanwhile.
  if (impl_ && impl_->open.load()) ::shutdown(impl_->fd, SHUT_RDWR);
}

void Connection::close() {
  if (impl_) impl_->close();
}
bool Connection::is_open() const noexcept { return impl_ && impl_->open.load(); }
std::string Connection::peer_address() const { return impl_ ? impl_->peer : std::string("not connected"); }
ConnectionStats Connection::stats() const {
  if (!impl_) return {};
  return ConnectionStats{impl_->bytes_sent.load(),      impl_->bytes_received.load(),
                         impl_->messages_sent.load(),   impl_->messages_received.load(),
                         impl_->heartbeats_sent.load(), impl_->heartbeats_received.load()};
}
const ConnectionOptions& Connection::options() const {
  static const ConnectionOptions defaults;
  return impl_ ? impl_->options : defaults;
}

// ---- Server

Server::Server() = default;
Server::~Server() { close(); }
Server::Server(Server&& other) noexcept
    : fd_(std::exchange(other.fd_, -1)), port_(other.port_), options_(other.options_) {}
Server& Server::operator=(Server&& other) noexcept {
  if (this != &other) {
    close();
    fd_ = std::exchange(other.fd_, -1);
    port_ = other.port_;
    options_ = other.options_;
  }
  return *this;
}

void Server::close() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

std::uint16_t Server::port() const noexcept { return port_; }

Result<Server> Server::listen(const std::string& address, std::uint16_t port, ServerOptions options) {
  Result<addrinfo*> list = resolve(address, port, true);
  if (!list) return std::move(list).error();
  std::string last_error = "no address";
  for (addrinfo* ai = *list; ai != nullptr; ai = ai->ai_next) {
    const int fd = ::socket(ai->ai_family, ai->ai_socktype | SOCK_CLOEXEC | SOCK_NONBLOCK, ai->ai_protocol);
    if (fd < 0) {
      last_error = "socket: " + errno_text(errno);
      continue;
    }
    const int one = 1;
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    if (::bind(fd, ai->ai_addr, ai->ai_addrlen) != 0 || ::listen(fd, options.backlog) != 0) {
      last_error = "bind/listen on " + format_address(ai->ai_addr) + ": " + errno_text(errno);
      ::close(fd);
      continue;
    }
    sockaddr_storage bound{};
    socklen_t length = sizeof bound;
    getsockname(fd, reinterpret_cast<sockaddr*>(&bound), &length);
    Server server;
    server.fd_ = fd;
    server.options_ = options;
    server.port_ = bound.ss_family == AF_INET6 ? ntohs(reinterpret_cast<sockaddr_in6*>(&bound)->sin6_port)
                                               : ntohs(reinterpret_cast<sockaddr_in*>(&bound)->sin_port);
    freeaddrinfo(*list);
    return server;
  }
  freeaddrinfo(*list);
  return make_error(Errc::io_error, "listen on " + address + ":" + std::to_string(port) + ": " + last_error);
}

Result<Connection> Server::accept(std::chrono::milliseconds timeout) {
  if (fd_ < 0) return make_error(Errc::disconnected, "accept: server is closed");
  const auto deadline = Clock::now() + timeout;
  while (true) {
    const int fd = ::accept4(fd_, nullptr, nullptr, SOCK_CLOEXEC | SOCK_NONBLOCK);
    if (fd >= 0) return Connection::adopt(fd, options_.connection);
    if (errno == EINTR || errno == ECONNABORTED) continue;
    if (errno != EAGAIN && errno != EWOULDBLOCK) return make_error(Errc::io_error, "accept: " + errno_text(errno));
    if (Clock::now() >= deadline)
      return make_error(Errc::timeout, "no client connected within " + std::to_string(timeout.count()) + " ms");
    pollfd waiter{fd_, POLLIN, 0};
    ::poll(&waiter, 1, remaining_ms(deadline));
  }
}

Result<Connection> connect(const std::string& host, std::uint16_t port, std::chrono::milliseconds timeout,
                           ConnectionOptions options) {
  const auto deadline = Clock::now() + timeout;
  Result<addrinfo*> list = resolve(host, port, false);
  if (!list) return std::move(list).error();
  Error last = make_error(Errc::disconnected, "no address for " + host);
  for (addrinfo* ai = *list; ai != nullptr; ai = ai->ai_next) {
    const std::string where = format_address(ai->ai_addr);
    const int fd = ::socket(ai->ai_family, ai->ai_socktype | SOCK_CLOEXEC | SOCK_NONBLOCK, ai->ai_protocol);
    if (fd < 0) {
      last = make_error(Errc::io_error, "socket: " + errno_text(errno));
      continue;
    }
    int rc = ::connect(fd, ai->ai_addr, ai->ai_addrlen);
    if (rc != 0 && errno == EINPROGRESS) {
      pollfd waiter{fd, POLLOUT, 0};
      while ((rc = ::poll(&waiter, 1, remaining_ms(deadline))) < 0 && errno == EINTR) {
      }
      if (rc == 0) {
        ::close(fd);
        last = make_error(Errc::timeout,
                          "connect to " + where + ": no answer within " + std::to_string(timeout.count()) + " ms");
        continue;
      }
      int error = 0;
      socklen_t length = sizeof error;
      getsockopt(fd, SOL_SOCKET, SO_ERROR, &error, &length);
      rc = error == 0 ? 0 : -1;
      errno = error;
    }
    if (rc != 0) {
      last = make_error(Errc::disconnected, "connect to " + where + ": " + errno_text(errno));
      ::close(fd);
      continue;
    }
    freeaddrinfo(*list);
    return Connection::adopt(fd, options);
  }
  freeaddrinfo(*list);
  return last;
}

}  // namespace slproto
