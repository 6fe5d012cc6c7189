// The console's progress figures (host/app/progress.hpp): rate and ETA from counts and elapsed
// time, their rounding and units, and the line a terminal shows.
#include <gtest/gtest.h>

#include <chrono>

#include "progress.hpp"

namespace slscan::app {
namespace {

using namespace std::chrono_literals;
using Clock = ProgressMeter::Clock;

session::Progress frames(std::size_t done, std::size_t total = 480) { return {"frames", done, total, "frames", {}}; }

TEST(Progress, DurationsRoundToTheSecondAndReadAsPeopleWriteThem) {
  EXPECT_EQ(format_duration(0), "0 s");
  EXPECT_EQ(format_duration(0.4), "0 s");
  EXPECT_EQ(format_duration(0.5), "1 s");
  EXPECT_EQ(format_duration(42.4), "42 s");
  EXPECT_EQ(format_duration(59.6), "1:00");
  EXPECT_EQ(format_duration(125), "2:05");
  EXPECT_EQ(format_duration(3599.4), "59:59");
  EXPECT_EQ(format_duration(3725), "1:02:05");
  EXPECT_EQ(format_duration(-3), "0 s");
}

TEST(Progress, RatesHaveThreeSignificantFiguresAndTheirUnit) {
  EXPECT_EQ(format_rate(12.345, "frames"), "12.3 frames/s");
  EXPECT_EQ(format_rate(143.4, "frames"), "143 frames/s");
  EXPECT_EQ(format_rate(1234.6, "frames"), "1235 frames/s");
  EXPECT_EQ(format_rate(0.52, "poses"), "0.520 poses/s");
  EXPECT_EQ(format_rate(9.996, "poses"), "10.0 poses/s");  // rounds up a decade: still 3 figures
  EXPECT_EQ(format_rate(99.96, "MB"), "100 MB/s");
  EXPECT_EQ(format_rate(0, "frames"), "0 frames/s");
}

TEST(Progress, RateAndEtaFollowTheCountsSinceTheStageBegan) {
  ProgressMeter meter;
  const Clock::time_point t0{};
  // The first update (frame 1 arrived) starts the clock: no rate yet.
  ProgressReading r = meter.update(frames(1), t0);
  EXPECT_EQ(r.elapsed_s, 0.0);
  EXPECT_FALSE(r.rate_per_s);
  EXPECT_FALSE(r.eta_s);
  // 120 more frames in 10 s: 12 frames/s, 359 left -> 29.9 s.
  r = meter.update(frames(121), t0 + 10s);
  EXPECT_DOUBLE_EQ(r.elapsed_s, 10.0);
  ASSERT_TRUE(r.rate_per_s);
  EXPECT_DOUBLE_EQ(*r.rate_per_s, 12.0);
  ASSERT_TRUE(r.eta_s);
  EXPECT_NEAR(*r.eta_s, 359.0 / 12.0, 1e-9);
  // All done: nothing left.
  r = meter.update(frames(480), t0 + 40s);
  EXPECT_NEAR(*r.rate_per_s, 479.0 / 40.0, 1e-9);
  EXPECT_EQ(*r.eta_s, 0.0);
}

TEST(Progress, NoEtaInTheFirstSecondNorWithoutAUnitOrTotal) {
  ProgressMeter meter;
  const Clock::time_point t0{};
  meter.update(frames(0), t0);
  ProgressReading r = meter.update(frames(5), t0 + 500ms);
  ASSERT_TRUE(r.rate_per_s);
  EXPECT_DOUBLE_EQ(*r.rate_per_s, 10.0);
  EXPECT_FALSE(r.eta_s) << "half a second is too little to say how long the rest takes";
  EXPECT_TRUE(meter.update(frames(20), t0 + 2s).eta_s);

  ProgressMeter stages;
  stages.update({"reconstruction", 0, 8, "", "register"}, t0);
  EXPECT_FALSE(stages.update({"reconstruction", 4, 8, "", "mesh"}, t0 + 30s).eta_s)
      << "stages of unequal length have no ETA";
  ProgressMeter unknown;
  unknown.update(frames(0, 0), t0);
  EXPECT_FALSE(unknown.update(frames(10, 0), t0 + 5s).eta_s) << "no total, no ETA";
}

TEST(Progress, ANewStageStartsTheClockOver) {
  ProgressMeter meter;
  const Clock::time_point t0{};
  meter.update(frames(0), t0);
  meter.update(frames(480), t0 + 60s);
  // Another stage 60 s later: its rate is its own, not diluted by the frames' minute.
  meter.update({"rendering", 0, 10, "poses", {}}, t0 + 60s);
  ProgressReading r = meter.update({"rendering", 2, 10, "poses", {}}, t0 + 64s);
  EXPECT_DOUBLE_EQ(r.elapsed_s, 4.0);
  EXPECT_DOUBLE_EQ(*r.rate_per_s, 0.5);
  EXPECT_DOUBLE_EQ(*r.eta_s, 16.0);
  // A count that goes down is a new run of the same stage.
  r = meter.update({"rendering", 1, 10, "poses", {}}, t0 + 70s);
  EXPECT_EQ(r.elapsed_s, 0.0);
  EXPECT_FALSE(r.rate_per_s);
  // reset() (end of a step): the next update starts over too.
  meter.update({"rendering", 3, 10, "poses", {}}, t0 + 72s);
  meter.reset();
  EXPECT_EQ(meter.update({"rendering", 3, 10, "poses", {}}, t0 + 80s).elapsed_s, 0.0);
}

TEST(Progress, TheTerminalLineShowsBarCountRateAndEta) {
  ProgressReading r;
  EXPECT_EQ(progress_line(frames(0), r, 10), "frames [..........] 0/480");
  r.rate_per_s = 12.0;
  r.eta_s = 359.0 / 12.0;
  EXPECT_EQ(progress_line(frames(121), r, 10), "frames [##........] 121/480 12.0 frames/s, ETA 30 s");
  r.eta_s = 0;
  EXPECT_EQ(progress_line(frames(480), r, 10), "frames [##########] 480/480 12.0 frames/s, ETA 0 s");
  // More than the total (a stream that sends extra frames) fills the bar, no more.
  EXPECT_EQ(progress_line(frames(500), r, 4), "frames [####] 500/480 12.0 frames/s, ETA 0 s");

  ProgressReading stage;
  stage.elapsed_s = 83;
  EXPECT_EQ(progress_line({"reconstruction", 2, 8, "", "register"}, stage, 8),
            "reconstruction [##......] 2/8 register, 1:23");
  ProgressReading poses;
  poses.rate_per_s = 0.25;
  poses.eta_s = 68;
  EXPECT_EQ(progress_line({"rendering", 3, 20, "poses", "free pose 4"}, poses, 4),
            "rendering [....] 3/20 free pose 4 0.250 poses/s, ETA 1:08");
}

TEST(Progress, NumbersInMessagesHaveTheDigitsTheyWereGivenWith) {
  EXPECT_EQ(short_number(0.5), "0.5");
  EXPECT_EQ(short_number(2), "2");
  EXPECT_EQ(short_number(-1), "-1");
  EXPECT_EQ(short_number(11.864247), "11.8642");
  EXPECT_EQ(short_number(1e-7), "1e-07");
  EXPECT_EQ(short_number(0.1 + 0.2), "0.3");
}

TEST(Progress, UtcTimestampsAreIso8601WithMilliseconds) {
  using std::chrono::system_clock;
  // 2026-12-03 14:16:03.123 UTC.
  const system_clock::time_point when = system_clock::time_point{} + std::chrono::seconds(1796307363) + 123ms;
  EXPECT_EQ(utc_timestamp(when), "2026-12-03T14:16:03.123Z");
  EXPECT_EQ(utc_timestamp(system_clock::time_point{}), "1970-01-01T00:00:00.000Z");
}

}  // namespace
}  // namespace slscan::app
