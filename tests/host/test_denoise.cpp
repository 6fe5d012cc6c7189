// Turntable denoise (Formulas 10-14) against a tilted, offset turntable.
#include <gtest/gtest.h>

#include <numbers>

#include "slscan/core/turntable_denoise.hpp"

namespace {

using slscan::core::OrganizedCloud;
using slscan::core::PointCloud;
using slscan::core::TurntableDenoiseOptions;

// The camera looks down at the table at 27 degrees, 400 mm away (the paper's geometry).
slproto::TurntableCalibration tilted_table() {
  slproto::TurntableCalibration table;
  const double tilt = (90.0 + 27.0) * std::numbers::pi / 180.0;
  table.cam_from_table = slproto::RigidTransform::rotation_about_axis({1, 0, 0}, {0, 0, 0}, tilt);
  table.cam_from_table.t = {5, 60, 400};
  table.platform_radius_mm = 150;
  return table;
}

Eigen::Vector3f in_camera(const slproto::TurntableCalibration& table, double x, double y, double z) {
  const auto p = table.cam_from_table.apply({x, y, z});
  return Eigen::Vector3f(static_cast<float>(p[0]), static_cast<float>(p[1]), static_cast<float>(p[2]));
}

TEST(TurntableDenoise, KeepsTheObjectDropsPlatformBelowAndBeyond) {
  const auto table = tilted_table();
  // Table-frame points: (x, y, height) and whether each should survive.
  struct Case {
    double x, y, z;
    bool keep;
  };
  const std::vector<Case> cases = {
      {0, 0, 10, true},     {100, 50, 0.5, true},  {140, 0, 80, true},    // object
      {30, 20, 0.0, false}, {80, -40, 0.1, false}, {0, 0, -5, false},     // platform, under it
      {0, 160, 10, false},  {200, 0, 50, false},   {0, 400, -30, false},  // beyond the radius
  };
  PointCloud cloud;
  for (const auto& c : cases) cloud.points.push_back(in_camera(table, c.x, c.y, c.z));
  cloud.confidence.assign(cases.size(), 1.0f);
  const auto result = slscan::core::denoise_by_turntable(cloud, table);
  EXPECT_EQ(result.counts.input, cases.size());
  EXPECT_EQ(result.counts.kept, 3u);
  EXPECT_EQ(result.counts.below_min_height, 4u);
  EXPECT_EQ(result.counts.outside_radius, 2u);  // (0, 400, -30) is below too: counted there, first
  ASSERT_EQ(result.cloud.size(), 3u);
  EXPECT_EQ(result.cloud.confidence.size(), 3u);
  for (std::size_t i = 0, k = 0; i < cases.size(); ++i) {
    if (cases[i].keep) {
      EXPECT_TRUE(result.cloud.points[k++].isApprox(cloud.points[i]));
    }
  }

  // The organised form keeps the grid and clears the same points.
  OrganizedCloud grid;
  grid.resize(static_cast<int>(cases.size()), 1);
  for (std::size_t i = 0; i < cases.size(); ++i) {
    grid.points[i] = cloud.points[i];
    grid.valid[i] = 1;
    grid.quality[i] = 1;
  }
  const auto organised = slscan::core::denoise_by_turntable(grid, table);
  for (std::size_t i = 0; i < cases.size(); ++i) EXPECT_EQ(organised.cloud.valid[i] != 0, cases[i].keep) << i;
  EXPECT_EQ(organised.counts.kept, 3u);
}

TEST(TurntableDenoise, FormulasMatchThePaper) {
  const auto table = tilted_table();
  const auto g = slscan::core::TurntableGeometry::from(table);
  // dis1 = |a x + b y + c z + d| / sqrt(a^2 + b^2 + c^2) with (a, b, c) = n, d = -n . x0.
  const Eigen::Vector3d p = in_camera(table, 30, -40, 12).cast<double>();
  EXPECT_NEAR(g.height(p), 12, 1e-4);
  EXPECT_NEAR(g.distance_to_axis(p), 50, 1e-4);
}

TEST(TurntableDenoise, OptionsAreValidated) {
  const auto table = tilted_table();
  TurntableDenoiseOptions options;
  options.max_height_mm = 50;
  PointCloud cloud;
  cloud.points = {in_camera(table, 0, 0, 40), in_camera(table, 0, 0, 60)};
  const auto result = slscan::core::denoise_by_turntable(cloud, table, options);
  EXPECT_EQ(result.counts.kept, 1u);
  EXPECT_EQ(result.counts.above_max_height, 1u);
  options.radius_mm = 10;
  cloud.points = {in_camera(table, 9, 0, 40), in_camera(table, 11, 0, 40)};
  EXPECT_EQ(slscan::core::denoise_by_turntable(cloud, table, options).counts.outside_radius, 1u);
  TurntableDenoiseOptions bad;
  bad.max_height_mm = 0.1;  // below min_height_mm
  EXPECT_THROW(bad.check(), std::invalid_argument);
  bad = {};
  bad.radius_mm = -1;
  EXPECT_THROW(bad.check(), std::invalid_argument);
  auto broken = table;
  broken.cam_from_table.R[0] = 3;
  EXPECT_THROW((void)slscan::core::denoise_by_turntable(cloud, broken), std::invalid_argument);
}

}  // namespace
