// The grid's k nearest neighbours and radius counts against the k-d tree's, point by point, on
// clouds that stress it: a scan-like surface with far outliers, a volume, a flat sheet, a line,
// heaps of duplicate points, a cloud spanning more cells than a key holds, tiny clouds.
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <Eigen/Core>
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <random>
#include <stdexcept>
#include <tuple>
#include <vector>

#include "cloud_filters_kdtree.hpp"
#include "neighbour_grid.hpp"
#include "slscan/core/cloud_filters.hpp"
#include "slscan/core/normals.hpp"

namespace {

using Points = std::vector<Eigen::Vector3f>;
using slscan::core::detail::KdTree;

// A bumpy sphere of radius ~`radius` mm, 0.01 mm noise, 0.5 % outliers in its bounding box.
Points surface_with_outliers(std::size_t n, double radius, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g(0, 1);
  std::uniform_real_distribution<double> box(-1.3 * radius, 1.3 * radius);
  Points points;
  while (points.size() < n) {
    const Eigen::Vector3d d = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
    const double r = radius * (1 + 0.1 * d.x() * d.y()) + 0.01 * g(rng);
    points.push_back((d * r).cast<float>());
  }
  for (std::size_t i = 0; i < n / 200; ++i)
    points[i * 197 % n] = Eigen::Vector3d(box(rng), box(rng), box(rng)).cast<float>();
  return points;
}

Points uniform_box(std::size_t n, const Eigen::Vector3f& size, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(0, 1);
  Points points(n);
  for (auto& p : points) p = Eigen::Vector3f(u(rng), u(rng), u(rng)).cwiseProduct(size);
  return points;
}

// Every point's k nearest from the grid have the k-d tree's distances, and each neighbour's
// coordinates are those of the cloud point it names; the index sets agree except among points at
// the same distance (`ties_everywhere`: not checked).
void expect_same_k_nearest(const Points& points, std::size_t k, bool ties_everywhere = false) {
  const KdTree tree(points);
  std::vector<std::vector<std::pair<float, std::uint32_t>>> grid_answer(points.size());
  std::vector<int> visits(points.size(), 0);
  std::vector<int> misplaced(points.size(), 0);
  slscan::core::detail::for_each_k_nearest(
      points, k, [&](std::size_t i, const slscan::core::detail::KNearest& nearest) {
        for (std::size_t j = 0; j < nearest.count; ++j) {
          grid_answer[i].emplace_back(nearest.squared_distance[j], nearest.index(j));
          if (nearest.point(j) != points[nearest.index(j)]) ++misplaced[i];
        }
        if (nearest.query != points[i]) ++misplaced[i];
        ++visits[i];
      });
  std::vector<std::uint32_t> indices(k);
  std::vector<float> d2(k);
  std::size_t index_mismatches = 0;
  for (std::size_t i = 0; i < points.size(); ++i) {
    ASSERT_EQ(visits[i], 1) << "point " << i;
    ASSERT_EQ(misplaced[i], 0) << "point " << i;
    const std::size_t found = tree.knn(points[i], k, indices.data(), d2.data());
    auto answer = grid_answer[i];
    ASSERT_EQ(answer.size(), found) << "point " << i;
    std::sort(answer.begin(), answer.end());
    for (std::size_t j = 0; j < found; ++j) {
      ASSERT_NEAR(answer[j].first, d2[j], 1e-6f * std::max(1.0f, d2[j])) << "point " << i << ", neighbour " << j;
      const float d = std::sqrt(d2[j]);
      const Eigen::Vector3f& q = points[answer[j].second];
      ASSERT_NEAR((q - points[i]).norm(), d, 1e-5f * std::max(1.0f, d)) << "point " << i << ", neighbour " << j;
    }
    std::vector<std::uint32_t> a, b(indices.begin(), indices.begin() + static_cast<std::ptrdiff_t>(found));
    for (const auto& [distance, index] : answer) a.push_back(index);
    std::sort(a.begin(), a.end());
    std::sort(b.begin(), b.end());
    if (a != b) ++index_mismatches;
  }
  if (!ties_everywhere) {
    EXPECT_LE(index_mismatches, points.size() / 100) << "more neighbour sets differ than ties explain";
  }
}

void expect_same_counts(const Points& points, float radius, std::uint32_t stop_at) {
  const KdTree tree(points);
  const auto counts = slscan::core::detail::count_within(points, radius, stop_at);
  ASSERT_EQ(counts.size(), points.size());
  for (std::size_t i = 0; i < points.size(); ++i) {
    const auto expected = static_cast<std::uint32_t>(tree.count_within(points[i], radius, stop_at));
    ASSERT_EQ(counts[i], std::min(expected, stop_at)) << "point " << i;
  }
}

TEST(NeighbourGrid, KNearestMatchTheKdTreeOnAScanSurfaceWithOutliers) {
  const Points points = surface_with_outliers(40000, 10.0, 1);
  expect_same_k_nearest(points, 21);
  expect_same_k_nearest(points, 3);
  expect_same_k_nearest(points, 64);
}

TEST(NeighbourGrid, KNearestMatchTheKdTreeInAVolumeSheetAndLine) {
  expect_same_k_nearest(uniform_box(20000, {5, 5, 5}, 2), 20);
  expect_same_k_nearest(uniform_box(20000, {50, 50, 0}, 3), 20);  // flat: one cell thick
  expect_same_k_nearest(uniform_box(5000, {0, 0, 30}, 4), 10);    // a line
}

TEST(NeighbourGrid, KNearestAmongDuplicatesAndInTinyClouds) {
  // 3000 points on 150 distinct positions, 20 at each: the 20 nearest are a position's copies.
  Points heaps = uniform_box(150, {2, 2, 2}, 5);
  for (std::size_t i = 0; heaps.size() < 3000; ++i) heaps.push_back(heaps[i % 150]);
  expect_same_k_nearest(heaps, 20);
  expect_same_k_nearest(uniform_box(5, {1, 1, 1}, 6), 20);  // fewer points than k
  expect_same_k_nearest(uniform_box(21, {1, 1, 1}, 7), 21);
  expect_same_k_nearest(Points(100, Eigen::Vector3f(1, 2, 3)), 8, true);  // all one point
}

TEST(NeighbourGrid, KNearestWhenTheCloudSpansMoreCellsThanAKeyHolds) {
  // A dense patch and a point 10^6 mm away: the cell is at least 1e6 / 2^21 mm, far coarser
  // than the patch needs, and the answers are still exact.
  Points points = uniform_box(5000, {1, 1, 1}, 8);
  points.emplace_back(1e6f, -1e6f, 5e5f);
  expect_same_k_nearest(points, 12);
  expect_same_counts(points, 0.05f, 6);
}

TEST(NeighbourGrid, CountsWithinARadiusMatchTheKdTree) {
  const Points surface = surface_with_outliers(40000, 10.0, 9);
  expect_same_counts(surface, 0.3f, 6);
  expect_same_counts(surface, 0.3f, 1000);  // counted to the end
  expect_same_counts(uniform_box(20000, {5, 5, 5}, 10), 0.2f, 12);
  expect_same_counts(surface, 50.0f, 100);  // one cell holds everything
}

// The stages built on the grid give the same bits on one thread and on several.
TEST(NeighbourGrid, OutlierRemovalAndNormalsDoNotDependOnThreads) {
  slscan::core::PointCloud cloud;
  cloud.points = surface_with_outliers(30000, 8.0, 12);
  auto run = [&](int threads) {
    return tbb::task_arena(threads).execute([&] {
      return std::make_tuple(slscan::core::statistical_outlier_removal(cloud, {20, 1.0}),
                             slscan::core::radius_outlier_removal(cloud, {0.3, 5}), slscan::core::pca_normals(cloud));
    });
  };
  const auto [sor1, radius1, normals1] = run(1);
  const auto [sor2, radius2, normals2] = run(2);
  EXPECT_EQ(std::bit_cast<std::uint64_t>(sor1.threshold), std::bit_cast<std::uint64_t>(sor2.threshold));
  EXPECT_EQ(sor1.kept_indices, sor2.kept_indices);
  EXPECT_GT(sor1.removed, 0u);
  EXPECT_EQ(radius1.kept_indices, radius2.kept_indices);
  ASSERT_EQ(normals1.size(), normals2.size());
  EXPECT_EQ(std::memcmp(normals1.data(), normals2.data(), normals1.size() * sizeof(normals1[0])), 0);
}

TEST(NeighbourGrid, RejectsPointsAndSizesItCannotPlace) {
  Points points = uniform_box(100, {1, 1, 1}, 11);
  points[42].x() = std::nanf("");
  try {
    slscan::core::detail::count_within(points, 0.1f, 5);
    FAIL() << "a NaN point was placed";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("point 42"), std::string::npos) << e.what();
  }
  points[42].x() = 0.5f;
  EXPECT_THROW(slscan::core::detail::count_within(points, 0.0f, 5), std::invalid_argument);
  EXPECT_THROW(slscan::core::detail::count_within(points, std::nanf(""), 5), std::invalid_argument);
  EXPECT_THROW(slscan::core::detail::NeighbourGrid(points, -1.0), std::invalid_argument);
}

}  // namespace
