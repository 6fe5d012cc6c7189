// End to end with the ESTIMATED calibration (issue 5): the virtual rig (default noise) is
// calibrated from a simulated calibration capture (slrig::calibration_poses, the poses of
// tests/host/test_calibration_rig.cpp), the calibration is compared with the rig's truth, then
// the ball-bar scene is reconstructed through ScanReconstructor (the scan's code path) once with
// that calibration and once with the rig's ground-truth calibration, and the bar is measured in
// both models.
// Run: build/<dir>/bench/rig/bench_calibrated_ballbar [--size small|full]
//   small (640 x 512, default): about a minute of CPU. full (2464 x 2056): the calibration
//   capture is 766 frames of 5 Mpx (3.9 GB in memory), several minutes.
#include <array>
#include <chrono>
#include <cstdio>
#include <exception>
#include <numbers>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "slrig/rig.hpp"
#include "slscan/core/calibration_rig.hpp"
#include "slscan/core/measure.hpp"
#include "slscan/core/scan_reconstruction.hpp"
#include "slscan/virtual_rig/virtual_calibration.hpp"

namespace {

using slproto::ProjectorSide;
using Clock = std::chrono::steady_clock;

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

int main(int argc, char** argv) try {
  slrig::RigSize size = slrig::RigSize::small;
  for (int i = 1; i < argc; ++i) {
    const std::string_view arg = argv[i];
    if (arg == "--size" && i + 1 < argc && std::string_view(argv[i + 1]) == "full") {
      size = slrig::RigSize::full;
      ++i;
    } else if (arg == "--size" && i + 1 < argc && std::string_view(argv[i + 1]) == "small") {
      ++i;
    } else {
      std::fprintf(stderr, "usage: bench_calibrated_ballbar [--size small|full]\n");
      return 2;
    }
  }
  const char* size_name = size == slrig::RigSize::full ? "full" : "small";
  const auto t0 = Clock::now();
  const slrig::Scene calibration_scene = slrig::scene_preset("calibration", size).value();
  const auto capture = slscan::virtual_rig::render_virtual_calibration_capture(
      calibration_scene, std::string("virtual rig, calibration preset (") + size_name + "), bench_calibrated_ballbar");
  const auto t_render = Clock::now();
  const auto calibrated = slscan::core::calibrate_rig(capture.capture);
  std::printf("%s", calibrated.report.summary().c_str());
  std::printf("\nagainst the rig's truth (%s rig):\n%s\n", size_name,
              slscan::virtual_rig::calibration_errors(calibrated, capture).table().c_str());
  const auto t1 = Clock::now();
  {
    // The same capture without the final joint refinement (separate solves only), for comparison.
    slscan::core::CalibrationOptions separate;
    separate.joint_refinement = false;
    const auto without = slscan::core::calibrate_rig(capture.capture, separate);
    std::printf("without the joint refinement (separate solves):\n%s\n",
                slscan::virtual_rig::calibration_errors(without, capture).table().c_str());
  }
  std::printf("render %.1f s, calibrate %.1f s (wall)\n", std::chrono::duration<double>(t_render - t0).count(),
              std::chrono::duration<double>(t1 - t_render).count());

  const slrig::Scene scene = slrig::scene_preset("ballbar", size).value();
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
