#include "slscan/core/cloud_compare.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <string>
#include <unordered_map>

#include "cloud_filters_kdtree.hpp"

namespace slscan::core {

void CompareOptions::check() const {
  if (surface_neighbors < 3 || surface_neighbors > 64)
    throw std::invalid_argument("compare: surface_neighbors " + std::to_string(surface_neighbors) + " outside [3, 64]");
  if (!std::isfinite(max_distance_mm)) throw std::invalid_argument("compare: max_distance_mm must be finite");
}

DistanceStats DistanceStats::of(std::vector<double>& values) {
  DistanceStats s;
  s.count = values.size();
  if (values.empty()) return s;
  std::sort(values.begin(), values.end());
  double sum = 0, sum2 = 0;
  for (double v : values) {
    sum += v;
    sum2 += v * v;
  }
  const auto n = static_cast<double>(values.size());
  s.mean = sum / n;
  s.rms = std::sqrt(sum2 / n);
  // Nearest-rank quantiles: no interpolation, so a figure is always one of the distances.
  auto quantile = [&](double q) {
    const auto rank = static_cast<std::size_t>(std::ceil(q * n));
    return values[std::min(values.size() - 1, rank == 0 ? 0 : rank - 1)];
  };
  s.median = quantile(0.5);
  s.p90 = quantile(0.9);
  s.p99 = quantile(0.99);
  s.max = values.back();
  return s;
}

namespace {

void check_pixels(const PixelTaggedCloud& cloud, const char* what) {
  if ((!cloud.u.empty() || !cloud.v.empty()) && !cloud.has_pixels())
    throw std::invalid_argument(std::string("compare: the ") + what + " cloud's u/v channels do not match its " +
                                std::to_string(cloud.points.size()) + " points");
}

std::uint64_t pixel_key(float u, float v) {
  const auto iu = static_cast<std::int64_t>(std::lround(u));
  const auto iv = static_cast<std::int64_t>(std::lround(v));
  return (static_cast<std::uint64_t>(iv) << 32) ^ static_cast<std::uint64_t>(static_cast<std::uint32_t>(iu));
}

}  // namespace

PixelComparison compare_by_pixel(const PixelTaggedCloud& measured, const PixelTaggedCloud& reference) {
  check_pixels(measured, "measured");
  check_pixels(reference, "reference");
  if (!measured.has_pixels() || !reference.has_pixels())
    throw std::invalid_argument("compare: a per-pixel comparison needs u/v on both clouds");
  std::unordered_map<std::uint64_t, std::uint32_t> reference_at;
  reference_at.reserve(reference.points.size());
  for (std::size_t i = 0; i < reference.points.size(); ++i)
    if (std::isfinite(reference.u[i]) && std::isfinite(reference.v[i]) && reference.points[i].allFinite())
      reference_at.emplace(pixel_key(reference.u[i], reference.v[i]), static_cast<std::uint32_t>(i));
  PixelComparison out;
  out.reference_pixels = reference_at.size();
  std::unordered_map<std::uint64_t, std::uint32_t> seen;
  seen.reserve(measured.points.size());
  std::vector<double> distances, dz;
  for (std::size_t i = 0; i < measured.points.size(); ++i) {
    if (!std::isfinite(measured.u[i]) || !std::isfinite(measured.v[i]) || !measured.points[i].allFinite()) continue;
    const std::uint64_t key = pixel_key(measured.u[i], measured.v[i]);
    if (!seen.emplace(key, static_cast<std::uint32_t>(i)).second) continue;
    const auto it = reference_at.find(key);
    if (it == reference_at.end()) continue;
    const Eigen::Vector3f d = measured.points[i] - reference.points[it->second];
    distances.push_back(static_cast<double>(d.norm()));
    dz.push_back(static_cast<double>(d.z()));
  }
  out.measured_pixels = seen.size();
  out.common_pixels = distances.size();
  out.coverage =
      out.reference_pixels ? static_cast<double>(out.common_pixels) / static_cast<double>(out.reference_pixels) : 0;
  out.distance = DistanceStats::of(distances);
  if (!dz.empty()) {
    std::nth_element(dz.begin(), dz.begin() + static_cast<std::ptrdiff_t>(dz.size() / 2), dz.end());
    out.median_signed_z = dz[dz.size() / 2];
  }
  return out;
}

CloudComparison compare_clouds(const PixelTaggedCloud& measured, const PixelTaggedCloud& reference,
                               const CompareOptions& options) {
  options.check();
  check_pixels(measured, "measured");
  check_pixels(reference, "reference");
  std::vector<Eigen::Vector3f> reference_points;
  reference_points.reserve(reference.points.size());
  for (const auto& p : reference.points)
    if (p.allFinite()) reference_points.push_back(p);
  if (reference_points.size() < static_cast<std::size_t>(options.surface_neighbors))
    throw std::invalid_argument("compare: the reference cloud has " + std::to_string(reference_points.size()) +
                                " finite points, fewer than surface_neighbors (" +
                                std::to_string(options.surface_neighbors) + ")");
  const detail::KdTree tree(reference_points);
  const auto k = static_cast<std::size_t>(options.surface_neighbors);
  const std::size_t n = measured.points.size();
  constexpr double kNan = std::numeric_limits<double>::quiet_NaN();
  std::vector<double> to_point(n, kNan), to_surface(n, kNan);
  const double gate = options.max_distance_mm > 0 ? options.max_distance_mm : std::numeric_limits<double>::infinity();
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1024), [&](const tbb::blocked_range<std::size_t>& r) {
    std::vector<std::uint32_t> indices(k);
    std::vector<float> d2(k);
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      const Eigen::Vector3f& q = measured.points[i];
      if (!q.allFinite()) continue;
      const std::size_t found = tree.knn(q, k, indices.data(), d2.data());
      const double nearest = std::sqrt(static_cast<double>(d2[0]));
      if (found == 0 || nearest > gate) continue;
      to_point[i] = nearest;
      Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
      for (std::size_t j = 0; j < found; ++j) centroid += reference_points[indices[j]].cast<double>();
      centroid /= static_cast<double>(found);
      Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
      for (std::size_t j = 0; j < found; ++j) {
        const Eigen::Vector3d d = reference_points[indices[j]].cast<double>() - centroid;
        covariance += d * d.transpose();
      }
      const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(covariance);
      const Eigen::Vector3d normal = solver.eigenvectors().col(0);  // smallest eigenvalue
      to_surface[i] = std::abs(normal.dot(q.cast<double>() - centroid));
    }
  });
  CloudComparison out;
  out.measured_points = n;
  out.reference_points = reference_points.size();
  std::vector<double> p2p, p2s;
  p2p.reserve(n);
  p2s.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    if (std::isnan(to_point[i])) {
      if (measured.points[i].allFinite()) ++out.unmatched;
      continue;
    }
    p2p.push_back(to_point[i]);
    p2s.push_back(to_surface[i]);
  }
  out.point_to_point = DistanceStats::of(p2p);
  out.point_to_surface = DistanceStats::of(p2s);
  if (measured.has_pixels() && reference.has_pixels()) out.per_pixel = compare_by_pixel(measured, reference);
  return out;
}

}  // namespace slscan::core
