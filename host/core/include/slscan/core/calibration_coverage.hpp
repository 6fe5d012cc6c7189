// What the poses of a guided calibration capture cover, from the board's corners in the camera
// (no calibration needed): whether a new pose adds anything to those taken (a pose the user set
// again, a table that did not turn), and how the set covers the image and the depths so far.
#pragma once

#include <string>
#include <vector>

#include "slscan/core/calibration_target.hpp"

namespace slscan::core {

// The board of one pose in the camera image: every inner corner, by corner id.
struct PoseFootprint {
  std::string name;
  std::vector<Eigen::Vector2d> corners;  // [id]
};

// `view` must hold every corner of `target` (a found board); throws std::invalid_argument.
PoseFootprint pose_footprint(const std::string& name, const TargetView& view, const CheckerboardTarget& target);

// The mean distance (camera px) between the two boards' corners, the lesser of the two corner
// orders (a detector may list a board from either end). Throws on footprints of other sizes.
double footprint_distance_px(const PoseFootprint& a, const PoseFootprint& b);

struct PoseNovelty {
  int closest = -1;  // index into the poses taken; -1 when none
  double distance_px = 0;
};
PoseNovelty closest_pose(const PoseFootprint& pose, const std::vector<PoseFootprint>& taken);

// The size a pose's shift is measured against: the board's inner diagonal in the image (first
// to last corner, px). A tilt moves the corners little for what it adds, so the image diagonal
// would be too coarse a yardstick (two of the guide's poses, tilted apart, lie 2.0 % of it apart).
double footprint_size_px(const PoseFootprint& pose);

// A pose whose corners lie within this share of its board's size of a pose taken (mean over
// the corners) adds nothing the solve can use: the small rig's guided poses lie at least 7.2 %
// apart (free 7 and free 2: 16.4 px, tests/host/test_calibration_coverage.cpp), the same pose
// taken twice with the detector's noise 0.1 %.
constexpr double kMinPoseShiftOfBoard = 0.03;

// "" when `pose` is at least `min_shift_of_board` of its board's size from every pose taken;
// else the words for the user, naming the closest pose and the distances.
std::string too_similar_problem(const PoseFootprint& pose, const std::vector<PoseFootprint>& taken,
                                double min_shift_of_board = kMinPoseShiftOfBoard);

struct CoverageOptions {
  int cells_x = 8, cells_y = 6;  // the image's grid
};

struct PoseSetCoverage {
  int poses = 0;
  int cells = 0;          // cells_x * cells_y
  int cells_covered = 0;  // cells whose centre lies inside some pose's board (its corners' hull)
  // The board centres' depths in the camera frame (mm), from a camera solve of the poses so far
  // (calibrate_camera); has_depth is false before 3 poses or when that solve fails.
  bool has_depth = false;
  double nearest_mm = 0, farthest_mm = 0;
  std::string depth_note;  // why there is no depth yet

  double covered_fraction() const { return cells > 0 ? static_cast<double>(cells_covered) / cells : 0.0; }
  // "image 23 of 48 cells (48 %); depth 431-489 mm (58 mm) over 5 poses"
  std::string summary() const;
};

PoseSetCoverage pose_set_coverage(const CheckerboardTarget& target, const std::vector<PoseFootprint>& poses, int width,
                                  int height, const CoverageOptions& options = {});

}  // namespace slscan::core
