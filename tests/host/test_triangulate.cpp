// Triangulation against an analytic plane, with Brown-Conrady distortion in both the camera
// and the projector: the decoded coordinate of each pixel is computed in double precision
// from the true intersection, and the triangulator must give the plane point back.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <memory>
#include <numbers>

#include "slscan/core/triangulate.hpp"

namespace {

using slproto::CodingAxis;
using slproto::PinholeModel;
using slproto::ProjectorCalibration;
using slproto::RigidTransform;
using slproto::Vec3;
using slscan::core::CameraRayTable;
using slscan::core::DecodedView;
using slscan::core::DecodeMask;
using slscan::core::ProjectorTriangulator;

PinholeModel distorted_camera() {
  PinholeModel camera;
  camera.width = 320;
  camera.height = 256;
  camera.fx = 520;
  camera.fy = 521;
  camera.cx = 161.3;
  camera.cy = 126.8;
  camera.distortion = {-0.18, 0.09, 8e-4, -6e-4, -0.02};
  return camera;
}

// Beside the camera (columns coding: horizontal baseline) or above/below it (rows coding needs
// a vertical baseline: along a horizontal one, rows barely change with depth).
ProjectorCalibration distorted_projector(double side, CodingAxis axis = CodingAxis::columns) {
  ProjectorCalibration projector;
  auto& p = projector.intrinsics;
  p.width = 1140;
  p.height = 912;
  p.fx = 1700;
  p.fy = 1702;
  p.cx = 570.2;
  p.cy = 820.0;  // DLPs project upwards: principal point near the bottom edge
  p.distortion = {0.07, -0.05, -4e-4, 7e-4, 0.01};
  // Left/right of the camera, converging on a point ~400 mm in front of it.
  const double angle = side * 14.0 * std::numbers::pi / 180.0;
  if (axis == CodingAxis::columns) {
    projector.cam_from_proj = RigidTransform::rotation_about_axis({0, 1, 0}, {0, 0, 0}, -angle);
    projector.cam_from_proj.t = {side * 100.0, 3.0, 2.0};
  } else {
    projector.cam_from_proj = RigidTransform::rotation_about_axis({1, 0, 0}, {0, 0, 0}, angle);
    projector.cam_from_proj.t = {4.0, side * 100.0, 2.0};
  }
  return projector;
}

struct Plane {
  Eigen::Vector3d normal;  // unit
  double offset;           // normal . x = offset
};

// Fills a DecodedView with the exact projector coordinate of where each pixel's ray meets the
// plane; returns the true points alongside.
DecodedView exact_decode(const PinholeModel& camera, const ProjectorCalibration& projector, const Plane& plane,
                         CodingAxis axis, std::vector<Eigen::Vector3d>& truth) {
  DecodedView view;
  view.width = camera.width;
  view.height = camera.height;
  view.axis = axis;
  const auto n = static_cast<std::size_t>(camera.width * camera.height);
  view.coordinate.assign(n, std::numeric_limits<float>::quiet_NaN());
  view.quality.assign(n, 0.0f);
  view.mask.assign(n, DecodeMask::out_of_range);
  truth.assign(n, Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN()));
  const RigidTransform proj_from_cam = projector.cam_from_proj.inverse();
  for (int v = 0; v < camera.height; ++v)
    for (int u = 0; u < camera.width; ++u) {
      double x, y;
      if (!camera.pixel_to_ray(u, v, x, y)) continue;
      const Eigen::Vector3d ray(x, y, 1);
      const double t = plane.offset / plane.normal.dot(ray);
      const Eigen::Vector3d point = t * ray;
      const Vec3 in_projector = proj_from_cam.apply({point.x(), point.y(), point.z()});
      double pu, pv;
      if (!projector.intrinsics.project(in_projector, pu, pv)) continue;
      if (pu < 0 || pu > 1139 || pv < 0 || pv > 911) continue;
      const auto i = static_cast<std::size_t>(v * camera.width + u);
      view.coordinate[i] = static_cast<float>(axis == CodingAxis::columns ? pu : pv);
      view.quality[i] = 50.0f;
      view.mask[i] = DecodeMask::valid;
      truth[i] = point;
    }
  return view;
}

TEST(CameraRayTable, InvertsTheDistortionExactly) {
  const PinholeModel camera = distorted_camera();
  const CameraRayTable rays = CameraRayTable::build(camera);
  ASSERT_EQ(rays.x.size(), static_cast<std::size_t>(camera.width * camera.height));
  double worst = 0;
  for (int v = 0; v < camera.height; v += 5)
    for (int u = 0; u < camera.width; u += 5) {
      const auto i = static_cast<std::size_t>(v * camera.width + u);
      double pu, pv;
      ASSERT_TRUE(camera.project({rays.x[i], rays.y[i], 1.0}, pu, pv));
      worst = std::max(worst, std::hypot(pu - u, pv - v));
    }
  EXPECT_LT(worst, 1e-4);  // float storage of the ray: ~1e-7 of ~0.4 times f ~ 500
}

class TriangulatePlane : public ::testing::TestWithParam<CodingAxis> {};

TEST_P(TriangulatePlane, RecoversTheAnalyticPlaneWithDistortionInBothDevices) {
  const CodingAxis axis = GetParam();
  const PinholeModel camera = distorted_camera();
  const auto rays = std::make_shared<const CameraRayTable>(CameraRayTable::build(camera));
  for (double side : {-1.0, 1.0}) {
    const ProjectorCalibration projector = distorted_projector(side, axis);
    const Plane plane{Eigen::Vector3d(0.3, -0.2, -1.0).normalized(), 0};
    Plane placed = plane;
    placed.offset = plane.normal.dot(Eigen::Vector3d(0, 0, 400));
    std::vector<Eigen::Vector3d> truth;
    const DecodedView decoded = exact_decode(camera, projector, placed, axis, truth);
    const ProjectorTriangulator triangulator(rays, projector, axis);
    const auto result = triangulator.triangulate(decoded);
    std::size_t expected = 0, compared = 0;
    double worst_mm = 0, worst_reprojection_px = 0;
    const RigidTransform proj_from_cam = projector.cam_from_proj.inverse();
    for (std::size_t i = 0; i < truth.size(); ++i) {
      if (decoded.mask[i] != DecodeMask::valid) {
        EXPECT_FALSE(result.cloud.valid[i]);
        continue;
      }
      ++expected;
      if (!result.cloud.valid[i]) continue;
      ++compared;
      const Eigen::Vector3d p = result.cloud.points[i].cast<double>();
      worst_mm = std::max(worst_mm, (p - truth[i]).norm());
      double pu, pv;
      ASSERT_TRUE(projector.intrinsics.project(proj_from_cam.apply({p.x(), p.y(), p.z()}), pu, pv));
      worst_reprojection_px =
          std::max(worst_reprojection_px, std::abs((axis == CodingAxis::columns ? pu : pv) - decoded.coordinate[i]));
      EXPECT_EQ(result.cloud.quality[i], 50.0f);
    }
    ASSERT_GT(expected, 20000u) << "the projector should light most of the plane";
    EXPECT_EQ(compared, expected) << "every decoded pixel must triangulate";
    EXPECT_EQ(result.counts.valid, expected);
    // Float rays and points at ~400 mm: ~0.1 um; the residual gate is 1e-3 projector px.
    EXPECT_LT(worst_mm, 1e-3) << "side " << side;
    EXPECT_LT(worst_reprojection_px, 1e-3) << "side " << side;
  }
}

INSTANTIATE_TEST_SUITE_P(BothAxes, TriangulatePlane, ::testing::Values(CodingAxis::columns, CodingAxis::rows));

TEST(Triangulate, IgnoringProjectorDistortionWouldBeWrong) {
  // The same scene with the projector's distortion dropped from the triangulator's model must
  // be measurably wrong: proof that the distortion is really being used.
  const PinholeModel camera = distorted_camera();
  const auto rays = std::make_shared<const CameraRayTable>(CameraRayTable::build(camera));
  const ProjectorCalibration projector = distorted_projector(1.0);
  ProjectorCalibration undistorted = projector;
  undistorted.intrinsics.distortion = {};
  Plane plane{Eigen::Vector3d(0, 0, -1), -400};
  std::vector<Eigen::Vector3d> truth;
  const DecodedView decoded = exact_decode(camera, projector, plane, CodingAxis::columns, truth);
  const auto right = ProjectorTriangulator(rays, projector, CodingAxis::columns).triangulate(decoded);
  const auto wrong = ProjectorTriangulator(rays, undistorted, CodingAxis::columns).triangulate(decoded);
  double worst_right = 0, worst_wrong = 0;
  for (std::size_t i = 0; i < truth.size(); ++i) {
    if (!right.cloud.valid[i] || !wrong.cloud.valid[i]) continue;
    worst_right = std::max(worst_right, (right.cloud.points[i].cast<double>() - truth[i]).norm());
    worst_wrong = std::max(worst_wrong, (wrong.cloud.points[i].cast<double>() - truth[i]).norm());
  }
  EXPECT_LT(worst_right, 2e-3);
  EXPECT_GT(worst_wrong, 0.5);
}

TEST(Triangulate, BulkPathAgreesWithSinglePixelsAndCountsEachReason) {
  // Rows of a plane view with some pixels made undecoded, some given a coordinate whose
  // surface meets the ray behind the camera, and a depth window that cuts the plane: every
  // pixel must come out as intersect() says, and the counts must add up per reason.
  const PinholeModel camera = distorted_camera();
  const auto rays = std::make_shared<const CameraRayTable>(CameraRayTable::build(camera));
  const ProjectorCalibration projector = distorted_projector(1.0);
  const Plane plane{Eigen::Vector3d(0.3, -0.2, -1.0).normalized(), 0};
  Plane placed = plane;
  placed.offset = plane.normal.dot(Eigen::Vector3d(0, 0, 400));
  std::vector<Eigen::Vector3d> truth;
  DecodedView decoded = exact_decode(camera, projector, placed, CodingAxis::columns, truth);
  const auto n = decoded.coordinate.size();
  std::size_t undecoded = 0;
  for (std::size_t i = 0; i < n; i += 7) {
    if (std::isnan(decoded.coordinate[i])) continue;
    decoded.coordinate[i] = std::numeric_limits<float>::quiet_NaN();
    ++undecoded;
  }
  for (std::size_t i = 3; i < n; i += 11) decoded.coordinate[i] = 1139.0f;  // behind the camera near the left
  slscan::core::TriangulateOptions options;
  options.min_depth_mm = 380;
  options.max_depth_mm = 420;
  const ProjectorTriangulator triangulator(rays, projector, CodingAxis::columns, options);
  const auto result = triangulator.triangulate(decoded);
  std::size_t agreeing = 0, valid = 0, not_decoded = 0;
  double worst_mm = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (std::isnan(decoded.coordinate[i])) ++not_decoded;
    Eigen::Vector3f point;
    const bool single = triangulator.intersect(rays->x[i], rays->y[i], decoded.coordinate[i], point);
    ASSERT_EQ(single, result.cloud.valid[i] != 0) << "pixel " << i;
    if (!single) {
      EXPECT_TRUE(std::isnan(result.cloud.points[i].z()));
      EXPECT_EQ(result.cloud.quality[i], 0.0f);
      continue;
    }
    ++valid;
    worst_mm = std::max(worst_mm, static_cast<double>((result.cloud.points[i] - point).norm()));
    if (result.cloud.points[i] == point) ++agreeing;
    EXPECT_EQ(result.cloud.quality[i], decoded.quality[i]);
  }
  const auto& c = result.counts;
  EXPECT_EQ(c.valid, valid);
  EXPECT_EQ(c.not_decoded, not_decoded);
  EXPECT_GT(undecoded, 1000u);
  EXPECT_GT(c.no_intersection, 500u) << "coordinate 1139 should meet some rays behind the camera";
  EXPECT_GT(c.outside_depth, 1000u) << "the depth window cuts the tilted plane";
  EXPECT_GT(valid, 10000u);
  EXPECT_EQ(c.valid + c.not_decoded + c.no_intersection + c.not_converged + c.outside_frustum + c.outside_depth, n);
  // A tile may take one Newton step more than a lone pixel (it stops when all its pixels
  // have): that changes nothing beyond float round-off.
  EXPECT_LT(worst_mm, 1e-4);
  EXPECT_GT(agreeing, valid * 9 / 10);
}

TEST(Triangulate, MasksWhatCannotBeMeasured) {
  const PinholeModel camera = distorted_camera();
  const auto rays = std::make_shared<const CameraRayTable>(CameraRayTable::build(camera));
  const ProjectorCalibration projector = distorted_projector(1.0);
  const ProjectorTriangulator triangulator(rays, projector, CodingAxis::columns);
  DecodedView view;
  view.width = camera.width;
  view.height = camera.height;
  view.axis = CodingAxis::columns;
  const auto n = static_cast<std::size_t>(camera.width * camera.height);
  view.coordinate.assign(n, std::numeric_limits<float>::quiet_NaN());
  view.quality.assign(n, 1.0f);
  view.mask.assign(n, DecodeMask::low_contrast);
  const auto result = triangulator.triangulate(view);
  EXPECT_EQ(result.counts.not_decoded, n);
  EXPECT_EQ(result.cloud.count_valid(), 0u);

  // A column whose plane meets this pixel's ray behind the camera.
  Eigen::Vector3f point;
  const auto centre = static_cast<std::size_t>(128 * camera.width + 160);
  EXPECT_FALSE(triangulator.intersect(rays->x[centre], rays->y[centre], 1139.0f, point));
  EXPECT_FALSE(triangulator.intersect(rays->x[centre], rays->y[centre], std::nanf(""), point));

  DecodedView wrong_axis = view;
  wrong_axis.axis = CodingAxis::rows;
  EXPECT_THROW((void)triangulator.triangulate(wrong_axis), std::invalid_argument);
  DecodedView wrong_size = view;
  wrong_size.width = 10;
  EXPECT_THROW((void)triangulator.triangulate(wrong_size), std::invalid_argument);
  slscan::core::TriangulateOptions bad;
  bad.max_depth_mm = 0;
  EXPECT_THROW(bad.check(), std::invalid_argument);
  EXPECT_THROW(ProjectorTriangulator(nullptr, projector, CodingAxis::columns), std::invalid_argument);
}

}  // namespace
