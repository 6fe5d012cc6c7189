// Cloud comparison against known offsets: a tilted plane moved along its normal by a known
// distance, with pixel tags, some pixels missing on either side.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "slscan/core/cloud_compare.hpp"

using namespace slscan::core;

namespace {

// A tilted plane z = 500 + 0.2 x seen on a 200 x 150 grid of 0.5 mm pitch.
PixelTaggedCloud plane(double offset_along_normal, int skip_every) {
  PixelTaggedCloud c;
  const Eigen::Vector3f normal = Eigen::Vector3f(-0.2f, 0.0f, 1.0f).normalized();
  for (int v = 0; v < 150; ++v)
    for (int u = 0; u < 200; ++u) {
      if (skip_every > 0 && (u + v) % skip_every == 0) continue;
      const float x = 0.5f * static_cast<float>(u - 100), y = 0.5f * static_cast<float>(v - 75);
      c.points.push_back(Eigen::Vector3f(x, y, 500.0f + 0.2f * x) + static_cast<float>(offset_along_normal) * normal);
      c.u.push_back(static_cast<float>(u));
      c.v.push_back(static_cast<float>(v));
    }
  return c;
}

TEST(CompareClouds, KnownOffsetAlongTheNormal) {
  const PixelTaggedCloud reference = plane(0.0, 7);
  const PixelTaggedCloud measured = plane(0.1, 5);
  const CloudComparison c = compare_clouds(measured, reference);
  ASSERT_TRUE(c.per_pixel.has_value());
  // Per pixel: the same (u, v) moved 0.1 mm along the normal.
  EXPECT_NEAR(c.per_pixel->distance.median, 0.1, 1e-4);
  EXPECT_NEAR(c.per_pixel->distance.p99, 0.1, 1e-4);
  EXPECT_NEAR(c.per_pixel->median_signed_z, 0.1 / std::sqrt(1.04), 1e-4);
  // Reference has 6/7 of the pixels, measured 4/5; common = pixels in both.
  std::size_t common = 0;
  for (int v = 0; v < 150; ++v)
    for (int u = 0; u < 200; ++u) common += ((u + v) % 7 != 0 && (u + v) % 5 != 0) ? 1 : 0;
  EXPECT_EQ(c.per_pixel->common_pixels, common);
  EXPECT_NEAR(c.per_pixel->coverage, static_cast<double>(common) / static_cast<double>(reference.points.size()), 1e-12);
  // To the surface: exactly the offset (the plane fit is exact); to the nearest point: at
  // least the offset, and where the reference lacks the pixel, at most the offset and one grid
  // step along the tilted plane.
  EXPECT_NEAR(c.point_to_surface.median, 0.1, 1e-3);
  EXPECT_NEAR(c.point_to_surface.p99, 0.1, 2e-3);
  EXPECT_GE(c.point_to_point.median, 0.0999);
  EXPECT_LE(c.point_to_point.max, std::hypot(0.1, 0.5 * std::sqrt(1.04)) + 1e-4);
  EXPECT_EQ(c.unmatched, 0u);
}

TEST(CompareClouds, FarPointsAreUnmatchedAndQuantilesAreNearestRank) {
  PixelTaggedCloud reference = plane(0.0, 0);
  PixelTaggedCloud measured = plane(0.0, 0);
  measured.points[0].z() += 50.0f;  // far off: beyond the 5 mm gate
  measured.points[1].z() += 1.0f;
  const CloudComparison c = compare_clouds(measured, reference);
  EXPECT_EQ(c.unmatched, 1u);
  EXPECT_EQ(c.point_to_point.count, measured.points.size() - 1);
  ASSERT_TRUE(c.per_pixel);
  EXPECT_EQ(c.per_pixel->distance.count, measured.points.size());
  EXPECT_NEAR(c.per_pixel->distance.max, 50.0, 1e-3);
  EXPECT_EQ(c.per_pixel->distance.median, 0.0);

  std::vector<double> values{5, 1, 4, 2, 3, 6, 7, 8, 9, 10};
  const DistanceStats s = DistanceStats::of(values);
  EXPECT_EQ(s.median, 5);
  EXPECT_EQ(s.p90, 9);
  EXPECT_EQ(s.p99, 10);
  EXPECT_DOUBLE_EQ(s.mean, 5.5);
}

TEST(CompareClouds, BadInputIsRefused) {
  PixelTaggedCloud measured = plane(0.0, 0), reference = plane(0.0, 0);
  measured.u.pop_back();
  EXPECT_THROW(compare_clouds(measured, reference), std::invalid_argument);
  EXPECT_THROW(compare_clouds(plane(0.0, 0), PixelTaggedCloud{}), std::invalid_argument);
  PixelTaggedCloud untagged = plane(0.0, 0);
  untagged.u.clear();
  untagged.v.clear();
  EXPECT_FALSE(compare_clouds(untagged, reference).per_pixel.has_value());
  EXPECT_THROW(compare_by_pixel(untagged, reference), std::invalid_argument);
}

}  // namespace
