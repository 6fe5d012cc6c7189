// The noise estimate samples rows in parallel and selects its medians by counting (two 16-bit
// digits of the float's order key). It must give exactly what the definition gives: the
// values std::nth_element leaves in the middle of the plainly gathered samples, on maps with
// masked pixels, ties, negative and signed-zero qualities, period wraps, odd sizes and rows
// with nothing in them.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "slscan/core/noise_estimate.hpp"

namespace {

using slscan::core::estimate_map_noise;
using slscan::core::NoiseEstimate;

// The definition, written plainly (serial gathering, std::nth_element).
NoiseEstimate reference(const std::vector<float>& values, int w, int h, const std::vector<float>* quality, float wrap) {
  NoiseEstimate out;
  if (w < 3 || h < 3) return out;
  const int step = h >= 64 ? 4 : 1;
  auto at = [&](const std::vector<float>& m, int u, int v) {
    return m[static_cast<std::size_t>(v) * static_cast<std::size_t>(w) + static_cast<std::size_t>(u)];
  };
  float min_quality = -std::numeric_limits<float>::max();
  if (quality != nullptr) {
    std::vector<float> q;
    for (int v = 1; v + 1 < h; v += step)
      for (int u = 1; u + 1 < w; ++u)
        if (std::isfinite(at(values, u, v))) q.push_back(at(*quality, u, v));
    min_quality = 0;
    if (!q.empty()) {
      std::nth_element(q.begin(), q.begin() + static_cast<long>(q.size() / 2), q.end());
      min_quality = q[q.size() / 2];
    }
    out.min_quality = min_quality;
  }
  auto wrapped = [wrap](float x) { return wrap > 0 ? x - wrap * std::nearbyint(x / wrap) : x; };
  std::vector<float> d;
  for (int v = 1; v + 1 < h; v += step)
    for (int u = 1; u + 1 < w; ++u) {
      const float c = at(values, u, v);
      const float q = quality != nullptr ? at(*quality, u, v) : 0.0f;
      if (!std::isfinite(c) || !(q >= min_quality)) continue;
      const float l = at(values, u - 1, v), r = at(values, u + 1, v);
      if (std::isfinite(l) && std::isfinite(r)) d.push_back(std::fabs(wrapped(l - 2 * c + r)));
      const float a = at(values, u, v - 1), b = at(values, u, v + 1);
      if (std::isfinite(a) && std::isfinite(b)) d.push_back(std::fabs(wrapped(a - 2 * c + b)));
    }
  if (d.size() < 100) return out;
  std::nth_element(d.begin(), d.begin() + static_cast<long>(d.size() / 2), d.end());
  out.samples = d.size();
  out.second_difference = 1.4826 * static_cast<double>(d[d.size() / 2]);
  out.per_point = out.second_difference / std::sqrt(6.0);
  return out;
}

struct Map {
  int w, h;
  std::vector<float> values, quality;
};

// A ramp with noise, period jumps, masked patches and empty rows; qualities with ties,
// negatives and both zeros.
Map make_map(int w, int h, unsigned seed, float noise, float wrap) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> gauss(0.0f, noise);
  std::uniform_int_distribution<int> die(0, 99);
  Map m{w, h, std::vector<float>(static_cast<std::size_t>(w * h)), std::vector<float>(static_cast<std::size_t>(w * h))};
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const auto i = static_cast<std::size_t>(v) * static_cast<std::size_t>(w) + static_cast<std::size_t>(u);
      float value = 0.37f * static_cast<float>(u) + 0.11f * static_cast<float>(v) + gauss(rng);
      const int roll = die(rng);
      if (roll < 8 || v % 17 == 5) value = nan;
      if (roll >= 8 && roll < 10 && wrap > 0) value += wrap * static_cast<float>(die(rng) % 3 - 1);
      m.values[i] = value;
      const int q = die(rng);
      m.quality[i] = q < 5    ? -0.0f
                     : q < 10 ? 0.0f
                     : q < 15 ? -static_cast<float>(q)
                              : static_cast<float>(q - q % 4) * 0.625f;
    }
  return m;
}

void expect_same(const NoiseEstimate& got, const NoiseEstimate& want) {
  EXPECT_EQ(got.samples, want.samples);
  EXPECT_EQ(got.second_difference, want.second_difference);
  EXPECT_EQ(got.per_point, want.per_point);
  EXPECT_EQ(got.min_quality, want.min_quality);
}

TEST(NoiseEstimate, CountingSelectionGivesTheDefinitionsMedians) {
  for (const auto& [w, h, seed, noise, wrap] :
       {std::tuple{640, 512, 1u, 0.05f, 0.0f}, std::tuple{641, 97, 2u, 0.3f, 8.0f}, std::tuple{37, 63, 3u, 0.01f, 0.0f},
        std::tuple{300, 200, 4u, 0.0f, 16.0f}}) {
    SCOPED_TRACE(std::to_string(w) + " x " + std::to_string(h));
    const Map m = make_map(w, h, seed, noise, wrap);
    const NoiseEstimate gated = estimate_map_noise(m.values, w, h, &m.quality, wrap);
    expect_same(gated, reference(m.values, w, h, &m.quality, wrap));
    EXPECT_GT(gated.samples, 100u);
    expect_same(estimate_map_noise(m.values, w, h, nullptr, wrap), reference(m.values, w, h, nullptr, wrap));
  }
}

TEST(NoiseEstimate, TooLittleDataGivesZeros) {
  const Map m = make_map(12, 4, 5u, 0.1f, 0.0f);  // ~20 samples
  const NoiseEstimate e = estimate_map_noise(m.values, 12, 4, &m.quality);
  EXPECT_EQ(e.samples, 0u);
  EXPECT_EQ(e.per_point, 0.0);
  std::vector<float> empty(64 * 64, std::numeric_limits<float>::quiet_NaN());
  expect_same(estimate_map_noise(empty, 64, 64, &empty), reference(empty, 64, 64, &empty, 0.0f));
}

}  // namespace
