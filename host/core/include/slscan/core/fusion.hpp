// Stage 3: left/right fusion in camera pixel space, and removal of flying pixels on the
// organised grid. Both projectors' clouds come from the same camera, so they meet pixel by
// pixel: where both measured and agree, the quality-weighted mean; where one is shadowed, the
// other fills the hole; where they disagree (multi-path, specular), the pixel is dropped.
#pragma once

#include <cstddef>

#include "slscan/core/point_cloud.hpp"

namespace slscan::core {

struct FusionOptions {
  // Two measurements of one pixel farther apart than this are not the same surface point.
  float agreement_mm = 0.2f;
  void check() const;  // throws std::invalid_argument naming the field
};

struct FusionCounts {
  std::size_t both = 0, left_only = 0, right_only = 0, rejected = 0;
  std::size_t fused() const { return both + left_only + right_only; }
};

struct FusionResult {
  // quality = sum of the contributing qualities; intensity (when both sides have it) the
  // quality-weighted mean, like the point
  OrganizedCloud cloud;
  FusionCounts counts;
};

// Both clouds must have the same size (throws std::invalid_argument otherwise). The result is
// written into `storage`'s buffers (every slot of them): a grid of an earlier view passed here
// is reused instead of fresh memory.
FusionResult fuse_left_right(const OrganizedCloud& left, const OrganizedCloud& right, const FusionOptions& options = {},
                             OrganizedCloud storage = {});

// Flying pixels (mixed foreground/background at depth edges, shadow borders, isolated noise):
// a point is kept only if, in at least two independent (not opposite) of the 8 grid
// directions, the two neighbours on that side extrapolate linearly to its depth within
// max_abs_mm + relative * |their step|. A true edge pixel continues its own surface inwards
// and along the edge; a mixed pixel continues neither side of the edge, and a line of mixed
// pixels along a straight edge continues only along itself. Lone specks and 1-px-wide lines
// go too. No k-d tree: neighbours come from the grid.
struct FlyingPixelOptions {
  float max_abs_mm = 0.1f;
  float relative = 0.25f;
  void check() const;
};

struct FlyingPixelCounts {
  std::size_t input = 0, removed = 0;
};

struct FlyingPixelResult {
  OrganizedCloud cloud;
  FlyingPixelCounts counts;
};

// The cloud is taken by value: a caller that no longer needs its own moves it in (a 5 MP view
// is ~100 MB).
FlyingPixelResult remove_flying_pixels(OrganizedCloud cloud, const FlyingPixelOptions& options = {});

}  // namespace slscan::core
