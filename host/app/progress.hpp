// The console's progress figures: a long step's rate and time left from its counts and the time
// it has run, and the one-line bar a terminal shows (docs/cli.md, "Progress"). Pure functions
// of counts and clock readings, so the tests check the figures without a terminal or a clock.
#pragma once

#include <chrono>
#include <cstddef>
#include <optional>
#include <string>

#include "slproto/number_text.hpp"
#include "slscan/session/session_log.hpp"

namespace slscan::app {

// A duration as people read it, rounded to the second: "0 s", "42 s", "2:05" (m:ss), "1:02:05".
std::string format_duration(double seconds);

// A rate to three significant figures (whole numbers from 100 on) with its unit:
// "12.3 frames/s", "143 frames/s", "1235 frames/s", "0.520 poses/s".
std::string format_rate(double per_second, const std::string& unit);

// A number as given, for messages ("0.5", not "0.500000"): slproto's, shared with the board.
using slproto::short_number;

// An instant in UTC as ISO 8601 with milliseconds: "2026-12-03T14:16:03.123Z" (--json-log).
std::string utc_timestamp(std::chrono::system_clock::time_point when);

struct ProgressReading {
  double elapsed_s = 0;              // since the stage's first update
  std::optional<double> rate_per_s;  // items a second since then; none before the second update
  std::optional<double> eta_s;       // time left at that rate; none without a rate, a total or a unit
};

// Follows one stage at a time. The rate counts the items done since the stage's first update
// over the time since then (so a stage that starts at item 1 is not credited with item 1's
// time); the ETA is what is left at that rate, once the stage has run `min_eta_s` (earlier
// guesses swing too much to be worth showing). A new stage name or total, or a count that goes
// down, starts over.
class ProgressMeter {
 public:
  using Clock = std::chrono::steady_clock;
  static constexpr double min_eta_s = 1.0;
  ProgressReading update(const session::Progress& progress, Clock::time_point now);
  void reset() { started_ = false; }  // the step ended: the next update starts over

 private:
  bool started_ = false;
  std::string stage_;
  std::size_t total_ = 0;
  std::size_t first_done_ = 0;
  std::size_t last_done_ = 0;
  Clock::time_point start_{};
};

// The terminal's line: "frames [#########.....................] 120/480 12.0 frames/s, ETA 30 s"
// (the step under way, when given, before the rate); for steps without a unit, the step and the
// time so far:
// "reconstruction [###########...................] 3/8 register, 42 s".
std::string progress_line(const session::Progress& progress, const ProgressReading& reading, int bar_width = 30);

}  // namespace slscan::app
