// Left/right fusion and flying-pixel removal on hand-built organised clouds.
#include <gtest/gtest.h>

#include <cmath>

#include "slscan/core/fusion.hpp"

namespace {

using slscan::core::FlyingPixelOptions;
using slscan::core::FusionOptions;
using slscan::core::OrganizedCloud;

void set(OrganizedCloud& cloud, int u, int v, const Eigen::Vector3f& p, float quality) {
  const auto i = static_cast<std::size_t>(v * cloud.width + u);
  cloud.points[i] = p;
  cloud.quality[i] = quality;
  cloud.valid[i] = 1;
}

TEST(Fusion, AgreeingMeanShadowFillAndRejection) {
  OrganizedCloud left, right;
  left.resize(4, 1);
  right.resize(4, 1);
  // Pixel 0: both agree (0.05 mm apart) -> weighted mean. Pixel 1: left only. Pixel 2: right
  // only. Pixel 3: both, 1 mm apart -> rejected.
  set(left, 0, 0, {0, 0, 100.00f}, 30);
  set(right, 0, 0, {0, 0, 100.05f}, 10);
  set(left, 1, 0, {1, 0, 101}, 5);
  set(right, 2, 0, {2, 0, 102}, 7);
  set(left, 3, 0, {3, 0, 103}, 5);
  set(right, 3, 0, {3, 0, 104}, 5);
  const auto result = slscan::core::fuse_left_right(left, right);
  EXPECT_EQ(result.counts.both, 1u);
  EXPECT_EQ(result.counts.left_only, 1u);
  EXPECT_EQ(result.counts.right_only, 1u);
  EXPECT_EQ(result.counts.rejected, 1u);
  EXPECT_EQ(result.counts.fused(), 3u);
  const auto& c = result.cloud;
  ASSERT_TRUE(c.valid[0]);
  EXPECT_NEAR(c.points[0].z(), (30 * 100.00 + 10 * 100.05) / 40, 1e-5);
  EXPECT_FLOAT_EQ(c.quality[0], 40);
  ASSERT_TRUE(c.valid[1]);
  EXPECT_EQ(c.points[1], Eigen::Vector3f(1, 0, 101));
  ASSERT_TRUE(c.valid[2]);
  EXPECT_EQ(c.points[2], Eigen::Vector3f(2, 0, 102));
  EXPECT_FALSE(c.valid[3]);
  EXPECT_TRUE(std::isnan(c.points[3].z()));
  EXPECT_EQ(c.count_valid(), 3u);
}

TEST(Fusion, IntensityIsTheQualityWeightedMeanLikeThePoint) {
  OrganizedCloud left, right;
  left.resize(3, 1);
  right.resize(3, 1);
  set(left, 0, 0, {0, 0, 100.00f}, 30);
  set(right, 0, 0, {0, 0, 100.05f}, 10);
  set(left, 1, 0, {1, 0, 101}, 5);
  set(right, 2, 0, {2, 0, 102}, 7);
  left.intensity = {0.8f, 0.4f, 0.9f};
  right.intensity = {0.2f, 0.7f, 0.3f};
  const auto fused = slscan::core::fuse_left_right(left, right);
  ASSERT_EQ(fused.cloud.intensity.size(), 3u);
  EXPECT_NEAR(fused.cloud.intensity[0], (30 * 0.8 + 10 * 0.2) / 40, 1e-6);
  EXPECT_EQ(fused.cloud.intensity[1], 0.4f) << "left only: the left's";
  EXPECT_EQ(fused.cloud.intensity[2], 0.3f) << "right only: the right's";
  // A side without the channel (hand-built clouds): the fused cloud has none rather than zeros.
  right.intensity.clear();
  EXPECT_TRUE(slscan::core::fuse_left_right(left, right).cloud.intensity.empty());
}

TEST(Fusion, ToleranceIsAnOption) {
  OrganizedCloud left, right;
  left.resize(1, 1);
  right.resize(1, 1);
  set(left, 0, 0, {0, 0, 100}, 1);
  set(right, 0, 0, {0, 0, 100.3f}, 1);
  FusionOptions loose;
  loose.agreement_mm = 0.5f;
  EXPECT_EQ(slscan::core::fuse_left_right(left, right).counts.rejected, 1u);
  EXPECT_EQ(slscan::core::fuse_left_right(left, right, loose).counts.both, 1u);
  FusionOptions bad;
  bad.agreement_mm = 0;
  EXPECT_THROW(bad.check(), std::invalid_argument);
  OrganizedCloud other;
  other.resize(2, 1);
  EXPECT_THROW((void)slscan::core::fuse_left_right(left, other), std::invalid_argument);
}

// A tilted plane (foreground, left half) in front of a background plane (right half), with a
// column of mixed pixels between them, one isolated outlier, and a thin steep ramp.
TEST(FlyingPixels, RemovesMixedAndIsolatedPixelsKeepsTrueEdges) {
  const int w = 40, h = 30;
  OrganizedCloud cloud;
  cloud.resize(w, h);
  auto foreground = [](int u, int v) { return 300.0f + 0.8f * static_cast<float>(u) + 0.3f * static_cast<float>(v); };
  auto background = [](int u, int v) { return 420.0f + 0.1f * static_cast<float>(u) - 0.05f * static_cast<float>(v); };
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      float z;
      if (u < 20) {
        z = foreground(u, v);
      } else if (u == 20) {
        z = 0.5f * (foreground(u, v) + background(u, v)) + static_cast<float>(v % 3);  // mixed
      } else {
        z = background(u, v);
      }
      set(cloud, u, v, {0.01f * static_cast<float>(u) * z, 0.01f * static_cast<float>(v) * z, z}, 1);
    }
  set(cloud, 10, 15, {0, 0, foreground(10, 15) + 3.0f}, 1);  // a lone spike in the foreground
  const auto result = slscan::core::remove_flying_pixels(cloud);
  EXPECT_EQ(result.counts.input, static_cast<std::size_t>(w * h));
  for (int v = 0; v < h; ++v) {
    const auto row = static_cast<std::size_t>(v * w);
    EXPECT_FALSE(result.cloud.valid[row + 20]) << "mixed pixel at row " << v;
    EXPECT_TRUE(result.cloud.valid[row + 19]) << "foreground edge pixel at row " << v;
    EXPECT_TRUE(result.cloud.valid[row + 21]) << "background edge pixel at row " << v;
  }
  EXPECT_FALSE(result.cloud.valid[static_cast<std::size_t>(15 * w + 10)]);
  EXPECT_EQ(result.counts.removed, static_cast<std::size_t>(h + 1));
  EXPECT_EQ(result.cloud.count_valid(), static_cast<std::size_t>(w * h - h - 1));

  FlyingPixelOptions bad;
  bad.relative = -1;
  EXPECT_THROW(bad.check(), std::invalid_argument);
}

TEST(FlyingPixels, KeepsSteepSmoothSurfacesAndDropsSpecks) {
  OrganizedCloud cloud;
  cloud.resize(12, 12);
  // A surface at grazing incidence: 5 mm of depth per pixel, curved.
  for (int v = 0; v < 10; ++v)
    for (int u = 0; u < 10; ++u) {
      const float z =
          300.0f + 5.0f * static_cast<float>(u) + 0.02f * static_cast<float>(u * u) + 0.1f * static_cast<float>(v);
      set(cloud, u, v, {0, 0, z}, 1);
    }
  set(cloud, 11, 11, {0, 0, 500}, 1);  // a lone valid pixel with no neighbours
  const auto result = slscan::core::remove_flying_pixels(cloud);
  EXPECT_EQ(result.counts.removed, 1u);
  EXPECT_FALSE(result.cloud.valid[static_cast<std::size_t>(11 * 12 + 11)]);
}

}  // namespace
