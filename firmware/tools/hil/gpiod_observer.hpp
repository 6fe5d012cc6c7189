// The observer on a real board: libgpiod edge events (kernel CLOCK_MONOTONIC timestamps) on
// the inputs a board file's [observer] section names, wired back from the trigger lines, each
// edge recorded under the board line it watches. Independent of slscand: its own process, its
// own line request, its own clock reads by the kernel.
#pragma once

#include <atomic>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "hil_record.hpp"
#include "slscand/hal/board.hpp"
#include "slscand/hal/gpio.hpp"

namespace slscan::hil {

class GpiodObserver {
 public:
  GpiodObserver() = default;
  ~GpiodObserver();
  GpiodObserver(const GpiodObserver&) = delete;
  GpiodObserver& operator=(const GpiodObserver&) = delete;

  // Requests the [observer] inputs (both edges) and starts recording. False with `error` set
  // when the chip or a line cannot be had, or this build has no libgpiod.
  bool start(const slscand::hal::BoardConfig& board, std::string& error);
  void stop();
  std::vector<Edge> edges();
  // Non-empty when the request failed mid-run or the kernel dropped events (a seqno gap).
  std::string error();

 private:
  void run();
  std::unique_ptr<slscand::hal::GpioChip> chip_;
  std::unique_ptr<slscand::hal::LineRequest> request_;
  std::vector<std::pair<unsigned, unsigned>> map_;  // observer input -> watched board line
  std::thread thread_;
  std::atomic<bool> quit_{false};
  std::mutex mutex_;
  std::vector<Edge> edges_;
  std::string error_;
};

}  // namespace slscan::hil
