// GPIO lines: the interface every GPIO backend implements (libgpiod v1, libgpiod v2, sim).
// Lines are requested in one call, outputs are set by offset, and edges on inputs come back
// with the kernel's CLOCK_MONOTONIC timestamp (libgpiod on Linux >= 5.7), so latency can be
// measured independently of the code that drove the outputs.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "slproto/result.hpp"
#include "slscand/hal/clock.hpp"

namespace slscand::hal {

using slproto::Result;
using slproto::Status;

enum class LineDirection : std::uint8_t { output, input };
enum class EdgeDetection : std::uint8_t { none, rising, falling, both };

struct LineSettings {
  unsigned offset = 0;
  LineDirection direction = LineDirection::output;
  bool initial_value = false;                 // outputs only
  EdgeDetection edges = EdgeDetection::none;  // inputs only
  bool active_low = false;
  std::string name;  // what the line is for, used in error messages ("projector.left.trig_in_1")
};

struct LineRequestConfig {
  std::string consumer = "slscand";
  std::vector<LineSettings> lines;

  // Refuses duplicate offsets, edge detection on outputs and an empty request, naming the line.
  Status check() const;
  const LineSettings* find(unsigned offset) const;
};

struct EdgeEvent {
  unsigned offset = 0;
  bool rising = true;
  Nanos timestamp_ns = 0;   // CLOCK_MONOTONIC, from the kernel (or the sim bus)
  std::uint64_t seqno = 0;  // per request, from 1; a gap means the kernel buffer overflowed
};

class LineRequest {
 public:
  virtual ~LineRequest() = default;
  virtual Status set_value(unsigned offset, bool value) = 0;
  virtual Result<bool> get_value(unsigned offset) = 0;
  // Waits up to `timeout_ns` for edges on the request's edge-detecting inputs and returns what
  // arrived, oldest first; an empty vector means the timeout passed.
  virtual Result<std::vector<EdgeEvent>> wait_edges(Nanos timeout_ns) = 0;
  virtual const LineRequestConfig& config() const = 0;
};

class GpioChip {
 public:
  virtual ~GpioChip() = default;
  virtual std::string name() const = 0;  // e.g. "gpiochip0 [pinctrl-bcm2711]"
  virtual unsigned line_count() const = 0;
  virtual Result<std::unique_ptr<LineRequest>> request_lines(const LineRequestConfig& config) = 0;
};

// "gpiochip0" -> "/dev/gpiochip0"; paths are kept as given.
std::string gpio_chip_path(const std::string& chip);

}  // namespace slscand::hal
