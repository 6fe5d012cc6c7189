// The sim backend: the virtual rig (slrig) behind the same interfaces as real hardware.
//
// A virtual GPIO bus carries every line of the board file. Two virtual DLP projectors obey
// their TRIG_IN_1/TRIG_IN_2 lines and drive TRIG_OUT_1 for each pattern's exposure, after the
// board's projector latency. The virtual camera obeys its trigger (the projectors' TRIG_OUT_1,
// or the board's camera trigger line), samples which projector shows which pattern at the
// start of its exposure, and after exposure + read-out delivers the frame rendered by
// slrig::ViewRenderer at the angle the emulated turntable physically reached. The sequencer
// therefore runs its real code against the same timing model as hardware, and a sequencing
// bug (camera triggered before the projector switched) shows up as a wrong image.
//
// The bus also records every edge it carries with its own timestamp: the logic analyser of
// the hardware-in-the-loop timing tests.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include "slproto/calibration_poses.hpp"
#include "slproto/pattern_plan.hpp"
#include "slrig/rig.hpp"
#include "slscand/hal/board.hpp"
#include "slscand/hal/camera.hpp"
#include "slscand/hal/gpio.hpp"
#include "slscand/hal/sim/turntable_emulator.hpp"

namespace slscand::hal::sim {

struct SimFaults {
  std::array<bool, 2> projector_silent{};  // a projector that never raises TRIG_OUT_1
  bool camera_silent = false;              // exposures happen, frames never arrive
  // Counted in camera frames from set_faults(): the n-th frame is exposed and read out but
  // never delivered (the driver's counter skips it), or delivered with half its bytes.
  int drop_frame_after = -1;
  int short_frame_after = -1;
  // set_exposure_us() answers OK and changes nothing: a camera that ignores the control.
  bool camera_ignores_exposure = false;
};

struct RecordedEdge {
  unsigned offset = 0;
  bool rising = false;
  Nanos timestamp_ns = 0;
};

// What the virtual camera saw in one exposure (for tests of the sequencing itself).
struct ExposureRecord {
  Nanos start_ns = 0;
  int side = -1;           // projector lit at exposure start, -1 = none
  int pattern_index = -1;  // its pattern, -1 = none
  int lit_count = 0;       // projectors lit at exposure start (2 = both: a sequencing bug)
  Nanos exposure_ns = 0;   // the camera's exposure time then
};

class SimRig {
 public:
  // Builds the scene named by the board (sim.scene, sim.rig_size) and starts the emulated
  // turntable. `scene` overrides the preset when given.
  static slproto::Result<std::shared_ptr<SimRig>> create(const BoardConfig& board, const slrig::Scene* scene = nullptr);
  ~SimRig();
  SimRig(const SimRig&) = delete;
  SimRig& operator=(const SimRig&) = delete;

  std::unique_ptr<GpioChip> make_gpio_chip();
  std::unique_ptr<Camera> make_camera();
  TurntableEmulator& turntable();
  const slrig::Scene& scene() const;
  // The rig's exact calibration (its camera, projectors and turntable as built): what only a
  // simulated board knows, for the demo's --true-calibration and for checking a calibration.
  slproto::RigCalibration true_calibration() const;

  // "Flashes" the projectors' pattern memory and exposure (a real DLPC350 is loaded over USB
  // beforehand). Until then the projectors show the scene's own plan at the board's exposure.
  void load_patterns(const slproto::PatternPlan& plan, Nanos exposure_ns);
  // Replaces the scene's objects by the requested checkerboard at the requested pose
  // (ScanRequest.calibration_target), rendered as the rig's calibration preset renders its
  // board; nullopt restores the board's own scene. Each placement renders with its own noise
  // (separate exposures), the same for every view of the scan.
  slproto::Status place_calibration_target(const std::optional<slproto::CalibrationTargetPlacement>& target);
  void set_faults(const SimFaults& faults);
  std::vector<RecordedEdge> recorded_edges() const;
  std::vector<ExposureRecord> exposures() const;
  void clear_records();
  std::array<bool, 2> projectors_lit() const;
  bool line_value(unsigned offset) const;

  struct Core;  // shared with the chip and camera objects it hands out

 private:
  explicit SimRig(std::shared_ptr<Core> core) : core_(std::move(core)) {}
  std::shared_ptr<Core> core_;
};

}  // namespace slscand::hal::sim
