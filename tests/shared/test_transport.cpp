#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <cstring>
#include <filesystem>
#include <future>
#include <thread>

#include "sample_messages.hpp"
#include "slproto/capture.hpp"
#include "slproto/crc32c.hpp"
#include "slproto/handshake.hpp"
#include "slproto/transport.hpp"

namespace {

using namespace slproto;
using namespace std::chrono_literals;
using ::testing::HasSubstr;
using Clock = std::chrono::steady_clock;

struct Pair {
  Server server;
  Connection board;  // server side
  Connection host;   // client side
};

Pair connected_pair(ConnectionOptions options = {}) {
  Pair pair;
  ServerOptions server_options;
  server_options.connection = options;
  Result<Server> server = Server::listen("127.0.0.1", 0, server_options);
  EXPECT_TRUE(server.ok()) << server.error().message;
  pair.server = std::move(server).value();
  auto accepted = std::async(std::launch::async, [&] { return pair.server.accept(5s); });
  Result<Connection> host = connect("127.0.0.1", pair.server.port(), 5s, options);
  EXPECT_TRUE(host.ok()) << host.error().message;
  Result<Connection> board = accepted.get();
  EXPECT_TRUE(board.ok()) << board.error().message;
  pair.host = std::move(host).value();
  pair.board = std::move(board).value();
  return pair;
}

// A raw TCP client that speaks no protocol at all: connects and then does what the test says.
int raw_connect(std::uint16_t port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_port = htons(port);
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  EXPECT_EQ(::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address), 0);
  return fd;
}

TEST(Transport, HandshakeAndEveryMessageTypeBothWays) {
  ConnectionOptions options;
  options.deliver_heartbeats = true;  // so the sample heartbeat arrives like any other record
  Pair pair = connected_pair(options);
  ServerIdentity identity{"bench-rig", "slscand 0.1.0", pb::CAPABILITY_TURNTABLE, {}, 2, "s3cret", {}, 8333, 40000};
  identity.camera.set_width(2464);
  auto server_side = std::async(std::launch::async, [&] { return server_handshake(pair.board, identity); });
  Result<pb::HelloReply> reply =
      client_handshake(pair.host, make_hello("test-host", "slscan 0.1.0", 0, "s3cret", "bench-rig"));
  ASSERT_TRUE(reply.ok()) << reply.error().message;
  EXPECT_TRUE(reply->accepted());
  EXPECT_EQ(reply->protocol_version(), protocol_version);
  EXPECT_EQ(reply->board_name(), "bench-rig");
  EXPECT_EQ(reply->camera().width(), 2464u);
  EXPECT_EQ(reply->projector_count(), 2u);
  EXPECT_EQ(reply->pattern_exposure_us(), 8333u);  // the board file's timing, for the host's defaults
  EXPECT_EQ(reply->pattern_period_us(), 40000u);
  Result<pb::Hello> hello = server_side.get();
  ASSERT_TRUE(hello.ok()) << hello.error().message;
  EXPECT_EQ(hello->client_name(), "test-host");

  for (const auto& sample : samples::sample_records()) {
    SCOPED_TRACE(message_type_name(type_of(sample.body)));
    for (Connection* from : {&pair.host, &pair.board}) {
      Connection* to = from == &pair.host ? &pair.board : &pair.host;
      Status sent = sample.payload.empty() ? from->send(sample.body)
                                           : from->send_frame(std::get<pb::FrameHeader>(sample.body), sample.payload);
      ASSERT_TRUE(sent.ok()) << sent.error().message;
      Body expected = sample.body;
      if (auto* frame = std::get_if<pb::FrameHeader>(&expected)) frame->set_payload_crc32c(crc32c(sample.payload));
      const std::string wanted = as_message_lite(expected).SerializeAsString();
      Result<Message> got = to->receive(2s);
      // Skip the transport's own heartbeats (they differ from the sample one).
      while (got.ok() && got->type() == MessageType::heartbeat &&
             as_message_lite(got->body).SerializeAsString() != wanted)
        got = to->receive(2s);
      ASSERT_TRUE(got.ok()) << got.error().message;
      EXPECT_EQ(got->type(), type_of(sample.body));
      EXPECT_EQ(as_message_lite(got->body).SerializeAsString(), wanted);
      EXPECT_TRUE(std::equal(got->payload.begin(), got->payload.end(), sample.payload.begin(), sample.payload.end()));
    }
  }
}

TEST(Transport, HandshakeRejectsWrongTokenAndVersion) {
  {
    Pair pair = connected_pair();
    ServerIdentity identity{"rig", "1", 0, {}, 2, "right", {}, 0, 0};
    auto server_side = std::async(std::launch::async, [&] { return server_handshake(pair.board, identity); });
    Result<pb::HelloReply> reply = client_handshake(pair.host, make_hello("h", "1", 0, "wrong"));
    ASSERT_FALSE(reply.ok());
    EXPECT_EQ(reply.error().code, Errc::unauthorized);
    EXPECT_THAT(reply.error().message, HasSubstr("auth token is wrong"));
    Result<pb::Hello> server_result = server_side.get();
    ASSERT_FALSE(server_result.ok());
    EXPECT_EQ(server_result.error().code, Errc::unauthorized);
    EXPECT_FALSE(pair.board.is_open());
  }
  {
    Pair pair = connected_pair();
    ServerIdentity identity{"rig", "1", 0, {}, 2, "", {}, 0, 0};
    auto server_side = std::async(std::launch::async, [&] { return server_handshake(pair.board, identity); });
    pb::Hello future = make_hello("h", "9");
    future.set_protocol_version(7);
    future.set_min_protocol_version(5);
    Result<pb::HelloReply> reply = client_handshake(pair.host, future);
    ASSERT_FALSE(reply.ok());
    EXPECT_EQ(reply.error().code, Errc::wrong_version);
    EXPECT_THAT(reply.error().message, HasSubstr("5..7"));
    EXPECT_FALSE(server_side.get().ok());
  }
  {
    Pair pair = connected_pair();
    ServerIdentity identity{"rig-a", "1", 0, {}, 2, "", {}};
    auto server_side = std::async(std::launch::async, [&] { return server_handshake(pair.board, identity); });
    Result<pb::HelloReply> reply = client_handshake(pair.host, make_hello("h", "1", 0, "", "rig-b"));
    ASSERT_FALSE(reply.ok());
    EXPECT_EQ(reply.error().code, Errc::unsupported);
    EXPECT_FALSE(server_side.get().ok());
  }
}

// The server's own admission (slscand's connection limit) refuses the hello before it is
// accepted, with its error; it is asked only once the hello itself is acceptable.
TEST(Transport, HandshakeAdmissionRefusesBeforeAccepting) {
  {
    Pair pair = connected_pair();
    ServerIdentity identity{"rig", "1", 0, {}, 2, "", {}, 0, 0};
    int asked = 0;
    auto server_side = std::async(std::launch::async, [&] {
      return server_handshake(pair.board, identity, default_handshake_timeout, [&]() -> Status {
        ++asked;
        return make_error(Errc::busy, "busy: 2 connections (the limit)");
      });
    });
    Result<pb::HelloReply> reply = client_handshake(pair.host, make_hello("h", "1"));
    ASSERT_FALSE(reply.ok());
    EXPECT_EQ(reply.error().code, Errc::busy);
    EXPECT_THAT(reply.error().message, HasSubstr("2 connections (the limit)"));
    EXPECT_EQ(server_side.get().error().code, Errc::busy);
    EXPECT_EQ(asked, 1);
  }
  {
    Pair pair = connected_pair();
    ServerIdentity identity{"rig", "1", 0, {}, 2, "right", {}, 0, 0};
    int asked = 0;
    auto server_side = std::async(std::launch::async, [&] {
      return server_handshake(pair.board, identity, default_handshake_timeout, [&]() -> Status {
        ++asked;
        return {};
      });
    });
    Result<pb::HelloReply> reply = client_handshake(pair.host, make_hello("h", "1", 0, "wrong"));
    EXPECT_EQ(reply.error().code, Errc::unauthorized);
    EXPECT_FALSE(server_side.get().ok());
    EXPECT_EQ(asked, 0) << "a wrong token took an admission";
  }
}

TEST(Transport, ReceiveTimeoutKeepsTheConnectionUsable) {
  Pair pair = connected_pair();
  const auto start = Clock::now();
  Result<Message> nothing = pair.host.receive(150ms);
  ASSERT_FALSE(nothing.ok());
  EXPECT_EQ(nothing.error().code, Errc::timeout);
  EXPECT_GE(Clock::now() - start, 140ms);
  Result<Message> poll = pair.host.receive(0ms);
  ASSERT_FALSE(poll.ok());
  EXPECT_EQ(poll.error().code, Errc::timeout);
  ASSERT_TRUE(pair.board.send(samples::sample_progress()).ok());
  Result<Message> got = pair.host.receive(2s);
  ASSERT_TRUE(got.ok()) << got.error().message;
  EXPECT_EQ(got->type(), MessageType::progress);
}

TEST(Transport, HeartbeatsKeepAnIdleConnectionAlive) {
  ConnectionOptions options;
  options.heartbeat_interval = 50ms;
  options.peer_timeout = 300ms;
  options.deliver_heartbeats = true;
  Pair pair = connected_pair(options);
  // 1 s of silence from the application: heartbeats every ~50 ms, none of them late.
  int heartbeats = 0;
  const auto end = Clock::now() + 1s;
  while (Clock::now() < end) {
    Result<Message> got = pair.host.receive(500ms);
    ASSERT_TRUE(got.ok()) << got.error().message;
    EXPECT_EQ(got->type(), MessageType::heartbeat);
    ++heartbeats;
  }
  EXPECT_GE(heartbeats, 8);
  EXPECT_TRUE(pair.host.is_open());
  EXPECT_GE(pair.board.stats().heartbeats_sent, 8u);
}

TEST(Transport, SilentPeerIsDetectedWithinOneSecond) {
  Result<Server> server = Server::listen("127.0.0.1", 0);
  ASSERT_TRUE(server.ok());
  const int raw = raw_connect(server->port());  // connects, then never sends a byte
  Result<Connection> board = server->accept(2s);
  ASSERT_TRUE(board.ok());
  const auto start = Clock::now();
  Result<Message> got = board->receive(10s);
  const auto waited = Clock::now() - start;
  ASSERT_FALSE(got.ok());
  EXPECT_EQ(got.error().code, Errc::disconnected);
  EXPECT_THAT(got.error().message, HasSubstr("heartbeats stopped"));
  EXPECT_LT(waited, 1s);
  EXPECT_GE(waited, board->options().peer_timeout - 50ms);
  ::close(raw);
}

TEST(Transport, PeerThatStopsReadingIsDetectedWithinOneSecondOfTheStall) {
  Result<Server> server = Server::listen("127.0.0.1", 0);
  ASSERT_TRUE(server.ok());
  const int raw = raw_connect(server->port());  // never reads: the board's sends stall
  Result<Connection> board = server->accept(2s);
  ASSERT_TRUE(board.ok());
  pb::FrameHeader header = samples::sample_frame_header(2464, 2056);
  std::vector<std::byte> payload(2464u * 2056u, std::byte{0x55});
  Status status;
  Clock::time_point last_ok = Clock::now();
  for (int i = 0; i < 100 && status.ok(); ++i) {
    status = board->send_frame(header, payload, 30s);
    if (status.ok()) last_ok = Clock::now();
  }
  ASSERT_FALSE(status.ok()) << "100 frames of 5 MB fit in the socket buffers?";
  EXPECT_EQ(status.error().code, Errc::disconnected);
  // Either our stall detector or the kernel's TCP_USER_TIMEOUT fires first.
  EXPECT_THAT(status.error().message, ::testing::AnyOf(HasSubstr("accepted no data"), HasSubstr("timed out")))
      << status.error().message;
  EXPECT_LT(Clock::now() - last_ok, 1500ms);  // buffer fill + 800 ms stall
  EXPECT_FALSE(board->is_open());
  ::close(raw);
}

// The host's receiving thread may be held up by reconstruction for longer than peer_timeout;
// its heartbeats still arrive, so the board's sends wait (back-pressure: the sequencer pauses
// between patterns) instead of declaring the host gone.
TEST(Transport, APeerThatIsAliveButNotReadingGetsBackPressureNotADisconnect) {
  Pair pair = connected_pair();
  std::atomic<bool> stop{false};
  // The board listens to the host during a scan as slscand does (abort, heartbeats).
  std::thread board_listener([&] {
    while (!stop.load()) (void)pair.board.receive(20ms);
  });
  constexpr int frames = 12;
  auto reader = std::async(std::launch::async, [&]() -> std::string {
    std::this_thread::sleep_for(2500ms);  // three peer timeouts without reading a byte
    for (int received = 0; received < frames;) {
      Result<Message> message = pair.host.receive(10s);
      if (!message) return "host, after " + std::to_string(received) + " frames: " + message.error().message;
      if (message->get<pb::FrameHeader>() != nullptr) ++received;
    }
    return {};
  });
  const pb::FrameHeader header = samples::sample_frame_header(2464, 2056);
  const std::vector<std::byte> payload(2464u * 2056u, std::byte{0x2a});
  const auto start = Clock::now();
  Status status;
  for (int i = 0; i < frames && status.ok(); ++i) status = pair.board.send_frame(header, payload, 10s);
  EXPECT_TRUE(status.ok()) << status.error().message;
  EXPECT_GE(Clock::now() - start, 2s) << "the frames fit in the socket buffers: the test tests nothing";
  EXPECT_EQ(reader.get(), "");
  stop = true;
  board_listener.join();
}

TEST(Transport, PeerClosingMidRecordIsReportedAtOnce) {
  Result<Server> server = Server::listen("127.0.0.1", 0);
  ASSERT_TRUE(server.ok());
  const int raw = raw_connect(server->port());
  Result<Connection> board = server->accept(2s);
  ASSERT_TRUE(board.ok());
  std::vector<std::byte> record;
  ASSERT_TRUE(encode(samples::sample_frame_header(), samples::sample_payload(21), record).ok());
  ASSERT_EQ(::write(raw, record.data(), 40), 40);
  ::close(raw);
  const auto start = Clock::now();
  Result<Message> got = board->receive(5s);
  ASSERT_FALSE(got.ok());
  EXPECT_EQ(got.error().code, Errc::disconnected);
  EXPECT_THAT(got.error().message, HasSubstr("in the middle of a record at stream offset 0"));
  EXPECT_THAT(got.error().message, HasSubstr("frame control message: have 8 of"));
  EXPECT_LT(Clock::now() - start, 200ms);
}

TEST(Transport, GarbageFromThePeerClosesTheConnectionWithTheReason) {
  Result<Server> server = Server::listen("127.0.0.1", 0);
  ASSERT_TRUE(server.ok());
  const int raw = raw_connect(server->port());
  Result<Connection> board = server->accept(2s);
  ASSERT_TRUE(board.ok());
  const std::string http = "GET / HTTP/1.1\r\nHost: board.local\r\nAccept: */*\r\n\r\n";
  ASSERT_EQ(::write(raw, http.data(), http.size()), static_cast<ssize_t>(http.size()));
  Result<Message> got = board->receive(2s);
  ASSERT_FALSE(got.ok());
  EXPECT_EQ(got.error().code, Errc::malformed);
  EXPECT_THAT(got.error().message, HasSubstr("bad magic 47 45 54 20"));
  EXPECT_FALSE(board->is_open());
  ::close(raw);
}

TEST(Transport, CleanCloseDeliversEverythingThenEndOfStream) {
  Pair pair = connected_pair();
  for (int i = 0; i < 50; ++i) {
    pb::Progress progress = samples::sample_progress();
    progress.set_frames_sent(static_cast<std::uint64_t>(i));
    ASSERT_TRUE(pair.board.send(progress).ok());
  }
  auto closer = std::async(std::launch::async, [&] { pair.board.close(); });
  for (int i = 0; i < 50; ++i) {
    Result<Message> got = pair.host.receive(2s);
    ASSERT_TRUE(got.ok()) << i << ": " << got.error().message;
    EXPECT_EQ(got->get<pb::Progress>()->frames_sent(), static_cast<std::uint64_t>(i));
  }
  Result<Message> end = pair.host.receive(2s);
  ASSERT_FALSE(end.ok());
  EXPECT_EQ(end.error().code, Errc::disconnected);
  EXPECT_THAT(end.error().message, HasSubstr("closed the connection"));
  pair.host.close();
  closer.get();
  EXPECT_FALSE(pair.board.send(samples::sample_progress()).ok());
}

TEST(Transport, CloseFromAnotherThreadWakesABlockedReceive) {
  Pair pair = connected_pair();
  auto waiter = std::async(std::launch::async, [&] {
    const auto start = Clock::now();
    Result<Message> got = pair.host.receive(10s);
    return std::pair{std::move(got), Clock::now() - start};
  });
  std::this_thread::sleep_for(100ms);
  pair.host.close();
  auto [got, waited] = waiter.get();
  ASSERT_FALSE(got.ok());
  EXPECT_EQ(got.error().code, Errc::disconnected);
  EXPECT_LT(waited, 1s);
}

TEST(Transport, ConnectFailuresAreClear) {
  Result<Server> server = Server::listen("127.0.0.1", 0);
  ASSERT_TRUE(server.ok());
  const std::uint16_t port = server->port();
  server->close();
  Result<Connection> refused = connect("127.0.0.1", port, 1s);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().code, Errc::disconnected);
  EXPECT_THAT(refused.error().message, HasSubstr("refused"));
  Result<Connection> bad_name = connect("no-such-host.invalid", 1, 1s);
  ASSERT_FALSE(bad_name.ok());
  EXPECT_THAT(bad_name.error().message, HasSubstr("no-such-host.invalid"));
  Result<Server> taken = Server::listen("127.0.0.1", 0);
  ASSERT_TRUE(taken.ok());
  Result<Server> again = Server::listen("127.0.0.1", taken->port());
  ASSERT_FALSE(again.ok());
  EXPECT_THAT(again.error().message, HasSubstr("in use"));
  Result<Connection> none = taken->accept(50ms);
  ASSERT_FALSE(none.ok());
  EXPECT_EQ(none.error().code, Errc::timeout);
}

TEST(Transport, RecordToCaptureWritesTheStreamAsReceived) {
  const auto dir = std::filesystem::temp_directory_path() / ("slproto_transport_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string file = (dir / "recorded.slcap").string();
  {
    Pair pair = connected_pair();
    Result<CaptureWriter> capture = CaptureWriter::create(file);
    ASSERT_TRUE(capture.ok());
    pair.host.record_to(&*capture);
    std::vector<std::uint32_t> crcs;
    for (std::uint32_t i = 0; i < 5; ++i) {
      pb::FrameHeader header = samples::sample_frame_header(64, 32);
      header.set_sequence(i);
      const auto payload = samples::sample_payload(64 * 32, i);
      crcs.push_back(crc32c(payload));
      ASSERT_TRUE(pair.board.send_frame(header, payload).ok());
    }
    ASSERT_TRUE(pair.board.send(samples::sample_scan_done()).ok());
    for (int i = 0; i < 6; ++i) ASSERT_TRUE(pair.host.receive(2s).ok());
    pair.host.record_to(nullptr);
    ASSERT_TRUE(capture->finish().ok());

    Result<CaptureReader> reader = CaptureReader::open(file);
    ASSERT_TRUE(reader.ok());
    std::uint32_t frames = 0;
    bool done = false;
    while (true) {
      Result<const Message*> message = reader->next();
      ASSERT_TRUE(message.ok()) << message.error().message;
      if (*message == nullptr) break;
      if (const auto* frame = (*message)->get<pb::FrameHeader>()) {
        ASSERT_LT(frame->sequence(), crcs.size());
        EXPECT_EQ(frame->sequence(), frames);
        EXPECT_EQ(crc32c((*message)->payload), crcs[frame->sequence()]);
        ++frames;
      }
      done = done || (*message)->type() == MessageType::scan_done;
    }
    EXPECT_EQ(frames, 5u);
    EXPECT_TRUE(done);
  }
  std::filesystem::remove_all(dir);
}

// The acceptance test of issue 2: 200 full-resolution 8-bit frames from a server thread to a
// client thread, every payload checksum verified on arrival.
TEST(Transport, LoopbackStreamsTwoHundredFullResolutionFrames) {
  constexpr std::uint32_t width = 2464, height = 2056, frames = 200;
  constexpr std::size_t frame_bytes = std::size_t{width} * height, stamp_at = 1000;
  // A few distinct images, each stamped with its sequence number, so a dropped, repeated or
  // reordered frame, or a corrupted byte, is caught. The sender stamps its own copies in
  // place (no per-frame copy); the receiver compares against separate reference images.
  std::vector<std::vector<std::byte>> reference;
  for (std::uint32_t i = 0; i < 3; ++i) reference.push_back(samples::sample_payload(frame_bytes, i + 100));

  Result<Server> server = Server::listen("127.0.0.1", 0);
  ASSERT_TRUE(server.ok());
  std::promise<Status> sender_status;
  std::thread sender([&, images = reference]() mutable {
    Result<Connection> board = server->accept(5s);
    if (!board) return sender_status.set_value(board.error());
    for (std::uint32_t i = 0; i < frames; ++i) {
      std::vector<std::byte>& image = images[i % images.size()];
      std::memcpy(image.data() + stamp_at, &i, sizeof i);
      pb::FrameHeader header = samples::sample_frame_header(width, height);
      header.set_sequence(i);
      if (Status status = board->send_frame(header, image); !status) return sender_status.set_value(status);
    }
    pb::ScanDone done;
    done.set_frames_sent(frames);
    sender_status.set_value(board->send(done));
    (void)board->receive(5s);  // wait for the host's close
  });

  Result<Connection> host = connect("127.0.0.1", server->port(), 5s);
  ASSERT_TRUE(host.ok()) << host.error().message;
  std::uint32_t received = 0;
  std::uint64_t payload_bytes = 0;
  const auto start = Clock::now();
  while (true) {
    Result<Message> message = host->receive(10s);
    ASSERT_TRUE(message.ok()) << "after " << received << " frames: " << message.error().message;
    if (message->type() == MessageType::scan_done) {
      EXPECT_EQ(message->get<pb::ScanDone>()->frames_sent(), frames);
      break;
    }
    const pb::FrameHeader* frame = message->get<pb::FrameHeader>();
    ASSERT_NE(frame, nullptr);
    ASSERT_EQ(frame->sequence(), received);
    ASSERT_EQ(message->payload.size(), frame_bytes);
    // The decoder delivered the frame only after its CRC32C over the received payload matched
    // the header's (the sender computed it from its image); the header copy must agree, and the
    // bytes themselves are compared with the reference below (stronger than a second CRC).
    ASSERT_EQ(message->header.payload_crc, frame->payload_crc32c()) << "frame " << received;
    ASSERT_NE(frame->payload_crc32c(), 0u);
    std::uint32_t stamp = 0;
    std::memcpy(&stamp, message->payload.data() + stamp_at, sizeof stamp);
    ASSERT_EQ(stamp, received);
    const auto& expected = reference[received % reference.size()];
    ASSERT_EQ(std::memcmp(message->payload.data(), expected.data(), stamp_at), 0) << "frame " << received;
    ASSERT_EQ(
        std::memcmp(message->payload.data() + stamp_at + 4, expected.data() + stamp_at + 4, frame_bytes - stamp_at - 4),
        0)
        << "frame " << received;
    ++received;
    payload_bytes += message->payload.size();
  }
  const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
  host->close();
  sender.join();
  Status status = sender_status.get_future().get();
  ASSERT_TRUE(status.ok()) << status.error().message;
  EXPECT_EQ(received, frames);
  std::printf("loopback: %u frames, %.1f MB in %.2f s = %.0f MB/s (informational, not asserted)\n", received,
              static_cast<double>(payload_bytes) / 1e6, seconds, static_cast<double>(payload_bytes) / 1e6 / seconds);
}

}  // namespace
