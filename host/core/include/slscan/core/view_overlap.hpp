// Where turntable views overlap, the model keeps the view that saw the surface best. A point
// measured at a steep angle of incidence is several times noisier than one seen face on (on the
// virtual rig: 2.8 um RMS up to 60 deg, 3.9 um at 60-70 deg, 6.6 um at 70-80 deg), and the
// steep points of each view are exactly the ones another view, turned 60 deg, sees face on.
// So a steep point gives way when another view measured the same spot within the incidence
// limit; where no view did, it stays: the selection never opens a hole.
#pragma once

#include <Eigen/Geometry>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "slproto/calibration.hpp"
#include "slscan/core/point_cloud.hpp"

namespace slscan::core {

struct OverlapSelectionOptions {
  double max_incidence_deg = 60;  // steeper points give way to a view that saw the spot within this
  // The other view's measurement is of the same spot when it lies within this distance of the
  // point's tangent plane (along the point's normal) ...
  double same_spot_mm = 0.1;
  // ... and within this many of its pixel footprints of the point (lateral sanity).
  double same_spot_footprints = 3;

  void check() const;  // throws std::invalid_argument naming the field
};

struct OverlapSelectionCounts {
  std::size_t input = 0;     // points of every view
  std::size_t steep = 0;     // beyond max_incidence_deg in their own view
  std::size_t replaced = 0;  // of those, dropped: another view measured the spot within the limit
};

struct OverlapSelection {
  std::vector<std::vector<std::uint8_t>> keep;  // per view, per point of views[i]: 1 = into the model
  OverlapSelectionCounts counts;
};

// `points[i]`: view i's points in its camera frame with normals facing its camera (the
// ScanReconstructor's per-view clouds); `grids[i]`: the same view's organised cloud (camera
// frame, its valid pixels) to look up what it measured where; `table_from_view[i]`: the
// registered poses; `camera`: the camera model (the same camera for every view). Throws
// std::invalid_argument on mismatched sizes, missing normals or bad options.
OverlapSelection select_best_views(const std::vector<PointCloud>& points,
                                   const std::vector<const SparseOrganizedCloud*>& grids,
                                   const std::vector<Eigen::Isometry3d>& table_from_view,
                                   const slproto::PinholeModel& camera, const OverlapSelectionOptions& options = {});

}  // namespace slscan::core
