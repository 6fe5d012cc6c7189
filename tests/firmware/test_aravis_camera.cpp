// The Aravis (GenICam) camera backend: the wire-format, frame-id and clock pieces without a
// camera, then the backend and a whole slscand scan against Aravis' fake GigE Vision camera
// (arv-fake-gv-camera-0.8, package aravis-tools) started on loopback by the test. Where the
// fake cannot start (not installed, port 3956 taken) the live tests are skipped with the reason.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/file.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <fstream>
#include <thread>

#include "slproto/handshake.hpp"
#include "slproto/transport.hpp"
#include "slscand/app/check.hpp"
#include "slscand/app/daemon.hpp"
#include "slscand/hal/aravis/aravis_camera.hpp"
#include "slscand/hal/backends.hpp"

extern char** environ;

// The ASan build's leak check: GLib, GIO and Aravis keep per-process state (type system,
// interface lists, socket sources) they free only at arv_shutdown(), which a process that may
// reopen cameras does not call. (This would also hide a leaked ArvCamera or ArvStream: the
// backend owns both in one class and frees them in its destructor and stop().)
extern "C" const char* __lsan_default_suppressions() {
  return "leak:libglib-2.0.so\nleak:libgobject-2.0.so\nleak:libgio-2.0.so\nleak:libaravis-0.8.so\n";
}

using namespace slscand;
using namespace slscand::hal;
using namespace std::chrono_literals;
namespace pb = slproto::pb;

namespace {

// ------------------------------------------------------------------ pure parts

TEST(GenicamWireFormat, PrefersUnpackedThenPfncThenGigeVisionPacked) {
  EXPECT_EQ(*choose_genicam_wire_format(PixelFormat::mono12, {"Mono8", "Mono12Packed", "Mono12p", "Mono12"}),
            GenicamWireFormat::mono12);
  EXPECT_EQ(*choose_genicam_wire_format(PixelFormat::mono12, {"Mono8", "Mono12Packed", "Mono12p"}),
            GenicamWireFormat::mono12p);
  EXPECT_EQ(*choose_genicam_wire_format(PixelFormat::mono10, {"Mono10Packed", "Mono8"}),
            GenicamWireFormat::mono10_packed);
  EXPECT_EQ(*choose_genicam_wire_format(PixelFormat::mono8, {"BayerRG8", "Mono8"}), GenicamWireFormat::mono8);
  // Mono16 is not Mono12: its values would overflow the protocol's 12-bit range.
  auto none = choose_genicam_wire_format(PixelFormat::mono12, {"Mono8", "Mono16"});
  ASSERT_FALSE(none.ok());
  EXPECT_EQ(none.error().code, slproto::Errc::unsupported);
  EXPECT_NE(none.error().message.find("needs one of Mono12, Mono12p, Mono12Packed"), std::string::npos)
      << none.error().message;
  EXPECT_NE(none.error().message.find("offers Mono8, Mono16"), std::string::npos) << none.error().message;
}

std::vector<unsigned> unpack16(GenicamWireFormat format, const std::vector<std::uint8_t>& wire, int width, int height) {
  std::vector<std::uint8_t> out(static_cast<std::size_t>(width * height) * 2, 0xee);
  auto s = genicam_unpack(format, wire.data(), wire.size(), width, height, out.data());
  EXPECT_TRUE(s.ok()) << s.error().message;
  std::vector<unsigned> values;
  for (std::size_t i = 0; i + 1 < out.size(); i += 2) values.push_back(out[i] | (out[i + 1] << 8));
  return values;
}

TEST(GenicamWireFormat, UnpacksGigeVisionPackedFormats) {
  // Mono12Packed: a = 0xABC, b = 0x123 -> [0xAB] [b low nibble << 4 | a low nibble] [0x12].
  EXPECT_EQ(unpack16(GenicamWireFormat::mono12_packed, {0xAB, 0x3C, 0x12, 0xFF, 0x0F, 0x00}, 4, 1),
            (std::vector<unsigned>{0xABC, 0x123, 0xFFF, 0x000}));
  // Mono10Packed: a = 0x3FE (0xFF, low bits 10b), b = 0x001 (0x00, low bits 01b) -> byte 1 = 0b0001'0010.
  EXPECT_EQ(unpack16(GenicamWireFormat::mono10_packed, {0xFF, 0x12, 0x00}, 2, 1),
            (std::vector<unsigned>{0x3FE, 0x001}));
  EXPECT_EQ(genicam_image_bytes(GenicamWireFormat::mono12_packed, 2464, 2056), 2464u * 2056u * 3u / 2u);
}

TEST(GenicamWireFormat, UnpacksPfncBitStreamsAcrossByteBoundaries) {
  // Mono10p: 4 pixels in 5 bytes, LSB first. 0x001, 0x3FF, 0x155, 0x2AA.
  // bits: p0 = 0000000001, p1 = 1111111111, p2 = 0101010101, p3 = 1010101010 (each LSB first in the stream).
  std::vector<std::uint8_t> wire(5, 0);
  const unsigned px[4] = {0x001, 0x3FF, 0x155, 0x2AA};
  std::size_t bit = 0;
  for (unsigned v : px) {
    for (int b = 0; b < 10; ++b, ++bit) {
      if ((v >> b) & 1u) wire[bit / 8] |= static_cast<std::uint8_t>(1u << (bit % 8));
    }
  }
  EXPECT_EQ(unpack16(GenicamWireFormat::mono10p, wire, 2, 2), (std::vector<unsigned>{0x001, 0x3FF, 0x155, 0x2AA}));
  // Mono12p: 0xABC, 0x123 -> 0xBC, 0x3A, 0x12.
  EXPECT_EQ(unpack16(GenicamWireFormat::mono12p, {0xBC, 0x3A, 0x12}, 2, 1), (std::vector<unsigned>{0xABC, 0x123}));
}

TEST(GenicamWireFormat, UnpackedKeepsOnlyTheFormatsBitsAndShortImagesAreErrors) {
  EXPECT_EQ(unpack16(GenicamWireFormat::mono10, {0xFF, 0xFF, 0x01, 0x02}, 2, 1), (std::vector<unsigned>{0x3FF, 0x201}));
  std::vector<std::uint8_t> out(8);
  const std::vector<std::uint8_t> wire(5);
  auto s = genicam_unpack(GenicamWireFormat::mono12_packed, wire.data(), wire.size(), 4, 1, out.data());
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, slproto::Errc::truncated);
  EXPECT_NE(s.error().message.find("needs 6 bytes; the buffer has 5"), std::string::npos) << s.error().message;
}

TEST(FrameIdUnwrapper, SixteenBitBlockIdsWrapWithoutAGap) {
  FrameIdUnwrapper ids;
  EXPECT_EQ(ids.next(65534), 65534u);
  EXPECT_EQ(ids.next(65535), 65535u);
  EXPECT_EQ(ids.next(0), 65536u);  // a device that counts through 0
  EXPECT_EQ(ids.next(1), 65537u);
  FrameIdUnwrapper gv1;
  gv1.next(65535);
  EXPECT_EQ(gv1.next(1), 65536u);  // GigE Vision 1.x skips block id 0
  EXPECT_EQ(gv1.next(3), 65538u);  // a real gap stays a gap
  FrameIdUnwrapper wide;
  wide.next(1'000'000);
  EXPECT_EQ(wide.next(1'000'001), 1'000'001u);
}

TEST(ClockMapping, LatchSampleWithTheShortestRoundTripWins) {
  auto m = clock_mapping_from_latches({{1000, 500, 1400}, {2000, 1540, 2080}, {3000, 0, 3001}});
  ASSERT_TRUE(m.ok());
  EXPECT_EQ(m->kind, ClockMapping::Kind::latched);
  EXPECT_EQ(m->device_to_monotonic_ns, 2040 - 1540);
  EXPECT_EQ(m->uncertainty_ns, 40);
  EXPECT_FALSE(clock_mapping_from_latches({{1, 0, 2}}).ok());  // a latch that reads 0 is no latch
  EXPECT_TRUE(looks_like_wall_clock(1'700'000'000'000'000'000, 1'700'000'000'100'000'000));
  EXPECT_FALSE(looks_like_wall_clock(123'456'789, 1'700'000'000'100'000'000));  // a camera's own counter
}

// ------------------------------------------------------------------ the fake camera

// One fake camera at a time on this machine (it binds 127.0.0.1:3956): an flock serialises the
// tests across ctest's parallel jobs and other worktrees.
class FakeCamera {
 public:
  ~FakeCamera() { stop(); }

  // Returns "" when running, else why it cannot.
  std::string start() {
    lock_fd_ = ::open("/tmp/slscan-arv-fake-gv-camera.lock", O_RDWR | O_CREAT | O_CLOEXEC, 0666);
    if (lock_fd_ < 0 || ::flock(lock_fd_, LOCK_EX) != 0) return "cannot take /tmp/slscan-arv-fake-gv-camera.lock";
    serial_ = "SL" + std::to_string(::getpid() % 1000000);
    const std::string program = "arv-fake-gv-camera-0.8";
    std::string args[] = {program, "-i", "127.0.0.1", "-s", serial_};
    char* argv[] = {args[0].data(), args[1].data(), args[2].data(), args[3].data(), args[4].data(), nullptr};
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_addopen(&actions, 1, "/dev/null", O_WRONLY, 0);
    posix_spawn_file_actions_addopen(&actions, 2, "/dev/null", O_WRONLY, 0);
    const int rc = posix_spawnp(&pid_, program.c_str(), &actions, nullptr, argv, environ);
    posix_spawn_file_actions_destroy(&actions);
    if (rc != 0) {
      pid_ = -1;
      return program + " is not installed (package aravis-tools; scripts/bootstrap.sh installs it)";
    }
    // Up when Aravis finds it; it exits at once when it cannot bind its port.
    for (int i = 0; i < 50; ++i) {
      int status = 0;
      if (::waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        return program + " exited at start (is another GigE Vision device on 127.0.0.1:3956?)";
      }
      for (const auto& line : list_aravis_cameras()) {
        if (line.find(id()) != std::string::npos) return "";
      }
      std::this_thread::sleep_for(100ms);
    }
    stop();
    return program + " started but Aravis does not discover it on loopback";
  }

  void stop() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
      pid_ = -1;
    }
    if (lock_fd_ >= 0) {
      ::close(lock_fd_);  // releases the flock
      lock_fd_ = -1;
    }
  }
  // The camera vanishes (power cut, cable pulled) but the lock stays ours.
  void kill_camera() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
      pid_ = -1;
    }
  }

  std::string serial() const { return serial_; }
  std::string id() const { return "Aravis-Fake-" + serial_; }

 private:
  pid_t pid_ = -1;
  int lock_fd_ = -1;
  std::string serial_;
};

class AravisFake : public ::testing::Test {
 protected:
  void SetUp() override {
    const std::string why = fake_.start();
    if (!why.empty()) GTEST_SKIP() << why;
  }
  std::unique_ptr<Camera> open(AravisOptions options = {}) {
    if (options.device == "auto") options.device = fake_.id();
    auto camera = open_aravis_camera(options);
    EXPECT_TRUE(camera.ok()) << camera.error().message;
    return camera ? std::move(*camera) : nullptr;
  }
  static CameraFormat format(int w, int h, PixelFormat p = PixelFormat::mono8) {
    CameraFormat f;
    f.width = w;
    f.height = h;
    f.pixel_format = p;
    return f;
  }
  FakeCamera fake_;
};

TEST_F(AravisFake, OpensByIdSerialAndAutoAndDescribesItself) {
  for (const std::string& device : {fake_.id(), fake_.serial()}) {
    AravisOptions options;
    options.device = device;
    auto camera = open_aravis_camera(options);
    ASSERT_TRUE(camera.ok()) << device << ": " << camera.error().message;
    const std::string text = (*camera)->describe();
    EXPECT_NE(text.find("Aravis Fake serial " + fake_.serial()), std::string::npos) << text;
    EXPECT_NE(text.find("at 127.0.0.1"), std::string::npos) << text;
  }
  auto first = open_aravis_camera({});  // "auto": the only camera here
  ASSERT_TRUE(first.ok()) << first.error().message;
  AravisOptions missing;
  missing.device = "Nobody-GV99";
  auto none = open_aravis_camera(missing);
  ASSERT_FALSE(none.ok());
  EXPECT_NE(none.error().message.find("cannot open GenICam camera 'Nobody-GV99'"), std::string::npos);
  EXPECT_NE(none.error().message.find(fake_.id()), std::string::npos) << none.error().message;  // lists what it found
}

TEST_F(AravisFake, RegionAndFormatsAreSetOrRefusedByName) {
  AravisOptions options;
  options.offset_x = 16;
  options.offset_y = 8;
  auto camera = open(options);
  ASSERT_TRUE(camera);
  auto f = camera->set_format(format(320, 240));
  ASSERT_TRUE(f.ok()) << f.error().message;
  EXPECT_EQ(f->stride_bytes, 320u);
  EXPECT_EQ(f->frame_bytes(), 320u * 240u);
  // The fake has Mono8 and Mono16 only: a wrong pixel format is a clear error.
  auto mono12 = camera->set_format(format(320, 240, PixelFormat::mono12));
  ASSERT_FALSE(mono12.ok());
  EXPECT_EQ(mono12.error().code, slproto::Errc::unsupported);
  EXPECT_NE(mono12.error().message.find("pixel format mono12 needs one of Mono12, Mono12p, Mono12Packed"),
            std::string::npos)
      << mono12.error().message;
  EXPECT_NE(mono12.error().message.find("Mono16"), std::string::npos) << mono12.error().message;
  auto huge = camera->set_format(format(4096, 4096));
  ASSERT_FALSE(huge.ok());
  EXPECT_NE(huge.error().message.find("region 4096 x 4096"), std::string::npos) << huge.error().message;
}

TEST_F(AravisFake, ExposureAndGainAreSetWithinTheCamerasRange) {
  auto camera = open();
  ASSERT_TRUE(camera);
  EXPECT_TRUE(camera->set_exposure_us(2000).ok());
  auto low = camera->set_exposure_us(5);  // the fake's minimum is 10 us
  ASSERT_FALSE(low.ok());
  EXPECT_NE(low.error().message.find("outside the camera's 10"), std::string::npos) << low.error().message;
  EXPECT_FALSE(camera->set_exposure_us(-1).ok());
  EXPECT_TRUE(camera->set_gain(1.0).ok());
  auto gain = camera->set_gain(2.0);  // the fake has only GainRaw, which has no unit
  ASSERT_FALSE(gain.ok());
  EXPECT_NE(gain.error().message.find("GainRaw"), std::string::npos) << gain.error().message;
}

TEST_F(AravisFake, TriggerSourcesAreTheCamerasOwn) {
  AravisOptions options;
  options.trigger_input = "Line0";
  auto camera = open(options);
  ASSERT_TRUE(camera);
  EXPECT_TRUE(camera->set_trigger_mode(TriggerMode::external).ok());
  EXPECT_TRUE(camera->set_trigger_mode(TriggerMode::free_run).ok());
  options.trigger_input = "Line3";
  auto other = open(options);
  ASSERT_TRUE(other);
  auto s = other->set_trigger_mode(TriggerMode::external);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("TriggerSource Line3 is not one the camera offers (Line0, Software)"),
            std::string::npos)
      << s.error().message;
}

TEST_F(AravisFake, SoftwareTriggerGivesOneFramePerTriggerWithMappedTimestamps) {
  auto camera = open();
  ASSERT_TRUE(camera);
  ASSERT_TRUE(camera->set_format(format(64, 48)).ok());
  // At 10 ms and raw gain 0 the fake's image is its plain ramp: (x + y + frame id) % 255.
  ASSERT_TRUE(camera->set_exposure_us(10000).ok());
  ASSERT_TRUE(camera->set_gain(1.0).ok());
  ASSERT_TRUE(camera->set_trigger_mode(TriggerMode::software).ok());
  ASSERT_TRUE(camera->start().ok());
  std::optional<std::uint64_t> last;
  for (int i = 0; i < 5; ++i) {
    const Nanos triggered = monotonic_now_ns();
    ASSERT_TRUE(camera->software_trigger().ok());
    auto frame = camera->wait_frame(2 * kSecond);
    ASSERT_TRUE(frame.ok()) << frame.error().message;
    EXPECT_EQ(frame->format.width, 64);
    ASSERT_EQ(frame->pixels.size(), 64u * 48u);
    if (last) {
      EXPECT_EQ(frame->sequence, *last + 1);
    }
    last = frame->sequence;
    for (int y = 0; y < 48; y += 7) {
      for (int x = 0; x < 64; x += 5) {
        ASSERT_EQ(frame->pixels[static_cast<std::size_t>(y * 64 + x)], (x + y + frame->sequence) % 255)
            << "frame " << frame->sequence << " pixel " << x << "," << y;
      }
    }
    // The fake stamps on the wall clock; mapped onto CLOCK_MONOTONIC it falls between the
    // trigger and the frame's arrival.
    EXPECT_GE(frame->exposure_start_ns, triggered - kMilli);
    EXPECT_LE(frame->exposure_start_ns, frame->dequeued_ns);
    EXPECT_EQ(frame->exposure_end_ns - frame->exposure_start_ns, 10 * kMilli);
  }
  const CameraLinkStats stats = camera->link_stats();
  EXPECT_EQ(stats.frames_completed, 5u);
  EXPECT_EQ(stats.frames_failed, 0u);
  EXPECT_EQ(stats.packets_missing, 0u);
  EXPECT_TRUE(camera->stop().ok());
  EXPECT_TRUE(camera->stop().ok());  // idempotent
}

TEST_F(AravisFake, ATriggerThatNeverComesTimesOutByName) {
  auto camera = open();
  ASSERT_TRUE(camera);
  ASSERT_TRUE(camera->set_format(format(64, 48)).ok());
  ASSERT_TRUE(camera->set_trigger_mode(TriggerMode::software).ok());
  ASSERT_TRUE(camera->start().ok());
  const Nanos t0 = monotonic_now_ns();
  auto frame = camera->wait_frame(300 * kMilli);
  ASSERT_FALSE(frame.ok());
  EXPECT_EQ(frame.error().code, slproto::Errc::timeout);
  EXPECT_NE(frame.error().message.find("no frame within 300 ms"), std::string::npos) << frame.error().message;
  EXPECT_GE(monotonic_now_ns() - t0, 290 * kMilli);
  // The same in external mode names the input and the wiring.
  ASSERT_TRUE(camera->stop().ok());
  ASSERT_TRUE(camera->set_trigger_mode(TriggerMode::external).ok());
  ASSERT_TRUE(camera->start().ok());
  auto line = camera->wait_frame(200 * kMilli);
  ASSERT_FALSE(line.ok());
  EXPECT_NE(line.error().message.find("no trigger on Line0 (RisingEdge)"), std::string::npos) << line.error().message;
}

TEST_F(AravisFake, AVanishedCameraIsReportedAsGone) {
  auto camera = open();
  ASSERT_TRUE(camera);
  ASSERT_TRUE(camera->set_format(format(64, 48)).ok());
  ASSERT_TRUE(camera->set_trigger_mode(TriggerMode::software).ok());
  ASSERT_TRUE(camera->start().ok());
  ASSERT_TRUE(camera->software_trigger().ok());
  ASSERT_TRUE(camera->wait_frame(2 * kSecond).ok());
  fake_.kill_camera();
  (void)camera->software_trigger();
  auto frame = camera->wait_frame(300 * kMilli);
  ASSERT_FALSE(frame.ok());
  EXPECT_EQ(frame.error().code, slproto::Errc::disconnected) << frame.error().message;
  EXPECT_NE(frame.error().message.find("stopped answering"), std::string::npos) << frame.error().message;
  EXPECT_TRUE(camera->stop().ok());
}

TEST_F(AravisFake, CheckReportsFeaturesAndLink) {
  auto camera = open();
  ASSERT_TRUE(camera);
  const auto details = camera->check_details();
  ASSERT_EQ(details.size(), 2u);
  EXPECT_EQ(details[0].name, "camera features");
  EXPECT_NE(details[0].detail.find("Mono8"), std::string::npos) << details[0].detail;
  EXPECT_NE(details[0].detail.find("trigger sources Line0, Software"), std::string::npos) << details[0].detail;
  EXPECT_EQ(details[1].name, "camera link");
  EXPECT_NE(details[1].detail.find("GigE Vision at 127.0.0.1 via lo"), std::string::npos) << details[1].detail;
  EXPECT_NE(details[1].detail.find("packet size"), std::string::npos) << details[1].detail;
}

TEST_F(AravisFake, SlscandCheckReportsTheCameraItsFeaturesAndLinkOrTheWrongFormat) {
  auto board = load_board(std::string(SLSCAN_SOURCE_DIR) + "/boards/sim-gige.toml");
  ASSERT_TRUE(board.ok()) << board.error().message;
  board->camera_device = fake_.id();
  CheckOptions options;
  options.realtime = false;
  options.port = 0;
  const CheckReport report = check_board(*board, options);
  for (const char* name : {"camera features", "camera link", "camera controls"}) {
    const CheckItem* item = report.find(name);
    ASSERT_NE(item, nullptr) << name << "\n" << report.to_text();
    EXPECT_EQ(item->state, CheckState::ok) << name << ": " << item->detail;
  }
  EXPECT_NE(report.find("camera controls")->detail.find("320 x 240 mono8"), std::string::npos)
      << report.find("camera controls")->detail;
  EXPECT_NE(report.find("camera controls")->detail.find("software trigger"), std::string::npos);
  EXPECT_NE(report.find("camera link")->detail.find("GigE Vision at 127.0.0.1"), std::string::npos);
  // The same board asking for mono12, which the fake lacks: the check names the formats it has.
  board->camera_format.pixel_format = PixelFormat::mono12;
  const CheckReport wrong = check_board(*board, options);
  const CheckItem* controls = wrong.find("camera controls");
  ASSERT_NE(controls, nullptr) << wrong.to_text();
  EXPECT_EQ(controls->state, CheckState::missing);
  EXPECT_NE(controls->detail.find("needs one of Mono12, Mono12p, Mono12Packed"), std::string::npos) << controls->detail;
  EXPECT_NE(controls->fix.find("camera features"), std::string::npos) << controls->fix;
  EXPECT_FALSE(wrong.all_ok());
}

// ------------------------------------------------------------------ a whole scan through slscand

class AravisScan : public AravisFake {
 protected:
  void start_daemon() {
    auto board = load_board(std::string(SLSCAN_SOURCE_DIR) + "/boards/sim-gige.toml");
    ASSERT_TRUE(board.ok()) << board.error().message;
    board->camera_device = fake_.id();
    auto devices = open_board_devices(*board);
    ASSERT_TRUE(devices.ok()) << devices.error().message;
    DaemonOptions options;
    options.port = 0;
    options.realtime = false;
    auto daemon = Daemon::create(*board, std::move(*devices), options);
    ASSERT_TRUE(daemon.ok()) << daemon.error().message;
    daemon_ = std::move(*daemon);
    server_ = std::thread([this] { daemon_->serve(); });
  }
  void TearDown() override {
    if (daemon_) daemon_->stop();
    if (server_.joinable()) server_.join();
    daemon_.reset();
  }
  slproto::Connection connect() {
    auto connection = slproto::connect("127.0.0.1", daemon_->port(), 5s);
    EXPECT_TRUE(connection.ok()) << connection.error().message;
    auto reply = slproto::client_handshake(*connection, slproto::make_hello("test", "0", 0, ""));
    EXPECT_TRUE(reply.ok()) << reply.error().message;
    return std::move(*connection);
  }
  static pb::ScanRequest request(std::uint64_t id) {
    pb::ScanRequest r;
    r.set_scan_id(id);
    r.add_turntable_angles_deg(0);
    r.add_projectors(0);
    *r.mutable_plan() = slproto::to_proto(slproto::PatternPlanConfig{});
    r.set_exposure_us(2000);
    r.set_pattern_period_us(200000);
    r.set_pixel_format(pb::PIXEL_FORMAT_MONO8);
    r.set_timing_events(true);
    return r;
  }
  struct Received {
    std::vector<pb::FrameHeader> frames;
    std::vector<std::size_t> payload_bytes;
    std::vector<pb::Error> errors;
    std::optional<pb::ScanDone> done;
  };
  Received receive(slproto::Connection& c, const std::function<void(std::size_t)>& on_frame = {}) {
    Received r;
    for (;;) {
      auto m = c.receive(30s);
      EXPECT_TRUE(m.ok()) << m.error().message;
      if (!m) break;
      if (const auto* f = m->get<pb::FrameHeader>()) {
        r.frames.push_back(*f);
        r.payload_bytes.push_back(m->payload.size());
        if (on_frame) on_frame(r.frames.size());
      } else if (const auto* e = m->get<pb::Error>()) {
        r.errors.push_back(*e);
      } else if (const auto* d = m->get<pb::ScanDone>()) {
        r.done = *d;
        break;
      }
    }
    return r;
  }
  std::unique_ptr<Daemon> daemon_;
  std::thread server_;
};

TEST_F(AravisScan, ScanWithTheFakeCameraLosesNoFrameAndReportsItsTiming) {
  start_daemon();
  if (HasFatalFailure()) return;
  slproto::Connection c = connect();
  ASSERT_TRUE(c.send(request(7)).ok());
  const Received r = receive(c);
  ASSERT_TRUE(r.done.has_value());
  ASSERT_EQ(r.done->final_state(), pb::SCAN_STATE_DONE) << r.done->text();
  const std::size_t patterns = slproto::PatternPlan().size();
  EXPECT_EQ(r.done->frames_sent(), patterns);
  ASSERT_EQ(r.frames.size(), patterns);
  EXPECT_EQ(r.done->frames_dropped(), 0u);
  EXPECT_EQ(r.done->camera_frames_lost(), 0u);
  EXPECT_EQ(r.done->camera_packets_missing(), 0u);
  for (std::size_t i = 0; i < r.frames.size(); ++i) {
    const pb::FrameHeader& f = r.frames[i];
    EXPECT_EQ(f.sequence(), i);
    EXPECT_EQ(f.pattern_index(), i);
    EXPECT_EQ(f.width(), 320u);
    EXPECT_EQ(f.height(), 240u);
    EXPECT_EQ(r.payload_bytes[i], 320u * 240u);
    // The camera's own timestamps, on the board's clock, after the projector was triggered.
    EXPECT_GE(f.exposure_start_ns(), f.trigger_ns());
    EXPECT_LE(f.exposure_start_ns(), f.readout_ns());
  }
  bool exposure_stat = false;
  for (const auto& stat : r.done->timing()) {
    if (stat.name() == "trigger_to_exposure_start") {
      exposure_stat = true;
      EXPECT_EQ(stat.count(), patterns);
    }
  }
  EXPECT_TRUE(exposure_stat);
}

TEST_F(AravisScan, CameraKilledMidScanEndsInAClearErrorWithTheFramesSoFar) {
  start_daemon();
  if (HasFatalFailure()) return;
  slproto::Connection c = connect();
  ASSERT_TRUE(c.send(request(8)).ok());
  const Received r = receive(c, [&](std::size_t n) {
    if (n == 5) fake_.kill_camera();
  });
  ASSERT_TRUE(r.done.has_value());
  EXPECT_EQ(r.done->final_state(), pb::SCAN_STATE_FAILED);
  EXPECT_NE(r.done->text().find("stopped answering"), std::string::npos) << r.done->text();
  ASSERT_FALSE(r.errors.empty());
  EXPECT_NE(r.errors.front().text().find("camera"), std::string::npos);
  // What arrived before the camera went stays: every frame sent was received, in order.
  EXPECT_GE(r.frames.size(), 5u);
  EXPECT_LT(r.frames.size(), slproto::PatternPlan().size());
  EXPECT_EQ(r.done->frames_sent(), r.frames.size());
  for (std::size_t i = 0; i < r.frames.size(); ++i) EXPECT_EQ(r.frames[i].sequence(), i);
}

}  // namespace
