// Differences between a measured cloud and a reference cloud: point to nearest point, point
// to the reference's local surface (a plane fitted to its nearest points), and, when both
// clouds carry the camera pixel each point came from, pixel for pixel.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <optional>
#include <vector>

namespace slscan::core {

// Order statistics of a set of distances (mm). All zero when count is 0.
struct DistanceStats {
  std::size_t count = 0;
  double mean = 0, rms = 0, median = 0, p90 = 0, p99 = 0, max = 0;
  // Sorts `values` in place.
  static DistanceStats of(std::vector<double>& values);
};

// A cloud with, optionally, the camera pixel (u, v) of each point (pixel centres at integers).
struct PixelTaggedCloud {
  std::vector<Eigen::Vector3f> points;
  std::vector<float> u, v;  // empty, or one per point
  bool has_pixels() const { return !u.empty() && u.size() == points.size() && v.size() == points.size(); }
};

struct CompareOptions {
  int surface_neighbors = 8;  // reference points the local plane is fitted through
  // Measured points farther than this from the reference are counted as unmatched and left
  // out of the point-to-point and point-to-surface figures (a measured cloud usually covers
  // more than the reference: background, parts the reference filtered). <= 0: keep all.
  double max_distance_mm = 5.0;
  void check() const;  // throws std::invalid_argument naming the field
};

struct PixelComparison {
  DistanceStats distance;      // |measured - reference| at pixels both have
  double median_signed_z = 0;  // median of measured z - reference z (a depth bias shows here)
  std::size_t reference_pixels = 0, measured_pixels = 0, common_pixels = 0;
  double coverage = 0;  // common / reference pixels
};

struct CloudComparison {
  std::size_t measured_points = 0, reference_points = 0;
  std::size_t unmatched = 0;                 // measured points beyond max_distance_mm of the reference
  DistanceStats point_to_point;              // measured point -> nearest reference point
  DistanceStats point_to_surface;            // measured point -> plane through its nearest reference points
  std::optional<PixelComparison> per_pixel;  // when both clouds carry pixels
};

// Throws std::invalid_argument on an empty reference or inconsistent pixel channels.
CloudComparison compare_clouds(const PixelTaggedCloud& measured, const PixelTaggedCloud& reference,
                               const CompareOptions& options = {});

// The per-pixel part alone (both clouds must carry pixels; pixel coordinates are rounded to
// the nearest integer; a pixel listed twice in one cloud keeps its first point).
PixelComparison compare_by_pixel(const PixelTaggedCloud& measured, const PixelTaggedCloud& reference);

}  // namespace slscan::core
