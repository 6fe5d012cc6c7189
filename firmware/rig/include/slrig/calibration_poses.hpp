// The poses of a calibration capture on the virtual rig, as a person would take them on a real
// rig (docs/calibration.md, "Poses"): the checkerboard held in front of the scanner at ten
// varied poses, then lying on the turntable at the six scan angles. Shared by the calibration
// test, the calibration bench, `slscan demo` and `slrig-render --calibration`, so every figure
// comes from the same capture.
#pragma once

#include <string>
#include <vector>

#include "slrig/rig.hpp"

namespace slrig {

struct CalibrationPoseSpec {
  std::string name;  // "free 3", "table 120"
  bool on_turntable = false;
  double commanded_angle_deg = 0;  // turntable poses: the angle the table is told to turn to
  // The calibration scene with the board placed for this pose (free poses: `on_turntable`
  // false, `table_from_object` read in the camera frame).
  Scene scene;
  // Free poses: the board's true pose. Turntable poses: the board in the table frame (the
  // camera pose follows from the renderer's actual angle: ground_truth().cam_from_table).
  slproto::RigidTransform cam_from_board;
  slproto::RigidTransform table_from_board;
  // Noise seeds: a free pose renders one view per coding axis (separate exposures), views
  // `view_index` and `view_index + 1`; a turntable pose renders view `view_index`.
  int view_index = 0;
};

// `calibration_scene` is scene_preset("calibration", size) (its board is taken out and placed
// at each pose). Throws std::logic_error when a free pose would put the board into the
// platform (a pose nobody could hold) or the scene has no checkerboard.
std::vector<CalibrationPoseSpec> calibration_poses(const Scene& calibration_scene);

}  // namespace slrig
