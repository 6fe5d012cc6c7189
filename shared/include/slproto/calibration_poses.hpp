// The poses of a calibration capture (docs/calibration.md, "Poses"), as a person takes them:
// the checkerboard held in front of the scanner at varied tilts and positions, then lying on
// the turntable at the scan's angles. One list for everyone who needs it: `slscan calibrate
// --connect` tells the user which pose to set (and, on a simulated board, sends it in
// ScanRequest.calibration_target), and the virtual rig renders the same poses
// (slrig::calibration_poses), so every figure comes from the same pose set.
#pragma once

#include <string>
#include <vector>

#include "slproto/messages.hpp"
#include "slproto/rig_model.hpp"

namespace slproto {

// The checkerboard, counted in squares (its frame: origin at the first inner corner, x along
// squares_x, y along squares_y, z into the board).
struct CheckerboardSize {
  int squares_x = 9;
  int squares_y = 7;
  double square_mm = 15;
  double thickness_mm = 3;
};

struct GuidedCalibrationPose {
  std::string name;  // "free 3", "table 120"
  bool on_turntable = false;
  double table_angle_deg = 0;  // turntable poses: the angle the table is turned to
  // Free poses: the board faces the camera, tilted by tilt_x_deg about the camera's x axis,
  // then tilt_y_deg about its y axis, spun spin_deg in its own plane; its middle at
  // (offset_x_mm, offset_y_mm, distance_mm) in the camera frame. Turntable poses: face up,
  // spun spin_deg about the table's axis, its middle at (offset_x_mm, offset_y_mm) on the
  // platform, the same for every angle (the board is not touched between them).
  double tilt_x_deg = 0, tilt_y_deg = 0, spin_deg = 0;
  double offset_x_mm = 0, offset_y_mm = 0, distance_mm = 0;

  // What to tell the user: "tilt 25 deg about x (top away), ..."; empty for table poses
  // after the first (the table turns by itself).
  std::string instruction() const;
};

// 14 free poses (the last four steep and off to the image's sides: perspective across a steep
// board is what separates the principal point from a small turn of the whole rig) and one
// turntable pose at each of the six scan angles (0, 60, ..., 300). Tuned for the virtual rig's
// working volume (430-490 mm from the camera); on another scanner they are a guide, not exact.
const std::vector<GuidedCalibrationPose>& calibration_pose_guide();

// The board's pose for `pose`: camera_from_board (free poses) or table_from_board (turntable).
RigidTransform guided_board_pose(const GuidedCalibrationPose& pose, const CheckerboardSize& board);

// The ScanRequest field for a pose, and back (the board side). from_proto checks the field
// (sizes, counts, a proper rotation) and names what is wrong.
pb::CalibrationTarget to_proto(const GuidedCalibrationPose& pose, const CheckerboardSize& board);
struct CalibrationTargetPlacement {
  std::string pose_name;
  CheckerboardSize board;
  bool on_turntable = false;
  RigidTransform pose;  // camera_from_board or table_from_board
};
Result<CalibrationTargetPlacement> from_proto(const pb::CalibrationTarget& target);

}  // namespace slproto
