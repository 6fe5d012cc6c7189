// The default rig (docs/virtual-rig.md, "Default geometry") and the scene presets.
#include <cmath>
#include <numbers>

#include "scene_build.hpp"
#include "slrig/rig.hpp"

namespace slrig {

namespace {

using detail::cross;
using detail::normalized;
using detail::V3;

constexpr double kDeg = std::numbers::pi / 180.0;

// Default rig geometry.
constexpr double kTiltDeg = 27;             // camera optical axis below the table plane
constexpr double kWorkingDistanceMm = 560;  // camera centre to the aim point
constexpr double kAimHeightMm = 40;         // aim point above the platform centre
constexpr double kBaselineMm = 180;         // each projector beside the camera, along camera x
constexpr double kFocalMm = 12, kPixelUm = 3.45;

slproto::RigidTransform transform_from_axes(V3 x, V3 y, V3 z, V3 t) {
  slproto::RigidTransform T;
  T.R = {x.x, y.x, z.x, x.y, y.y, z.y, x.z, y.z, z.z};
  T.t = t.arr();
  return T;
}

// table_from_device for a device at `position` looking at `target`, its x axis as close to
// `right` as the view direction allows (OpenCV frame: y = z x x points down the image).
slproto::RigidTransform look_at(V3 position, V3 target, V3 right) {
  const V3 z = normalized(target - position);
  const V3 y = normalized(cross(z, right));
  const V3 x = cross(y, z);
  return transform_from_axes(x, y, z, position);
}

slproto::RigidTransform rotation_z(double deg, V3 t) {
  const double c = std::cos(deg * kDeg), s = std::sin(deg * kDeg);
  return transform_from_axes({c, s, 0}, {-s, c, 0}, {0, 0, 1}, t);
}

slproto::RigidTransform rotation_x(double deg) {
  const double c = std::cos(deg * kDeg), s = std::sin(deg * kDeg);
  return transform_from_axes({1, 0, 0}, {0, c, s}, {0, -s, c}, {0, 0, 0});
}

Scene default_rig(RigSize size) {
  Scene scene;
  // Camera: HS510GC-like 2464 x 2056, 3.45 um pixels, 12 mm lens.
  slproto::PinholeModel cam;
  cam.width = 2464;
  cam.height = 2056;
  cam.fx = cam.fy = kFocalMm / (kPixelUm * 1e-3);
  cam.cx = 1231.5 + 4.2;
  cam.cy = 1027.5 - 3.1;
  cam.distortion = {-0.08, 0.012, 2e-4, -1.5e-4, 0};
  if (size == RigSize::small) {
    // 640 x 512 with the same horizontal field of view (square pixels, 13.3 um equivalent).
    const double s = 640.0 / 2464.0;
    slproto::PinholeModel small = cam;
    small.width = 640;
    small.height = 512;
    small.fx = small.fy = cam.fx * s;
    small.cx = 319.5 + (cam.cx - 1231.5) * s;
    small.cy = 255.5 + (cam.cy - 1027.5) * s;
    cam = small;
  }
  scene.camera = cam;

  const double tilt = kTiltDeg * kDeg;
  const V3 aim{0, 0, kAimHeightMm};
  const V3 camera_position = aim + kWorkingDistanceMm * V3{0, -std::cos(tilt), std::sin(tilt)};
  const auto table_from_cam = look_at(camera_position, aim, {1, 0, 0});
  const auto cam_from_table = table_from_cam.inverse();
  scene.turntable.cam_from_table = cam_from_table;

  // Projectors: DLP4500-like 1140 x 912, beside the camera, converging on the aim point.
  const V3 camera_right{table_from_cam.R[0], table_from_cam.R[3], table_from_cam.R[6]};
  for (int side = 0; side < 2; ++side) {
    ProjectorModel& p = scene.projectors[static_cast<std::size_t>(side)];
    p.intrinsics.width = 1140;
    p.intrinsics.height = 912;
    p.intrinsics.fx = p.intrinsics.fy = 1500;
    p.intrinsics.cx = 569.5 + (side == 0 ? 2.5 : -1.8);
    p.intrinsics.cy = 455.5 + (side == 0 ? -3.0 : 2.2);
    p.intrinsics.distortion = side == 0 ? slproto::LensDistortion{0.02, -0.005, 1e-4, 0, 0}
                                        : slproto::LensDistortion{0.018, -0.004, 0, -1e-4, 0};
    const double offset = side == 0 ? -kBaselineMm : kBaselineMm;
    const auto table_from_proj = look_at(camera_position + offset * camera_right, aim, camera_right);
    p.cam_from_proj = cam_from_table * table_from_proj;
  }
  scene.pattern_plan = slproto::PatternPlanConfig{};
  return scene;
}

SceneObject ballbar_object() {
  SceneObject o;
  o.kind = ObjectKind::ballbar;
  o.name = "ballbar";
  o.albedo = 0.8;
  o.stand_height = 80;
  o.table_from_object = rotation_z(20, {0, 0, o.stand_height});
  return o;
}

}  // namespace

const char* material_name(Material material) noexcept {
  switch (material) {
    case Material::matte:
      return "matte";
    case Material::glazed:
      return "glazed";
    case Material::polished_metal:
      return "polished_metal";
    case Material::brushed_metal:
      return "brushed_metal";
    case Material::dark_plastic:
      return "dark_plastic";
  }
  return "matte";
}

slproto::Result<Material> parse_material(std::string_view name) {
  for (Material m :
       {Material::matte, Material::glazed, Material::polished_metal, Material::brushed_metal, Material::dark_plastic})
    if (name == material_name(m)) return m;
  return slproto::make_error(slproto::Errc::invalid_argument,
                             "unknown material '" + std::string(name) +
                                 "' (known: matte, glazed, polished_metal, brushed_metal, dark_plastic)");
}

void apply_material(SceneObject& object, Material material) {
  // Albedo is the diffuse part; specular the Blinn-Phong lobe's peak against a white matte
  // surface facing the projector; the exponent its width (half the peak at
  // acos(0.5^(1/power)) between the normal and the half vector: 9 deg at 60, 4.8 deg at 200,
  // 19 deg at 12).
  switch (material) {
    case Material::matte:
      object.albedo = 0.8;
      object.specular = 0;
      object.specular_power = 50;
      break;
    case Material::glazed:  // the teacup's glaze
      object.albedo = 0.85;
      object.specular = 0.5;
      object.specular_power = 60;
      break;
    case Material::polished_metal:
      // Mostly mirror: a strong, narrow lobe that clips anything within ~10 deg of the mirror
      // angle, and a weak diffuse part (surface roughness) that the structured light decodes
      // elsewhere.
      object.albedo = 0.25;
      object.specular = 30;
      object.specular_power = 200;
      break;
    case Material::brushed_metal:
      // The grooves spread the reflection into a broad lobe (still ten times a white matte
      // surface at its peak, clipping within ~35 deg of the mirror angle), more diffuse.
      object.albedo = 0.35;
      object.specular = 10;
      object.specular_power = 12;
      break;
    case Material::dark_plastic:
      // Black ABS-like: albedo ~0.05 drowns in the read noise at the reference exposure; a
      // dielectric's faint, broad highlight.
      object.albedo = 0.05;
      object.specular = 0.04;
      object.specular_power = 30;
      break;
  }
}

std::vector<Vec3> checkerboard_corners(const SceneObject& board) {
  std::vector<Vec3> corners;
  for (int j = 0; j + 1 < board.squares_y; ++j)
    for (int i = 0; i + 1 < board.squares_x; ++i) corners.push_back({i * board.square_mm, j * board.square_mm, 0});
  return corners;
}

slproto::Result<Scene> scene_preset(std::string_view name, RigSize size) {
  Scene scene = default_rig(size);
  scene.name = std::string(name) + (size == RigSize::small ? "-small" : "");
  if (name == "ballbar") {
    scene.objects.push_back(ballbar_object());
  } else if (name == "plane") {
    // A 140 x 100 mm matte plate standing on the table, leaning back 20 deg, facing the camera.
    SceneObject o;
    o.kind = ObjectKind::plane;
    o.name = "plate";
    o.width = 140;
    o.height = 100;
    o.albedo = 0.8;
    const double lean = 20 * kDeg;
    const V3 z{0, -std::cos(lean), std::sin(lean)};
    const V3 x{1, 0, 0};
    const V3 y = cross(z, x);
    o.table_from_object = transform_from_axes(x, y, z, {0, 50 * std::sin(lean), 50 * std::cos(lean) + 1});
    scene.objects.push_back(o);
  } else if (name == "sphere") {
    SceneObject o;
    o.kind = ObjectKind::sphere;
    o.name = "sphere";
    o.radius = 25;
    o.albedo = 0.8;
    o.table_from_object.t = {40, 0, 25};
    scene.objects.push_back(o);
  } else if (name == "blade") {
    SceneObject o;
    o.kind = ObjectKind::blade;
    o.name = "blade";
    o.width = 120;  // span
    o.height = 60;  // root chord
    o.twist_deg = 35;
    o.albedo = 0.7;
    o.table_from_object = rotation_z(30, {0, 0, 0});
    scene.objects.push_back(o);
  } else if (name == "shiny_blade") {
    // The blade in brushed metal, leaning 35 deg, its concave side to the camera at angle 0 (as a blade sits
    // in a scanning fixture, its root 4 mm above the platform), so its highlights face the
    // camera in most views: at the reference exposure ~40 % of what a projector lights clips.
    SceneObject o;
    o.kind = ObjectKind::blade;
    o.name = "shiny blade";
    o.width = 120;
    o.height = 60;
    o.twist_deg = 35;
    apply_material(o, Material::brushed_metal);
    o.table_from_object = rotation_z(150, {0, 0, 4}) * rotation_x(35);
    scene.objects.push_back(o);
  } else if (name == "dark_blade") {
    // The blade preset's shape and pose in dark plastic.
    SceneObject o;
    o.kind = ObjectKind::blade;
    o.name = "dark blade";
    o.width = 120;
    o.height = 60;
    o.twist_deg = 35;
    apply_material(o, Material::dark_plastic);
    o.table_from_object = rotation_z(30, {0, 0, 0});
    scene.objects.push_back(o);
  } else if (name == "teacup") {
    SceneObject o;
    o.kind = ObjectKind::teacup;
    o.name = "teacup";
    o.radius = 40;
    o.height = 70;
    o.thickness = 3;
    o.albedo = 0.85;
    o.specular = 0.5;  // glazed: highlights overexpose, as the paper warns
    o.specular_power = 60;
    o.table_from_object = rotation_z(-30, {10, 10, 0});
    scene.objects.push_back(o);
  } else if (name == "calibration") {
    // A 9 x 7 checkerboard of 15 mm squares on a 160 x 130 mm plate, leaning back on the table
    // so its normal points 35 deg above the horizon toward the camera; the views turn it
    // through +-45 deg (turntable axis calibration needs several angles).
    SceneObject o;
    o.kind = ObjectKind::checkerboard;
    o.name = "checkerboard";
    o.squares_x = 9;
    o.squares_y = 7;
    o.square_mm = 15;
    o.width = 160;
    o.height = 130;
    o.thickness = 3;
    o.albedo = 0.8;
    o.dark_albedo = 0.05;
    const double beta = 35 * kDeg;
    const V3 x{1, 0, 0};
    const V3 z{0, std::cos(beta), -std::sin(beta)};  // into the board
    const V3 y = cross(z, x);
    const V3 centre{0, 0, o.height / 2 * std::cos(beta) + 1};
    const V3 squares_centre{(o.squares_x - 2) * o.square_mm / 2, (o.squares_y - 2) * o.square_mm / 2, 0};
    const auto R = transform_from_axes(x, y, z, {0, 0, 0});
    const V3 offset(R.rotate(squares_centre.arr()));
    o.table_from_object = transform_from_axes(x, y, z, centre - offset);
    scene.objects.push_back(o);
    scene.view_angles_deg = {-45, -30, -15, 0, 15, 30, 45};
  } else {
    return slproto::make_error(
        slproto::Errc::invalid_argument,
        "unknown scene preset '" + std::string(name) +
            "' (known: ballbar, plane, sphere, blade, teacup, calibration, shiny_blade, dark_blade)");
  }
  return scene;
}

}  // namespace slrig
