// Scene validation and the scene's exact calibration.
#include <cmath>
#include <string>

#include "slrig/rig.hpp"

namespace slrig {

namespace {

slproto::Error invalid(const std::string& message) {
  return slproto::make_error(slproto::Errc::invalid_argument, message);
}

bool finite_positive(double v) { return std::isfinite(v) && v > 0; }
bool finite_non_negative(double v) { return std::isfinite(v) && v >= 0; }

slproto::Status check_object(const SceneObject& o, const std::string& where) {
  if (auto s = o.table_from_object.check(where + ".pose"); !s) return s;
  if (!(o.albedo >= 0 && o.albedo <= 1)) return invalid(where + ".albedo must lie in [0, 1]");
  if (!finite_non_negative(o.specular)) return invalid(where + ".specular must be >= 0");
  if (!finite_positive(o.specular_power)) return invalid(where + ".specular_power must be > 0");
  switch (o.kind) {
    case ObjectKind::sphere:
      if (!finite_positive(o.radius)) return invalid(where + ".radius must be > 0");
      break;
    case ObjectKind::ballbar:
      if (!finite_positive(o.radius_a)) return invalid(where + ".radius_a must be > 0");
      if (!finite_positive(o.radius_b)) return invalid(where + ".radius_b must be > 0");
      if (!(o.centre_distance > o.radius_a + o.radius_b && std::isfinite(o.centre_distance)))
        return invalid(where + ".centre_distance must exceed the sum of the radii");
      if (!finite_non_negative(o.bar_radius) || o.bar_radius >= std::min(o.radius_a, o.radius_b))
        return invalid(where + ".bar_radius must be >= 0 and smaller than both sphere radii");
      if (!finite_non_negative(o.stand_radius) || o.stand_radius > o.bar_radius)
        return invalid(where + ".stand_radius must be >= 0 and not above bar_radius (the post ends inside the bar)");
      if (!finite_non_negative(o.stand_height)) return invalid(where + ".stand_height must be >= 0");
      break;
    case ObjectKind::plane:
      if (!finite_positive(o.width)) return invalid(where + ".width must be > 0");
      if (!finite_positive(o.height)) return invalid(where + ".height must be > 0");
      break;
    case ObjectKind::checkerboard:
      if (o.squares_x < 2 || o.squares_y < 2 || o.squares_x > 1000 || o.squares_y > 1000)
        return invalid(where + ".squares_x and squares_y must lie in [2, 1000]");
      if (!finite_positive(o.square_mm)) return invalid(where + ".square_mm must be > 0");
      if (!(o.width >= o.squares_x * o.square_mm) || !std::isfinite(o.width))
        return invalid(where + ".width must cover the squares (>= squares_x * square_mm)");
      if (!(o.height >= o.squares_y * o.square_mm) || !std::isfinite(o.height))
        return invalid(where + ".height must cover the squares (>= squares_y * square_mm)");
      if (!finite_positive(o.thickness)) return invalid(where + ".thickness must be > 0");
      if (!(o.dark_albedo >= 0 && o.dark_albedo <= 1)) return invalid(where + ".dark_albedo must lie in [0, 1]");
      break;
    case ObjectKind::blade:
      if (!finite_positive(o.width)) return invalid(where + ".width (span) must be > 0");
      if (!finite_positive(o.height)) return invalid(where + ".height (chord) must be > 0");
      if (!std::isfinite(o.twist_deg) || std::abs(o.twist_deg) > 180)
        return invalid(where + ".twist_deg must lie in [-180, 180]");
      break;
    case ObjectKind::teacup:
      if (!finite_positive(o.radius)) return invalid(where + ".radius must be > 0");
      if (!(o.height > 10) || !std::isfinite(o.height)) return invalid(where + ".height must be > 10 mm");
      if (!finite_positive(o.thickness) || o.thickness >= o.radius)
        return invalid(where + ".thickness must be > 0 and below the radius");
      break;
    case ObjectKind::mesh:
      if (o.mesh_path.empty()) return invalid(where + ".mesh_path is empty");
      if (!finite_positive(o.mesh_scale)) return invalid(where + ".mesh_scale must be > 0");
      break;
  }
  return slproto::Ok{};
}

}  // namespace

slproto::Status check_scene(const Scene& scene) {
  if (auto s = scene.camera.check("camera"); !s) return s;
  const SensorModel& sensor = scene.sensor;
  if (sensor.bit_depth != 8 && sensor.bit_depth != 10 && sensor.bit_depth != 12)
    return invalid("sensor.bit_depth must be 8, 10 or 12 (got " + std::to_string(sensor.bit_depth) + ")");
  if (!finite_positive(sensor.full_well_electrons)) return invalid("sensor.full_well_electrons must be > 0");
  if (!finite_non_negative(sensor.read_noise_dn)) return invalid("sensor.read_noise_dn must be >= 0");
  if (!finite_non_negative(sensor.dark_level_dn)) return invalid("sensor.dark_level_dn must be >= 0");
  if (!finite_positive(sensor.white_level_dn)) return invalid("sensor.white_level_dn must be > 0");
  if (!finite_positive(sensor.exposure_us)) return invalid("sensor.exposure_us must be > 0");
  if (!(sensor.blooming >= 0 && sensor.blooming <= 1))
    return invalid("sensor.blooming must lie in [0, 1] (the share of the charge above full well that spills)");
  if (auto s = scene.pattern_plan.check(); !s) return invalid("pattern_plan: " + s.error().message);
  for (std::size_t i = 0; i < 2; ++i) {
    const ProjectorModel& p = scene.projectors[i];
    const std::string where = std::string("projectors[") + std::to_string(i) + "]";
    if (auto s = p.intrinsics.check(where + ".intrinsics"); !s) return s;
    if (auto s = p.cam_from_proj.check(where + ".cam_from_proj"); !s) return s;
    if (!finite_positive(p.gamma)) return invalid(where + ".gamma must be > 0");
    if (!finite_non_negative(p.defocus_sigma_px) || p.defocus_sigma_px > 50)
      return invalid(where + ".defocus_sigma_px must lie in [0, 50]");
    if (!finite_non_negative(p.brightness)) return invalid(where + ".brightness must be >= 0");
    if (p.intrinsics.width != scene.pattern_plan.projector_width ||
        p.intrinsics.height != scene.pattern_plan.projector_height)
      return invalid(where + ".intrinsics: resolution " + std::to_string(p.intrinsics.width) + " x " +
                     std::to_string(p.intrinsics.height) + " differs from the pattern plan's " +
                     std::to_string(scene.pattern_plan.projector_width) + " x " +
                     std::to_string(scene.pattern_plan.projector_height));
  }
  const TurntableModel& tt = scene.turntable;
  if (auto s = tt.cam_from_table.check("turntable.cam_from_table"); !s) return s;
  if (!finite_positive(tt.platform_radius_mm)) return invalid("turntable.platform_radius_mm must be > 0");
  if (!(tt.albedo >= 0 && tt.albedo <= 1)) return invalid("turntable.albedo must lie in [0, 1]");
  if (!finite_non_negative(tt.angle_error_sigma_deg)) return invalid("turntable.angle_error_sigma_deg must be >= 0");
  if (!std::isfinite(tt.axis_wobble_deg) || std::abs(tt.axis_wobble_deg) > 10)
    return invalid("turntable.axis_wobble_deg must lie in [-10, 10]");
  if (!finite_non_negative(tt.settle_time_ms)) return invalid("turntable.settle_time_ms must be >= 0");
  if (!finite_non_negative(scene.ambient.level)) return invalid("ambient.level must be >= 0");
  if (!(scene.ambient.flicker_depth >= 0 && scene.ambient.flicker_depth <= 1))
    return invalid("ambient.flicker_depth must lie in [0, 1]");
  if (!(scene.ambient.mains_hz >= 10 && scene.ambient.mains_hz <= 1000))
    return invalid("ambient.mains_hz must lie in [10, 1000] (50 or 60 for mains)");
  if (!std::isfinite(scene.ambient.phase_deg)) return invalid("ambient.phase_deg is not a finite number");
  if (scene.interreflection_samples < 1 || scene.interreflection_samples > 4096)
    return invalid("interreflection_samples must lie in [1, 4096]");
  if (!finite_positive(scene.wall_distance_mm)) return invalid("wall_distance_mm must be > 0");
  if (!(scene.wall_albedo >= 0 && scene.wall_albedo <= 1)) return invalid("wall_albedo must lie in [0, 1]");
  for (std::size_t i = 0; i < scene.view_angles_deg.size(); ++i)
    if (!std::isfinite(scene.view_angles_deg[i]))
      return invalid("view_angles_deg[" + std::to_string(i) + "] is not a finite number");
  if (scene.objects.size() > 1000) return invalid("objects: more than 1000 objects");
  for (std::size_t i = 0; i < scene.objects.size(); ++i)
    if (auto s = check_object(scene.objects[i], "objects[" + std::to_string(i) + "]"); !s) return s;
  return slproto::Ok{};
}

slproto::RigCalibration ground_truth_calibration(const Scene& scene) {
  slproto::RigCalibration calibration;
  calibration.camera = scene.camera;
  calibration.camera_reprojection_rms_px = 0;
  for (std::size_t i = 0; i < 2; ++i) {
    calibration.projectors[i].intrinsics = scene.projectors[i].intrinsics;
    calibration.projectors[i].cam_from_proj = scene.projectors[i].cam_from_proj;
    calibration.projectors[i].reprojection_rms_px = 0;
  }
  calibration.turntable.cam_from_table = scene.turntable.cam_from_table;
  calibration.turntable.platform_radius_mm = scene.turntable.platform_radius_mm;
  calibration.turntable.pose_residual_mm = 0;
  calibration.pattern_plan = scene.pattern_plan;
  calibration.source = "virtual rig ground truth: " + (scene.name.empty() ? std::string("scene") : scene.name);
  calibration.created_by = "slrig";
  return calibration;
}

}  // namespace slrig
