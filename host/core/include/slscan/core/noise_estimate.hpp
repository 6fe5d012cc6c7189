// How noisy a view is, estimated from the data itself, so that the cleanup's limits follow
// the scanner rather than our virtual rig (docs/pipeline.md, "Noise-adaptive limits"): the
// robust spread (1.4826 x the median absolute value) of the second difference along the
// image rows and columns, on the organised grid. For white noise of sigma per point the second
// difference has sigma sqrt(6); a smooth surface contributes its curvature, which is far
// below the noise at the pixel scale; depth edges are few and the median ignores them.
//
// With a quality plane (the decoder's modulation B) only the pixels of at least the view's
// median quality are the centres of the differences: the better-measured half of the view.
// Phase noise scales as 1 / B, so a dim background (on the rig the wall 400 mm behind the
// axis, with period-order errors once the sensor is noisy) is several times noisier than the
// lit object and would otherwise set the limits for it.
#pragma once

#include <cstddef>
#include <vector>

#include "slscan/core/point_cloud.hpp"

namespace slscan::core {

struct NoiseEstimate {
  double second_difference = 0;  // robust sigma of z(i-1) - 2 z(i) + z(i+1): what a linear extrapolation misses
  double per_point = 0;          // second_difference / sqrt(6): a point's own noise, as if white
  std::size_t samples = 0;       // 0: too little data (the estimates are 0)
  float min_quality = 0;         // the quality gate used (the median quality; 0: none)
};

// Depth (camera z, mm) of an organised cloud; best_half: gated by its quality (above).
NoiseEstimate estimate_depth_noise(const OrganizedCloud& cloud, bool best_half = true);

// A per-pixel map (NaN where missing), e.g. the decoded projector coordinate (px); with
// `quality` (same size) gated by it as above. wrap_period > 0 (a phase decode's period, px):
// each second difference is taken modulo the period, so period-order errors (jumps by whole
// periods) do not count as noise.
NoiseEstimate estimate_map_noise(const std::vector<float>& values, int width, int height,
                                 const std::vector<float>* quality = nullptr, float wrap_period = 0);

}  // namespace slscan::core
