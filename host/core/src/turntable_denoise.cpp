#include "slscan/core/turntable_denoise.hpp"

#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/parallel_for.h>

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "slproto/number_text.hpp"

namespace slscan::core {

void TurntableDenoiseOptions::check() const {
  auto fail = [](const std::string& msg) { throw std::invalid_argument("turntable denoise options: " + msg); };
  if (!std::isfinite(min_height_mm)) fail("min_height_mm is not finite");
  if (!(max_height_mm >= 0) || !std::isfinite(max_height_mm)) fail("max_height_mm must be >= 0 (0: no limit)");
  if (max_height_mm > 0 && max_height_mm <= min_height_mm)
    fail("max_height_mm " + slproto::short_number(max_height_mm) + " is not above min_height_mm " +
         slproto::short_number(min_height_mm));
  if (!(radius_mm >= 0) || !std::isfinite(radius_mm)) fail("radius_mm must be >= 0 (0: the calibration's radius)");
}

TurntableGeometry TurntableGeometry::from(const slproto::TurntableCalibration& calibration) {
  if (auto status = calibration.cam_from_table.check("turntable cam_from_table"); !status)
    throw std::invalid_argument(status.error().message);
  TurntableGeometry g;
  const auto c = calibration.axis_point();
  const auto n = calibration.axis_direction();
  g.axis_point = Eigen::Vector3d(c[0], c[1], c[2]);
  g.axis_direction = Eigen::Vector3d(n[0], n[1], n[2]).normalized();
  g.radius_mm = calibration.platform_radius_mm;
  return g;
}

namespace {

enum class Verdict : std::uint8_t { keep, below, above, outside };

struct Classifier {
  TurntableGeometry geometry;
  double min_height, max_height, radius;

  Classifier(const slproto::TurntableCalibration& turntable, const TurntableDenoiseOptions& options)
      : geometry(TurntableGeometry::from(turntable)),
        min_height(options.min_height_mm),
        max_height(options.max_height_mm),
        radius(options.radius_mm > 0 ? options.radius_mm : turntable.platform_radius_mm) {
    if (!(radius > 0) || !std::isfinite(radius))
      throw std::invalid_argument("turntable denoise: platform radius " + slproto::short_number(radius) +
                                  " is not positive");
  }

  Verdict operator()(const Eigen::Vector3f& point) const {
    const Eigen::Vector3d p = point.cast<double>();
    const double height = geometry.height(p);
    if (!(height > min_height)) return Verdict::below;
    if (max_height > 0 && height > max_height) return Verdict::above;
    if (!(geometry.distance_to_axis(p) <= radius)) return Verdict::outside;
    return Verdict::keep;
  }
};

void tally(TurntableDenoiseCounts& counts, Verdict verdict) {
  ++counts.input;
  switch (verdict) {
    case Verdict::keep:
      ++counts.kept;
      break;
    case Verdict::below:
      ++counts.below_min_height;
      break;
    case Verdict::above:
      ++counts.above_max_height;
      break;
    case Verdict::outside:
      ++counts.outside_radius;
      break;
  }
}

void add(TurntableDenoiseCounts& total, const TurntableDenoiseCounts& c) {
  total.input += c.input;
  total.kept += c.kept;
  total.below_min_height += c.below_min_height;
  total.above_max_height += c.above_max_height;
  total.outside_radius += c.outside_radius;
}

}  // namespace

TurntableDenoiseResult<OrganizedCloud> denoise_by_turntable(OrganizedCloud cloud,
                                                            const slproto::TurntableCalibration& turntable,
                                                            const TurntableDenoiseOptions& options) {
  options.check();
  const std::size_t n = static_cast<std::size_t>(cloud.width) * static_cast<std::size_t>(cloud.height);
  if (cloud.points.size() != n || cloud.valid.size() != n || cloud.quality.size() != n)
    throw std::invalid_argument("turntable denoise: organised cloud buffers do not match its size");
  const Classifier classify(turntable, options);
  TurntableDenoiseResult<OrganizedCloud> result;
  result.cloud = std::move(cloud);  // filtered in place: no copy when the caller moved its cloud in
  const float nan = std::numeric_limits<float>::quiet_NaN();
  tbb::combinable<TurntableDenoiseCounts> counts_by_thread;
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096), [&](const tbb::blocked_range<std::size_t>& r) {
    TurntableDenoiseCounts& counts = counts_by_thread.local();
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      if (!result.cloud.valid[i]) continue;
      const Verdict verdict = classify(result.cloud.points[i]);
      tally(counts, verdict);
      if (verdict != Verdict::keep) {
        result.cloud.points[i] = Eigen::Vector3f(nan, nan, nan);
        result.cloud.quality[i] = 0.0f;
        result.cloud.valid[i] = 0;
      }
    }
  });
  counts_by_thread.combine_each([&](const TurntableDenoiseCounts& c) { add(result.counts, c); });
  return result;
}

TurntableDenoiseResult<PointCloud> denoise_by_turntable(const PointCloud& cloud,
                                                        const slproto::TurntableCalibration& turntable,
                                                        const TurntableDenoiseOptions& options) {
  options.check();
  const Classifier classify(turntable, options);
  std::vector<std::size_t> kept;
  kept.reserve(cloud.size());
  TurntableDenoiseResult<PointCloud> result;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const Verdict verdict = classify(cloud.points[i]);
    tally(result.counts, verdict);
    if (verdict == Verdict::keep) kept.push_back(i);
  }
  result.cloud = cloud.select(kept);
  return result;
}

}  // namespace slscan::core
