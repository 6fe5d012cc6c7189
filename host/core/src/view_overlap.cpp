#include "slscan/core/view_overlap.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>

namespace slscan::core {

void OverlapSelectionOptions::check() const {
  if (!(max_incidence_deg > 0 && max_incidence_deg <= 90))
    throw std::invalid_argument("overlap selection: max_incidence_deg must be in (0, 90]");
  if (!(same_spot_mm > 0)) throw std::invalid_argument("overlap selection: same_spot_mm must be > 0");
  if (!(same_spot_footprints > 0)) throw std::invalid_argument("overlap selection: same_spot_footprints must be > 0");
}

OverlapSelection select_best_views(const std::vector<PointCloud>& points,
                                   const std::vector<const SparseOrganizedCloud*>& grids,
                                   const std::vector<Eigen::Isometry3d>& table_from_view,
                                   const slproto::PinholeModel& camera, const OverlapSelectionOptions& options) {
  options.check();
  const std::size_t n = points.size();
  if (grids.size() != n || table_from_view.size() != n)
    throw std::invalid_argument("select_best_views: " + std::to_string(n) + " views, " + std::to_string(grids.size()) +
                                " organised clouds, " + std::to_string(table_from_view.size()) + " poses");
  for (std::size_t i = 0; i < n; ++i) {
    if (points[i].normals.size() != points[i].size())
      throw std::invalid_argument("select_best_views: view " + std::to_string(i) + " has no normals");
    if (grids[i] == nullptr || grids[i]->width != camera.width || grids[i]->height != camera.height ||
        grids[i]->points.size() != grids[i]->slots.size() ||
        grids[i]->row_begin.size() != static_cast<std::size_t>(camera.height) + 1 ||
        grids[i]->row_begin.back() != grids[i]->slots.size())
      throw std::invalid_argument("select_best_views: view " + std::to_string(i) + "'s organised cloud is not " +
                                  std::to_string(camera.width) + "x" + std::to_string(camera.height));
  }
  OverlapSelection selection;
  selection.keep.resize(n);
  const float steep_cos = static_cast<float>(std::cos(options.max_incidence_deg * std::numbers::pi / 180.0));
  std::vector<OverlapSelectionCounts> per_view(n);

  tbb::parallel_for(std::size_t{0}, n, [&](std::size_t i) {
    const PointCloud& cloud = points[i];
    std::vector<std::uint8_t>& keep = selection.keep[i];
    keep.assign(cloud.size(), 1);
    OverlapSelectionCounts& counts = per_view[i];
    counts.input = cloud.size();
    std::vector<Eigen::Isometry3f> other_from_this(n);
    for (std::size_t j = 0; j < n; ++j)
      other_from_this[j] = (table_from_view[j].inverse() * table_from_view[i]).cast<float>();
    for (std::size_t k = 0; k < cloud.size(); ++k) {
      const Eigen::Vector3f& p = cloud.points[k];
      const Eigen::Vector3f& normal = cloud.normals[k];
      if (!normal.allFinite()) continue;
      const float own_cos = normal.dot(-p.normalized());  // the camera is at the origin
      if (own_cos >= steep_cos) continue;
      ++counts.steep;
      bool covered = false;
      for (std::size_t j = 0; j < n && !covered; ++j) {
        if (j == i) continue;
        const Eigen::Vector3f q = other_from_this[j] * p;
        const Eigen::Vector3f m = other_from_this[j].linear() * normal;
        const float other_cos = m.dot(-q.normalized());
        if (other_cos < steep_cos || other_cos <= own_cos) continue;
        double u = 0, v = 0;
        if (!camera.project({q.x(), q.y(), q.z()}, u, v)) continue;
        // Only a projection near the grid is rounded: a huge or non-finite one (an absurd
        // calibration) has no neighbour there, and lround of it would be undefined.
        const SparseOrganizedCloud& grid = *grids[j];
        if (!(u > -2.0 && v > -2.0 && u < grid.width + 1.0 && v < grid.height + 1.0)) continue;
        const long cu = std::lround(u), cv = std::lround(v);
        const double footprint = q.z() / camera.fx;
        const float lateral = static_cast<float>(options.same_spot_footprints * footprint);
        for (long dv = -1; dv <= 1 && !covered; ++dv)
          for (long du = -1; du <= 1 && !covered; ++du) {
            const std::ptrdiff_t s = grid.find(static_cast<int>(cu + du), static_cast<int>(cv + dv));
            if (s < 0) continue;
            const Eigen::Vector3f d = grid.points[static_cast<std::size_t>(s)] - q;
            // Along the normal: the same surface (an occluder in front is far off the plane);
            // across it: the same spot, not a neighbour on the far side of the window.
            covered = std::fabs(d.dot(m)) <= options.same_spot_mm && d.norm() <= lateral;
          }
      }
      if (covered) {
        keep[k] = 0;
        ++counts.replaced;
      }
    }
  });
  for (const auto& c : per_view) {
    selection.counts.input += c.input;
    selection.counts.steep += c.steep;
    selection.counts.replaced += c.replaced;
  }
  return selection;
}

}  // namespace slscan::core
