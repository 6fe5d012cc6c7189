// The planar calibration target and the corner observations calibration is built from.
//
// Target frame: origin at the first inner corner (the one OpenCV's detector lists first),
// x along a row of inner corners, y along a column, z = 0 on the printed surface. Corner ids
// are row-major: id = row * inner_x + col, at (col * square, row * square, 0).
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

namespace slscan::core {

struct CheckerboardTarget {
  int squares_x = 9, squares_y = 7;  // squares along x and y; inner corners = squares - 1
  double square_mm = 10;
  // Height of the printed surface above whatever the target lies on: the platform plane is
  // this far below the target plane when the target lies on the turntable.
  double thickness_mm = 0;

  int inner_x() const { return squares_x - 1; }
  int inner_y() const { return squares_y - 1; }
  int corner_count() const { return inner_x() * inner_y(); }
  Eigen::Vector3d corner(int id) const {
    const int column = id % inner_x(), row = id / inner_x();  // integer division: the grid index
    return {column * square_mm, row * square_mm, 0.0};
  }
  Eigen::Vector3d centre() const { return {0.5 * (inner_x() - 1) * square_mm, 0.5 * (inner_y() - 1) * square_mm, 0.0}; }
  // With an odd number of squares both ways the board looks the same turned by 180 degrees,
  // so a detector cannot tell which corner is first; calibration then resolves it (turntable)
  // or does not need to (free poses).
  bool is_point_symmetric() const { return squares_x % 2 == 1 && squares_y % 2 == 1; }
  // Throws std::invalid_argument naming the bad field.
  void check() const;
};

// One corner seen in one image: its id on the target and its sub-pixel position.
struct CornerObservation {
  int id = 0;
  Eigen::Vector2d pixel{0, 0};
};

// The corners of one target pose as seen by one device (camera or projector).
struct TargetView {
  std::string name;  // where it came from, for reports ("pose 3")
  std::vector<CornerObservation> corners;
};

}  // namespace slscan::core
