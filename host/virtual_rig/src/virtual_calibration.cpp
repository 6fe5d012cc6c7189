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
using slproto::Vec3;

cv::Mat render_frame(const slrig::ViewRenderer& renderer, ProjectorSide side, const slproto::PatternPlan& plan,
                     std::size_t index, int bit_depth) {
  cv::Mat image(renderer.height(), renderer.width(), bit_depth > 8 ? CV_16UC1 : CV_8UC1);
  renderer.render(side, plan, index, std::span<std::uint8_t>(image.data, renderer.frame_bytes()));
  return image;
}

double angle_deg(const Vec3& a, const Vec3& b) {
  const double dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const double norms = std::sqrt((a[0] * a[0] + a[1] * a[1] + a[2] * a[2]) * (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]));
  return std::acos(std::clamp(dot / norms, -1.0, 1.0)) * 180.0 / M_PI;
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
  const auto& cam = result.calibration.camera;
  const auto& true_cam = truth.truth.camera;
  e.camera_fx_pct = 100 * (cam.fx / true_cam.fx - 1);
  e.camera_fy_pct = 100 * (cam.fy / true_cam.fy - 1);
  e.camera_cx_px = cam.cx - true_cam.cx;
  e.camera_cy_px = cam.cy - true_cam.cy;
  e.camera_rms_px = result.calibration.camera_reprojection_rms_px;
  for (std::size_t s = 0; s < 2; ++s) {
    const auto& p = result.calibration.projectors[s];
    const auto& t = truth.truth.projectors[s];
    auto& out = e.projectors[s];
    out.fx_pct = 100 * (p.intrinsics.fx / t.intrinsics.fx - 1);
    out.fy_pct = 100 * (p.intrinsics.fy / t.intrinsics.fy - 1);
    out.cx_px = p.intrinsics.cx - t.intrinsics.cx;
    out.cy_px = p.intrinsics.cy - t.intrinsics.cy;
    const Vec3 dt{p.cam_from_proj.t[0] - t.cam_from_proj.t[0], p.cam_from_proj.t[1] - t.cam_from_proj.t[1],
                  p.cam_from_proj.t[2] - t.cam_from_proj.t[2]};
    out.translation_mm = std::sqrt(dt[0] * dt[0] + dt[1] * dt[1] + dt[2] * dt[2]);
    out.rotation_deg = core::rotation_angle_between_deg(p.cam_from_proj, t.cam_from_proj);
    out.rms_px = p.reprojection_rms_px;
  }
  const auto& table = result.calibration.turntable;
  const auto& true_table = truth.truth.turntable;
  e.axis_direction_deg = angle_deg(table.axis_direction(), true_table.axis_direction());
  const Vec3 d = table.axis_direction(), c = true_table.axis_point(), o = table.axis_point();
  const Vec3 diff{c[0] - o[0], c[1] - o[1], c[2] - o[2]};
  e.plane_mm = diff[0] * d[0] + diff[1] * d[1] + diff[2] * d[2];
  e.axis_position_mm =
      std::sqrt(std::max(0.0, diff[0] * diff[0] + diff[1] * diff[1] + diff[2] * diff[2] - e.plane_mm * e.plane_mm));
  const auto& steps = result.report.turntable;
  for (std::size_t i = 1; i < steps.size() && i < truth.actual_table_deg.size(); ++i)
    e.worst_step_error_deg =
        std::max(e.worst_step_error_deg,
                 std::abs(steps[i].step_deg - (truth.actual_table_deg[i] - truth.actual_table_deg[i - 1])));
  return e;
}

std::string CalibrationErrors::table() const {
  char buffer[1024];
  std::string out;
  std::snprintf(buffer, sizeof buffer, "camera: fx %+.4f %%, fy %+.4f %%, cx %+.3f px, cy %+.3f px, RMS %.4f px\n",
                camera_fx_pct, camera_fy_pct, camera_cx_px, camera_cy_px, camera_rms_px);
  out += buffer;
  for (std::size_t s = 0; s < 2; ++s) {
    const Projector& p = projectors[s];
    std::snprintf(buffer, sizeof buffer,
                  "projector %s: fx %+.4f %%, fy %+.4f %%, cx %+.3f px, cy %+.3f px, translation %.4f mm, "
                  "rotation %.4f deg, RMS %.4f px\n",
                  s == 0 ? "left" : "right", p.fx_pct, p.fy_pct, p.cx_px, p.cy_px, p.translation_mm, p.rotation_deg,
                  p.rms_px);
    out += buffer;
  }
  std::snprintf(buffer, sizeof buffer,
                "turntable: axis direction %.4f deg, axis position %.4f mm, plane %+.4f mm, worst step error %.4f "
                "deg\n",
                axis_direction_deg, axis_position_mm, plane_mm, worst_step_error_deg);
  out += buffer;
  return out;
}

}  // namespace slscan::virtual_rig
