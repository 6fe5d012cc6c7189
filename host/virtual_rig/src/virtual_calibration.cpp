#include "slscan/virtual_rig/virtual_calibration.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <opencv2/core.hpp>
#include <span>

#include "slrig/calibration_poses.hpp"
#include "slrig/rig.hpp"

namespace slscan::virtual_rig {
namespace {

using slproto::ProjectorSide;

cv::Mat render_frame(const slrig::ViewRenderer& renderer, ProjectorSide side, const slproto::PatternPlan& plan,
                     std::size_t index, int bit_depth) {
  cv::Mat image(renderer.height(), renderer.width(), bit_depth > 8 ? CV_16UC1 : CV_8UC1);
  renderer.render(side, plan, index, std::span<std::uint8_t>(image.data, renderer.frame_bytes()));
  return image;
}

}  // namespace

VirtualCalibrationCapture render_virtual_calibration_capture(const slrig::Scene& calibration_scene,
                                                             const std::string& source, double table_angle_sigma_deg,
                                                             const RenderProgress& progress) {
  slrig::Scene scene = calibration_scene;
  scene.turntable.angle_error_sigma_deg = table_angle_sigma_deg;
  const slrig::SceneObject& board = scene.objects.at(0);
  VirtualCalibrationCapture out;
  core::CalibrationCapture& capture = out.capture;
  capture.target = {board.squares_x, board.squares_y, board.square_mm, board.thickness};
  capture.pattern_plan = scene.pattern_plan;
  capture.bit_depth = scene.sensor.bit_depth;
  capture.platform_radius_mm = scene.turntable.platform_radius_mm;
  capture.source = source;
  const std::array<slproto::PatternPlan, 2> plans{capture.plan(slproto::CodingAxis::columns),
                                                  capture.plan(slproto::CodingAxis::rows)};
  const int depth = scene.sensor.bit_depth;
  std::vector<slrig::CalibrationPoseSpec> specs = slrig::calibration_poses(scene);
  for (slrig::CalibrationPoseSpec& spec : specs) {
    const int pose = static_cast<int>(capture.poses.size());
    if (progress) progress(capture.poses.size(), specs.size(), spec.name);
    capture.poses.push_back({spec.name, spec.on_turntable, spec.commanded_angle_deg});
    if (!spec.on_turntable) {
      out.cam_from_board.push_back(spec.cam_from_board);
      for (std::size_t a = 0; a < 2; ++a) {
        // The renderer codes the axis of its scene's plan: one renderer per axis, each its own
        // view index so the two axes' frames have independent noise (separate exposures).
        spec.scene.pattern_plan = plans[a].config();
        const slrig::ViewRenderer renderer(spec.scene, 0.0, spec.view_index + static_cast<int>(a));
        for (ProjectorSide side : {ProjectorSide::left, ProjectorSide::right})
          for (std::size_t i = 0; i < plans[a].size(); ++i)
            capture.frames.push_back({pose, core::CalibrationFrame::Kind::pattern, side, plans[a].config().axis, i,
                                      render_frame(renderer, side, plans[a], i, depth)});
      }
      continue;
    }
    spec.scene.pattern_plan = plans[0].config();
    const slrig::ViewRenderer renderer(spec.scene, spec.commanded_angle_deg, spec.view_index);
    const double actual_deg = renderer.ground_truth().actual_angle_deg;
    out.actual_table_deg.push_back(actual_deg);
    out.cam_from_board.push_back(renderer.ground_truth().cam_from_table * spec.table_from_board);
    // The camera image: both projectors' white (flood light).
    const std::size_t white = static_cast<std::size_t>(plans[0].index_of(slproto::PatternKind::white));
    cv::Mat both;
    cv::addWeighted(render_frame(renderer, ProjectorSide::left, plans[0], white, depth), 0.5,
                    render_frame(renderer, ProjectorSide::right, plans[0], white, depth), 0.5, 0.0, both);
    capture.frames.push_back(
        {pose, core::CalibrationFrame::Kind::camera, ProjectorSide::left, slproto::CodingAxis::columns, 0, both});
    // Both projectors' plans along both axes too, so the projectors pin each table pose's depth.
    // The table does not move between the axes: the rows' renderer is told the angle the table
    // actually reached (no new angle error) and gets its own noise seed (separate exposures).
    slrig::Scene rows_scene = spec.scene;
    rows_scene.pattern_plan = plans[1].config();
    rows_scene.turntable.angle_error_sigma_deg = 0;
    rows_scene.sensor.seed += 7919;
    const slrig::ViewRenderer rows_renderer(rows_scene, actual_deg, spec.view_index);
    for (std::size_t a = 0; a < 2; ++a) {
      const slrig::ViewRenderer& r = a == 0 ? renderer : rows_renderer;
      for (ProjectorSide side : {ProjectorSide::left, ProjectorSide::right})
        for (std::size_t i = 0; i < plans[a].size(); ++i)
          capture.frames.push_back({pose, core::CalibrationFrame::Kind::pattern, side, plans[a].config().axis, i,
                                    render_frame(r, side, plans[a], i, depth)});
    }
  }
  if (progress) progress(specs.size(), specs.size(), {});
  scene.objects.clear();
  out.truth = slrig::ground_truth_calibration(scene);
  return out;
}

CalibrationErrors calibration_errors(const core::RigCalibrationResult& result, const VirtualCalibrationCapture& truth) {
  CalibrationErrors e;
  static_cast<core::CalibrationDifference&>(e) = core::calibration_difference(result.calibration, truth.truth);
  const auto& steps = result.report.turntable;
  for (std::size_t i = 1; i < steps.size() && i < truth.actual_table_deg.size(); ++i)
    e.worst_step_error_deg =
        std::max(e.worst_step_error_deg,
                 std::abs(steps[i].step_deg - (truth.actual_table_deg[i] - truth.actual_table_deg[i - 1])));
  return e;
}

std::string CalibrationErrors::table() const {
  char buffer[128];
  std::snprintf(buffer, sizeof buffer, "turntable: worst step error %.4f deg\n", worst_step_error_deg);
  return core::CalibrationDifference::table() + buffer;
}

}  // namespace slscan::virtual_rig
