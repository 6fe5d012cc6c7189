#include "slscan/core/calibration_compare.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "slscan/core/calibration_solve.hpp"

namespace slscan::core {
namespace {

using slproto::Vec3;

double angle_deg(const Vec3& a, const Vec3& b) {
  const double dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const double norms = std::sqrt((a[0] * a[0] + a[1] * a[1] + a[2] * a[2]) * (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]));
  return std::acos(std::clamp(dot / norms, -1.0, 1.0)) * 180.0 / M_PI;
}

}  // namespace

CalibrationDifference calibration_difference(const slproto::RigCalibration& estimated,
                                             const slproto::RigCalibration& reference) {
  CalibrationDifference e;
  const auto& cam = estimated.camera;
  const auto& ref_cam = reference.camera;
  e.camera_fx_pct = 100 * (cam.fx / ref_cam.fx - 1);
  e.camera_fy_pct = 100 * (cam.fy / ref_cam.fy - 1);
  e.camera_cx_px = cam.cx - ref_cam.cx;
  e.camera_cy_px = cam.cy - ref_cam.cy;
  e.camera_rms_px = estimated.camera_reprojection_rms_px;
  for (std::size_t s = 0; s < 2; ++s) {
    const auto& p = estimated.projectors[s];
    const auto& t = reference.projectors[s];
    auto& out = e.projectors[s];
    out.fx_pct = 100 * (p.intrinsics.fx / t.intrinsics.fx - 1);
    out.fy_pct = 100 * (p.intrinsics.fy / t.intrinsics.fy - 1);
    out.cx_px = p.intrinsics.cx - t.intrinsics.cx;
    out.cy_px = p.intrinsics.cy - t.intrinsics.cy;
    const Vec3 dt{p.cam_from_proj.t[0] - t.cam_from_proj.t[0], p.cam_from_proj.t[1] - t.cam_from_proj.t[1],
                  p.cam_from_proj.t[2] - t.cam_from_proj.t[2]};
    out.translation_mm = std::sqrt(dt[0] * dt[0] + dt[1] * dt[1] + dt[2] * dt[2]);
    out.rotation_deg = rotation_angle_between_deg(p.cam_from_proj, t.cam_from_proj);
    out.rms_px = p.reprojection_rms_px;
  }
  const auto& table = estimated.turntable;
  const auto& ref_table = reference.turntable;
  e.axis_direction_deg = angle_deg(table.axis_direction(), ref_table.axis_direction());
  const Vec3 d = table.axis_direction(), c = ref_table.axis_point(), o = table.axis_point();
  const Vec3 diff{c[0] - o[0], c[1] - o[1], c[2] - o[2]};
  e.plane_mm = diff[0] * d[0] + diff[1] * d[1] + diff[2] * d[2];
  e.axis_position_mm =
      std::sqrt(std::max(0.0, diff[0] * diff[0] + diff[1] * diff[1] + diff[2] * diff[2] - e.plane_mm * e.plane_mm));
  return e;
}

std::string CalibrationDifference::table() const {
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
  std::snprintf(buffer, sizeof buffer, "turntable: axis direction %.4f deg, axis position %.4f mm, plane %+.4f mm\n",
                axis_direction_deg, axis_position_mm, plane_mm);
  out += buffer;
  return out;
}

}  // namespace slscan::core
