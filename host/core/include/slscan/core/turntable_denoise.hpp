// Stage 4: denoise by the turntable's geometry (paper Formulas 10-14). With the platform
// plane n . x + d = 0 (n the rotation axis, up) and the axis through c along n:
//   dis1 = n . p + d (signed height above the platform top) must exceed min_height_mm, which
//          removes the platform itself and everything below it;
//   dis2 = |p - (c + (n . (p - c)) n)| (distance to the axis) must not exceed the platform
//          radius, which removes the background and anything beside the table.
// The plane and the axis do not move when the table turns, so one calibration serves all views.
#pragma once

#include <cstddef>

#include "slproto/calibration.hpp"
#include "slscan/core/point_cloud.hpp"

namespace slscan::core {

struct TurntableDenoiseOptions {
  double min_height_mm = 0.25;  // keep points higher than this above the platform top
  double max_height_mm = 0;     // > 0: also drop points higher than this (0: no limit)
  double radius_mm = 0;         // keep points within this distance of the axis; 0: the calibration's radius
  void check() const;           // throws std::invalid_argument naming the field
};

struct TurntableDenoiseCounts {
  std::size_t input = 0, kept = 0;
  std::size_t below_min_height = 0;  // platform, under it
  std::size_t above_max_height = 0;
  std::size_t outside_radius = 0;  // background, beside the table
};

struct TurntableGeometry {
  Eigen::Vector3d axis_point;      // c, camera frame (platform centre, top surface)
  Eigen::Vector3d axis_direction;  // n, unit, pointing up away from the platform
  double radius_mm = 0;
  static TurntableGeometry from(const slproto::TurntableCalibration& calibration);
  double height(const Eigen::Vector3d& p) const { return axis_direction.dot(p - axis_point); }  // dis1
  double distance_to_axis(const Eigen::Vector3d& p) const {                                     // dis2
    const Eigen::Vector3d d = p - axis_point;
    return (d - axis_direction.dot(d) * axis_direction).norm();
  }
};

template <class Cloud>
struct TurntableDenoiseResult {
  Cloud cloud;
  TurntableDenoiseCounts counts;
};

// Points are in the camera frame of the turntable calibration (any view angle).
// The organised cloud is taken by value (a caller that no longer needs its own moves it in).
TurntableDenoiseResult<OrganizedCloud> denoise_by_turntable(OrganizedCloud cloud,
                                                            const slproto::TurntableCalibration& turntable,
                                                            const TurntableDenoiseOptions& options = {});
TurntableDenoiseResult<PointCloud> denoise_by_turntable(const PointCloud& cloud,
                                                        const slproto::TurntableCalibration& turntable,
                                                        const TurntableDenoiseOptions& options = {});

}  // namespace slscan::core
