#include "slscan/core/cloud_filters.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <tbb/parallel_sort.h>

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "neighbour_grid.hpp"
#include "slproto/number_text.hpp"

namespace slscan::core {
namespace {

void check_channels(const PointCloud& cloud, const char* who) {
  const auto n = cloud.size();
  auto bad = [&](std::size_t m) { return m != 0 && m != n; };
  if (bad(cloud.normals.size()) || bad(cloud.confidence.size()) || bad(cloud.intensity.size()) ||
      bad(cloud.view_id.size()))
    throw std::invalid_argument(
        std::string(who) + ": cloud of " + std::to_string(n) + " points has " + std::to_string(cloud.normals.size()) +
        " normals, " + std::to_string(cloud.confidence.size()) + " confidences, " +
        std::to_string(cloud.intensity.size()) + " intensities and " + std::to_string(cloud.view_id.size()) +
        " view ids (each must be 0 or " + std::to_string(n) + ")");
  for (std::size_t i = 0; i < n; ++i)
    if (!cloud.points[i].allFinite())
      throw std::invalid_argument(std::string(who) + ": point " + std::to_string(i) + " is not finite");
}

FilterResult keep_flagged(const PointCloud& cloud, const std::vector<std::uint8_t>& keep) {
  FilterResult result;
  std::vector<std::size_t> kept;
  kept.reserve(cloud.size());
  for (std::size_t i = 0; i < keep.size(); ++i)
    if (keep[i]) kept.push_back(i);
  result.cloud = cloud.select(kept);
  result.kept_indices.assign(kept.begin(), kept.end());
  result.removed = cloud.size() - kept.size();
  return result;
}

}  // namespace

PointCloud to_point_cloud(const OrganizedCloud& cloud, std::uint16_t view_id,
                          const std::vector<Eigen::Vector3f>* normals) {
  if (cloud.valid.size() != cloud.points.size() || cloud.quality.size() != cloud.points.size())
    throw std::invalid_argument("to_point_cloud: organised cloud has " + std::to_string(cloud.points.size()) +
                                " points, " + std::to_string(cloud.valid.size()) + " validity flags and " +
                                std::to_string(cloud.quality.size()) + " qualities");
  if (normals && normals->size() != cloud.points.size())
    throw std::invalid_argument("to_point_cloud: " + std::to_string(normals->size()) + " normals for " +
                                std::to_string(cloud.points.size()) + " slots");
  PointCloud out;
  const std::size_t n = cloud.count_valid();
  out.points.reserve(n);
  out.confidence.reserve(n);
  const bool with_intensity = cloud.intensity.size() == cloud.points.size();
  if (with_intensity) out.intensity.reserve(n);
  if (normals) out.normals.reserve(n);
  for (std::size_t i = 0; i < cloud.points.size(); ++i) {
    if (!cloud.valid[i] || !cloud.points[i].allFinite()) continue;
    if (normals && !(*normals)[i].allFinite()) continue;
    out.points.push_back(cloud.points[i]);
    out.confidence.push_back(cloud.quality[i]);
    if (with_intensity) out.intensity.push_back(cloud.intensity[i]);
    if (normals) out.normals.push_back((*normals)[i]);
  }
  out.view_id.assign(out.points.size(), view_id);
  return out;
}

PointCloud transform_cloud(const PointCloud& cloud, const Eigen::Isometry3d& target_from_source) {
  PointCloud out = cloud;
  const Eigen::Matrix3f R = target_from_source.linear().cast<float>();
  const Eigen::Vector3d t = target_from_source.translation();
  const Eigen::Matrix3d Rd = target_from_source.linear();
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, cloud.size(), 8192),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t i = r.begin(); i < r.end(); ++i) {
                        out.points[i] = (Rd * cloud.points[i].cast<double>() + t).cast<float>();
                        if (!out.normals.empty()) out.normals[i] = R * cloud.normals[i];
                      }
                    });
  return out;
}

FilterResult statistical_outlier_removal(const PointCloud& cloud, const StatisticalOutlierOptions& options) {
  if (options.k < 1) throw std::invalid_argument("statistical_outlier_removal: k must be >= 1");
  if (!(options.std_ratio > 0)) throw std::invalid_argument("statistical_outlier_removal: std_ratio must be > 0");
  check_channels(cloud, "statistical_outlier_removal");
  const std::size_t n = cloud.size();
  const auto k = static_cast<std::size_t>(options.k) + 1;  // the point itself comes first
  if (n <= k) {
    FilterResult all;
    all.cloud = cloud;
    for (std::size_t i = 0; i < n; ++i) all.kept_indices.push_back(static_cast<std::uint32_t>(i));
    return all;
  }
  std::vector<float> mean_distance(n);
  detail::for_each_k_nearest(cloud.points, k, [&](std::size_t i, const detail::KNearest& nearest) {
    // The point itself (or a copy of it) adds 0: the mean is over the other found - 1.
    float sum = 0;
    for (std::size_t j = 0; j < nearest.count; ++j) sum += std::sqrt(nearest.squared_distance[j]);
    mean_distance[i] = sum / static_cast<float>(nearest.count - 1);
  });
  using Sums = std::pair<double, double>;
  // Deterministic: the same partial sums in the same order on any thread timing.
  const Sums sums = tbb::parallel_deterministic_reduce(
      tbb::blocked_range<std::size_t>(0, n, 8192), Sums{0, 0},
      [&](const tbb::blocked_range<std::size_t>& r, Sums s) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
          s.first += mean_distance[i];
          s.second += static_cast<double>(mean_distance[i]) * mean_distance[i];
        }
        return s;
      },
      [](Sums a, const Sums& b) {
        return Sums{a.first + b.first, a.second + b.second};
      });
  const double mean = sums.first / static_cast<double>(n);
  const double variance = std::max(0.0, (sums.second - sums.first * mean) / static_cast<double>(n - 1));
  const double threshold = mean + options.std_ratio * std::sqrt(variance);
  std::vector<std::uint8_t> keep(n);
  for (std::size_t i = 0; i < n; ++i) keep[i] = mean_distance[i] <= threshold;
  FilterResult result = keep_flagged(cloud, keep);
  result.threshold = threshold;
  return result;
}

OrganizedOutlierResult statistical_outlier_removal(OrganizedCloud cloud, double focal_px,
                                                   const StatisticalOutlierOptions& options, int window_radius) {
  if (options.k < 1) throw std::invalid_argument("statistical_outlier_removal: k must be >= 1");
  if (!(options.std_ratio > 0)) throw std::invalid_argument("statistical_outlier_removal: std_ratio must be > 0");
  if (!(focal_px > 0)) throw std::invalid_argument("statistical_outlier_removal: focal_px must be > 0");
  if (window_radius < 1 || window_radius > 7)
    throw std::invalid_argument("statistical_outlier_removal: window_radius must be in [1, 7]");
  const int w = cloud.width, h = cloud.height;
  const std::size_t n = static_cast<std::size_t>(w) * static_cast<std::size_t>(h);
  if (cloud.points.size() != n || cloud.valid.size() != n || cloud.quality.size() != n)
    throw std::invalid_argument("statistical_outlier_removal: organised cloud buffers do not match its size");
  const auto k = static_cast<std::size_t>(options.k);
  const float edge_per_depth = static_cast<float>((window_radius + 1) / focal_px);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  // The valid slots in row-major order, and a mean distance for each: a view's object after
  // the platform is removed is ~2.5 % of its grid, so nothing is kept per slot of the grid.
  std::vector<std::uint32_t> slots;
  slots.reserve(cloud.count_valid());
  for (std::size_t i = 0; i < n; ++i)
    if (cloud.valid[i]) slots.push_back(static_cast<std::uint32_t>(i));
  std::vector<float> mean_distance(slots.size());
  const auto width = static_cast<std::uint32_t>(w);
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, slots.size(), 1024), [&](const tbb::blocked_range<std::size_t>& r) {
        std::vector<float> d2;
        const std::size_t window_side = 2 * static_cast<std::size_t>(window_radius) + 1;
        d2.reserve(window_side * window_side);
        for (std::size_t slot = r.begin(); slot < r.end(); ++slot) {
          const std::size_t i = slots[slot];
          const int u = static_cast<int>(slots[slot] % width), v = static_cast<int>(slots[slot] / width);
          const Eigen::Vector3f& p = cloud.points[i];
          d2.clear();
          for (int vv = std::max(0, v - window_radius); vv <= std::min(h - 1, v + window_radius); ++vv)
            for (int uu = std::max(0, u - window_radius); uu <= std::min(w - 1, u + window_radius); ++uu) {
              const std::size_t j =
                  static_cast<std::size_t>(vv) * static_cast<std::size_t>(w) + static_cast<std::size_t>(uu);
              if (j != i && cloud.valid[j]) d2.push_back((cloud.points[j] - p).squaredNorm());
            }
          const float edge = edge_per_depth * std::fabs(p.z());
          float sum = 0;
          const std::size_t found = std::min(k, d2.size());
          if (found < d2.size())
            std::nth_element(d2.begin(), d2.begin() + static_cast<std::ptrdiff_t>(found), d2.end());
          for (std::size_t m = 0; m < found; ++m) sum += std::sqrt(d2[m]);
          sum += static_cast<float>(k - found) * edge;
          mean_distance[slot] = sum / static_cast<float>(k);
        }
      });
  double total = 0, total2 = 0;
  for (const float d : mean_distance) {
    total += d;
    total2 += static_cast<double>(d) * d;
  }
  const std::size_t count = slots.size();
  OrganizedOutlierResult result;
  result.cloud = std::move(cloud);  // no copy when the caller moved its cloud in
  if (count < 2) return result;
  const double mean = total / static_cast<double>(count);
  const double variance = std::max(0.0, (total2 - total * mean) / static_cast<double>(count - 1));
  result.threshold = mean + options.std_ratio * std::sqrt(variance);
  for (std::size_t slot = 0; slot < count; ++slot) {
    if (mean_distance[slot] <= result.threshold) continue;
    const std::size_t i = slots[slot];
    result.cloud.points[i] = Eigen::Vector3f(nan, nan, nan);
    result.cloud.quality[i] = 0.0f;
    result.cloud.valid[i] = 0;
    ++result.removed;
  }
  return result;
}

FilterResult radius_outlier_removal(const PointCloud& cloud, const RadiusOutlierOptions& options) {
  if (!(options.radius_mm > 0)) throw std::invalid_argument("radius_outlier_removal: radius_mm must be > 0");
  if (options.min_neighbors < 0) throw std::invalid_argument("radius_outlier_removal: min_neighbors must be >= 0");
  check_channels(cloud, "radius_outlier_removal");
  const std::size_t n = cloud.size();
  std::vector<std::uint8_t> keep(n, 1);
  if (n > 0) {
    const auto needed = static_cast<std::uint32_t>(options.min_neighbors) + 1;  // the point itself counts
    const std::vector<std::uint32_t> counts =
        detail::count_within(cloud.points, static_cast<float>(options.radius_mm), needed);
    for (std::size_t i = 0; i < n; ++i) keep[i] = counts[i] >= needed;
  }
  FilterResult result = keep_flagged(cloud, keep);
  result.threshold = options.radius_mm;
  return result;
}

PointCloud voxel_downsample(const PointCloud& cloud, double voxel_mm) {
  if (!(voxel_mm > 0) || !std::isfinite(voxel_mm))
    throw std::invalid_argument("voxel_downsample: voxel_mm must be a positive number");
  check_channels(cloud, "voxel_downsample");
  const std::size_t n = cloud.size();
  if (n == 0) return cloud;
  // 21 bits per axis around the cloud's minimum corner.
  Eigen::Vector3d lo = cloud.points[0].cast<double>();
  for (const auto& p : cloud.points) lo = lo.cwiseMin(p.cast<double>());
  const double inv = 1.0 / voxel_mm;
  const Eigen::Vector3d anchor = (lo * inv).array().floor().matrix();
  constexpr std::int64_t kMaxCell = (std::int64_t{1} << 21) - 1;
  std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed(n);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 8192), [&](const tbb::blocked_range<std::size_t>& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      const Eigen::Vector3d c = (cloud.points[i].cast<double>() * inv).array().floor().matrix() - anchor;
      std::uint64_t key = 0;
      for (int a = 0; a < 3; ++a) {
        const auto cell = static_cast<std::int64_t>(c[a]);
        if (cell > kMaxCell)
          throw std::invalid_argument("voxel_downsample: the cloud spans more than 2^21 voxels of " +
                                      slproto::short_number(voxel_mm) + " mm along an axis");
        key = (key << 21) | static_cast<std::uint64_t>(cell);
      }
      keyed[i] = {key, static_cast<std::uint32_t>(i)};
    }
  });
  tbb::parallel_sort(keyed.begin(), keyed.end());
  std::vector<std::size_t> starts;
  for (std::size_t i = 0; i < n; ++i)
    if (i == 0 || keyed[i].first != keyed[i - 1].first) starts.push_back(i);
  starts.push_back(n);
  const std::size_t m = starts.size() - 1;
  PointCloud out;
  out.points.resize(m);
  if (cloud.has_normals()) out.normals.resize(m);
  if (!cloud.confidence.empty()) out.confidence.resize(m);
  if (!cloud.intensity.empty()) out.intensity.resize(m);
  if (!cloud.view_id.empty()) out.view_id.resize(m);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, m, 4096), [&](const tbb::blocked_range<std::size_t>& r) {
    for (std::size_t v = r.begin(); v < r.end(); ++v) {
      Eigen::Vector3d sum = Eigen::Vector3d::Zero();
      Eigen::Vector3f normal = Eigen::Vector3f::Zero();
      double confidence = 0, intensity = 0;
      float best_confidence = -std::numeric_limits<float>::infinity();
      std::uint16_t view = 0;
      for (std::size_t j = starts[v]; j < starts[v + 1]; ++j) {
        const std::uint32_t i = keyed[j].second;
        sum += cloud.points[i].cast<double>();
        if (cloud.has_normals()) normal += cloud.normals[i];
        const float c = cloud.confidence.empty() ? 0.0f : cloud.confidence[i];
        confidence += c;
        if (!cloud.intensity.empty()) intensity += cloud.intensity[i];
        if (!cloud.view_id.empty() && c > best_confidence) {
          best_confidence = c;
          view = cloud.view_id[i];
        }
      }
      const auto count = static_cast<double>(starts[v + 1] - starts[v]);
      out.points[v] = (sum / count).cast<float>();
      if (cloud.has_normals()) {
        const float len = normal.norm();
        out.normals[v] = len > 0 ? Eigen::Vector3f(normal / len) : cloud.normals[keyed[starts[v]].second];
      }
      if (!cloud.confidence.empty()) out.confidence[v] = static_cast<float>(confidence / count);
      if (!cloud.intensity.empty()) out.intensity[v] = static_cast<float>(intensity / count);
      if (!cloud.view_id.empty()) out.view_id[v] = view;
    }
  });
  return out;
}

}  // namespace slscan::core
