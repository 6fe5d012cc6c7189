// SparseOrganizedCloud: what a view keeps of its grid once cleaned (the valid slots only). The
// overlap selection and the pictures read it where they read the whole grid before, so it must
// give back exactly what the grid held, and nothing where the grid held nothing.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <stdexcept>

#include "slscan/core/point_cloud.hpp"

namespace {

using slscan::core::OrganizedCloud;
using slscan::core::SparseOrganizedCloud;

// A grid with a random ~10 % of its slots valid, rows that are empty, full, and valid at their
// first and last pixel (the row edges a binary search gets wrong).
OrganizedCloud patchy_grid(int width, int height, bool with_intensity) {
  OrganizedCloud cloud;
  cloud.resize(width, height);
  if (!with_intensity) cloud.intensity.clear();
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> value(-100.0f, 100.0f);
  for (int v = 0; v < height; ++v)
    for (int u = 0; u < width; ++u) {
      const bool valid = v == 3 ? false : v == 4 ? true : (u == 0 || u == width - 1) ? v % 2 == 0 : rng() % 10 == 0;
      if (!valid) continue;
      const auto i = static_cast<std::size_t>(v) * static_cast<std::size_t>(width) + static_cast<std::size_t>(u);
      cloud.points[i] = {value(rng), value(rng), value(rng)};
      cloud.quality[i] = value(rng);
      if (with_intensity) cloud.intensity[i] = value(rng);
      cloud.valid[i] = 1;
    }
  return cloud;
}

TEST(SparseOrganizedCloud, KeepsEveryValidSlotInGridOrderAndGivesTheGridBackBitForBit) {
  for (const bool with_intensity : {false, true}) {
    const OrganizedCloud grid = patchy_grid(37, 23, with_intensity);
    const SparseOrganizedCloud sparse = SparseOrganizedCloud::of(grid);
    EXPECT_EQ(sparse.size(), grid.count_valid());
    EXPECT_EQ(sparse.intensity.size(), with_intensity ? sparse.size() : 0u);
    for (std::size_t k = 1; k < sparse.size(); ++k) ASSERT_LT(sparse.slots[k - 1], sparse.slots[k]);
    const OrganizedCloud back = sparse.to_organized();
    ASSERT_EQ(back.width, grid.width);
    ASSERT_EQ(back.height, grid.height);
    ASSERT_EQ(back.intensity.size(), with_intensity ? grid.size() : 0u);
    for (std::size_t i = 0; i < grid.size(); ++i) {
      ASSERT_EQ(back.valid[i], grid.valid[i]) << i;
      if (!grid.valid[i]) {
        EXPECT_TRUE(std::isnan(back.points[i].x())) << i;
        EXPECT_EQ(back.quality[i], 0.0f) << i;
        continue;
      }
      EXPECT_EQ(back.points[i], grid.points[i]) << i;
      EXPECT_EQ(back.quality[i], grid.quality[i]) << i;
      if (with_intensity) {
        EXPECT_EQ(back.intensity[i], grid.intensity[i]) << i;
      }
    }
  }
  // Without intensity when asked so, even where the grid has it.
  EXPECT_TRUE(SparseOrganizedCloud::of(patchy_grid(9, 5, true), false).intensity.empty());
}

TEST(SparseOrganizedCloud, FindsEachPixelsSampleAndNothingElsewhere) {
  const OrganizedCloud grid = patchy_grid(41, 19, false);
  const SparseOrganizedCloud sparse = SparseOrganizedCloud::of(grid);
  for (int v = -2; v < grid.height + 2; ++v)
    for (int u = -2; u < grid.width + 2; ++u) {
      const std::ptrdiff_t k = sparse.find(u, v);
      const bool inside = u >= 0 && v >= 0 && u < grid.width && v < grid.height;
      const auto i = static_cast<std::size_t>(v) * static_cast<std::size_t>(grid.width) + static_cast<std::size_t>(u);
      if (!inside || !grid.valid[i]) {
        ASSERT_EQ(k, -1) << u << ", " << v;
        continue;
      }
      ASSERT_GE(k, 0) << u << ", " << v;
      EXPECT_EQ(sparse.slots[static_cast<std::size_t>(k)], i);
      EXPECT_EQ(sparse.points[static_cast<std::size_t>(k)], grid.points[i]);
    }
}

TEST(SparseOrganizedCloud, EmptyGridsAndMismatchedBuffers) {
  OrganizedCloud none;
  none.resize(16, 8);
  const SparseOrganizedCloud empty = SparseOrganizedCloud::of(none);
  EXPECT_EQ(empty.size(), 0u);
  EXPECT_EQ(empty.row_begin.size(), 9u);
  EXPECT_EQ(empty.find(3, 3), -1);
  EXPECT_EQ(empty.to_organized().count_valid(), 0u);
  const SparseOrganizedCloud zero = SparseOrganizedCloud::of(OrganizedCloud{});
  EXPECT_EQ(zero.find(0, 0), -1);
  EXPECT_EQ(zero.to_organized().size(), 0u);
  OrganizedCloud broken = patchy_grid(8, 8, false);
  broken.quality.pop_back();
  EXPECT_THROW((void)SparseOrganizedCloud::of(broken), std::invalid_argument);
}

}  // namespace
