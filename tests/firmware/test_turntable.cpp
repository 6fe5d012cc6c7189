// The GRBL turntable driver through the termios serial port against the pty emulator: normal
// moves wait for completion (not the queue ack), and each fault gives its own clear error
// and leaves the driver usable.
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <thread>

#include "slscand/hal/grbl/grbl_turntable.hpp"
#include "slscand/hal/sim/turntable_emulator.hpp"

using namespace slscand;
using namespace slscand::hal;
using slproto::Errc;

namespace {

struct Rig {
  std::unique_ptr<sim::TurntableEmulator> emulator;
  std::unique_ptr<GrblTurntable> table;
};

Rig connect_rig(GrblOptions options = {}, double feed_deg_per_s = 720) {
  Rig rig;
  auto emulator = sim::TurntableEmulator::start(720);  // 720 deg/s: fast tests
  EXPECT_TRUE(emulator.ok());
  rig.emulator = std::move(*emulator);
  auto port = open_termios_port(rig.emulator->slave_path(), 115200);
  EXPECT_TRUE(port.ok()) << port.error().message;
  options.feed_deg_per_min = feed_deg_per_s * 60;
  options.stall_timeout_ns = 150 * kMilli;
  options.banner_timeout_ns = 500 * kMilli;
  auto table = GrblTurntable::connect(std::move(*port), options);
  EXPECT_TRUE(table.ok()) << table.error().message;
  if (table) rig.table = std::move(*table);
  return rig;
}

}  // namespace

TEST(GrblStatus, Parses) {
  auto s = parse_grbl_status("<Idle|MPos:60.000,0.000,0.000|FS:0,0>");
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->state, TurntableState::idle);
  EXPECT_DOUBLE_EQ(s->angle_deg, 60.0);
  auto run = parse_grbl_status("<Run|WPos:-12.5,0,0>");
  ASSERT_TRUE(run.ok());
  EXPECT_EQ(run->state, TurntableState::moving);
  EXPECT_DOUBLE_EQ(run->angle_deg, -12.5);
  EXPECT_EQ(parse_grbl_status("<Alarm|MPos:1,0,0>")->state, TurntableState::alarm);
  EXPECT_FALSE(parse_grbl_status("ok").ok());
  EXPECT_FALSE(parse_grbl_status("<Idle|FS:0,0>").ok());
  EXPECT_FALSE(parse_grbl_status("<Idle|MPos:abc>").ok());
}

TEST(TermiosPort, ClearErrors) {
  auto missing = open_termios_port("/dev/ttyDOESNOTEXIST", 115200);
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find("/dev/ttyDOESNOTEXIST"), std::string::npos);
  auto not_tty = open_termios_port("/dev/null", 115200);
  ASSERT_FALSE(not_tty.ok());
  EXPECT_NE(not_tty.error().message.find("not a serial port"), std::string::npos);
  auto emulator = sim::TurntableEmulator::start();
  ASSERT_TRUE(emulator.ok());
  auto bad_baud = open_termios_port((*emulator)->slave_path(), 12345);
  ASSERT_FALSE(bad_baud.ok());
  EXPECT_NE(bad_baud.error().message.find("12345"), std::string::npos);
}

TEST(TermiosPort, ReadLineSplitsAndTimesOut) {
  auto emulator = sim::TurntableEmulator::start();
  ASSERT_TRUE(emulator.ok());
  auto port = open_termios_port((*emulator)->slave_path(), 115200);
  ASSERT_TRUE(port.ok());
  ASSERT_TRUE((*port)->write_all("G90\nG21\n", kSecond).ok());
  std::string carry;
  auto first = read_line(**port, carry, monotonic_now_ns() + kSecond);
  ASSERT_TRUE(first.ok()) << first.error().message;
  EXPECT_EQ(*first, "ok");
  auto second = read_line(**port, carry, monotonic_now_ns() + kSecond);
  ASSERT_TRUE(second.ok());
  EXPECT_EQ(*second, "ok");
  auto none = read_line(**port, carry, monotonic_now_ns() + 50 * kMilli);
  ASSERT_FALSE(none.ok());
  EXPECT_EQ(none.error().code, Errc::timeout);
}

TEST(GrblTurntable, MoveReturnsOnlyWhenTheTableHasArrived) {
  Rig rig = connect_rig();
  ASSERT_TRUE(rig.table);
  for (double target : {60.0, 120.0, 300.0, 0.0}) {
    auto reached = rig.table->rotate_to(target, 5 * kSecond);
    ASSERT_TRUE(reached.ok()) << reached.error().message;
    EXPECT_NEAR(*reached, target, 1e-3);
    // Completion, not the queue's ack: the platform is physically there and stopped.
    EXPECT_NEAR(rig.emulator->angle_deg(), target, 1e-3);
    EXPECT_FALSE(rig.emulator->moving());
  }
  auto status = rig.table->status();
  ASSERT_TRUE(status.ok());
  EXPECT_EQ(status->state, TurntableState::idle);
}

TEST(GrblTurntable, GarbageBytesAreSkipped) {
  Rig rig = connect_rig();
  ASSERT_TRUE(rig.table);
  sim::TurntableFaults faults;
  faults.garbage = true;
  rig.emulator->set_faults(faults);
  auto reached = rig.table->rotate_to(90.0, 5 * kSecond);
  ASSERT_TRUE(reached.ok()) << reached.error().message;
  EXPECT_NEAR(*reached, 90.0, 1e-3);
}

TEST(GrblTurntable, SilentControllerTimesOut) {
  Rig rig = connect_rig();
  ASSERT_TRUE(rig.table);
  sim::TurntableFaults faults;
  faults.silent = true;
  rig.emulator->set_faults(faults);
  const Nanos start = monotonic_now_ns();
  auto reached = rig.table->rotate_to(60.0, 2 * kSecond);
  ASSERT_FALSE(reached.ok());
  EXPECT_EQ(reached.error().code, Errc::timeout);
  EXPECT_NE(reached.error().message.find("G1X60.000"), std::string::npos) << reached.error().message;
  EXPECT_LT(monotonic_now_ns() - start, 3 * kSecond);  // bounded, never a hang
}

TEST(GrblTurntable, StalledMotorIsDetectedAndStopped) {
  Rig rig = connect_rig();
  ASSERT_TRUE(rig.table);
  sim::TurntableFaults faults;
  faults.stall_at_deg = 25.0;
  rig.emulator->set_faults(faults);
  auto reached = rig.table->rotate_to(60.0, 5 * kSecond);
  ASSERT_FALSE(reached.ok());
  EXPECT_EQ(reached.error().code, Errc::hardware);
  EXPECT_NE(reached.error().message.find("stalled at 25.000"), std::string::npos) << reached.error().message;
  EXPECT_FALSE(rig.emulator->moving());   // the driver stopped it
  EXPECT_GE(rig.emulator->resets(), 2u);  // connect + stop
  // Once the fault is gone the same driver works again.
  rig.emulator->set_faults({});
  auto again = rig.table->rotate_to(60.0, 5 * kSecond);
  ASSERT_TRUE(again.ok()) << again.error().message;
  EXPECT_NEAR(*again, 60.0, 1e-3);
}

TEST(GrblTurntable, WrongAngleIsReported) {
  Rig rig = connect_rig();
  ASSERT_TRUE(rig.table);
  sim::TurntableFaults faults;
  faults.landing_error_deg = 2.5;
  rig.emulator->set_faults(faults);
  auto reached = rig.table->rotate_to(120.0, 5 * kSecond);
  ASSERT_FALSE(reached.ok());
  EXPECT_EQ(reached.error().code, Errc::hardware);
  EXPECT_NE(reached.error().message.find("reports 122.500 deg after a move to 120.000"), std::string::npos)
      << reached.error().message;
}

TEST(GrblTurntable, NoBannerMeansWrongPort) {
  auto emulator = sim::TurntableEmulator::start();
  ASSERT_TRUE(emulator.ok());
  sim::TurntableFaults faults;
  faults.silent = true;
  (*emulator)->set_faults(faults);
  auto port = open_termios_port((*emulator)->slave_path(), 115200);
  ASSERT_TRUE(port.ok());
  GrblOptions options;
  options.banner_timeout_ns = 200 * kMilli;
  auto table = GrblTurntable::connect(std::move(*port), options);
  ASSERT_FALSE(table.ok());
  EXPECT_EQ(table.error().code, Errc::timeout);
  EXPECT_NE(table.error().message.find("no GRBL banner"), std::string::npos);
}

TEST(GrblTurntable, CancelStopsAMoveWhereItIs) {
  Rig rig = connect_rig({}, 20);  // 20 deg/s: the 180 deg move would take 9 s
  ASSERT_TRUE(rig.table);
  std::atomic<bool> cancel{false};
  std::thread canceller([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    cancel = true;
  });
  const Nanos start = monotonic_now_ns();
  auto reached = rig.table->rotate_to(180.0, 20 * kSecond, &cancel);
  const Nanos took = monotonic_now_ns() - start;
  canceller.join();
  ASSERT_FALSE(reached.ok());
  EXPECT_EQ(reached.error().code, Errc::aborted);
  EXPECT_NE(reached.error().message.find("move to 180.000 deg aborted"), std::string::npos) << reached.error().message;
  EXPECT_NE(reached.error().message.find("table stopped"), std::string::npos) << reached.error().message;
  EXPECT_LT(took, 5 * kSecond);
  EXPECT_FALSE(rig.emulator->moving());
  const double stopped_at = rig.emulator->angle_deg();
  EXPECT_GT(stopped_at, 0.0);
  EXPECT_LT(stopped_at, 100.0);
  // A feed hold before the reset keeps GRBL out of alarm: the next move just works.
  auto again = rig.table->rotate_to(stopped_at + 1.0, 5 * kSecond);
  ASSERT_TRUE(again.ok()) << again.error().message;
  EXPECT_NEAR(*again, stopped_at + 1.0, 1e-2);
  // A cancel flag that is already set: no move is even commanded.
  const std::uint64_t lines = rig.emulator->lines_received();
  auto none = rig.table->rotate_to(0.0, 5 * kSecond, &cancel);
  ASSERT_FALSE(none.ok());
  EXPECT_EQ(none.error().code, Errc::aborted);
  EXPECT_EQ(rig.emulator->lines_received(), lines);
  EXPECT_NEAR(rig.emulator->angle_deg(), *again, 1e-3);
}
