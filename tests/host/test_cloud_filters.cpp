// Cloud conversion and cleanup against brute-force references and injected outliers.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "slscan/core/cloud_filters.hpp"

namespace {

using slscan::core::PointCloud;

PointCloud noisy_sphere_with_outliers(std::size_t inliers, std::size_t outliers, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g(0, 1);
  PointCloud cloud;
  for (std::size_t i = 0; i < inliers; ++i) {
    Eigen::Vector3d d(g(rng), g(rng), g(rng));
    d.normalize();
    cloud.points.push_back((d * (20 + 0.005 * g(rng))).cast<float>());
  }
  std::uniform_real_distribution<double> box(-40, 40);
  while (cloud.size() < inliers + outliers) {
    const Eigen::Vector3d p(box(rng), box(rng), box(rng));
    // Truly off the surface: SOR's cut (mean + 2 std) is inflated by the outliers themselves
    // to ~4 mm here, as in PCL; stray points closer than that are a job for the radius filter.
    if (std::abs(p.norm() - 20) < 5) continue;
    cloud.points.push_back(p.cast<float>());
  }
  cloud.confidence.assign(cloud.size(), 1.0f);
  cloud.view_id.assign(cloud.size(), 3);
  return cloud;
}

TEST(ToPointCloud, KeepsValidSlotsConfidenceViewAndNormals) {
  slscan::core::OrganizedCloud org;
  org.resize(4, 3);
  for (int i = 0; i < 12; ++i) {
    if (i == 2 || i == 7) continue;
    org.points[static_cast<std::size_t>(i)] = Eigen::Vector3f(static_cast<float>(i), 0, 100);
    org.quality[static_cast<std::size_t>(i)] = 0.5f + static_cast<float>(i);
    org.valid[static_cast<std::size_t>(i)] = 1;
  }
  const PointCloud cloud = slscan::core::to_point_cloud(org, 4);
  ASSERT_EQ(cloud.size(), 10u);
  EXPECT_EQ(cloud.points[2].x(), 3.0f);
  EXPECT_EQ(cloud.confidence[2], 3.5f);
  EXPECT_TRUE(std::all_of(cloud.view_id.begin(), cloud.view_id.end(), [](auto v) { return v == 4; }));
  EXPECT_FALSE(cloud.has_normals());

  std::vector<Eigen::Vector3f> normals(12, Eigen::Vector3f(0, 0, -1));
  normals[5] = Eigen::Vector3f(NAN, NAN, NAN);
  const PointCloud with_normals = slscan::core::to_point_cloud(org, 1, &normals);
  EXPECT_EQ(with_normals.size(), 9u);
  EXPECT_EQ(with_normals.normals.size(), 9u);
  normals.pop_back();
  EXPECT_THROW(slscan::core::to_point_cloud(org, 1, &normals), std::invalid_argument);
}

TEST(TransformCloud, MovesPointsAndRotatesNormals) {
  PointCloud cloud;
  cloud.points = {{1, 0, 0}};
  cloud.normals = {{1, 0, 0}};
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(0, 0, 5);
  const PointCloud out = slscan::core::transform_cloud(cloud, T);
  EXPECT_LT((out.points[0] - Eigen::Vector3f(0, 1, 5)).norm(), 1e-6f);
  EXPECT_LT((out.normals[0] - Eigen::Vector3f(0, 1, 0)).norm(), 1e-6f);
}

TEST(StatisticalOutlierRemoval, RemovesInjectedOutliersKeepsSurface) {
  const std::size_t inliers = 20000, outliers = 400;
  const PointCloud cloud = noisy_sphere_with_outliers(inliers, outliers, 1);
  const auto result = slscan::core::statistical_outlier_removal(cloud, {20, 2.0});
  std::size_t kept_inliers = 0, kept_outliers = 0;
  for (auto i : result.kept_indices) (i < inliers ? kept_inliers : kept_outliers)++;
  EXPECT_EQ(kept_outliers, 0u);
  EXPECT_GE(kept_inliers, inliers * 995 / 1000);
  EXPECT_EQ(result.removed, cloud.size() - result.kept_indices.size());
  ASSERT_EQ(result.cloud.size(), result.kept_indices.size());
  EXPECT_EQ(result.cloud.confidence.size(), result.cloud.size());
  EXPECT_EQ(result.cloud.view_id[0], 3);
}

TEST(StatisticalOutlierRemoval, MatchesBruteForceDefinition) {
  const PointCloud cloud = noisy_sphere_with_outliers(600, 30, 2);
  const int k = 8;
  const double ratio = 1.0;
  std::vector<double> mean_d(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    std::vector<double> d;
    for (std::size_t j = 0; j < cloud.size(); ++j)
      if (j != i) d.push_back((cloud.points[i] - cloud.points[j]).cast<double>().norm());
    std::partial_sort(d.begin(), d.begin() + k, d.end());
    mean_d[i] = 0;
    for (int q = 0; q < k; ++q) mean_d[i] += d[static_cast<std::size_t>(q)] / k;
  }
  double mean = 0, sq = 0;
  for (double m : mean_d) mean += m / static_cast<double>(cloud.size());
  for (double m : mean_d) sq += (m - mean) * (m - mean);
  const double threshold = mean + ratio * std::sqrt(sq / static_cast<double>(cloud.size() - 1));
  std::vector<std::uint32_t> expected;
  for (std::size_t i = 0; i < cloud.size(); ++i)
    if (mean_d[i] <= threshold) expected.push_back(static_cast<std::uint32_t>(i));
  const auto result = slscan::core::statistical_outlier_removal(cloud, {k, ratio});
  EXPECT_NEAR(result.threshold, threshold, 1e-4);
  EXPECT_EQ(result.kept_indices, expected);
}

// A camera (f = 1000 px) looking at a tilted, gently curved surface 500 mm away, 0.01 mm noise
// along z, with outliers pushed 3 mm off it: the grid version finds the same threshold and the
// same points as the k-d tree version on the same points, since every pixel's 20 nearest lie
// well inside its 7 x 7 window on a surface that faces the camera.
TEST(StatisticalOutlierRemoval, OrganisedMatchesTheKdTreeOnASurfaceFacingTheCamera) {
  const int w = 160, h = 120;
  const double f = 1000;
  slscan::core::OrganizedCloud grid;
  grid.resize(w, h);
  std::mt19937_64 rng(5);
  std::normal_distribution<double> noise(0, 0.01);
  std::vector<std::size_t> outliers;
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const std::size_t i = static_cast<std::size_t>(v * w + u);
      const double x0 = (u - w / 2.0) / f, y0 = (v - h / 2.0) / f;
      double z = 500 + 40 * x0 + 1e3 * x0 * x0 + noise(rng);
      if ((u * 7 + v * 13) % 97 == 0) {
        z += 3;
        outliers.push_back(i);
      }
      grid.points[i] = Eigen::Vector3f(static_cast<float>(x0 * z), static_cast<float>(y0 * z), static_cast<float>(z));
      grid.quality[i] = 1;
      grid.valid[i] = (u + v) % 11 == 0 ? 0 : 1;  // a few holes, as a decoder leaves
    }
  const auto organised = slscan::core::statistical_outlier_removal(grid, f, {20, 2.0});
  const PointCloud flat = slscan::core::to_point_cloud(grid, 0);
  const auto reference = slscan::core::statistical_outlier_removal(flat, {20, 2.0});
  EXPECT_NEAR(organised.threshold, reference.threshold, 1e-3 * reference.threshold);
  std::size_t outliers_left = 0;
  for (std::size_t i : outliers) outliers_left += organised.cloud.valid[i] && grid.valid[i] ? 1 : 0;
  EXPECT_EQ(outliers_left, 0u);
  EXPECT_EQ(organised.removed, reference.removed);
  EXPECT_EQ(organised.cloud.count_valid(), grid.count_valid() - organised.removed);
  EXPECT_THROW(slscan::core::statistical_outlier_removal(grid, 0.0), std::invalid_argument);
}

TEST(RadiusOutlierRemoval, MatchesBruteForceDefinition) {
  const PointCloud cloud = noisy_sphere_with_outliers(800, 40, 3);
  const double radius = 2.0;
  const int min_neighbors = 3;
  std::vector<std::uint32_t> expected;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    int count = 0;
    for (std::size_t j = 0; j < cloud.size(); ++j)
      count += j != i && (cloud.points[i] - cloud.points[j]).squaredNorm() < static_cast<float>(radius * radius);
    if (count >= min_neighbors) expected.push_back(static_cast<std::uint32_t>(i));
  }
  const auto result = slscan::core::radius_outlier_removal(cloud, {radius, min_neighbors});
  EXPECT_EQ(result.kept_indices, expected);
  EXPECT_LT(expected.size(), cloud.size());  // the case is not trivial
}

TEST(VoxelDownsample, AveragesEachVoxel) {
  PointCloud cloud;
  // Two points per 1 mm voxel of a 10x10x10 block, at 0.25 and 0.75 of each voxel.
  for (int x = 0; x < 10; ++x)
    for (int y = 0; y < 10; ++y)
      for (int z = 0; z < 10; ++z)
        for (float f : {0.25f, 0.75f}) {
          cloud.points.emplace_back(static_cast<float>(x) + f, static_cast<float>(y) + f, static_cast<float>(z) + f);
          cloud.normals.push_back(Eigen::Vector3f(f, 1, 0).normalized());
          cloud.confidence.push_back(f);
          cloud.view_id.push_back(f > 0.5f ? 2 : 1);
        }
  const PointCloud out = slscan::core::voxel_downsample(cloud, 1.0);
  ASSERT_EQ(out.size(), 1000u);
  for (std::size_t i = 0; i < out.size(); ++i) {
    const Eigen::Vector3f frac = out.points[i] - out.points[i].array().floor().matrix();
    EXPECT_LT((frac - Eigen::Vector3f::Constant(0.5f)).norm(), 1e-5f);
    EXPECT_NEAR(out.confidence[i], 0.5f, 1e-6f);
    EXPECT_EQ(out.view_id[i], 2);  // the more confident point's view
    EXPECT_NEAR(out.normals[i].norm(), 1.0f, 1e-5f);
  }
  EXPECT_THROW(slscan::core::voxel_downsample(cloud, 0), std::invalid_argument);
}

TEST(Filters, RejectBadInput) {
  PointCloud cloud = noisy_sphere_with_outliers(100, 0, 4);
  EXPECT_THROW(slscan::core::statistical_outlier_removal(cloud, {0, 1.0}), std::invalid_argument);
  EXPECT_THROW(slscan::core::radius_outlier_removal(cloud, {-1.0, 2}), std::invalid_argument);
  cloud.points[5].y() = NAN;
  EXPECT_THROW(slscan::core::statistical_outlier_removal(cloud), std::invalid_argument);
  cloud.points[5].y() = 0;
  cloud.confidence.pop_back();
  EXPECT_THROW(slscan::core::voxel_downsample(cloud, 1.0), std::invalid_argument);
}

}  // namespace
