#include "slscan/core/noise_estimate.hpp"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

namespace slscan::core {

namespace {

// The rows sampled: every 4th (every row of a small image).
int row_step(int h) { return h >= 64 ? 4 : 1; }

// Samples gathered per sampled row, in parallel: row r's first counts[r] of its `stride` slots.
struct RowSamples {
  std::size_t stride = 0;
  std::vector<float> values;
  std::vector<std::uint32_t> counts;

  std::size_t total() const {
    std::size_t n = 0;
    for (const std::uint32_t c : counts) n += c;
    return n;
  }
  // f(value) for every sample, rows split among threads; each thread has its own `State`.
  template <class State, class F>
  void for_each(tbb::enumerable_thread_specific<State>& states, F f) const {
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, counts.size(), 16), [&](const auto& rows) {
      State& state = states.local();
      for (std::size_t r = rows.begin(); r < rows.end(); ++r) {
        const float* row = values.data() + r * stride;
        for (std::uint32_t i = 0; i < counts[r]; ++i) f(state, row[i]);
      }
    });
  }
};

// fill(v, out) writes row v's samples to out (at most `per_row`) and returns how many.
template <class Fill>
RowSamples sample_rows(int h, std::size_t per_row, Fill fill) {
  RowSamples samples;
  const int step = row_step(h);
  const auto rows = static_cast<std::size_t>(h - 2 + step - 1) / static_cast<std::size_t>(step);
  samples.stride = per_row;
  samples.values.resize(rows * per_row);
  samples.counts.assign(rows, 0);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, rows, 8), [&](const auto& block) {
    for (std::size_t r = block.begin(); r < block.end(); ++r)
      samples.counts[r] = fill(1 + static_cast<int>(r) * step, samples.values.data() + r * per_row);
  });
  return samples;
}

// A float's bits as an unsigned key in the same order (negatives flipped whole, positives
// with the sign bit set); -0 sorts just below +0.
inline std::uint32_t order_key(float v) {
  std::uint32_t bits;
  std::memcpy(&bits, &v, sizeof bits);
  return (bits & 0x80000000u) != 0 ? ~bits : bits | 0x80000000u;
}

// The k-th smallest sample (0-based): the value std::nth_element leaves at begin + k, found
// in two counting passes over 16-bit digits of the keys (high half, then the low half within
// the high bin that holds rank k) rather than a serial selection over ~2 M samples.
float kth_smallest(const RowSamples& samples, std::size_t k) {
  using Histogram = std::vector<std::uint32_t>;
  auto find_bin = [&](tbb::enumerable_thread_specific<Histogram>& histograms, std::size_t& rank) {
    Histogram total(65536, 0);
    for (const Histogram& h : histograms)
      for (std::size_t b = 0; b < total.size(); ++b) total[b] += h[b];
    std::uint32_t bin = 0;
    while (rank >= total[bin]) rank -= total[bin++];
    return bin;
  };
  std::size_t rank = k;
  tbb::enumerable_thread_specific<Histogram> high_counts(Histogram(65536, 0));
  samples.for_each(high_counts, [](Histogram& h, float v) { ++h[order_key(v) >> 16]; });
  const std::uint32_t high = find_bin(high_counts, rank);
  tbb::enumerable_thread_specific<Histogram> low_counts(Histogram(65536, 0));
  samples.for_each(low_counts, [high](Histogram& h, float v) {
    const std::uint32_t key = order_key(v);
    if (key >> 16 == high) ++h[key & 0xffffu];
  });
  const std::uint32_t key = high << 16 | find_bin(low_counts, rank);
  const std::uint32_t bits = (key & 0x80000000u) != 0 ? key & 0x7fffffffu : ~key;
  float v;
  std::memcpy(&v, &bits, sizeof v);
  return v;
}

// The median quality of the sampled pixels that have a value: the better-measured half of the
// view sets the estimate (noise_estimate.hpp).
template <class Value, class Quality>
float median_quality(int w, int h, Value value, Quality quality) {
  const RowSamples q = sample_rows(h, static_cast<std::size_t>(w), [&](int v, float* out) {
    std::uint32_t n = 0;
    for (int u = 1; u + 1 < w; ++u)
      if (std::isfinite(value(u, v))) out[n++] = quality(u, v);
    return n;
  });
  const std::size_t count = q.total();
  if (count == 0) return 0;
  return kth_smallest(q, count / 2);
}

// Second differences along rows and columns of the sampled rows, centred on the pixels whose
// quality is at least `min_quality`; their robust sigma.
template <class Value, class Quality>
NoiseEstimate estimate(int w, int h, Value value, Quality quality, bool best_half, float wrap = 0) {
  NoiseEstimate out;
  if (w < 3 || h < 3) return out;
  const float min_quality = best_half ? median_quality(w, h, value, quality) : -std::numeric_limits<float>::max();
  out.min_quality = best_half ? min_quality : 0;
  // A period-order error moves a value by whole periods: wrapped, it leaves the noise.
  const auto wrapped = [wrap](float x) { return wrap > 0 ? x - wrap * std::nearbyint(x / wrap) : x; };
  const RowSamples d = sample_rows(h, 2 * static_cast<std::size_t>(w), [&](int v, float* row) {
    std::uint32_t n = 0;
    for (int u = 1; u + 1 < w; ++u) {
      const float c = value(u, v);
      if (!std::isfinite(c) || !(quality(u, v) >= min_quality)) continue;
      const float l = value(u - 1, v), r = value(u + 1, v);
      if (std::isfinite(l) && std::isfinite(r)) row[n++] = std::fabs(wrapped(l - 2 * c + r));
      const float a = value(u, v - 1), b = value(u, v + 1);
      if (std::isfinite(a) && std::isfinite(b)) row[n++] = std::fabs(wrapped(a - 2 * c + b));
    }
    return n;
  });
  const std::size_t count = d.total();
  if (count < 100) return out;
  out.samples = count;
  out.second_difference = 1.4826 * static_cast<double>(kth_smallest(d, count / 2));
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
