// A TI DLP LightCrafter 4500 in pattern-sequence mode, driven through its trigger pins:
// TRIG_IN_2 high runs the sequence (low: dark), each rising edge on TRIG_IN_1 shows the next
// pattern, and TRIG_OUT_1 is high while a pattern is exposed. TRIG_OUT_1 comes back into a
// GPIO input: its rising edge is the projector's acknowledgement and, with the kernel's
// timestamp, the start of the exposure. The pattern images themselves are flashed into the
// DLPC350 beforehand (USB HID); this class never needs the USB link during a scan.
#pragma once

#include <deque>
#include <memory>
#include <string>

#include "slscand/hal/gpio.hpp"

namespace slscand::hal {

struct DlpLines {
  unsigned trig_in_1 = 0;   // output: advance to the next pattern
  unsigned trig_in_2 = 0;   // output: sequence run (high) / stop (low)
  unsigned trig_out_1 = 0;  // input: high while a pattern is exposed
};

class DlpProjector {
 public:
  static constexpr Nanos kTriggerPulseNs = 20 * kMicro;  // DLPC350 needs >= 20 us

  // Requests the three lines on `chip`; `name` ("projector.left") goes into every error.
  static Result<std::unique_ptr<DlpProjector>> open(GpioChip& chip, const DlpLines& lines, const std::string& name);

  const std::string& name() const { return name_; }
  const DlpLines& lines() const { return lines_; }

  // Runs the pattern sequence from its first pattern (the next advance() shows pattern 0).
  Status start();
  // Rising edge on TRIG_IN_1: the next pattern. Returns the time read just before the line was
  // driven (the edge's earliest possible time).
  Result<Nanos> advance();
  // The projector's acknowledgement: the next TRIG_OUT_1 rising edge (exposure start), or
  // Errc::hardware naming the projector when none comes within `timeout_ns`.
  Result<EdgeEvent> wait_exposure_start(Nanos timeout_ns);
  // The falling edge that ends that exposure.
  Result<EdgeEvent> wait_exposure_end(Nanos timeout_ns);
  // Dark: both trigger inputs low. Safe to call at any time, also after an error.
  Status stop();

  int pattern_index() const { return pattern_index_; }  // -1 before the first advance
  bool running() const { return running_; }

 private:
  DlpProjector(std::unique_ptr<LineRequest> request, const DlpLines& lines, std::string name);
  Result<EdgeEvent> wait_edge(bool rising, Nanos timeout_ns);

  std::unique_ptr<LineRequest> request_;
  DlpLines lines_;
  std::string name_;
  std::deque<EdgeEvent> pending_;
  int pattern_index_ = -1;
  bool running_ = false;
};

}  // namespace slscand::hal
