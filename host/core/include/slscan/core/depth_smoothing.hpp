// Depth smoothing of one view's organised cloud: a local quadratic fit of depth over the
// camera's pixel grid. Triangulation noise lies along each pixel's camera ray (the camera pixel
// is exact, the decoded projector coordinate is noisy), so each point moves only along its own
// ray, to the depth the fit predicts at its pixel: the lateral sampling is untouched and a
// smooth surface (plane, sphere, any quadric over the window) keeps its shape, without the
// inward bias of a plane fit on a curved surface. Runs on the worker that fused the view,
// while the next view streams in.
#pragma once

#include <cstddef>

#include "slscan/core/point_cloud.hpp"

namespace slscan::core {

struct DepthSmoothingOptions {
  // The window is set on the surface, not in pixels, so that a coarse camera does not average
  // over a larger patch (where a quadratic stops following a curved surface: a sphere's radius
  // shrinks) than a fine one: its half-width in pixels is window_radius_mm over the pixel
  // footprint at the cloud's median depth, at most max_window_radius_px. Under one pixel the
  // sampling is too coarse for smoothing to pay, and the cloud is left as measured.
  double window_radius_mm = 0.5;
  int max_window_radius_px = 4;
  // Neighbours whose depth differs from the centre's by more than this many pixel footprints
  // (depth / focal length) per pixel of grid distance lie across a depth edge (another
  // surface) and are left out of the fit. 4: surfaces up to 76 deg from face on are followed.
  float max_depth_slope = 4.0f;
  int min_neighbors = 12;  // fewer usable pixels (the centre included): the point stays as measured

  void check() const;  // throws std::invalid_argument naming the field
};

struct DepthSmoothingCounts {
  int window_radius_px = 0;  // as chosen for this cloud; 0: too coarse, nothing smoothed
  std::size_t input = 0;     // valid points
  std::size_t full = 0;      // smoothed with the whole window (the fixed kernel)
  std::size_t partial = 0;   // smoothed with part of it (edges, holes, depth steps)
  std::size_t kept = 0;      // too few neighbours: left as measured
  double mean_shift_um = 0;  // mean |depth change|: how much noise was taken out
};

// Smooths `cloud` in place (expressed in its camera's frame: the camera centre at the origin;
// `focal_px` its camera's focal length in pixels, for the pixel footprint). Throws
// std::invalid_argument on bad options or an inconsistent cloud. Threads over rows.
DepthSmoothingCounts smooth_depth(OrganizedCloud& cloud, double focal_px, const DepthSmoothingOptions& options = {});

}  // namespace slscan::core
