// End to end with the ESTIMATED calibration (issue 5): the small virtual rig (640 x 512,
// default noise) is calibrated from a simulated calibration capture (the poses of
// tests/host/test_calibration_rig.cpp), then the ball-bar scene is reconstructed through
// ScanReconstructor (the scan's code path) once with that calibration and once with the rig's
// ground-truth calibration, and the ball bar is measured in both models.
// Run: build/<dir>/bench/rig/bench_calibrated_ballbar   (about a minute of CPU; small rig only:
// a full-resolution calibration capture is 800 frames of 5 Mpx)
#include <array>
#include <chrono>
#include <cstdio>
#include <exception>
#include <numbers>
#include <span>
#include <string>
#include <vector>

#include "slrig/rig.hpp"
#include "slscan/core/calibration_rig.hpp"
#include "slscan/core/measure.hpp"
#include "slscan/core/scan_reconstruction.hpp"

namespace {

using slproto::ProjectorSide;
using slproto::RigidTransform;
using slproto::Vec3;
using Clock = std::chrono::steady_clock;

RigidTransform rotation(const Vec3& axis, double deg) {
  return RigidTransform::rotation_about_axis(axis, {0, 0, 0}, deg * std::numbers::pi / 180.0);
}

cv::Mat render_frame(const slrig::ViewRenderer& renderer, ProjectorSide side, const slproto::PatternPlan& plan,
                     std::size_t index) {
  cv::Mat image(renderer.height(), renderer.width(), CV_8UC1);
  renderer.render(side, plan, index, std::span<std::uint8_t>(image.data, renderer.frame_bytes()));
  return image;
}

// Free poses in front of the rig and six turntable angles, as the calibration test.
slscan::core::CalibrationCapture calibration_capture(slrig::Scene scene) {
  using slscan::core::CalibrationFrame;
  scene.turntable.angle_error_sigma_deg = 0.05;
  const slrig::SceneObject board = scene.objects.at(0);
  scene.objects.clear();
  slscan::core::CalibrationCapture capture;
  capture.target = {board.squares_x, board.squares_y, board.square_mm, board.thickness};
  capture.pattern_plan = scene.pattern_plan;
  capture.platform_radius_mm = scene.turntable.platform_radius_mm;
  capture.source = "virtual rig, calibration preset (small), bench_calibrated_ballbar";
  const std::array<slproto::PatternPlan, 2> plans{capture.plan(slproto::CodingAxis::columns),
                                                  capture.plan(slproto::CodingAxis::rows)};
  const Vec3 middle{(board.squares_x - 2) * board.square_mm / 2, (board.squares_y - 2) * board.square_mm / 2, 0};
  const std::vector<std::array<double, 6>> free_poses{// tilt x, tilt y, spin, offset x, offset y, distance
                                                      {25, 0, 5, -20, -10, 440},     {-25, 0, -5, 15, -15, 460},
                                                      {0, 30, 10, 20, -5, 450},      {0, -30, -10, -15, -20, 470},
                                                      {20, 20, 0, 0, -10, 430},      {-20, -20, 15, 10, -5, 480},
                                                      {20, -25, -15, -25, -15, 460}, {-25, 20, 20, 25, -10, 445},
                                                      {10, 35, 0, 0, -20, 490},      {-35, -10, -20, 5, -5, 435}};
  for (std::size_t p = 0; p < free_poses.size(); ++p) {
    const auto& a = free_poses[p];
    RigidTransform cam_from_board = rotation({1, 0, 0}, a[0]) * rotation({0, 1, 0}, a[1]) * rotation({0, 0, 1}, a[2]);
    const Vec3 m = cam_from_board.rotate(middle);
    cam_from_board.t = {a[3] - m[0], a[4] - m[1], a[5] - m[2]};
    slrig::Scene view_scene = scene;
    slrig::SceneObject held = board;
    held.on_turntable = false;
    held.table_from_object = cam_from_board;
    view_scene.objects.push_back(held);
    const int pose = static_cast<int>(capture.poses.size());
    capture.poses.push_back({"free " + std::to_string(p), false, 0});
    for (std::size_t axis = 0; axis < 2; ++axis) {
      view_scene.pattern_plan = plans[axis].config();
      const slrig::ViewRenderer renderer(view_scene, 0.0, static_cast<int>(2 * p + axis));
      for (ProjectorSide side : {ProjectorSide::left, ProjectorSide::right})
        for (std::size_t i = 0; i < plans[axis].size(); ++i)
          capture.frames.push_back({pose, CalibrationFrame::Kind::pattern, side, plans[axis].config().axis, i,
                                    render_frame(renderer, side, plans[axis], i)});
    }
  }
  RigidTransform table_from_board = rotation({0, 0, 1}, 15) * rotation({1, 0, 0}, 180);
  const Vec3 m = table_from_board.rotate(middle);
  table_from_board.t = {25 - m[0], -10 - m[1], board.thickness - m[2]};
  slrig::Scene table_scene = scene;
  slrig::SceneObject lying = board;
  lying.table_from_object = table_from_board;
  table_scene.objects.push_back(lying);
  for (int k = 0; k < 6; ++k) {
    const double angle = 60.0 * k;
    const slrig::ViewRenderer renderer(table_scene, angle, 100 + k);
    const int pose = static_cast<int>(capture.poses.size());
    capture.poses.push_back({"table " + std::to_string(static_cast<int>(angle)), true, angle});
    cv::Mat both;
    cv::addWeighted(render_frame(renderer, ProjectorSide::left, plans[0], 0), 0.5,
                    render_frame(renderer, ProjectorSide::right, plans[0], 0), 0.5, 0.0, both);
    capture.frames.push_back(
        {pose, CalibrationFrame::Kind::camera, ProjectorSide::left, slproto::CodingAxis::columns, 0, both});
  }
  return capture;
}

slscan::core::BallBarResult scan_ball_bar(const slrig::Scene& scene, const slproto::RigCalibration& calibration) {
  const slproto::PatternPlan plan(calibration.pattern_plan);
  slscan::core::ReconstructionOptions options;
  options.decode.bit_depth = scene.sensor.bit_depth;
  options.build_mesh = false;
  const int width = scene.camera.width, height = scene.camera.height;
  slscan::core::ScanReconstructor reconstructor(calibration, plan, width, height, options);
  std::vector<std::uint8_t> frame;
  for (std::size_t view = 0; view < scene.view_angles_deg.size(); ++view) {
    const double angle = scene.view_angles_deg[view];
    const slrig::ViewRenderer renderer(scene, angle, static_cast<int>(view));
    frame.resize(renderer.frame_bytes());
    for (int side = 0; side < 2; ++side)
      for (std::size_t p = 0; p < plan.size(); ++p) {
        renderer.render(static_cast<ProjectorSide>(side), p, frame);
        slscan::core::FrameInfo info;
        info.view_index = static_cast<int>(view);
        info.commanded_angle_deg = info.reported_angle_deg = angle;
        info.projector = side;
        info.pattern_index = p;
        info.stride_bytes = static_cast<std::size_t>(width);
        reconstructor.add_frame(info, std::as_bytes(std::span(frame)));
      }
  }
  const slscan::core::ScanResult result = reconstructor.finish();
  if (!result.registered) std::printf("  (fine registration not applied: %s)\n", result.registration_error.c_str());
  const slrig::SceneObject& bar = scene.objects.at(0);
  slscan::core::BallBarOptions bar_options;
  bar_options.nominal_radii_mm = {bar.radius_a, bar.radius_b};
  return slscan::core::measure_ball_bar(result.model, bar_options);
}

}  // namespace

int main() try {
  const auto t0 = Clock::now();
  const slrig::Scene calibration_scene = slrig::scene_preset("calibration", slrig::RigSize::small).value();
  const auto calibrated = slscan::core::calibrate_rig(calibration_capture(calibration_scene));
  std::printf("%s", calibrated.report.summary().c_str());
  const auto t1 = Clock::now();

  const slrig::Scene scene = slrig::scene_preset("ballbar", slrig::RigSize::small).value();
  const slrig::SceneObject& bar = scene.objects.at(0);
  struct Run {
    const char* name;
    slproto::RigCalibration calibration;
  };
  slproto::RigCalibration estimated = calibrated.calibration;
  // The calibration target's pattern plan is the scan's (the same rig); make that explicit.
  estimated.pattern_plan = scene.pattern_plan;
  for (const Run& run : {Run{"ground-truth calibration", slrig::ground_truth_calibration(scene)},
                         Run{"estimated calibration", estimated}}) {
    const slscan::core::BallBarResult m = scan_ball_bar(scene, run.calibration);
    std::printf("%-26s centre distance %.4f mm (error %+.1f um), radii error %+.1f / %+.1f um\n", run.name,
                m.centre_distance_mm, 1e3 * (m.centre_distance_mm - bar.centre_distance),
                1e3 * (m.spheres[0].radius_mm - bar.radius_a), 1e3 * (m.spheres[1].radius_mm - bar.radius_b));
  }
  std::printf("calibration %.1f s, two scans %.1f s (wall)\n", std::chrono::duration<double>(t1 - t0).count(),
              std::chrono::duration<double>(Clock::now() - t1).count());
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "bench_calibrated_ballbar: %s\n", e.what());
  return 1;
}
