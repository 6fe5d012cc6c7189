#include "slscan/core/normals.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "cloud_filters_kdtree.hpp"

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

std::vector<Eigen::Vector3f> grid_normals(const OrganizedCloud& cloud, const Eigen::Vector3f& viewpoint,
                                          const GridNormalOptions& options) {
  if (options.window_radius < 1) throw std::invalid_argument("grid_normals: window_radius must be >= 1");
  if (static_cast<std::size_t>(cloud.width) * static_cast<std::size_t>(cloud.height) != cloud.points.size() ||
      cloud.valid.size() != cloud.points.size())
    throw std::invalid_argument("grid_normals: organised cloud is " + std::to_string(cloud.width) + "x" +
                                std::to_string(cloud.height) + " but holds " + std::to_string(cloud.points.size()) +
                                " points and " + std::to_string(cloud.valid.size()) + " validity flags");
  std::vector<Eigen::Vector3f> normals(cloud.points.size(), Eigen::Vector3f(kNaN, kNaN, kNaN));
  const int w = cloud.width, h = cloud.height, r = options.window_radius;
  const float max_d2 = options.max_neighbor_distance_mm * options.max_neighbor_distance_mm;
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 16), [&](const tbb::blocked_range<int>& rows) {
    for (int v = rows.begin(); v < rows.end(); ++v) {
      for (int u = 0; u < w; ++u) {
        const std::size_t i = static_cast<std::size_t>(v) * static_cast<std::size_t>(w) + static_cast<std::size_t>(u);
        if (!cloud.valid[i]) continue;
        const Eigen::Vector3f centre = cloud.points[i];
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
        if (n < options.min_neighbors) continue;
        const Eigen::Vector3d mean = sum / n;
        const Eigen::Matrix3d covariance = outer / n - mean * mean.transpose();
        Eigen::Vector3f normal = smallest_eigenvector(covariance);
        if (normal.dot(viewpoint - centre) < 0) normal = -normal;
        normals[i] = normal;
      }
    }
  });
  return normals;
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
  const detail::KdTree tree(cloud.points);
  const auto& order = tree.spatial_order();
  const auto k = static_cast<std::size_t>(options.k);
  const Eigen::Vector3f axis = options.axis_direction.normalized();
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, cloud.size(), 1024), [&](const tbb::blocked_range<std::size_t>& range) {
        std::vector<std::uint32_t> indices(k);
        std::vector<float> d2(k);
        for (std::size_t q = range.begin(); q < range.end(); ++q) {
          const std::size_t i = order[q];
          const Eigen::Vector3f p = cloud.points[i];
          const std::size_t found = tree.knn(p, k, indices.data(), d2.data());
          if (found < 3) continue;
          Eigen::Vector3d sum = Eigen::Vector3d::Zero();
          Eigen::Matrix3d outer = Eigen::Matrix3d::Zero();
          for (std::size_t j = 0; j < found; ++j) {
            const Eigen::Vector3d d = (cloud.points[indices[j]] - p).cast<double>();
            sum += d;
            outer.noalias() += d * d.transpose();
          }
          const Eigen::Vector3d mean = sum / static_cast<double>(found);
          Eigen::Vector3f normal = smallest_eigenvector(outer / static_cast<double>(found) - mean * mean.transpose());
          Eigen::Vector3f outward;
          if (toward_camera) {
            outward = options.view_camera_centres[cloud.view_id[i]] - p;
          } else {
            const Eigen::Vector3f rel = p - options.axis_point;
            outward = rel - axis * axis.dot(rel);
          }
          if (normal.dot(outward) < 0) normal = -normal;
          normals[i] = normal;
        }
      });
  return normals;
}

}  // namespace slscan::core
