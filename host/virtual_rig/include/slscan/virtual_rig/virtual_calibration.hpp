// A calibration capture of the virtual rig (slrig::calibration_poses), rendered in memory in
// the layout calibrate_rig reads, with the truth every figure is checked against. Used by the
// calibration test and the benches (bench_calibrated_ballbar, bench_metrology); `slscan` itself
// calibrates the virtual rig through slscand's sim board, as a real scanner.
#pragma once

#include <array>
#include <cstddef>
#include <functional>
#include <string>
#include <vector>

#include "slproto/calibration.hpp"
#include "slscan/core/calibration_compare.hpp"
#include "slscan/core/calibration_rig.hpp"

namespace slrig {
struct Scene;
}

namespace slscan::virtual_rig {

struct VirtualCalibrationCapture {
  core::CalibrationCapture capture;
  slproto::RigCalibration truth;                        // the rig's exact calibration
  std::vector<slproto::RigidTransform> cam_from_board;  // per pose, the board's true pose
  std::vector<double> actual_table_deg;                 // per turntable pose, the angle the table reached
};

// Renders every pose of `calibration_scene` (scene_preset("calibration", size)): free poses
// with each projector's plan along columns and rows, turntable poses as one image of both
// projectors' white. The turntable misses each commanded angle by a random
// N(0, table_angle_sigma_deg) (a table that does not quite do as told). `progress`, when given,
// is told as each pose begins (`done` of `total` poses, its name) and once at the end.
using RenderProgress = std::function<void(std::size_t done, std::size_t total, const std::string& pose)>;
VirtualCalibrationCapture render_virtual_calibration_capture(const slrig::Scene& calibration_scene,
                                                             const std::string& source,
                                                             double table_angle_sigma_deg = 0.05,
                                                             const RenderProgress& progress = {});

// The calibration's errors against the truth, in the terms (docs/calibration.md): the
// difference from the rig's exact calibration, and the turntable steps against the angles the
// table really reached.
struct CalibrationErrors : core::CalibrationDifference {
  double worst_step_error_deg = 0;
  std::string table() const;  // one line per figure, for benches and tests
};
CalibrationErrors calibration_errors(const core::RigCalibrationResult& result, const VirtualCalibrationCapture& truth);

}  // namespace slscan::virtual_rig
