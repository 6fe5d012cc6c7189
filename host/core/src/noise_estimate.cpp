#include "slscan/core/noise_estimate.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace slscan::core {

namespace {

// The rows sampled: every 4th (every row of a small image).
int row_step(int h) { return h >= 64 ? 4 : 1; }

// The median quality of the sampled pixels that have a value: the better-measured half of the
// view sets the estimate (noise_estimate.hpp).
template <class Value, class Quality>
float median_quality(int w, int h, Value value, Quality quality) {
  std::vector<float> q;
  for (int v = 1; v + 1 < h; v += row_step(h))
    for (int u = 1; u + 1 < w; ++u)
      if (std::isfinite(value(u, v))) q.push_back(quality(u, v));
  if (q.empty()) return 0;
  const auto middle = q.begin() + static_cast<long>(q.size() / 2);
  std::nth_element(q.begin(), middle, q.end());
  return *middle;
}

// Second differences along rows and columns of the sampled rows, centred on the pixels whose
// quality is at least `min_quality`; their robust sigma.
template <class Value, class Quality>
NoiseEstimate estimate(int w, int h, Value value, Quality quality, bool best_half, float wrap = 0) {
  NoiseEstimate out;
  if (w < 3 || h < 3) return out;
  const float min_quality = best_half ? median_quality(w, h, value, quality) : -std::numeric_limits<float>::max();
  out.min_quality = best_half ? min_quality : 0;
  std::vector<float> d;
  // A period-order error moves a value by whole periods: wrapped, it leaves the noise.
  const auto wrapped = [wrap](float x) { return wrap > 0 ? x - wrap * std::nearbyint(x / wrap) : x; };
  for (int v = 1; v + 1 < h; v += row_step(h))
    for (int u = 1; u + 1 < w; ++u) {
      const float c = value(u, v);
      if (!std::isfinite(c) || !(quality(u, v) >= min_quality)) continue;
      const float l = value(u - 1, v), r = value(u + 1, v);
      if (std::isfinite(l) && std::isfinite(r)) d.push_back(std::fabs(wrapped(l - 2 * c + r)));
      const float a = value(u, v - 1), b = value(u, v + 1);
      if (std::isfinite(a) && std::isfinite(b)) d.push_back(std::fabs(wrapped(a - 2 * c + b)));
    }
  if (d.size() < 100) return out;
  const auto middle = d.begin() + static_cast<long>(d.size() / 2);
  std::nth_element(d.begin(), middle, d.end());
  out.samples = d.size();
  out.second_difference = 1.4826 * static_cast<double>(*middle);
  out.per_point = out.second_difference / std::sqrt(6.0);
  return out;
}

}  // namespace

NoiseEstimate estimate_depth_noise(const OrganizedCloud& cloud, bool best_half) {
  const auto w = static_cast<std::size_t>(cloud.width);
  const auto index = [w](int u, int v) { return static_cast<std::size_t>(v) * w + static_cast<std::size_t>(u); };
  return estimate(
      cloud.width, cloud.height,
      [&](int u, int v) {
        const std::size_t i = index(u, v);
        return cloud.valid[i] ? cloud.points[i].z() : std::numeric_limits<float>::quiet_NaN();
      },
      [&](int u, int v) { return cloud.quality.empty() ? 0.0f : cloud.quality[index(u, v)]; },
      best_half && !cloud.quality.empty());
}

NoiseEstimate estimate_map_noise(const std::vector<float>& values, int width, int height,
                                 const std::vector<float>* quality, float wrap_period) {
  const auto w = static_cast<std::size_t>(width);
  const auto index = [w](int u, int v) { return static_cast<std::size_t>(v) * w + static_cast<std::size_t>(u); };
  return estimate(
      width, height, [&](int u, int v) { return values[index(u, v)]; },
      [&](int u, int v) { return quality != nullptr ? (*quality)[index(u, v)] : 0.0f; }, quality != nullptr,
      wrap_period);
}

}  // namespace slscan::core
