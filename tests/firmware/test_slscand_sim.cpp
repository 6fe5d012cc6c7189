// slscand on the sim board, driven by a host over loopback: a full 6-view scan arrives in
// order with its timing log; abort, disconnect and each device fault end the scan cleanly
// (projectors dark, an error naming the cause) and leave the daemon ready for the next scan.
#include <arpa/inet.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <thread>

#include "slproto/calibration_poses.hpp"
#include "slproto/handshake.hpp"
#include "slproto/status.hpp"
#include "slproto/transport.hpp"
#include "slscand/app/daemon.hpp"
#include "slscand/hal/sim/sim_rig.hpp"
#include "slscand/sequencer/scan_plan.hpp"

using namespace slscand;
using namespace std::chrono_literals;
namespace pb = slproto::pb;

namespace {

class DaemonFixture : public ::testing::Test {
 protected:
  void start(double frame_timeout_ms = 20000, std::string timing_log_dir = {},
             const std::function<void(hal::BoardConfig&)>& adjust = {},
             const std::function<void(DaemonOptions&)>& adjust_options = {}) {
    auto board = hal::load_board(std::string(SLSCAN_SOURCE_DIR) + "/boards/sim.toml");
    ASSERT_TRUE(board.ok()) << board.error().message;
    // The renderer's speed (ASan, a loaded CI machine) is not part of the timing model.
    board->frame_timeout_ms = frame_timeout_ms;
    if (adjust) adjust(*board);
    auto devices = hal::open_board_devices(*board);
    ASSERT_TRUE(devices.ok()) << devices.error().message;
    DaemonOptions options;
    options.port = 0;
    options.realtime = false;
    options.timing_log_dir = std::move(timing_log_dir);
    if (adjust_options) adjust_options(options);
    auto daemon = Daemon::create(*board, std::move(*devices), options);
    ASSERT_TRUE(daemon.ok()) << daemon.error().message;
    daemon_ = std::move(*daemon);
    server_ = std::thread([this] { daemon_->serve(); });
  }
  void TearDown() override {
    if (daemon_) daemon_->stop();
    if (server_.joinable()) server_.join();
  }

  slproto::Connection connect(const std::string& token = {}) {
    auto connection = slproto::connect("127.0.0.1", daemon_->port(), 5s);
    EXPECT_TRUE(connection.ok()) << connection.error().message;
    auto reply = slproto::client_handshake(*connection, slproto::make_hello("test", "0", 0, token));
    EXPECT_TRUE(reply.ok()) << reply.error().message;
    EXPECT_EQ(reply->board_name(), "sim");
    EXPECT_TRUE(reply->capabilities() & pb::CAPABILITY_SIMULATED);
    // boards/sim.toml's [timing]: what slscan asks for when its user does not say.
    EXPECT_EQ(reply->pattern_exposure_us(), 2000u);
    EXPECT_EQ(reply->pattern_period_us(), 5000u);
    return std::move(*connection);
  }

  static pb::ScanRequest request(std::uint64_t id, int views) {
    pb::ScanRequest r;
    r.set_scan_id(id);
    for (int v = 0; v < views; ++v) r.add_turntable_angles_deg(60.0 * v);
    r.add_projectors(0);
    r.add_projectors(1);
    *r.mutable_plan() = slproto::to_proto(slproto::PatternPlanConfig{});
    r.set_exposure_us(2000);
    r.set_pattern_period_us(5000);
    r.set_pixel_format(pb::PIXEL_FORMAT_MONO8);
    r.set_timing_events(true);
    return r;
  }

  struct Received {
    std::vector<pb::FrameHeader> frames;
    std::vector<double> means;  // mean pixel value per frame
    std::vector<pb::Error> errors;
    std::optional<pb::ScanDone> done;
    int progress = 0;
  };

  // Receives until ScanDone (or `stop_after` frames, then returns without it).
  static Received receive_scan(slproto::Connection& c, std::size_t stop_after = SIZE_MAX) {
    Received r;
    while (r.frames.size() < stop_after) {
      auto m = c.receive(60s);
      EXPECT_TRUE(m.ok()) << m.error().message;
      if (!m) break;
      if (const auto* f = m->get<pb::FrameHeader>()) {
        r.frames.push_back(*f);
        double sum = 0;
        for (std::byte b : m->payload) sum += static_cast<double>(std::to_integer<int>(b));
        r.means.push_back(m->payload.empty() ? 0 : sum / static_cast<double>(m->payload.size()));
      } else if (const auto* e = m->get<pb::Error>()) {
        r.errors.push_back(*e);
      } else if (const auto* d = m->get<pb::ScanDone>()) {
        r.done = *d;
        break;
      } else if (m->get<pb::Progress>() != nullptr) {
        r.progress++;
      }
    }
    return r;
  }

  // Receives until the daemon reports the turntable moving to `view`; false on anything else
  // that ends the scan first.
  static bool wait_until_moving_to(slproto::Connection& c, std::uint32_t view) {
    for (;;) {
      auto m = c.receive(60s);
      if (!m) return false;
      if (const auto* p = m->get<pb::Progress>()) {
        if (p->state() == pb::SCAN_STATE_MOVING && p->view_index() == view) return true;
      } else if (m->get<pb::ScanDone>() != nullptr) {
        return false;
      }
    }
  }

  // A table that does not move any more: two readings apart give the same angle.
  void expect_table_stopped() {
    auto& table = daemon_->devices().sim_rig->turntable();
    EXPECT_FALSE(table.moving());
    const double before = table.angle_deg();
    std::this_thread::sleep_for(150ms);
    EXPECT_DOUBLE_EQ(table.angle_deg(), before);
  }

  // A one-view scan where the table already is: proves the daemon takes the next scan.
  void expect_next_scan_runs(slproto::Connection& c, std::uint64_t id) {
    pb::ScanRequest next = request(id, 1);
    next.set_turntable_angles_deg(0, daemon_->devices().sim_rig->turntable().angle_deg());
    ASSERT_TRUE(c.send(next).ok());
    const Received r = receive_scan(c);
    ASSERT_TRUE(r.done.has_value());
    EXPECT_EQ(r.done->final_state(), pb::SCAN_STATE_DONE) << r.done->text();
    ASSERT_EQ(r.frames.size(), 38u);
    EXPECT_EQ(r.frames.front().sequence(), 0u);
    EXPECT_EQ(r.frames.back().scan_id(), id);
  }

  void expect_dark_and_idle() {
    const auto& board = daemon_->board();
    auto& rig = *daemon_->devices().sim_rig;
    for (int side = 0; side < 2; ++side) {
      EXPECT_FALSE(rig.line_value(board.projectors[side].trig_in_2)) << "projector " << side << " still running";
    }
    EXPECT_EQ(rig.projectors_lit(), (std::array<bool, 2>{false, false}));
    EXPECT_FALSE(daemon_->busy());
  }

  std::unique_ptr<Daemon> daemon_;
  std::thread server_;
};

bool has_event(const pb::FrameHeader& f, pb::TimingEventKind kind) {
  for (const auto& e : f.timing_events()) {
    if (e.kind() == kind) return true;
  }
  return false;
}

}  // namespace

TEST_F(DaemonFixture, FullSixViewScanArrivesInOrderWithTimingLog) {
  start();
  slproto::Connection c = connect();
  ASSERT_TRUE(c.send(request(42, 6)).ok());
  const Received r = receive_scan(c);
  ASSERT_TRUE(r.done.has_value());
  EXPECT_EQ(r.done->final_state(), pb::SCAN_STATE_DONE) << r.done->text();
  EXPECT_TRUE(r.errors.empty());
  EXPECT_EQ(r.done->frames_sent(), 6u * 2u * 19u);
  EXPECT_EQ(r.done->views_completed(), 6u);
  EXPECT_EQ(r.done->frames_dropped(), 0u);
  EXPECT_GE(r.progress, 6 * 3);  // moving, settling, capturing per view
  ASSERT_EQ(r.frames.size(), 6u * 2u * 19u);
  const slproto::PatternPlan plan;
  std::size_t k = 0;
  for (std::uint32_t view = 0; view < 6; ++view) {
    for (std::uint32_t side = 0; side < 2; ++side) {
      for (std::uint32_t p = 0; p < 19; ++p, ++k) {
        const pb::FrameHeader& f = r.frames[k];
        ASSERT_EQ(f.sequence(), k);
        EXPECT_EQ(f.scan_id(), 42u);
        EXPECT_EQ(f.view_index(), view);
        EXPECT_DOUBLE_EQ(f.commanded_angle_deg(), 60.0 * view);
        EXPECT_NEAR(f.reported_angle_deg(), 60.0 * view, 0.05);
        EXPECT_EQ(f.projector_id(), side);
        EXPECT_EQ(f.pattern_index(), p);
        EXPECT_EQ(f.pattern_kind(), static_cast<pb::PatternKind>(plan[p].kind));
        EXPECT_EQ(f.width(), 640u);
        EXPECT_EQ(f.height(), 512u);
        // Timestamps in causal order, and the log that produced them travels with the frame.
        EXPECT_GT(f.trigger_ns(), 0u);
        EXPECT_GE(f.exposure_start_ns(), f.trigger_ns());
        EXPECT_EQ(f.exposure_end_ns() - f.exposure_start_ns(), 2000u * 1000u);
        EXPECT_GE(f.readout_ns(), f.exposure_end_ns());
        EXPECT_TRUE(has_event(f, pb::TIMING_EVENT_PROJECTOR_TRIGGER));
        EXPECT_TRUE(has_event(f, pb::TIMING_EVENT_PATTERN_SHOWN));
        EXPECT_TRUE(has_event(f, pb::TIMING_EVENT_EXPOSURE_START));
        EXPECT_TRUE(has_event(f, pb::TIMING_EVENT_FRAME_DEQUEUED));
        if (side == 0 && p == 0) {
          EXPECT_TRUE(has_event(f, pb::TIMING_EVENT_TURNTABLE_MOVE_DONE));
          EXPECT_TRUE(has_event(f, pb::TIMING_EVENT_SETTLE_DONE));
        }
      }
      // The camera really saw the sequence: the white frame outshines the black one.
      const std::size_t first = k - 19;
      EXPECT_GT(r.means[first], r.means[first + 1] + 5) << "view " << view << " side " << side;
    }
  }
  bool has_period = false;
  for (const auto& stat : r.done->timing()) {
    if (stat.name() == "pattern_period") {
      has_period = true;
      EXPECT_GT(stat.count(), 0u);
      EXPECT_GT(stat.mean_us(), 4000);
    }
  }
  EXPECT_TRUE(has_period);
  // The board keeps the full report of the scan: one trigger-to-exposure latency per frame,
  // one period per consecutive pair in a pass unless back-pressure paused it.
  const TimingReport& report = daemon_->stats().last_timing;
  EXPECT_EQ(report.trigger_to_exposure.count, 6u * 2u * 19u);
  EXPECT_EQ(report.pattern_period.count + report.paused_frames, 6u * 2u * 18u);
  EXPECT_GE(report.trigger_to_exposure.p50_us, 5.0);  // the sim's camera latency (boards/sim.toml)
  EXPECT_LE(report.period_jitter.p50_us, report.period_jitter.p99_us);
  expect_dark_and_idle();
}

// HDR: a bracket captures every view at each exposure, projector passes inside each exposure,
// the frames saying which; the camera really exposed each for its time (the white frame's
// signal scales with it), and the board waits its exposure_change_frames after each change.
TEST_F(DaemonFixture, AnExposureBracketCapturesEveryViewAtEachExposureInOrder) {
  start(20000, {}, [](hal::BoardConfig& b) { b.exposure_change_frames = 3; });
  slproto::Connection c = connect();
  pb::ScanRequest bracketed = request(50, 2);
  for (const std::uint32_t us : {2000u, 500u}) bracketed.add_exposure_bracket_us(us);
  daemon_->devices().sim_rig->clear_records();
  ASSERT_TRUE(c.send(bracketed).ok());
  const Received r = receive_scan(c);
  ASSERT_TRUE(r.done.has_value());
  ASSERT_EQ(r.done->final_state(), pb::SCAN_STATE_DONE) << r.done->text();
  ASSERT_EQ(r.frames.size(), 2u * 2u * 2u * 19u);
  EXPECT_EQ(r.done->frames_sent(), r.frames.size());
  std::size_t k = 0;
  const std::uint32_t exposures[2] = {2000, 500};
  for (std::uint32_t view = 0; view < 2; ++view) {
    for (std::uint32_t e = 0; e < 2; ++e) {
      for (std::uint32_t side = 0; side < 2; ++side) {
        for (std::uint32_t p = 0; p < 19; ++p, ++k) {
          const pb::FrameHeader& f = r.frames[k];
          ASSERT_EQ(f.sequence(), k);
          EXPECT_EQ(f.view_index(), view);
          EXPECT_EQ(f.exposure_index(), e) << k;
          EXPECT_EQ(f.exposure_us(), exposures[e]) << k;
          EXPECT_EQ(f.projector_id(), side) << k;
          EXPECT_EQ(f.pattern_index(), p) << k;
          EXPECT_EQ(f.exposure_end_ns() - f.exposure_start_ns(), std::uint64_t{exposures[e]} * 1000u) << k;
        }
        // White minus black at a quarter of the exposure: a quarter of the signal (ambient
        // scales too, so the difference does), within the frames' rounding.
        const std::size_t first = k - 19;
        if (e == 1) {
          const std::size_t long_first = first - 2 * 19;
          const double long_signal = r.means[long_first] - r.means[long_first + 1];
          const double short_signal = r.means[first] - r.means[first + 1];
          EXPECT_GT(long_signal, 5);
          EXPECT_NEAR(short_signal / long_signal, 0.25, 0.03) << "view " << view << " side " << side;
        }
      }
    }
    // The change to the second exposure waited 3 periods (5 ms each) before its first trigger.
    const std::size_t last_long = view * 76 + 37, first_short = view * 76 + 38;
    EXPECT_GE(r.frames[first_short].trigger_ns() - r.frames[last_long].trigger_ns(), 3u * 5'000'000u);
    EXPECT_TRUE(has_event(r.frames[first_short], pb::TIMING_EVENT_EXPOSURE_CHANGED));
  }
  // The virtual camera saw what the frames say.
  const auto seen = daemon_->devices().sim_rig->exposures();
  ASSERT_EQ(seen.size(), r.frames.size());
  for (std::size_t i = 0; i < seen.size(); ++i)
    EXPECT_EQ(seen[i].exposure_ns, static_cast<Nanos>(r.frames[i].exposure_us()) * 1000) << i;
  expect_dark_and_idle();
}

TEST_F(DaemonFixture, ABracketTheBoardCannotRunIsRefusedNamingTheValueAndTheLimit) {
  start();
  slproto::Connection c = connect();
  auto refused = [&](const std::vector<std::uint32_t>& bracket) {
    pb::ScanRequest bad = request(60, 1);
    for (const std::uint32_t us : bracket) bad.add_exposure_bracket_us(us);
    EXPECT_TRUE(c.send(bad).ok());
    const Received r = receive_scan(c);
    EXPECT_TRUE(r.done.has_value() && r.done->final_state() == pb::SCAN_STATE_FAILED);
    EXPECT_TRUE(r.frames.empty());
    return r.errors.empty() ? std::string() : r.errors[0].text();
  };
  EXPECT_THAT(refused({2000, 100}), testing::HasSubstr("exposure_bracket_us[1] = 100 is below the projector's 235 us"));
  EXPECT_THAT(refused({2000, 6000}),
              testing::HasSubstr("exposure_bracket_us[1] = 6000 is longer than pattern_period_us 5000"));
  EXPECT_THAT(refused({2000, 500, 2000}), testing::HasSubstr("exposure_bracket_us[2] = 2000 repeats"));
  EXPECT_THAT(refused({2000, 1000, 900, 800, 700, 600, 500, 400, 300}), testing::HasSubstr("9 exposures (at most 8)"));
  // Within the period but too long for the board's read-out after it.
  EXPECT_THAT(refused({2000, 4000}), testing::HasSubstr("shorter than trigger delay + exposure + read-out"));
  EXPECT_EQ(daemon_->stats().scans_refused, 5u);
  expect_next_scan_runs(c, 61);
}

TEST_F(DaemonFixture, ACameraThatIgnoresTheExposureControlFailsTheBracketedScan) {
  start();
  slproto::Connection c = connect();
  hal::sim::SimFaults faults;
  faults.camera_ignores_exposure = true;
  daemon_->devices().sim_rig->set_faults(faults);
  pb::ScanRequest bracketed = request(70, 1);
  for (const std::uint32_t us : {2000u, 500u}) bracketed.add_exposure_bracket_us(us);
  ASSERT_TRUE(c.send(bracketed).ok());
  const Received r = receive_scan(c);
  ASSERT_TRUE(r.done.has_value());
  EXPECT_EQ(r.done->final_state(), pb::SCAN_STATE_FAILED);
  ASSERT_EQ(r.errors.size(), 1u);
  EXPECT_THAT(r.errors[0].text(),
              testing::HasSubstr("was exposed for 2000 us, not the 500 us asked (bracket member 1"));
  EXPECT_THAT(r.errors[0].text(), testing::HasSubstr("ignores or clamps its exposure control"));
  EXPECT_EQ(r.frames.size(), 38u);  // the first exposure's passes were right and delivered
  expect_dark_and_idle();
  daemon_->devices().sim_rig->set_faults({});
  expect_next_scan_runs(c, 71);
}

TEST_F(DaemonFixture, AbortEndsTheScanAndTheNextOneRuns) {
  start();
  slproto::Connection c = connect();
  ASSERT_TRUE(c.send(request(1, 6)).ok());
  Received partial = receive_scan(c, 10);
  ASSERT_EQ(partial.frames.size(), 10u);
  pb::Abort abort;
  abort.set_scan_id(1);
  abort.set_reason("operator");
  ASSERT_TRUE(c.send(abort).ok());
  const Received rest = receive_scan(c);
  ASSERT_TRUE(rest.done.has_value());
  EXPECT_EQ(rest.done->final_state(), pb::SCAN_STATE_ABORTED);
  EXPECT_NE(rest.done->text().find("aborted by the host: operator"), std::string::npos) << rest.done->text();
  EXPECT_LT(partial.frames.size() + rest.frames.size(), 6u * 2u * 19u);
  expect_dark_and_idle();

  ASSERT_TRUE(c.send(request(2, 1)).ok());
  const Received next = receive_scan(c);
  ASSERT_TRUE(next.done.has_value());
  EXPECT_EQ(next.done->final_state(), pb::SCAN_STATE_DONE) << next.done->text();
  EXPECT_EQ(next.frames.size(), 38u);
  EXPECT_EQ(next.frames.front().sequence(), 0u);
}

TEST_F(DaemonFixture, HostDisconnectLeavesTheDaemonReady) {
  start();
  {
    slproto::Connection c = connect();
    ASSERT_TRUE(c.send(request(5, 6)).ok());
    Received partial = receive_scan(c, 5);
    ASSERT_EQ(partial.frames.size(), 5u);
    c.close();
  }
  for (int i = 0; i < 500 && (daemon_->stats().scans_aborted + daemon_->stats().scans_failed) == 0; ++i) {
    std::this_thread::sleep_for(20ms);
  }
  const DaemonStats stats = daemon_->stats();
  EXPECT_EQ(stats.scans_aborted + stats.scans_failed, 1u);
  EXPECT_NE(stats.last_error.find("host"), std::string::npos) << stats.last_error;
  expect_dark_and_idle();

  slproto::Connection again = connect();
  ASSERT_TRUE(again.send(request(6, 1)).ok());
  const Received next = receive_scan(again);
  ASSERT_TRUE(next.done.has_value());
  EXPECT_EQ(next.done->final_state(), pb::SCAN_STATE_DONE) << next.done->text();
  EXPECT_EQ(next.frames.size(), 38u);
}

TEST_F(DaemonFixture, FaultsAreReportedWithTheirCause) {
  start(/*frame_timeout_ms=*/20000);
  slproto::Connection c = connect();
  hal::sim::SimRig& rig = *daemon_->devices().sim_rig;

  // A projector that does not acknowledge.
  hal::sim::SimFaults faults;
  faults.projector_silent[1] = true;
  rig.set_faults(faults);
  ASSERT_TRUE(c.send(request(10, 1)).ok());
  Received r = receive_scan(c);
  ASSERT_TRUE(r.done.has_value());
  EXPECT_EQ(r.done->final_state(), pb::SCAN_STATE_FAILED);
  ASSERT_EQ(r.errors.size(), 1u);
  EXPECT_EQ(slproto::errc_from_wire(r.errors[0].code()), slproto::Errc::hardware);
  EXPECT_NE(r.errors[0].text().find("projector.right did not acknowledge"), std::string::npos) << r.errors[0].text();
  EXPECT_EQ(r.frames.size(), 19u);  // the left pass was complete and delivered
  expect_dark_and_idle();

  // A turntable whose motor stalls.
  rig.set_faults({});
  hal::sim::TurntableFaults table_faults;
  table_faults.stall_at_deg = 30;
  rig.turntable().set_faults(table_faults);
  ASSERT_TRUE(c.send(request(11, 2)).ok());
  r = receive_scan(c);
  ASSERT_TRUE(r.done.has_value());
  EXPECT_EQ(r.done->final_state(), pb::SCAN_STATE_FAILED);
  ASSERT_EQ(r.errors.size(), 1u);
  EXPECT_NE(r.errors[0].text().find("stalled"), std::string::npos) << r.errors[0].text();
  EXPECT_FALSE(rig.turntable().moving());
  expect_dark_and_idle();

  // Faults cleared: the same connection scans again.
  rig.turntable().set_faults({});
  ASSERT_TRUE(c.send(request(12, 1)).ok());
  r = receive_scan(c);
  ASSERT_TRUE(r.done.has_value());
  EXPECT_EQ(r.done->final_state(), pb::SCAN_STATE_DONE) << r.done->text();
  EXPECT_EQ(r.frames.size(), 38u);
}

TEST_F(DaemonFixture, CameraTimeoutIsReported) {
  // Long enough for the renderer on a loaded machine (the scan after the fault must pass).
  start(/*frame_timeout_ms=*/5000);
  slproto::Connection c = connect();
  hal::sim::SimFaults faults;
  faults.camera_silent = true;
  daemon_->devices().sim_rig->set_faults(faults);
  ASSERT_TRUE(c.send(request(20, 1)).ok());
  const Received r = receive_scan(c);
  ASSERT_TRUE(r.done.has_value());
  EXPECT_EQ(r.done->final_state(), pb::SCAN_STATE_FAILED);
  ASSERT_EQ(r.errors.size(), 1u);
  EXPECT_NE(r.errors[0].text().find("camera timeout at view 0, left projector, pattern 0"), std::string::npos)
      << r.errors[0].text();
  expect_dark_and_idle();
  // The camera is back: the daemon scans again, numbering its frames from 0.
  daemon_->devices().sim_rig->set_faults({});
  expect_next_scan_runs(c, 21);
}

TEST_F(DaemonFixture, RefusedAndBusyRequests) {
  start();
  slproto::Connection c = connect();
  pb::ScanRequest bad = request(30, 1);
  bad.set_exposure_us(100);
  ASSERT_TRUE(c.send(bad).ok());
  const Received r = receive_scan(c);
  ASSERT_TRUE(r.done.has_value());
  EXPECT_EQ(r.done->final_state(), pb::SCAN_STATE_FAILED);
  ASSERT_EQ(r.errors.size(), 1u);
  EXPECT_NE(r.errors[0].text().find("235 us"), std::string::npos);
  EXPECT_EQ(daemon_->stats().scans_refused, 1u);

  // A second request while one runs is answered "busy"; the first completes.
  ASSERT_TRUE(c.send(request(31, 1)).ok());
  ASSERT_TRUE(c.send(request(32, 1)).ok());
  const Received first = receive_scan(c);
  ASSERT_TRUE(first.done.has_value());
  EXPECT_EQ(first.done->scan_id(), 31u);
  EXPECT_EQ(first.done->final_state(), pb::SCAN_STATE_DONE);
  ASSERT_EQ(first.errors.size(), 1u);
  EXPECT_EQ(slproto::errc_from_wire(first.errors[0].code()), slproto::Errc::busy);
}

// A calibration target the sim board cannot draw (a board of no thickness passes the protocol's
// check: a printed sheet is that thin) is the scan's error, naming the pose and the field; the
// daemon keeps serving. Before, the renderer's exception in the camera thread ended slscand.
TEST_F(DaemonFixture, ACalibrationTargetTheSimCannotDrawFailsTheScanNotTheDaemon) {
  start();
  slproto::Connection c = connect();
  const slproto::GuidedCalibrationPose& pose = slproto::calibration_pose_guide().front();
  pb::ScanRequest scan = request(40, 1);
  *scan.mutable_calibration_target() = slproto::to_proto(pose, slproto::CheckerboardSize{9, 7, 15, 0});
  ASSERT_TRUE(c.send(scan).ok());
  const Received r = receive_scan(c);
  ASSERT_TRUE(r.done.has_value());
  EXPECT_EQ(r.done->final_state(), pb::SCAN_STATE_FAILED);
  ASSERT_EQ(r.errors.size(), 1u);
  EXPECT_NE(r.errors[0].text().find("sim board: cannot place the calibration target '" + pose.name + "'"),
            std::string::npos)
      << r.errors[0].text();
  EXPECT_NE(r.errors[0].text().find("thickness must be > 0"), std::string::npos) << r.errors[0].text();
  EXPECT_TRUE(r.frames.empty());
  expect_dark_and_idle();
  expect_next_scan_runs(c, 41);
}

TEST_F(DaemonFixture, TimingLogIsWrittenOnTheBoard) {
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("slscand-timing-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  start(20000, dir.string());
  slproto::Connection c = connect();
  ASSERT_TRUE(c.send(request(77, 1)).ok());
  const Received r = receive_scan(c);
  ASSERT_TRUE(r.done.has_value());
  ASSERT_EQ(r.done->final_state(), pb::SCAN_STATE_DONE) << r.done->text();
  std::ifstream in(dir / "scan-77-timing.csv");
  ASSERT_TRUE(in.good());
  std::stringstream text;
  text << in.rdbuf();
  const std::string log = text.str();
  auto count = [&](const std::string& kind) {
    std::size_t n = 0;
    for (std::size_t pos = log.find(kind); pos != std::string::npos; pos = log.find(kind, pos + 1)) ++n;
    return n;
  };
  EXPECT_EQ(count("TIMING_EVENT_PROJECTOR_TRIGGER,"), 38u);
  EXPECT_EQ(count("TIMING_EVENT_FRAME_SENT,"), 38u);  // only the board's log has the send times
  EXPECT_EQ(count("TIMING_EVENT_TURNTABLE_MOVE_DONE,"), 1u);
  std::filesystem::remove_all(dir);
}

// A slow table (5 deg/s: the 60 deg move takes 12 s) so the host's abort lands mid-move, and
// "stopped at once" stays distinguishable from "stopped at the end" on a loaded machine.
void slow_turntable(hal::BoardConfig& board) { board.feed_deg_per_min = 300; }

TEST_F(DaemonFixture, AbortDuringATurntableMoveStopsTheTableAtOnce) {
  start(20000, {}, slow_turntable);
  slproto::Connection c = connect();
  ASSERT_TRUE(c.send(request(50, 2)).ok());
  ASSERT_TRUE(wait_until_moving_to(c, 1));
  std::this_thread::sleep_for(300ms);
  pb::Abort abort;
  abort.set_scan_id(50);
  abort.set_reason("operator");
  const auto sent = std::chrono::steady_clock::now();
  ASSERT_TRUE(c.send(abort).ok());
  const Received rest = receive_scan(c);
  const auto took = std::chrono::steady_clock::now() - sent;
  ASSERT_TRUE(rest.done.has_value());
  EXPECT_EQ(rest.done->final_state(), pb::SCAN_STATE_ABORTED);
  EXPECT_EQ(rest.done->views_completed(), 1u);
  EXPECT_NE(rest.done->text().find("aborted by the host: operator"), std::string::npos) << rest.done->text();
  EXPECT_NE(rest.done->text().find("turntable move to 60.000 deg aborted"), std::string::npos) << rest.done->text();
  // Not after the move: the rest of it would take over 11 s.
  EXPECT_LT(took, 6s);
  const double stopped_at = daemon_->devices().sim_rig->turntable().angle_deg();
  EXPECT_GT(stopped_at, 0.2);
  EXPECT_LT(stopped_at, 40.0);
  expect_table_stopped();
  expect_dark_and_idle();
  expect_next_scan_runs(c, 51);
}

TEST_F(DaemonFixture, HostDisconnectDuringATurntableMoveStopsTheTable) {
  start(20000, {}, slow_turntable);
  {
    slproto::Connection c = connect();
    ASSERT_TRUE(c.send(request(55, 2)).ok());
    ASSERT_TRUE(wait_until_moving_to(c, 1));
    std::this_thread::sleep_for(300ms);
    c.close();
  }
  for (int i = 0; i < 300 && (daemon_->stats().scans_aborted + daemon_->stats().scans_failed) == 0; ++i) {
    std::this_thread::sleep_for(20ms);
  }
  const DaemonStats stats = daemon_->stats();
  ASSERT_EQ(stats.scans_aborted, 1u) << stats.last_error;  // within 6 s, not after the 12 s move
  EXPECT_NE(stats.last_error.find("host disconnected"), std::string::npos) << stats.last_error;
  EXPECT_LT(daemon_->devices().sim_rig->turntable().angle_deg(), 40.0);
  expect_table_stopped();
  expect_dark_and_idle();
  slproto::Connection again = connect();
  expect_next_scan_runs(again, 56);
}

TEST_F(DaemonFixture, TurntableTimeoutsEndTheScan) {
  start(20000, {}, [](hal::BoardConfig& board) {
    slow_turntable(board);
    board.move_timeout_s = 0.5;  // the 60 deg move needs 12 s
  });
  slproto::Connection c = connect();
  ASSERT_TRUE(c.send(request(60, 2)).ok());
  Received r = receive_scan(c);
  ASSERT_TRUE(r.done.has_value());
  EXPECT_EQ(r.done->final_state(), pb::SCAN_STATE_FAILED);
  EXPECT_EQ(r.frames.size(), 38u);  // view 0 (no move) was delivered
  ASSERT_EQ(r.errors.size(), 1u);
  EXPECT_EQ(slproto::errc_from_wire(r.errors[0].code()), slproto::Errc::timeout);
  EXPECT_NE(r.errors[0].text().find("did not reach 60.000 deg within 500 ms"), std::string::npos) << r.errors[0].text();
  EXPECT_LT(daemon_->devices().sim_rig->turntable().angle_deg(), 20.0);
  expect_table_stopped();
  expect_dark_and_idle();
  expect_next_scan_runs(c, 61);

  // A controller that stops answering altogether: the move command itself is never acknowledged.
  hal::sim::TurntableFaults silent;
  silent.silent = true;
  daemon_->devices().sim_rig->turntable().set_faults(silent);
  ASSERT_TRUE(c.send(request(62, 2)).ok());
  r = receive_scan(c);
  ASSERT_TRUE(r.done.has_value());
  EXPECT_EQ(r.done->final_state(), pb::SCAN_STATE_FAILED);
  ASSERT_EQ(r.errors.size(), 1u);
  EXPECT_NE(r.errors[0].text().find("turntable did not acknowledge 'G1X0.000"), std::string::npos)
      << r.errors[0].text();
  expect_dark_and_idle();
  daemon_->devices().sim_rig->turntable().set_faults({});
  expect_next_scan_runs(c, 63);
}

namespace {
slproto::Result<pb::StatusReply> ask_status(std::uint16_t port) {
  auto connection = slproto::connect("127.0.0.1", port, 5s);
  if (!connection) return std::move(connection).error();
  auto reply = slproto::client_handshake(*connection, slproto::make_hello("status", "0"));
  if (!reply) return std::move(reply).error();
  return slproto::request_status(*connection, *reply, 5s);
}
}  // namespace

TEST_F(DaemonFixture, StatusNamesTheBoardItsVersionsAndItsLastScan) {
  start();
  auto before = ask_status(daemon_->port());
  ASSERT_TRUE(before.ok()) << before.error().message;
  EXPECT_EQ(before->board_name(), "sim");
  EXPECT_EQ(before->software_version(), software_version());
  EXPECT_EQ(before->protocol_version(), slproto::protocol_version);
  EXPECT_EQ(before->min_protocol_version(), slproto::min_protocol_version);
  EXPECT_EQ(before->max_protocol_version(), slproto::protocol_version);
  EXPECT_TRUE(before->capabilities() & pb::CAPABILITY_SIMULATED);
  EXPECT_FALSE(before->has_last_scan());
  EXPECT_FALSE(before->scanning());

  slproto::Connection c = connect();
  ASSERT_TRUE(c.send(request(71, 1)).ok());
  const Received r = receive_scan(c);
  ASSERT_TRUE(r.done.has_value());
  ASSERT_EQ(r.done->final_state(), pb::SCAN_STATE_DONE) << r.done->text();

  // The scanning host stays connected: a second host gets a status-only connection.
  auto after = ask_status(daemon_->port());
  ASSERT_TRUE(after.ok()) << after.error().message;
  ASSERT_TRUE(after->has_last_scan());
  const pb::LastScan& last = after->last_scan();
  EXPECT_EQ(last.scan_id(), 71u);
  EXPECT_EQ(last.final_state(), pb::SCAN_STATE_DONE);
  EXPECT_EQ(last.views_completed(), 1u);
  EXPECT_EQ(last.views_requested(), 1u);
  EXPECT_EQ(last.frames_sent(), 38u);
  EXPECT_EQ(last.frames_total(), 38u);
  EXPECT_EQ(last.text(), "scan complete");
  EXPECT_THAT(last.host(), ::testing::StartsWith("127.0.0.1:"));
  const auto now_ns =
      std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::system_clock::now().time_since_epoch()).count();
  EXPECT_NEAR(static_cast<double>(last.finished_unix_ns()), static_cast<double>(now_ns), 120e9);
  EXPECT_EQ(after->scans_done(), 1u);
  EXPECT_GE(after->connections(), 3u);

  // ...whose scan request is refused naming the host that has the scanner.
  auto second = slproto::connect("127.0.0.1", daemon_->port(), 5s);
  ASSERT_TRUE(second.ok());
  ASSERT_TRUE(slproto::client_handshake(*second, slproto::make_hello("second", "0")).ok());
  ASSERT_TRUE(second->send(request(72, 1)).ok());
  auto refused = second->receive_as<pb::ScanDone>(10s);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().code, slproto::Errc::busy);
  EXPECT_THAT(refused.error().message, ::testing::HasSubstr("busy: host 127.0.0.1:"));
  EXPECT_THAT(refused.error().message, ::testing::HasSubstr("is connected (one host at a time)"));

  // The first host can ask too, on its own connection.
  pb::HelloReply negotiated;
  negotiated.set_protocol_version(slproto::protocol_version);
  auto own = slproto::request_status(c, negotiated, 5s);
  ASSERT_TRUE(own.ok()) << own.error().message;
  EXPECT_EQ(own->last_scan().scan_id(), 71u);
}

// ---- faults of issue 8 that the tests above do not cover (docs/faults.md)

TEST_F(DaemonFixture, TurntableGarbageIsSkippedAndAWrongAngleEndsTheScan) {
  start();
  slproto::Connection c = connect();
  auto& table = daemon_->devices().sim_rig->turntable();
  // Line noise before every reply: the driver skips it and the scan completes.
  hal::sim::TurntableFaults noisy;
  noisy.garbage = true;
  table.set_faults(noisy);
  ASSERT_TRUE(c.send(request(70, 2)).ok());
  Received r = receive_scan(c);
  ASSERT_TRUE(r.done.has_value());
  EXPECT_EQ(r.done->final_state(), pb::SCAN_STATE_DONE) << r.done->text();
  EXPECT_EQ(r.frames.size(), 2u * 38u);

  // A table that lands 0.5 deg off: the scan fails naming both angles; view 0's frames arrived.
  hal::sim::TurntableFaults off;
  off.landing_error_deg = 0.5;
  table.set_faults(off);
  ASSERT_TRUE(c.send(request(71, 2)).ok());
  r = receive_scan(c);
  ASSERT_TRUE(r.done.has_value());
  EXPECT_EQ(r.done->final_state(), pb::SCAN_STATE_FAILED);
  ASSERT_EQ(r.errors.size(), 1u);
  EXPECT_EQ(slproto::errc_from_wire(r.errors[0].code()), slproto::Errc::hardware);
  EXPECT_NE(r.errors[0].text().find("after a move to"), std::string::npos) << r.errors[0].text();
  EXPECT_NE(r.errors[0].text().find("tolerance"), std::string::npos) << r.errors[0].text();
  expect_dark_and_idle();
  table.set_faults({});
  expect_next_scan_runs(c, 72);
}

TEST_F(DaemonFixture, DroppedAndShortCameraFramesEndTheScanWithTheCause) {
  start();
  slproto::Connection c = connect();
  hal::sim::SimRig& rig = *daemon_->devices().sim_rig;
  hal::sim::SimFaults drop;
  drop.drop_frame_after = 5;
  rig.set_faults(drop);
  ASSERT_TRUE(c.send(request(80, 1)).ok());
  Received r = receive_scan(c);
  ASSERT_TRUE(r.done.has_value());
  EXPECT_EQ(r.done->final_state(), pb::SCAN_STATE_FAILED);
  ASSERT_EQ(r.errors.size(), 1u);
  EXPECT_NE(r.errors[0].text().find("camera dropped 1 frame(s)"), std::string::npos) << r.errors[0].text();
  // The five frames before the gap were delivered, and nothing after it.
  EXPECT_EQ(r.frames.size(), 5u);
  for (std::size_t i = 0; i < r.frames.size(); ++i) EXPECT_EQ(r.frames[i].sequence(), i);
  expect_dark_and_idle();

  hal::sim::SimFaults short_frame;
  short_frame.short_frame_after = 3;
  rig.set_faults(short_frame);
  ASSERT_TRUE(c.send(request(81, 1)).ok());
  r = receive_scan(c);
  ASSERT_TRUE(r.done.has_value());
  EXPECT_EQ(r.done->final_state(), pb::SCAN_STATE_FAILED);
  ASSERT_EQ(r.errors.size(), 1u);
  EXPECT_NE(r.errors[0].text().find("bytes; expected 640 x 512 mono8 with 327680 bytes"), std::string::npos)
      << r.errors[0].text();
  EXPECT_EQ(r.frames.size(), 3u);
  expect_dark_and_idle();
  rig.set_faults({});
  expect_next_scan_runs(c, 82);
}

TEST_F(DaemonFixture, SlowHostPausesTheSequenceAndLosesNoFrame) {
  // A two-frame queue and small socket buffers: a host that takes 30 ms per frame (the
  // pattern period is 5 ms) fills them within a few frames, and the sequencer must wait.
  start(20000, {}, {}, [](DaemonOptions& options) {
    options.queue_capacity = 2;
    options.connection.socket_buffer_bytes = 64 << 10;
  });
  slproto::ConnectionOptions small;
  small.socket_buffer_bytes = 64 << 10;
  auto connection = slproto::connect("127.0.0.1", daemon_->port(), 5s, small);
  ASSERT_TRUE(connection.ok()) << connection.error().message;
  ASSERT_TRUE(slproto::client_handshake(*connection, slproto::make_hello("slow", "0")).ok());
  ASSERT_TRUE(connection->send(request(90, 1)).ok());
  std::vector<std::uint64_t> sequences;
  std::optional<pb::ScanDone> done;
  while (!done) {
    auto m = connection->receive(60s);
    ASSERT_TRUE(m.ok()) << m.error().message;
    if (const auto* f = m->get<pb::FrameHeader>()) {
      sequences.push_back(f->sequence());
      // A long stall after the first frame makes the host the bottleneck even where the virtual
      // camera renders slowly (the firmware tests also run under qemu-user emulation).
      std::this_thread::sleep_for(sequences.size() == 1 ? 2000ms : 30ms);
    } else if (const auto* d = m->get<pb::ScanDone>()) {
      done = *d;
    }
  }
  EXPECT_EQ(done->final_state(), pb::SCAN_STATE_DONE) << done->text();
  ASSERT_EQ(sequences.size(), 38u);
  for (std::size_t i = 0; i < sequences.size(); ++i) EXPECT_EQ(sequences[i], i);
  EXPECT_EQ(done->frames_dropped(), 0u);
  // The daemon records the scan's statistics after the host has its ScanDone.
  for (int i = 0; i < 200 && daemon_->stats().last_backpressure_pauses == 0; ++i) std::this_thread::sleep_for(10ms);
  EXPECT_GT(daemon_->stats().last_backpressure_pauses, 0u) << "the slow host never held the sequencer back";
}

// ---- network security (docs/security.md)

TEST_F(DaemonFixture, SecondHostIsTurnedAwayAndCannotTouchTheRunningScan) {
  start();
  slproto::Connection c = connect();
  ASSERT_TRUE(c.send(request(100, 2)).ok());
  Received first = receive_scan(c, 4);
  ASSERT_EQ(first.frames.size(), 4u);

  // A second host during the scan may ask for status, but its abort is refused naming who holds
  // the scanner, its connection is closed, and the running scan does not notice.
  auto other = slproto::connect("127.0.0.1", daemon_->port(), 5s);
  ASSERT_TRUE(other.ok()) << other.error().message;
  auto reply = slproto::client_handshake(*other, slproto::make_hello("intruder", "0"));
  ASSERT_TRUE(reply.ok()) << reply.error().message;
  auto status = slproto::request_status(*other, *reply, 5s);
  ASSERT_TRUE(status.ok()) << status.error().message;
  EXPECT_TRUE(status->scanning());
  pb::Abort abort;
  abort.set_scan_id(100);
  abort.set_reason("hijack");
  ASSERT_TRUE(other->send(abort).ok());
  auto refused = other->receive_as<pb::ScanDone>(5s);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().code, slproto::Errc::busy);
  EXPECT_NE(refused.error().message.find("busy: scan in progress for 127.0.0.1:"), std::string::npos)
      << refused.error().message;
  other->close();

  const Received rest = receive_scan(c);
  ASSERT_TRUE(rest.done.has_value());
  EXPECT_EQ(rest.done->final_state(), pb::SCAN_STATE_DONE) << rest.done->text();
  EXPECT_EQ(first.frames.size() + rest.frames.size(), 2u * 38u);
  for (int i = 0; i < 200 && daemon_->stats().connections_turned_away == 0; ++i) std::this_thread::sleep_for(10ms);
  EXPECT_EQ(daemon_->stats().connections_turned_away, 1u);

  // Idle but connected still holds the scanner; once the first host leaves, the next one scans.
  auto idle_other = slproto::connect("127.0.0.1", daemon_->port(), 5s);
  ASSERT_TRUE(idle_other.ok());
  ASSERT_TRUE(slproto::client_handshake(*idle_other, slproto::make_hello("second", "0")).ok());
  ASSERT_TRUE(idle_other->send(request(102, 1)).ok());
  auto idle_refused = idle_other->receive_as<pb::ScanDone>(5s);
  ASSERT_FALSE(idle_refused.ok());
  EXPECT_NE(idle_refused.error().message.find("is connected (one host at a time)"), std::string::npos)
      << idle_refused.error().message;
  idle_other->close();
  c.close();
  std::this_thread::sleep_for(300ms);
  slproto::Connection next = connect();
  expect_next_scan_runs(next, 101);
}

// Waits until the daemon closes a raw socket; returns how long that took.
std::chrono::milliseconds time_until_closed(int fd, std::chrono::seconds limit) {
  const auto begin = std::chrono::steady_clock::now();
  timeval tv{static_cast<time_t>(limit.count()), 0};
  ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  char buffer[4096];
  while (::recv(fd, buffer, sizeof buffer, 0) > 0) {
  }
  return std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::steady_clock::now() - begin);
}

int raw_connect(std::uint16_t port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_port = htons(port);
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0) {
    ::close(fd);
    return -1;
  }
  return fd;
}

TEST_F(DaemonFixture, SilentOversizedAndUnauthorisedConnectionsAreDropped) {
  start(20000, {}, {}, [](DaemonOptions& options) {
    options.handshake_timeout = 1000ms;
    options.auth_token = "0123456789abcdef-token";
  });
  // Slowloris: connects and says nothing. Dropped at the handshake timeout (the transport's
  // silent-peer check may drop it sooner), not held.
  const int silent = raw_connect(daemon_->port());
  ASSERT_GE(silent, 0);
  EXPECT_LT(time_until_closed(silent, 10s), 2500ms);
  ::close(silent);
  // The daemon counts a failed handshake after the peer has its answer: wait for the count,
  // so the silent peer's error cannot land after the oversized one's and hide it.
  auto wait_for_failed_handshakes = [&](std::uint64_t n) {
    for (int i = 0; i < 200 && daemon_->stats().handshakes_failed < n; ++i) std::this_thread::sleep_for(10ms);
    return daemon_->stats().handshakes_failed;
  };
  EXPECT_EQ(wait_for_failed_handshakes(1), 1u);

  // A hello with a 200 KB name: over the 64 KiB control limit, refused on its header alone.
  pb::Hello huge = slproto::make_hello(std::string(200 << 10, 'x'), "0", 0, "0123456789abcdef-token");
  auto bytes = slproto::encode(huge);
  ASSERT_TRUE(bytes.ok());
  const int big = raw_connect(daemon_->port());
  ASSERT_GE(big, 0);
  (void)::send(big, bytes->data(), 64, MSG_NOSIGNAL);  // the header and a little more
  EXPECT_LT(time_until_closed(big, 10s), 2500ms);
  ::close(big);
  EXPECT_EQ(wait_for_failed_handshakes(2), 2u);
  EXPECT_NE(daemon_->stats().last_error.find("limit"), std::string::npos) << daemon_->stats().last_error;

  // No token, a wrong one, a prefix of the right one: refused, and each says why.
  for (const std::string& token :
       {std::string(), std::string("wrong-token-wrong-token"), std::string("0123456789abcdef")}) {
    auto connection = slproto::connect("127.0.0.1", daemon_->port(), 5s);
    ASSERT_TRUE(connection.ok());
    auto reply = slproto::client_handshake(*connection, slproto::make_hello("test", "0", 0, token));
    ASSERT_FALSE(reply.ok()) << "token '" << token << "' was accepted";
    EXPECT_EQ(reply.error().code, slproto::Errc::unauthorized);
  }
  EXPECT_EQ(wait_for_failed_handshakes(5), 5u);
  // The right token: the daemon serves the scan after all of that.
  slproto::Connection c = connect("0123456789abcdef-token");
  expect_next_scan_runs(c, 110);
}

TEST_F(DaemonFixture, ConnectionsBeyondTheLimitAreToldBusyAndTheHolderKeepsScanning) {
  start(20000, {}, {}, [](DaemonOptions& options) { options.max_connections = 2; });
  slproto::Connection c = connect();
  // A silent connection takes no slot: it is still in its hello (issue 17, fault 9).
  const int silent = raw_connect(daemon_->port());
  ASSERT_GE(silent, 0);
  std::this_thread::sleep_for(200ms);
  // A second host past its hello (status-only) fills the second slot.
  slproto::Connection second = connect();
  auto third = slproto::connect("127.0.0.1", daemon_->port(), 5s);
  ASSERT_TRUE(third.ok());
  auto reply = slproto::client_handshake(*third, slproto::make_hello("third", "0"));
  ASSERT_FALSE(reply.ok());
  EXPECT_EQ(reply.error().code, slproto::Errc::busy) << reply.error().message;
  EXPECT_NE(reply.error().message.find("connections (the limit)"), std::string::npos) << reply.error().message;
  ::close(silent);
  second.close();
  expect_next_scan_runs(c, 120);
}

// Issue 17, fault 9: eight silent connections, each reopened as soon as the daemon drops it,
// used to fill the connection limit (4) and get a real `slscan status` refused as busy 10 of
// 14 times. A connection in its hello no longer takes a slot.
TEST_F(DaemonFixture, SilentConnectionsReopenedWhenDroppedCannotLockOutStatus) {
  start(20000, {}, {}, [](DaemonOptions& options) { options.handshake_timeout = 500ms; });
  std::atomic<bool> done{false};
  std::atomic<int> reopened{0};
  std::thread attacker([&] {
    std::vector<int> fds(8, -1);
    while (!done) {
      for (int& fd : fds) {
        if (fd >= 0) {
          char byte;
          const ssize_t n = ::recv(fd, &byte, 1, MSG_DONTWAIT);
          if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) continue;  // still open
          ::close(fd);
          ++reopened;
        }
        fd = raw_connect(daemon_->port());
      }
      std::this_thread::sleep_for(1ms);
    }
    for (int fd : fds)
      if (fd >= 0) ::close(fd);
  });
  // Start asking once the daemon has dropped (and the attacker reopened) all eight once.
  for (int i = 0; i < 3000 && reopened.load() < 8; ++i) std::this_thread::sleep_for(10ms);
  const int reopened_before = reopened.load();
  int answered = 0;
  std::string refusals;
  for (int i = 0; i < 14; ++i) {
    auto status = ask_status(daemon_->port());
    if (status.ok())
      ++answered;
    else
      refusals += status.error().message + "\n";
    std::this_thread::sleep_for(100ms);  // spread the questions over several handshake timeouts
  }
  done = true;
  attacker.join();
  EXPECT_GE(reopened_before, 8) << "the silent connections were never dropped and reopened";
  EXPECT_GT(reopened.load(), reopened_before) << "no silent connection was dropped and reopened while asking";
  EXPECT_EQ(answered, 14) << refusals;
}

// More connections in their hello than max_handshakes: the oldest is dropped for the newcomer
// at once (not at its handshake timeout), and the newcomer is served.
TEST_F(DaemonFixture, TheOldestSilentHelloMakesRoomForANewcomer) {
  start(20000, {}, {}, [](DaemonOptions& options) {
    options.max_handshakes = 2;
    options.handshake_timeout = 30000ms;
  });
  const int oldest = raw_connect(daemon_->port());
  ASSERT_GE(oldest, 0);
  std::this_thread::sleep_for(100ms);
  const int newer = raw_connect(daemon_->port());
  ASSERT_GE(newer, 0);
  std::this_thread::sleep_for(100ms);
  auto status = ask_status(daemon_->port());
  EXPECT_TRUE(status.ok()) << status.error().message;
  EXPECT_LT(time_until_closed(oldest, 10s), 10s) << "the oldest hello was not dropped";
  ::close(oldest);
  ::close(newer);
}

TEST_F(DaemonFixture, ScanPlanLimitsAreEnforced) {
  start();
  slproto::Connection c = connect();
  auto refused = [&](const pb::ScanRequest& r, const std::string& expected) {
    ASSERT_TRUE(c.send(r).ok());
    const Received got = receive_scan(c);
    ASSERT_TRUE(got.done.has_value());
    EXPECT_EQ(got.done->final_state(), pb::SCAN_STATE_FAILED);
    ASSERT_EQ(got.errors.size(), 1u);
    EXPECT_NE(got.errors[0].text().find(expected), std::string::npos) << got.errors[0].text();
    EXPECT_TRUE(got.frames.empty());
  };
  pb::ScanRequest many = request(120, 1);
  for (int v = 1; v <= kMaxScanViews; ++v) many.add_turntable_angles_deg(0.5 * v);
  refused(many, "views (turntable_angles_deg) 361 is over the limit of 360");
  pb::ScanRequest long_exposure = request(121, 1);
  long_exposure.set_exposure_us(kMaxExposureUs + 1);
  long_exposure.set_pattern_period_us(kMaxPatternPeriodUs);
  refused(long_exposure, "exposure_us 1000001 is over the limit");
  pb::ScanRequest long_settle = request(122, 1);
  long_settle.set_settle_ms(kMaxSettleMs + 1);
  refused(long_settle, "settle_ms 60001 is over the limit");
  EXPECT_EQ(daemon_->stats().scans_refused, 3u);
  expect_next_scan_runs(c, 123);
}

TEST(DaemonPolicy, NetworkAddressNeedsATokenOrAnExplicitOptOut) {
  auto board = hal::load_board(std::string(SLSCAN_SOURCE_DIR) + "/boards/sim.toml");
  ASSERT_TRUE(board.ok());
  auto attempt = [&](const std::string& address, const std::string& token, bool insecure) {
    auto devices = hal::open_board_devices(*board);
    EXPECT_TRUE(devices.ok());
    DaemonOptions options;
    options.bind_address = address;
    options.port = 0;
    options.realtime = false;
    options.auth_token = token;
    options.insecure_no_token = insecure;
    return Daemon::create(*board, std::move(*devices), options);
  };
  auto refused = attempt("0.0.0.0", "", false);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().code, slproto::Errc::unauthorized);
  EXPECT_NE(refused.error().message.find("refusing to listen on 0.0.0.0 without a token"), std::string::npos);
  EXPECT_TRUE(attempt("0.0.0.0", "0123456789abcdef-token", false).ok());
  EXPECT_TRUE(attempt("0.0.0.0", "", true).ok());
  EXPECT_TRUE(attempt("127.0.0.1", "", false).ok());
}
