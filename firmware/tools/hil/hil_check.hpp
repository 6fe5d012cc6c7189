// The HIL checks over one scan's record (hil_record.hpp):
//   budgets   -- the board file's [timing_budget] against what the log and the frames measured;
//   behaviour -- the scan completed, no frame lost, frames in order;
//   observer  -- the sequencer's log and the frames against the edges the observer saw on the
//                trigger lines: counts, order, timestamps, each exposure inside its trigger pulse.
// Every failed check names the budget or the mismatch, the limit and the measured value.
#pragma once

#include <string>
#include <vector>

#include "hil_record.hpp"
#include "slscand/hal/board.hpp"

namespace slscan::hil {

struct Stat {
  std::string name;
  std::string unit;  // "us" or "ms"
  std::size_t count = 0;
  double mean = 0, p50 = 0, p99 = 0, max = 0;
};

Stat summarize(std::string name, std::string unit, std::vector<double> values);

struct Check {
  std::string group;  // "budget", "behaviour" or "observer"
  std::string name;   // the budget's key (timing_budget.X) or what was compared
  std::string measured;
  std::string limit;
  bool pass = false;
  std::string detail;  // for a failure: where (which frame, edge or line)
};

struct CheckOptions {
  // Latency and jitter budgets (and timestamp agreement with the observer). Off in the VM,
  // where emulated time means nothing: only behaviour and order are checked there.
  bool timing = true;
};

struct HilReport {
  std::vector<Stat> stats;
  std::vector<Check> checks;
  bool passed() const;
  std::vector<const Check*> failures() const;
  std::string table() const;
  std::string json() const;
};

HilReport evaluate(const HilRecord& record, const slscand::hal::BoardConfig& board, const CheckOptions& options = {});

}  // namespace slscan::hil
