// Calibration maths on synthetic correspondences: known camera, projector and turntable,
// corners projected with slproto::PinholeModel plus Gaussian pixel noise, then recovered.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

#include "slscan/core/calibration_solve.hpp"

namespace slscan::core {
namespace {

using slproto::PinholeModel;
using slproto::RigidTransform;
constexpr double kRad = std::numbers::pi / 180.0;

struct Truth {
  CheckerboardTarget target{10, 7, 20.0, 0.0};  // even x odd squares: corner order is unique
  PinholeModel camera{640, 512, 1100.0, 1100.6, 322.3, 258.1, {-0.08, 0.05, 0.0005, -0.0003, 0.0}};
  PinholeModel projector{1140, 912, 1400.0, 1400.0, 570.0, 880.0, {0.02, -0.01, 0.0, 0.0, 0.0}};
  RigidTransform cam_from_proj;
  RigidTransform cam_from_table;
  Truth() {
    cam_from_proj = RigidTransform::rotation_about_axis({0, 1, 0}, {0, 0, 0}, 14.0 * kRad);
    cam_from_proj.t = {-110.0, 4.0, 12.0};
    // Table seen from above at 35 degrees; its z axis (up) in the camera frame.
    const double tilt = 35.0 * kRad;
    const slproto::Vec3 up{0, -std::cos(tilt), -std::sin(tilt)};
    const slproto::Vec3 x{1, 0, 0};
    const slproto::Vec3 y{up[1] * x[2] - up[2] * x[1], up[2] * x[0] - up[0] * x[2], up[0] * x[1] - up[1] * x[0]};
    cam_from_table.R = {x[0], y[0], up[0], x[1], y[1], up[1], x[2], y[2], up[2]};
    cam_from_table.t = {6.0, 35.0, 430.0};
  }
};

RigidTransform random_pose(std::mt19937& rng) {
  std::uniform_real_distribution<double> tilt(-35, 35), spin(-20, 20), shift(-40, 40), depth(330, 470);
  RigidTransform r = RigidTransform::rotation_about_axis({1, 0, 0}, {0, 0, 0}, tilt(rng) * kRad) *
                     RigidTransform::rotation_about_axis({0, 1, 0}, {0, 0, 0}, tilt(rng) * kRad) *
                     RigidTransform::rotation_about_axis({0, 0, 1}, {0, 0, 0}, spin(rng) * kRad);
  // Put the board's centre at a point in front of the camera.
  const slproto::Vec3 c = r.rotate({80.0, 50.0, 0.0});
  r.t = {shift(rng) - c[0], shift(rng) * 0.8 - c[1], depth(rng) - c[2]};
  return r;
}

TargetView observe(const CheckerboardTarget& target, const PinholeModel& model,
                   const RigidTransform& device_from_target, double noise_px, std::mt19937& rng,
                   const std::string& name) {
  std::normal_distribution<double> noise(0.0, noise_px);
  TargetView view;
  view.name = name;
  for (int id = 0; id < target.corner_count(); ++id) {
    const Eigen::Vector3d x = target.corner(id);
    double u = 0, v = 0;
    if (!model.project(device_from_target.apply({x(0), x(1), x(2)}), u, v)) continue;
    if (u < 0 || v < 0 || u > model.width - 1 || v > model.height - 1) continue;
    view.corners.push_back({id, {u + noise(rng), v + noise(rng)}});
  }
  return view;
}

double angle_deg(const slproto::Vec3& a, const slproto::Vec3& b) {
  const double dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const double na = std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
  const double nb = std::sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]);
  return std::acos(std::clamp(dot / (na * nb), -1.0, 1.0)) / kRad;
}

double distance(const slproto::Vec3& a, const slproto::Vec3& b) {
  return std::sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]));
}

TEST(CalibrationSolve, CameraIntrinsicsFromTwelveNoisyPoses) {
  const Truth truth;
  std::mt19937 rng(7);
  std::vector<TargetView> views;
  for (int i = 0; i < 12; ++i)
    views.push_back(observe(truth.target, truth.camera, random_pose(rng), 0.05, rng, "pose " + std::to_string(i)));
  const DeviceCalibration cal = calibrate_camera(truth.target, views, 640, 512);
  EXPECT_NEAR(cal.model.fx / truth.camera.fx, 1.0, 1e-3);
  EXPECT_NEAR(cal.model.fy / truth.camera.fy, 1.0, 1e-3);
  EXPECT_NEAR(cal.model.cx, truth.camera.cx, 1.0);
  EXPECT_NEAR(cal.model.cy, truth.camera.cy, 1.0);
  EXPECT_NEAR(cal.model.distortion.k1, truth.camera.distortion.k1, 0.01);
  // Noise 0.05 px per coordinate: the residual RMS (2D) is about 0.05 * sqrt(2) less the
  // degrees of freedom fitted.
  EXPECT_LT(cal.rms_px, 0.1);
  EXPECT_GT(cal.rms_px, 0.03);
  ASSERT_EQ(cal.view_rms_px.size(), views.size());
  ASSERT_EQ(cal.from_target.size(), views.size());
}

TEST(CalibrationSolve, CameraRejectsTooFewViewsAndBadIds) {
  const Truth truth;
  std::mt19937 rng(3);
  std::vector<TargetView> views;
  for (int i = 0; i < 2; ++i) views.push_back(observe(truth.target, truth.camera, random_pose(rng), 0.05, rng, "p"));
  EXPECT_THROW(calibrate_camera(truth.target, views, 640, 512), std::invalid_argument);
  views.push_back(views[0]);
  views[2].corners[3].id = 999;
  views[2].name = "bad one";
  try {
    (void)calibrate_camera(truth.target, views, 640, 512);
    FAIL() << "no error for a corner id off the target";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("bad one"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("999"), std::string::npos) << e.what();
  }
}

TEST(CalibrationSolve, ProjectorIntrinsicsAndExtrinsicsFromNoisyCorners) {
  const Truth truth;
  std::mt19937 rng(11);
  std::vector<TargetView> cam_views, proj_views;
  const RigidTransform proj_from_cam = truth.cam_from_proj.inverse();
  // 0.02 px of noise on both devices: the extrinsic rotation trades off against both
  // principal points, and at 0.05 px its error over 12 poses is ~0.03 degrees (measured over
  // seeds), above the 0.02-degree target; the image path's corners are better than 0.05 px.
  for (int i = 0; i < 12; ++i) {
    const RigidTransform pose = random_pose(rng);
    cam_views.push_back(observe(truth.target, truth.camera, pose, 0.02, rng, "pose " + std::to_string(i)));
    proj_views.push_back(observe(truth.target, truth.projector, proj_from_cam * pose, 0.02, rng, "pose"));
  }
  const DeviceCalibration camera = calibrate_camera(truth.target, cam_views, 640, 512);
  const ProjectorSolve solve = calibrate_projector(truth.target, camera.model, cam_views, proj_views, 1140, 912);
  const auto& p = solve.calibration;
  EXPECT_NEAR(p.intrinsics.fx / truth.projector.fx, 1.0, 2e-3);
  EXPECT_NEAR(p.intrinsics.fy / truth.projector.fy, 1.0, 2e-3);
  EXPECT_NEAR(p.intrinsics.cx, truth.projector.cx, 2.0);
  EXPECT_NEAR(p.intrinsics.cy, truth.projector.cy, 2.0);
  EXPECT_LT(distance(p.cam_from_proj.t, truth.cam_from_proj.t), 0.2);
  EXPECT_LT(rotation_angle_between_deg(p.cam_from_proj, truth.cam_from_proj), 0.02);
  EXPECT_LT(p.reprojection_rms_px, 0.15);
  EXPECT_LT(solve.camera_rms_px, 0.1);
  ASSERT_EQ(solve.view_rms_px.size(), 12u);
}

// The whole-rig bundle: camera, two projectors and the poses, where only one view in two is
// seen by the second projector (the camera-view index mapping must be right). Started from
// perturbed values it must come back to the exact truth on noise-free corners, and stay within
// the targets with noise.
struct RigCase {
  std::vector<TargetView> camera_views;
  std::array<ProjectorObservations, 2> projectors;
  std::array<RigidTransform, 2> cam_from_proj;
};

RigCase rig_case(const Truth& truth, double camera_noise, double projector_noise, std::mt19937& rng) {
  RigCase out;
  out.cam_from_proj[0] = truth.cam_from_proj;
  out.cam_from_proj[1] = RigidTransform::rotation_about_axis({0, 1, 0}, {0, 0, 0}, -13.0 * kRad);
  out.cam_from_proj[1].t = {105.0, -3.0, 10.0};
  for (int i = 0; i < 12; ++i) {
    const RigidTransform pose = random_pose(rng);
    out.camera_views.push_back(
        observe(truth.target, truth.camera, pose, camera_noise, rng, "pose " + std::to_string(i)));
    for (std::size_t s = 0; s < 2; ++s) {
      if (s == 1 && i % 2 == 1) continue;
      out.projectors[s].views.push_back(observe(truth.target, truth.projector, out.cam_from_proj[s].inverse() * pose,
                                                projector_noise, rng, "pose " + std::to_string(i)));
      out.projectors[s].camera_view.push_back(static_cast<std::size_t>(i));
    }
  }
  return out;
}

TEST(CalibrationSolve, JointRefinementReturnsToTheTruthFromAPerturbedStart) {
  const Truth truth;
  std::mt19937 rng(5);
  RigCase c = rig_case(truth, 0.0, 0.0, rng);
  DeviceCalibration camera;
  camera.model = truth.camera;
  camera.model.fx *= 1.003;
  camera.model.cx += 2.0;
  camera.rms_px = 0.05;
  for (const TargetView& v : c.camera_views)
    camera.from_target.push_back(solve_target_pose(truth.target, camera.model, v));
  for (std::size_t s = 0; s < 2; ++s) {
    c.projectors[s].start.intrinsics = truth.projector;
    c.projectors[s].start.intrinsics.fy *= 0.997;
    c.projectors[s].start.cam_from_proj = c.cam_from_proj[s];
    c.projectors[s].start.cam_from_proj.t[0] += 0.5;
    c.projectors[s].start.reprojection_rms_px = 0.02;
  }
  const RigBundle bundle = refine_rig_jointly(truth.target, camera, c.camera_views, c.projectors, {}, {});
  EXPECT_NEAR(bundle.camera.model.fx, truth.camera.fx, 1e-3);
  EXPECT_NEAR(bundle.camera.model.cx, truth.camera.cx, 1e-3);
  EXPECT_LT(bundle.camera.rms_px, 1e-4);
  for (std::size_t s = 0; s < 2; ++s) {
    EXPECT_NEAR(bundle.projectors[s].intrinsics.fy, truth.projector.fy, 1e-3) << s;
    EXPECT_LT(distance(bundle.projectors[s].cam_from_proj.t, c.cam_from_proj[s].t), 1e-4) << s;
    EXPECT_LT(rotation_angle_between_deg(bundle.projectors[s].cam_from_proj, c.cam_from_proj[s]), 1e-5) << s;
    EXPECT_LT(bundle.projectors[s].reprojection_rms_px, 1e-4) << s;
    EXPECT_EQ(bundle.projector_view_rms_px[s].size(), c.projectors[s].views.size());
  }
  ASSERT_EQ(bundle.camera.from_target.size(), c.camera_views.size());
}

// Camera corners at 0.05 px, projector corners at 0.02 px (the image path's figures). Over seeds
// 13, 17, 29, 41 the joint fit took the camera's focal error from 0.0006-0.061 % to
// 0.0003-0.006 % and the projector translations from 0.02-0.22 mm to 0.005-0.11 mm; the
// extrinsic rotations stay 0.015-0.073 deg either way: relative to the true camera frame they
// are bounded by the camera's principal point (a 1-px cx error is a 0.05-deg turn of the whole
// rig at f = 1100 px, which moves nothing a scan measures).
TEST(CalibrationSolve, JointRefinementWithNoiseMeetsTheTargets) {
  const Truth truth;
  std::mt19937 rng(13);
  RigCase c = rig_case(truth, 0.05, 0.02, rng);
  const DeviceCalibration camera = calibrate_camera(truth.target, c.camera_views, 640, 512);
  for (std::size_t s = 0; s < 2; ++s) {
    std::vector<TargetView> cam;
    for (std::size_t i : c.projectors[s].camera_view) cam.push_back(c.camera_views[i]);
    c.projectors[s].start =
        calibrate_projector(truth.target, camera.model, cam, c.projectors[s].views, 1140, 912, {}, 6).calibration;
  }
  const RigBundle bundle = refine_rig_jointly(truth.target, camera, c.camera_views, c.projectors, {}, {});
  std::printf("camera cx separate %+.3f joint %+.3f, fx separate %+.4f%% joint %+.4f%%\n",
              camera.model.cx - truth.camera.cx, bundle.camera.model.cx - truth.camera.cx,
              100 * (camera.model.fx / truth.camera.fx - 1), 100 * (bundle.camera.model.fx / truth.camera.fx - 1));
  for (std::size_t s = 0; s < 2; ++s)
    std::printf("projector %zu: R separate %.4f joint %.4f deg, t separate %.4f joint %.4f mm\n", s,
                rotation_angle_between_deg(c.projectors[s].start.cam_from_proj, c.cam_from_proj[s]),
                rotation_angle_between_deg(bundle.projectors[s].cam_from_proj, c.cam_from_proj[s]),
                distance(c.projectors[s].start.cam_from_proj.t, c.cam_from_proj[s].t),
                distance(bundle.projectors[s].cam_from_proj.t, c.cam_from_proj[s].t));
  EXPECT_NEAR(bundle.camera.model.fx / truth.camera.fx, 1.0, 2e-4);
  EXPECT_NEAR(bundle.camera.model.fy / truth.camera.fy, 1.0, 2e-4);
  EXPECT_NEAR(bundle.camera.model.cx, truth.camera.cx, 1.0);
  EXPECT_NEAR(bundle.camera.model.cy, truth.camera.cy, 1.0);
  EXPECT_LT(bundle.camera.rms_px, 0.1);
  for (std::size_t s = 0; s < 2; ++s) {
    EXPECT_NEAR(bundle.projectors[s].intrinsics.fx / truth.projector.fx, 1.0, 1e-3) << s;
    EXPECT_LT(distance(bundle.projectors[s].cam_from_proj.t, c.cam_from_proj[s].t), 0.15) << s;
    EXPECT_LT(rotation_angle_between_deg(bundle.projectors[s].cam_from_proj, c.cam_from_proj[s]), 0.08) << s;
    EXPECT_LT(bundle.projectors[s].reprojection_rms_px, 0.05) << s;
  }
}

TEST(CalibrationSolve, JointRefinementRejectsAProjectorViewOfNoCameraView) {
  const Truth truth;
  std::mt19937 rng(2);
  RigCase c = rig_case(truth, 0.0, 0.0, rng);
  DeviceCalibration camera;
  camera.model = truth.camera;
  for (const TargetView& v : c.camera_views)
    camera.from_target.push_back(solve_target_pose(truth.target, camera.model, v));
  for (std::size_t s = 0; s < 2; ++s) {
    c.projectors[s].start.intrinsics = truth.projector;
    c.projectors[s].start.cam_from_proj = c.cam_from_proj[s];
  }
  c.projectors[1].camera_view.back() = 12;
  EXPECT_THROW(refine_rig_jointly(truth.target, camera, c.camera_views, c.projectors, {}, {}), std::invalid_argument);
}

struct TableCase {
  std::vector<TurntableView> views;
  std::vector<double> actual_deg;
};

TableCase table_views(const Truth& truth, const CheckerboardTarget& target, double noise, std::mt19937& rng,
                      const std::vector<int>& reversed_views = {}, double projector_noise = -1) {
  // Target lying face up on the platform, off centre and turned: its z axis points down.
  RigidTransform table_from_target = RigidTransform::rotation_about_axis({0, 0, 1}, {0, 0, 0}, 20 * kRad) *
                                     RigidTransform::rotation_about_axis({1, 0, 0}, {0, 0, 0}, std::numbers::pi);
  table_from_target.t = {-45.0, 10.0, target.thickness_mm};
  TableCase out;
  const std::vector<double> errors{0, 0.05, -0.04, 0.08, -0.02, 0.03};
  for (int i = 0; i < 6; ++i) {
    const double commanded = 60.0 * i, actual = commanded + errors[static_cast<std::size_t>(i)];
    const RigidTransform turn = RigidTransform::rotation_about_axis({0, 0, 1}, {0, 0, 0}, actual * kRad);
    TurntableView view;
    view.commanded_angle_deg = commanded;
    view.camera = observe(target, truth.camera, truth.cam_from_table * turn * table_from_target, noise, rng,
                          "table " + std::to_string(i));
    // The projector (truth.cam_from_proj) lights the board too: its corners, listed in the same
    // order as the camera's (a detector's reversal applies to both).
    if (projector_noise >= 0)
      view.projectors[0] = observe(target, truth.projector,
                                   truth.cam_from_proj.inverse() * truth.cam_from_table * turn * table_from_target,
                                   projector_noise, rng, "table " + std::to_string(i));
    for (int r : reversed_views)
      if (r == i) {
        for (CornerObservation& c : view.camera.corners) c.id = target.corner_count() - 1 - c.id;
        for (CornerObservation& c : view.projectors[0].corners) c.id = target.corner_count() - 1 - c.id;
      }
    out.views.push_back(view);
    out.actual_deg.push_back(actual);
  }
  return out;
}

void expect_table_matches(const Truth& truth, const TurntableSolve& solve, const TableCase& table) {
  const auto& cal = solve.calibration;
  const slproto::Vec3 true_axis{truth.cam_from_table.R[2], truth.cam_from_table.R[5], truth.cam_from_table.R[8]};
  EXPECT_LT(angle_deg(cal.axis_direction(), true_axis), 0.02);
  // Axis position: distance from the true platform centre to the fitted axis, and the true
  // centre's height above the fitted platform plane.
  const slproto::Vec3 d = cal.axis_direction();
  const slproto::Vec3 c = truth.cam_from_table.t, o = cal.axis_point();
  const slproto::Vec3 diff{c[0] - o[0], c[1] - o[1], c[2] - o[2]};
  const double along = diff[0] * d[0] + diff[1] * d[1] + diff[2] * d[2];
  const slproto::Vec3 across{diff[0] - along * d[0], diff[1] - along * d[1], diff[2] - along * d[2]};
  EXPECT_LT(std::sqrt(across[0] * across[0] + across[1] * across[1] + across[2] * across[2]), 0.1);
  EXPECT_LT(std::abs(along), 0.05);
  ASSERT_EQ(solve.measured_angle_deg.size(), table.actual_deg.size());
  for (std::size_t i = 1; i < table.actual_deg.size(); ++i) {
    EXPECT_NEAR(solve.measured_angle_deg[i], table.actual_deg[i] - table.actual_deg[0], 0.02) << "view " << i;
    EXPECT_NEAR(solve.step_deg[i], table.actual_deg[i] - table.actual_deg[i - 1], 0.02) << "view " << i;
  }
  EXPECT_LT(solve.rms_px, 0.1);
  EXPECT_LT(cal.pose_residual_mm, 0.05);
  EXPECT_LT(solve.target_tilt_deg, 0.1);
}

TEST(CalibrationSolve, TurntableAxisPlaneAndActualAngles) {
  const Truth truth;
  std::mt19937 rng(5);
  CheckerboardTarget target = truth.target;
  target.thickness_mm = 3.0;
  const TableCase table = table_views(truth, target, 0.05, rng);
  const TurntableSolve solve = calibrate_turntable(target, truth.camera, table.views, 150);
  expect_table_matches(truth, solve, table);
  for (bool flipped : solve.flipped) EXPECT_FALSE(flipped);
  EXPECT_EQ(solve.calibration.platform_radius_mm, 150);
}

TEST(CalibrationSolve, TurntableResolvesSymmetricBoardOrder) {
  const Truth truth;
  std::mt19937 rng(9);
  const CheckerboardTarget target{9, 7, 20.0, 0.0};
  ASSERT_TRUE(target.is_point_symmetric());
  const TableCase table = table_views(truth, target, 0.05, rng, {2, 3});
  const TurntableSolve solve = calibrate_turntable(target, truth.camera, table.views, 150);
  expect_table_matches(truth, solve, table);
  EXPECT_EQ(solve.flipped, (std::vector<bool>{false, false, true, true, false, false}));
}

// The platform plane from the camera alone is a PnP depth, which scales with the camera's focal
// length: a calibration 0.05 % off in focal puts it ~0.13 mm off here. A calibrated projector that
// lit the table poses pins their depth by triangulation. Views 2 and 3 are listed from the other
// end, so the projector's corners must be reversed with the camera's.
TEST(CalibrationSolve, TurntableProjectorCornersPinThePlane) {
  const Truth truth;
  std::mt19937 rng(21);
  const CheckerboardTarget target{9, 7, 20.0, 3.0};
  const TableCase table = table_views(truth, target, 0.05, rng, {2, 3}, 0.02);
  PinholeModel camera = truth.camera;
  camera.fx *= 1.0005;
  camera.fy *= 1.0005;
  const auto plane_error = [&](const TurntableSolve& solve) {
    const slproto::Vec3 d = solve.calibration.axis_direction();
    const slproto::Vec3 c = truth.cam_from_table.t, o = solve.calibration.axis_point();
    return (c[0] - o[0]) * d[0] + (c[1] - o[1]) * d[1] + (c[2] - o[2]) * d[2];
  };
  const TurntableSolve camera_only = calibrate_turntable(target, camera, table.views, 150);
  std::array<TurntableProjector, 2> projectors;
  projectors[0].use = true;
  projectors[0].calibration.intrinsics = truth.projector;
  projectors[0].calibration.cam_from_proj = truth.cam_from_proj;
  projectors[0].weight = 0.05 / 0.02;
  const TurntableSolve with_projector = calibrate_turntable(target, camera, table.views, 150, projectors);
  std::printf("plane error: camera only %+.4f mm, with the projector %+.4f mm\n", plane_error(camera_only),
              plane_error(with_projector));
  EXPECT_GT(std::abs(plane_error(camera_only)), 0.1);
  EXPECT_LT(std::abs(plane_error(with_projector)), 0.05);
  EXPECT_EQ(with_projector.flipped, (std::vector<bool>{false, false, true, true, false, false}));
  for (std::size_t i = 1; i < table.actual_deg.size(); ++i)
    EXPECT_NEAR(with_projector.step_deg[i], table.actual_deg[i] - table.actual_deg[i - 1], 0.02) << "view " << i;
}

TEST(CalibrationSolve, TurntableSlipShowsInStepAndResidualIsLarge) {
  const Truth truth;
  std::mt19937 rng(2);
  TableCase table = table_views(truth, truth.target, 0.05, rng);
  // A view from a pose that is not a rotation about the axis (its corners shifted by 5 px): its
  // residual stands out.
  for (CornerObservation& c : table.views[4].camera.corners) c.pixel += Eigen::Vector2d(5.0, 0.0);
  const TurntableSolve solve = calibrate_turntable(truth.target, truth.camera, table.views, 150);
  // The fit spreads some of the error over the others, but the bumped view stays the worst.
  for (std::size_t i = 0; i < 6; ++i)
    if (i != 4) {
      EXPECT_GT(solve.reprojection_rms_px[4], solve.reprojection_rms_px[i]) << "view " << i;
      EXPECT_GT(solve.pose_residual_mm[4], solve.pose_residual_mm[i]) << "view " << i;
    }
  EXPECT_GT(solve.rms_px, 1.0);
}

TEST(CalibrationSolve, TurntableNeedsRotation) {
  const Truth truth;
  std::mt19937 rng(4);
  TableCase table = table_views(truth, truth.target, 0.05, rng);
  for (auto& view : table.views) {
    view.camera = table.views[0].camera;
    view.commanded_angle_deg = 0;
  }
  EXPECT_THROW(calibrate_turntable(truth.target, truth.camera, table.views, 150), std::invalid_argument);
}

}  // namespace
}  // namespace slscan::core
