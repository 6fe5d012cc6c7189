// Best-view selection where turntable views overlap: a sphere seen by two cameras 60 deg apart
// about a vertical axis through its centre, rendered analytically per pixel.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <vector>

#include "slscan/core/view_overlap.hpp"

namespace {

constexpr int kSize = 300;
constexpr double kRadius = 15;
const Eigen::Vector3d kCentre(0, 0, 400);  // in view 0's camera frame, which is the table frame here

slproto::PinholeModel camera() {
  slproto::PinholeModel c;
  c.width = c.height = kSize;
  c.fx = c.fy = 4000;
  c.cx = c.cy = (kSize - 1) / 2.0;
  return c;
}

// View `angle_deg`: the camera turned about the vertical (y) axis through the sphere's centre.
Eigen::Isometry3d table_from_view(double angle_deg) {
  return Eigen::Translation3d(kCentre) *
         Eigen::AngleAxisd(angle_deg * std::numbers::pi / 180, Eigen::Vector3d::UnitY()) *
         Eigen::Translation3d(-kCentre);
}

struct View {
  slscan::core::SparseOrganizedCloud grid;
  slscan::core::PointCloud points;
};

// The sphere as the camera of `table_from_view` sees it; `depth_offset_mm` moves every point
// along its ray (a different surface in front of or behind the sphere).
View render(const Eigen::Isometry3d& table_from_this, double depth_offset_mm = 0) {
  View view;
  slscan::core::OrganizedCloud grid;
  grid.resize(kSize, kSize);
  const slproto::PinholeModel cam = camera();
  const Eigen::Vector3d centre = table_from_this.inverse() * kCentre;
  for (int v = 0; v < kSize; ++v)
    for (int u = 0; u < kSize; ++u) {
      double x = 0, y = 0;
      if (!cam.pixel_to_ray(u, v, x, y)) continue;
      const Eigen::Vector3d ray = Eigen::Vector3d(x, y, 1).normalized();
      const double b = ray.dot(centre), disc = b * b - (centre.squaredNorm() - kRadius * kRadius);
      if (disc <= 0) continue;
      const Eigen::Vector3d p = ray * (b - std::sqrt(disc));
      const std::size_t i = static_cast<std::size_t>(v) * kSize + static_cast<std::size_t>(u);
      grid.points[i] = (p + ray * depth_offset_mm).cast<float>();
      grid.valid[i] = 1;
      grid.quality[i] = 1;
      view.points.points.push_back(p.cast<float>());
      view.points.normals.push_back((p - centre).normalized().cast<float>());
      view.points.view_id.push_back(0);
      view.points.confidence.push_back(1);
    }
  view.grid = slscan::core::SparseOrganizedCloud::of(grid);
  return view;
}

double incidence_deg(const Eigen::Vector3f& p, const Eigen::Vector3f& n) {
  return std::acos(std::clamp(n.dot(-p.normalized()), -1.0f, 1.0f)) * 180 / std::numbers::pi;
}

TEST(ViewOverlap, SteepPointsGiveWayOnlyWhereAnotherViewSawTheSpotFaceOn) {
  const std::vector<Eigen::Isometry3d> poses{table_from_view(0), table_from_view(60)};
  const View a = render(poses[0]), b = render(poses[1]);
  const std::vector<slscan::core::PointCloud> points{a.points, b.points};
  const auto selection = slscan::core::select_best_views(points, {&a.grid, &b.grid}, poses, camera());
  ASSERT_EQ(selection.keep.size(), 2u);
  EXPECT_EQ(selection.counts.input, a.points.size() + b.points.size());
  EXPECT_GT(selection.counts.replaced, 0u);
  EXPECT_LT(selection.counts.replaced, selection.counts.steep);  // the far sides stay: no other view
  std::size_t replaced = 0, steep = 0;
  for (std::size_t v = 0; v < 2; ++v) {
    const auto& cloud = points[v];
    const Eigen::Isometry3f other_from_this = (poses[1 - v].inverse() * poses[v]).cast<float>();
    for (std::size_t k = 0; k < cloud.size(); ++k) {
      const double own = incidence_deg(cloud.points[k], cloud.normals[k]);
      const double other =
          incidence_deg(other_from_this * cloud.points[k], other_from_this.linear() * cloud.normals[k]);
      steep += own > 60;
      if (!selection.keep[v][k]) {
        ++replaced;
        ASSERT_GT(own, 60) << "a point seen within the limit was dropped";
        ASSERT_LE(other, 60.5) << "dropped for a view that saw it no better than the limit";
        ASSERT_LT(other, own);
      } else if (own > 62 && other < 58) {
        // Seen face on by the other view, within its image (the sphere fits in both): must go.
        FAIL() << "view " << v << " point " << k << " at " << own << " deg stayed though the other view saw it at "
               << other << " deg";
      }
    }
  }
  EXPECT_EQ(replaced, selection.counts.replaced);
  EXPECT_EQ(steep, selection.counts.steep);
}

TEST(ViewOverlap, AnotherSurfaceAtThatPixelIsNotTheSameSpot) {
  const std::vector<Eigen::Isometry3d> poses{table_from_view(0), table_from_view(60)};
  // View 1's grid holds a surface 0.5 mm in front of the sphere (an occluder): nothing of view
  // 0 may give way to it.
  const View a = render(poses[0]), b = render(poses[1], -0.5);
  const auto selection = slscan::core::select_best_views({a.points, b.points}, {&a.grid, &b.grid}, poses, camera());
  for (std::size_t k = 0; k < a.points.size(); ++k) ASSERT_TRUE(selection.keep[0][k]) << k;
}

TEST(ViewOverlap, MismatchedInputsAndBadOptionsAreRefused) {
  const std::vector<Eigen::Isometry3d> poses{table_from_view(0), table_from_view(60)};
  const View a = render(poses[0]), b = render(poses[1]);
  EXPECT_THROW(slscan::core::select_best_views({a.points, b.points}, {&a.grid}, poses, camera()),
               std::invalid_argument);
  slscan::core::PointCloud no_normals = a.points;
  no_normals.normals.clear();
  EXPECT_THROW(slscan::core::select_best_views({no_normals, b.points}, {&a.grid, &b.grid}, poses, camera()),
               std::invalid_argument);
  slscan::core::OverlapSelectionOptions options;
  options.max_incidence_deg = 0;
  EXPECT_THROW(slscan::core::select_best_views({a.points, b.points}, {&a.grid, &b.grid}, poses, camera(), options),
               std::invalid_argument);
}

}  // namespace

// Issue 17: a calibration with fx 1e20 (1e100, 1e308) projected points to pixel coordinates no
// long holds, and std::lround of them crashed reprocessing. Such projections have no neighbour
// in the grid: nothing is replaced, nothing is undefined (the test runs under UBSan/ASan in CI).
TEST(ViewOverlap, HugeOrNonFiniteProjectionsReplaceNothing) {
  const std::vector<Eigen::Isometry3d> poses{table_from_view(0), table_from_view(60)};
  const View a = render(poses[0]), b = render(poses[1]);
  const std::vector<slscan::core::PointCloud> points{a.points, b.points};
  for (const double fx : {1e20, 1e100, 1e308, std::numeric_limits<double>::infinity()}) {
    slproto::PinholeModel absurd = camera();
    absurd.fx = absurd.fy = fx;
    const auto selection = slscan::core::select_best_views(points, {&a.grid, &b.grid}, poses, absurd);
    ASSERT_EQ(selection.keep.size(), 2u) << fx;
    EXPECT_EQ(selection.counts.input, a.points.size() + b.points.size()) << fx;
    EXPECT_EQ(selection.counts.replaced, 0u) << fx;
  }
  slproto::PinholeModel shifted = camera();
  shifted.cx = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(slscan::core::select_best_views(points, {&a.grid, &b.grid}, poses, shifted).counts.replaced, 0u);
}
