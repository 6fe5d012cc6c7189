#include "slscan/core/normals.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "neighbour_grid.hpp"

namespace slscan::core {
namespace {

const float kNaN = std::numeric_limits<float>::quiet_NaN();

// Smallest-eigenvalue eigenvector of a covariance accumulated in double about a local origin.
Eigen::Vector3f smallest_eigenvector(const Eigen::Matrix3d& covariance) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver;
  solver.computeDirect(covariance);
  return solver.eigenvectors().col(0).cast<float>();
}

}  // namespace

namespace {

void check_grid(const OrganizedCloud& cloud, const GridNormalOptions& options, const char* what) {
  if (options.window_radius < 1) throw std::invalid_argument(std::string(what) + ": window_radius must be >= 1");
  if (static_cast<std::size_t>(cloud.width) * static_cast<std::size_t>(cloud.height) != cloud.points.size() ||
      cloud.valid.size() != cloud.points.size())
    throw std::invalid_argument(std::string(what) + ": organised cloud is " + std::to_string(cloud.width) + "x" +
                                std::to_string(cloud.height) + " but holds " + std::to_string(cloud.points.size()) +
                                " points and " + std::to_string(cloud.valid.size()) + " validity flags");
}

// The normal of valid slot (u, v): PCA over its pixel window, NaN with too few neighbours.
Eigen::Vector3f window_normal(const OrganizedCloud& cloud, int u, int v, const Eigen::Vector3f& viewpoint,
                              const GridNormalOptions& options) {
  const int w = cloud.width, h = cloud.height, r = options.window_radius;
  const float max_d2 = options.max_neighbor_distance_mm * options.max_neighbor_distance_mm;
  const Eigen::Vector3f centre =
      cloud.points[static_cast<std::size_t>(v) * static_cast<std::size_t>(w) + static_cast<std::size_t>(u)];
  // Accumulate about the centre point: small offsets keep float sums exact enough.
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  Eigen::Matrix3d outer = Eigen::Matrix3d::Zero();
  int n = 0;
  for (int dv = -r; dv <= r; ++dv) {
    const int vv = v + dv;
    if (vv < 0 || vv >= h) continue;
    const std::size_t row = static_cast<std::size_t>(vv) * static_cast<std::size_t>(w);
    for (int du = -r; du <= r; ++du) {
      const int uu = u + du;
      if (uu < 0 || uu >= w) continue;
      const std::size_t j = row + static_cast<std::size_t>(uu);
      if (!cloud.valid[j]) continue;
      const Eigen::Vector3f d = cloud.points[j] - centre;
      if (d.squaredNorm() > max_d2) continue;
      const Eigen::Vector3d dd = d.cast<double>();
      sum += dd;
      outer.noalias() += dd * dd.transpose();
      ++n;
    }
  }
  if (n < options.min_neighbors) return {kNaN, kNaN, kNaN};
  const Eigen::Vector3d mean = sum / n;
  const Eigen::Matrix3d covariance = outer / n - mean * mean.transpose();
  Eigen::Vector3f normal = smallest_eigenvector(covariance);
  if (normal.dot(viewpoint - centre) < 0) normal = -normal;
  return normal;
}

}  // namespace

std::vector<Eigen::Vector3f> grid_normals(const OrganizedCloud& cloud, const Eigen::Vector3f& viewpoint,
                                          const GridNormalOptions& options) {
  check_grid(cloud, options, "grid_normals");
  std::vector<Eigen::Vector3f> normals(cloud.points.size(), Eigen::Vector3f(kNaN, kNaN, kNaN));
  const int w = cloud.width, h = cloud.height;
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 16), [&](const tbb::blocked_range<int>& rows) {
    for (int v = rows.begin(); v < rows.end(); ++v)
      for (int u = 0; u < w; ++u) {
        const std::size_t i = static_cast<std::size_t>(v) * static_cast<std::size_t>(w) + static_cast<std::size_t>(u);
        if (cloud.valid[i]) normals[i] = window_normal(cloud, u, v, viewpoint, options);
      }
  });
  return normals;
}

PointCloud oriented_point_cloud(const OrganizedCloud& cloud, std::uint16_t view_id, const Eigen::Vector3f& viewpoint,
                                const GridNormalOptions& options) {
  check_grid(cloud, options, "oriented_point_cloud");
  if (cloud.quality.size() != cloud.points.size())
    throw std::invalid_argument("oriented_point_cloud: organised cloud has " + std::to_string(cloud.points.size()) +
                                " points and " + std::to_string(cloud.quality.size()) + " qualities");
  // The slots to_point_cloud would keep, in its (row-major) order; then their normals.
  std::vector<std::uint32_t> slots;
  slots.reserve(cloud.count_valid());
  for (std::size_t i = 0; i < cloud.points.size(); ++i)
    if (cloud.valid[i] && cloud.points[i].allFinite()) slots.push_back(static_cast<std::uint32_t>(i));
  std::vector<Eigen::Vector3f> normals(slots.size());
  const auto w = static_cast<std::uint32_t>(cloud.width);
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, slots.size(), 1024), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t k = r.begin(); k < r.end(); ++k)
          normals[k] =
              window_normal(cloud, static_cast<int>(slots[k] % w), static_cast<int>(slots[k] / w), viewpoint, options);
      });
  PointCloud out;
  const bool with_intensity = cloud.intensity.size() == cloud.points.size();
  std::size_t kept = 0;
  for (const auto& n : normals) kept += n.allFinite() ? 1 : 0;
  out.points.reserve(kept);
  out.confidence.reserve(kept);
  out.normals.reserve(kept);
  if (with_intensity) out.intensity.reserve(kept);
  for (std::size_t k = 0; k < slots.size(); ++k) {
    if (!normals[k].allFinite()) continue;
    const std::size_t i = slots[k];
    out.points.push_back(cloud.points[i]);
    out.confidence.push_back(cloud.quality[i]);
    if (with_intensity) out.intensity.push_back(cloud.intensity[i]);
    out.normals.push_back(normals[k]);
  }
  out.view_id.assign(out.points.size(), view_id);
  return out;
}

std::vector<Eigen::Vector3f> pca_normals(const PointCloud& cloud, const PcaNormalOptions& options) {
  if (options.k < 3) throw std::invalid_argument("pca_normals: k must be >= 3, got " + std::to_string(options.k));
  const bool toward_camera = options.orientation == NormalOrientation::toward_view_camera;
  if (toward_camera) {
    if (cloud.view_id.size() != cloud.size())
      throw std::invalid_argument("pca_normals: toward_view_camera needs a view id per point");
    for (std::size_t i = 0; i < cloud.view_id.size(); ++i)
      if (cloud.view_id[i] >= options.view_camera_centres.size())
        throw std::invalid_argument("pca_normals: point " + std::to_string(i) + " has view id " +
                                    std::to_string(cloud.view_id[i]) + " but only " +
                                    std::to_string(options.view_camera_centres.size()) + " camera centres were given");
  } else if (!(options.axis_direction.norm() > 0)) {
    throw std::invalid_argument("pca_normals: axis_direction must be non-zero");
  }
  std::vector<Eigen::Vector3f> normals(cloud.size(), Eigen::Vector3f(kNaN, kNaN, kNaN));
  if (cloud.size() < 3) return normals;
  const auto k = static_cast<std::size_t>(options.k);
  const Eigen::Vector3f axis = options.axis_direction.normalized();
  detail::for_each_k_nearest(cloud.points, k, [&](std::size_t i, const detail::KNearest& nearest) {
    if (nearest.count < 3) return;
    const Eigen::Vector3f p = nearest.query;
    // Sums of offsets from the point (a few tenths of a mm): float holds them to ~1e-8 mm^2,
    // four orders below the noise's variance; the eigen solve is in double.
    float s[3] = {0, 0, 0}, ss[6] = {0, 0, 0, 0, 0, 0};
    for (std::size_t j = 0; j < nearest.count; ++j) {
      const std::uint32_t at = nearest.at[j];
      const float dx = nearest.x[at] - p.x(), dy = nearest.y[at] - p.y(), dz = nearest.z[at] - p.z();
      s[0] += dx;
      s[1] += dy;
      s[2] += dz;
      ss[0] += dx * dx;
      ss[1] += dx * dy;
      ss[2] += dx * dz;
      ss[3] += dy * dy;
      ss[4] += dy * dz;
      ss[5] += dz * dz;
    }
    const double count = static_cast<double>(nearest.count);
    const Eigen::Vector3d mean = Eigen::Vector3d(s[0], s[1], s[2]) / count;
    Eigen::Matrix3d outer;
    outer << ss[0], ss[1], ss[2], ss[1], ss[3], ss[4], ss[2], ss[4], ss[5];
    Eigen::Vector3f normal = smallest_eigenvector(outer / count - mean * mean.transpose());
    Eigen::Vector3f outward;
    if (toward_camera) {
      outward = options.view_camera_centres[cloud.view_id[i]] - p;
    } else {
      const Eigen::Vector3f rel = p - options.axis_point;
      outward = rel - axis * axis.dot(rel);
    }
    if (normal.dot(outward) < 0) normal = -normal;
    normals[i] = normal;
  });
  return normals;
}

}  // namespace slscan::core
