// The host facing a hostile (or broken) scanner (issue 17, docs/security.md): a fake board in
// the test speaks slproto and lies to `slscan scan --connect`: frames whose header and payload
// disagree, frames beyond the request (endless ones too), a declared length far beyond any
// frame, a ScanDone claiming frames that never came, silence with and without heartbeats. For
// each, slscan must exit non-zero promptly (a hang fails the test at its guard), say what was
// wrong and where (frame, stream offset), stay within a bounded memory, and leave a capture
// that holds every valid frame received and reads back cleanly.
#include <arpa/inet.h>
#include <fcntl.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <thread>

#include "slproto/calibration.hpp"
#include "slproto/capture.hpp"
#include "slproto/crc32c.hpp"
#include "slproto/framing.hpp"
#include "slproto/handshake.hpp"
#include "slproto/pattern_plan.hpp"
#include "slproto/transport.hpp"
#include "slrig/rig.hpp"

namespace {

namespace fs = std::filesystem;
namespace pb = slproto::pb;
using namespace std::chrono_literals;

std::string read_text(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

struct Finished {
  int exit_code = -1;
  std::string err;
  long max_rss_kb = 0;
};

// Runs slscan with stderr in a file; a child still running after `guard` is killed and the
// test fails (a hang).
Finished run(const std::vector<std::string>& args, const fs::path& log, std::chrono::seconds guard) {
  std::vector<std::string> copy = args;
  std::vector<char*> argv;
  argv.reserve(copy.size() + 1);
  for (auto& a : copy) argv.push_back(a.data());
  argv.push_back(nullptr);
  const pid_t pid = ::fork();
  if (pid == 0) {
    const int in = ::open("/dev/null", O_RDONLY);
    const int err = ::open(log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    ::dup2(in, STDIN_FILENO);
    ::dup2(err, STDOUT_FILENO);
    ::dup2(err, STDERR_FILENO);
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  const auto deadline = std::chrono::steady_clock::now() + guard;
  int status = 0;
  rusage usage{};
  while (::wait4(pid, &status, WNOHANG, &usage) == 0) {
    if (std::chrono::steady_clock::now() > deadline) {
      ::kill(pid, SIGKILL);
      ::wait4(pid, &status, 0, &usage);
      ADD_FAILURE() << "slscan did not finish within " << guard.count() << " s (a hang); log: " << read_text(log);
      return {-1, read_text(log), usage.ru_maxrss};
    }
    std::this_thread::sleep_for(20ms);
  }
  return {WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status), read_text(log), usage.ru_maxrss};
}

// What the fake board does once it has the host's scan request. `raw` is the socket itself,
// for bytes the Connection API would refuse to send.
using Script = std::function<void(slproto::Connection& connection, int raw, const pb::ScanRequest& request)>;

// A board on 127.0.0.1 that accepts one host, answers its hello, reads its scan request and
// runs `script`; then it waits for the host to hang up. `heartbeats` = false: it sends nothing
// it is not told to (a frozen board).
class FakeBoard {
 public:
  FakeBoard(Script script, bool heartbeats = true) {
    listen_fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (::bind(listen_fd_, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0 || ::listen(listen_fd_, 1) != 0)
      throw std::runtime_error("fake board: cannot listen");
    socklen_t length = sizeof address;
    ::getsockname(listen_fd_, reinterpret_cast<sockaddr*>(&address), &length);
    port_ = ntohs(address.sin_port);
    thread_ = std::thread([this, script = std::move(script), heartbeats] { serve(script, heartbeats); });
  }
  ~FakeBoard() {
    stop_ = true;
    thread_.join();
    ::close(listen_fd_);
  }
  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }
  const std::string& problem() const { return problem_; }

 private:
  void serve(const Script& script, bool heartbeats) {
    pollfd waiter{listen_fd_, POLLIN, 0};
    if (::poll(&waiter, 1, 30000) != 1) return void(problem_ = "no host connected");
    const int fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC);
    const int raw = ::dup(fd);
    slproto::ConnectionOptions options;
    if (!heartbeats) options.heartbeat_interval = 3600s, options.peer_timeout = 7200s;
    auto connection = slproto::Connection::adopt(fd, options);
    if (!connection) return void(problem_ = connection.error().message);
    slproto::ServerIdentity identity;
    identity.board_name = "liar";
    identity.software_version = "fake 0";
    if (auto hello = slproto::server_handshake(*connection, identity); !hello)
      return void(problem_ = hello.error().message);
    auto request = connection->receive_as<pb::ScanRequest>(10s);
    if (!request) return void(problem_ = request.error().message);
    script(*connection, raw, *request);
    // Until the host hangs up (or the test ends): a board that lies but stays connected.
    while (!stop_) {
      auto message = connection->receive(100ms);
      if (!message && message.error().code != slproto::Errc::timeout) break;
    }
    ::close(raw);
  }

  int listen_fd_ = -1;
  std::uint16_t port_ = 0;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::string problem_;
};

pb::FrameHeader frame_header(const pb::ScanRequest& request, std::uint32_t view, std::uint32_t projector,
                             std::uint32_t pattern, std::uint64_t sequence, std::uint32_t width = 640,
                             std::uint32_t height = 512) {
  pb::FrameHeader header;
  header.set_scan_id(request.scan_id());
  header.set_view_index(view);
  header.set_commanded_angle_deg(view < static_cast<std::uint32_t>(request.turntable_angles_deg_size())
                                     ? request.turntable_angles_deg(static_cast<int>(view))
                                     : 0.0);
  header.set_projector_id(projector);
  header.set_pattern_index(pattern);
  header.set_sequence(sequence);
  slproto::set_frame_geometry(header, width, height, pb::PIXEL_FORMAT_MONO8);
  return header;
}

const std::vector<std::byte>& frame_pixels() {
  static const std::vector<std::byte> pixels(640u * 512u, std::byte{100});
  return pixels;
}

// Sends the first `count` frames of view 0, projector 0 as a real board would.
void send_valid_frames(slproto::Connection& connection, const pb::ScanRequest& request, std::uint32_t count) {
  for (std::uint32_t k = 0; k < count; ++k)
    ASSERT_TRUE(connection.send_frame(frame_header(request, 0, 0, k, k), frame_pixels()).ok());
}

void write_all(int fd, std::span<const std::byte> bytes) {
  while (!bytes.empty()) {
    const ssize_t n = ::send(fd, bytes.data(), bytes.size(), MSG_NOSIGNAL);
    if (n <= 0) return;
    bytes = bytes.subspan(static_cast<std::size_t>(n));
  }
}

// A frame record (framing and CRCs correct) whose FrameHeader declares 640 x 512 mono8 and
// whose payload has `payload_bytes`: written raw, as the Connection refuses to send it.
void send_lying_frame(int raw, const pb::ScanRequest& request, std::uint32_t pattern, std::size_t payload_bytes) {
  const std::vector<std::byte> payload(payload_bytes, std::byte{7});
  pb::FrameHeader header = frame_header(request, 0, 0, pattern, pattern);
  header.set_payload_crc32c(slproto::crc32c(payload));
  std::vector<std::byte> record;
  ASSERT_TRUE(slproto::encode_prefix(slproto::MessageType::frame, header, static_cast<std::uint32_t>(payload.size()),
                                     header.payload_crc32c(), record)
                  .ok());
  record.insert(record.end(), payload.begin(), payload.end());
  write_all(raw, record);
}

class HostileScanner : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::temp_directory_path() / ("slscan_hostile_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
    auto scene = slrig::scene_preset("sphere", slrig::RigSize::small);
    ASSERT_TRUE(scene.ok()) << scene.error().message;
    const auto calibration = slrig::ground_truth_calibration(*scene);
    ASSERT_EQ(calibration.camera.width, 640);
    ASSERT_EQ(calibration.camera.height, 512);
    plan_size_ = slproto::PatternPlan(calibration.pattern_plan).size();
    ASSERT_TRUE(slproto::save_calibration((dir_ / "calib.json").string(), calibration).ok());
  }
  static void TearDownTestSuite() {
    if (!keep_) fs::remove_all(dir_);
  }
  void TearDown() override {
    if (HasFailure()) {
      keep_ = true;
      std::printf("keeping %s to look at\n", dir_.c_str());
    }
  }

  // slscan scan against `board` (one view, both projectors: 2 x plan frames), with a guard that
  // turns a hang into a failure.
  static Finished scan(const FakeBoard& board, const std::string& name, std::vector<std::string> extra = {}) {
    std::vector<std::string> args{SLSCAN_BIN,      "scan",
                                  "--connect",     board.address(),
                                  "--calib",       (dir_ / "calib.json").string(),
                                  "--out",         (dir_ / name).string(),
                                  "--exposure-us", "2000",
                                  "--period-us",   "5000",
                                  "--settle-ms",   "20",
                                  "--angles",      "0"};
    args.insert(args.end(), extra.begin(), extra.end());
    Finished finished = run(args, dir_ / (name + ".log"), 60s);
    EXPECT_TRUE(board.problem().empty()) << board.problem();
    return finished;
  }

  // The frames of the capture slscan left (capture.slcap, else the .partial), which must read
  // back to its end without an error; -1 if there is none.
  static long frames_kept(const std::string& name) {
    fs::path path = dir_ / name / "capture.slcap";
    if (!fs::exists(path)) path += ".partial";
    if (!fs::exists(path)) return -1;
    auto reader = slproto::CaptureReader::open(path.string());
    EXPECT_TRUE(reader.ok()) << reader.error().message;
    if (!reader) return -1;
    long frames = 0;
    for (;;) {
      auto message = reader->next();
      EXPECT_TRUE(message.ok()) << message.error().message;
      if (!message || *message == nullptr) break;
      if ((*message)->get<pb::FrameHeader>() != nullptr) ++frames;
    }
    return frames;
  }

  // What every case must show: a failure (the device exit code, 3), not a crash; a message
  // with `what`; memory far below what the lies declared; the valid frames kept.
  static void expect_refused(const Finished& finished, const std::string& name, const std::string& what,
                             long valid_frames) {
    EXPECT_EQ(finished.exit_code, 3) << finished.err;
    EXPECT_NE(finished.err.find(what), std::string::npos) << finished.err;
    EXPECT_EQ(finished.err.find("internal error"), std::string::npos) << finished.err;
    EXPECT_LT(finished.max_rss_kb, 400 * 1024) << "peak RSS of slscan";
    EXPECT_EQ(frames_kept(name), valid_frames) << finished.err;
    EXPECT_FALSE(fs::exists(dir_ / name / "model.ply"));
  }

  static inline fs::path dir_;
  static inline std::size_t plan_size_ = 0;
  static inline bool keep_ = false;
};

TEST_F(HostileScanner, PayloadShorterThanTheHeaderSays) {
  FakeBoard board([](slproto::Connection& c, int raw, const pb::ScanRequest& request) {
    send_valid_frames(c, request, 3);
    send_lying_frame(raw, request, 3, 1000);
  });
  const Finished finished = scan(board, "short");
  expect_refused(finished, "short", "stride_bytes * height = 327680 but the payload has 1000 bytes", 3);
  EXPECT_NE(finished.err.find("stream offset"), std::string::npos) << finished.err;
}

TEST_F(HostileScanner, PayloadLongerThanTheHeaderSays) {
  FakeBoard board([](slproto::Connection& c, int raw, const pb::ScanRequest& request) {
    send_valid_frames(c, request, 2);
    send_lying_frame(raw, request, 2, 640u * 512u + 4096u);
  });
  expect_refused(scan(board, "long"), "long", "but the payload has 331776 bytes", 2);
}

TEST_F(HostileScanner, FramesOfTheWrongSizeForTheCalibration) {
  FakeBoard board([](slproto::Connection& c, int, const pb::ScanRequest& request) {
    const std::vector<std::byte> small(320u * 256u, std::byte{1});
    (void)c.send_frame(frame_header(request, 0, 0, 0, 0, 320, 256), small);
  });
  expect_refused(scan(board, "wrong_size"), "wrong_size",
                 "frames are 320 x 256 but the calibration's camera is 640 x 512", 0);
}

TEST_F(HostileScanner, EndlessFramesBeyondThePlanStopAtTheFirst) {
  // Every frame of the request, then the same frames again, without end (until the host hangs up).
  FakeBoard board([](slproto::Connection& c, int, const pb::ScanRequest& request) {
    const auto plan = static_cast<std::uint32_t>(plan_size_);
    for (std::uint64_t sequence = 0;; ++sequence) {
      const auto slot = static_cast<std::uint32_t>(sequence % (2 * plan));
      if (!c.send_frame(frame_header(request, 0, slot / plan, slot % plan, sequence), frame_pixels()).ok()) return;
    }
  });
  const Finished finished = scan(board, "endless");
  expect_refused(finished, "endless", "repeats the frame at offset", static_cast<long>(2 * plan_size_));
  EXPECT_NE(finished.err.find("frame " + std::to_string(2 * plan_size_) + " (stream offset"), std::string::npos)
      << finished.err;
}

TEST_F(HostileScanner, FramesOfAViewOrPatternTheRequestDoesNotHave) {
  FakeBoard view([](slproto::Connection& c, int, const pb::ScanRequest& request) {
    send_valid_frames(c, request, 4);
    for (std::uint32_t v = 1; v < 100000; ++v)
      if (!c.send_frame(frame_header(request, v, 0, 0, 3 + v), frame_pixels()).ok()) return;
  });
  expect_refused(scan(view, "view"), "view", "frame (view 1, projector 0, pattern 0) is of a view the scan request", 4);
  FakeBoard pattern([](slproto::Connection& c, int, const pb::ScanRequest& request) {
    send_valid_frames(c, request, 1);
    (void)c.send_frame(frame_header(request, 0, 1, 4000000000u, 1), frame_pixels());
  });
  expect_refused(scan(pattern, "pattern"), "pattern", "is beyond the scan request's pattern plan", 1);
}

// HDR (docs/hdr.md): a board that does not offer CAPABILITY_EXPOSURE_BRACKET would ignore the
// bracket and send one exposure; slscan refuses before it asks for the scan, naming the fix.
TEST_F(HostileScanner, ABracketForABoardThatCannotSequenceItIsRefusedBeforeTheScan) {
  FakeBoard older([](slproto::Connection&, int, const pb::ScanRequest&) {});
  const Finished finished =
      run({SLSCAN_BIN, "scan", "--connect", older.address(), "--calib", (dir_ / "calib.json").string(), "--out",
           (dir_ / "bracket").string(), "--angles", "0", "--exposure-bracket", "2000,500"},
          dir_ / "bracket.log", 60s);
  EXPECT_EQ(finished.exit_code, 3) << finished.err;
  EXPECT_NE(finished.err.find("cannot sequence an exposure bracket (no CAPABILITY_EXPOSURE_BRACKET)"),
            std::string::npos)
      << finished.err;
  EXPECT_EQ(frames_kept("bracket"), -1) << "no scan was asked for, so no capture";
  // Auto-exposure meters with a bracket: refused alike, before the metering pass.
  FakeBoard older_again([](slproto::Connection&, int, const pb::ScanRequest&) {});
  const Finished metering =
      run({SLSCAN_BIN, "scan", "--connect", older_again.address(), "--calib", (dir_ / "calib.json").string(), "--out",
           (dir_ / "auto").string(), "--angles", "0", "--exposure", "auto"},
          dir_ / "auto.log", 60s);
  EXPECT_EQ(metering.exit_code, 3) << metering.err;
  EXPECT_NE(metering.err.find("--exposure auto: the scanner"), std::string::npos) << metering.err;
  EXPECT_NE(metering.err.find("no CAPABILITY_EXPOSURE_BRACKET), which metering needs"), std::string::npos)
      << metering.err;
  EXPECT_EQ(frames_kept("auto"), -1) << "no scan was asked for, so no capture";
}

TEST_F(HostileScanner, HugeDeclaredLengths) {
  // A header beyond the framing's limit is refused as soon as its 32 bytes are in.
  FakeBoard over([](slproto::Connection& c, int raw, const pb::ScanRequest& request) {
    send_valid_frames(c, request, 2);
    slproto::WireHeader header;
    header.type = slproto::MessageType::frame;
    header.control_length = 40;
    header.payload_length = 0xFFFFFFF0u;
    write_all(raw, header.serialize());
  });
  expect_refused(scan(over, "oversized"), "oversized", "payload length 4294967280 exceeds 268435456", 2);
  // A length within the limit (256 MiB) whose bytes never come: nothing is allocated ahead of
  // the bytes, and the heartbeats the board still sends do not keep the scan waiting forever.
  FakeBoard starved([](slproto::Connection& c, int raw, const pb::ScanRequest& request) {
    send_valid_frames(c, request, 2);
    pb::FrameHeader frame = frame_header(request, 0, 0, 2, 2, 65535, 4096);
    std::vector<std::byte> prefix;
    ASSERT_TRUE(slproto::encode_prefix(slproto::MessageType::frame, frame, 65535u * 4096u, 0, prefix).ok());
    write_all(raw, prefix);
    write_all(raw, std::vector<std::byte>(100000, std::byte{0}));
  });
  expect_refused(scan(starved, "starved", {"--stall-timeout-s", "2"}), "starved", "sent no frame for 2 s after 2 of",
                 2);
}

TEST_F(HostileScanner, ScanDoneClaimingFramesThatNeverCame) {
  FakeBoard board([](slproto::Connection& c, int, const pb::ScanRequest& request) {
    send_valid_frames(c, request, 5);
    pb::ScanDone done;
    done.set_scan_id(request.scan_id());
    done.set_final_state(pb::SCAN_STATE_DONE);
    done.set_frames_sent(1000000000000ull);
    done.set_views_completed(4000000000u);
    (void)c.send(done);
  });
  expect_refused(scan(board, "claims"), "claims", "ScanDone says 1000000000000 frames were sent, but 5 arrived", 5);
}

TEST_F(HostileScanner, SilenceMidScanWithHeartbeatsTimesOut) {
  FakeBoard board([](slproto::Connection& c, int, const pb::ScanRequest& request) {
    send_valid_frames(c, request, 3);  // then only heartbeats
  });
  expect_refused(scan(board, "stalled", {"--stall-timeout-s", "2"}), "stalled",
                 "the scanner sent no frame for 2 s after 3 of " + std::to_string(2 * plan_size_) + " frames", 3);
}

TEST_F(HostileScanner, SilenceMidScanWithoutHeartbeatsIsAGonePeer) {
  FakeBoard board([](slproto::Connection& c, int, const pb::ScanRequest& request) { send_valid_frames(c, request, 3); },
                  false);
  expect_refused(scan(board, "frozen"), "frozen", "heartbeats stopped", 3);
}

}  // namespace
