#include "scene_build.hpp"

#include <cmath>
#include <numbers>

namespace slrig::detail {

namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kDeg = kPi / 180.0;

Primitive make_part(PrimitiveKind kind, std::uint8_t part, const SceneObject& object) {
  Primitive p;
  p.kind = kind;
  p.part_id = part;
  p.material.albedo = object.albedo;
  p.material.specular = object.specular;
  p.material.specular_power = object.specular_power;
  return p;
}

// A frame whose local z axis is `axis` (unit), origin `origin`.
Frame frame_with_z(V3 axis, V3 origin) {
  const V3 z = normalized(axis);
  const V3 helper = std::abs(z.x) < 0.9 ? V3{1, 0, 0} : V3{0, 1, 0};
  const V3 x = normalized(cross(helper, z));
  const V3 y = cross(z, x);
  Frame f;
  const double R[9] = {x.x, y.x, z.x, x.y, y.y, z.y, x.z, y.z, z.z};
  for (int i = 0; i < 9; ++i) f.R[i] = R[i];
  f.t = origin;
  return f;
}

void add_quad(std::vector<Triangle>& out, V3 a, V3 b, V3 c, V3 d) {
  out.push_back({a, b, c});
  out.push_back({a, c, d});
}

// NACA 4-digit camber line and thickness (closed trailing edge), x in [0, 1].
void naca_section(double x, double m, double p, double t, double& yu_x, double& yu, double& yl_x, double& yl) {
  const double yt =
      5 * t * (0.2969 * std::sqrt(x) - 0.1260 * x - 0.3516 * x * x + 0.2843 * x * x * x - 0.1036 * x * x * x * x);
  double yc, dyc;
  if (x < p) {
    yc = m / (p * p) * (2 * p * x - x * x);
    dyc = 2 * m / (p * p) * (p - x);
  } else {
    yc = m / ((1 - p) * (1 - p)) * ((1 - 2 * p) + 2 * p * x - x * x);
    dyc = 2 * m / ((1 - p) * (1 - p)) * (p - x);
  }
  const double th = std::atan(dyc);
  yu_x = x - yt * std::sin(th);
  yu = yc + yt * std::cos(th);
  yl_x = x + yt * std::sin(th);
  yl = yc - yt * std::cos(th);
}

}  // namespace

double normal_from_hash(std::uint64_t h) {
  const double u1 = (static_cast<double>(h >> 32) + 0.5) / 4294967296.0;
  const double u2 = (static_cast<double>(h & 0xFFFFFFFFull) + 0.5) / 4294967296.0;
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * kPi * u2);
}

std::vector<Triangle> blade_mesh(const SceneObject& object) {
  // A twisted, tapered, cambered blade (NACA 6512-like sections) standing on its root: span
  // `width` along z, root chord `height`, twist `twist_deg` from root to tip about the
  // mid-chord line, chord tapering to 75 % at the tip.
  const double span = object.width, root_chord = object.height;
  const int stations = 64, sections = 96;
  std::vector<double> xs(stations + 1);
  for (int i = 0; i <= stations; ++i) xs[static_cast<std::size_t>(i)] = 0.5 * (1 - std::cos(kPi * i / stations));
  auto section_point = [&](int section, int i, bool upper) {
    const double s = static_cast<double>(section) / sections;
    const double chord = root_chord * (1.0 - 0.25 * s);
    const double twist = object.twist_deg * kDeg * s;
    double ux, uy, lx, ly;
    naca_section(xs[static_cast<std::size_t>(i)], 0.06, 0.5, 0.12, ux, uy, lx, ly);
    const double px = ((upper ? ux : lx) - 0.5) * chord, py = (upper ? uy : ly) * chord;
    const double c = std::cos(twist), sn = std::sin(twist);
    return V3{c * px - sn * py, sn * px + c * py, s * span};
  };
  std::vector<Triangle> out;
  // Counter-clockwise seen from outside: the upper surface (y up), the lower surface, the root
  // cap (facing -z) and the tip cap (facing +z). The ray caster does not care (it turns every
  // normal to the viewer), but the truth's surface samples and the `--nominal` STL take their
  // normals from the winding: until 2026-12-05 the blade was wound inside out, so bench_mesh
  // counted 99.8 % of a good mesh's faces as flipped and bench_metrology's blade mean had the
  // wrong sign.
  for (int k = 0; k < sections; ++k) {
    for (int i = 0; i < stations; ++i) {
      add_quad(out, section_point(k, i, true), section_point(k + 1, i, true), section_point(k + 1, i + 1, true),
               section_point(k, i + 1, true));
      add_quad(out, section_point(k, i, false), section_point(k, i + 1, false), section_point(k + 1, i + 1, false),
               section_point(k + 1, i, false));
    }
  }
  for (int i = 0; i < stations; ++i) {
    add_quad(out, section_point(0, i, true), section_point(0, i + 1, true), section_point(0, i + 1, false),
             section_point(0, i, false));
    add_quad(out, section_point(sections, i, true), section_point(sections, i, false),
             section_point(sections, i + 1, false), section_point(sections, i + 1, true));
  }
  return out;
}

std::vector<Triangle> teacup_mesh(const SceneObject& object) {
  // Cup: outer radius `radius`, height `height`, wall `thickness`, bottom 6 mm, open top.
  const double R = object.radius, H = object.height, w = object.thickness, bottom = 6;
  const double r = R - w;
  const int n = 360;
  std::vector<Triangle> out;
  auto ring = [&](double rad, double z, int i) {
    const double a = 2 * kPi * i / n;
    return V3{rad * std::cos(a), rad * std::sin(a), z};
  };
  for (int i = 0; i < n; ++i) {
    add_quad(out, ring(R, 0, i), ring(R, 0, i + 1), ring(R, H, i + 1), ring(R, H, i));            // outer side
    add_quad(out, ring(R, H, i), ring(R, H, i + 1), ring(r, H, i + 1), ring(r, H, i));            // rim
    add_quad(out, ring(r, H, i), ring(r, H, i + 1), ring(r, bottom, i + 1), ring(r, bottom, i));  // inner side
    out.push_back({V3{0, 0, bottom}, ring(r, bottom, i + 1), ring(r, bottom, i)});                // inner bottom
    out.push_back({V3{0, 0, 0}, ring(R, 0, i), ring(R, 0, i + 1)});                               // base
  }
  return out;
}

namespace {

std::vector<Triangle> teacup_handle_mesh(const SceneObject& object) {
  // A C-shaped torus section in the x-z plane whose open ends are buried in the cup wall.
  const double R = object.radius, H = object.height;
  const double major = 0.3 * H, minor = 0.065 * H, zc = 0.5 * H;
  const double end = 95 * kDeg;
  const int nphi = 96, npsi = 48;
  auto point = [&](int i, int j) {
    const double phi = -end + 2 * end * i / nphi, psi = 2 * kPi * j / npsi;
    const V3 radial{std::cos(phi), 0, std::sin(phi)};
    const V3 centre{R + major * std::cos(phi), 0, zc + major * std::sin(phi)};
    return centre + minor * (std::cos(psi) * radial + std::sin(psi) * V3{0, 1, 0});
  };
  std::vector<Triangle> out;
  for (int i = 0; i < nphi; ++i)
    for (int j = 0; j < npsi; ++j) add_quad(out, point(i, j), point(i, j + 1), point(i + 1, j + 1), point(i + 1, j));
  return out;
}

}  // namespace

slproto::Result<std::vector<Primitive>> object_parts(const SceneObject& object) {
  std::vector<Primitive> parts;
  switch (object.kind) {
    case ObjectKind::sphere: {
      Primitive p = make_part(PrimitiveKind::sphere, 0, object);
      p.a = object.radius;
      parts.push_back(p);
      break;
    }
    case ObjectKind::ballbar: {
      const double h = object.centre_distance / 2;
      Primitive a = make_part(PrimitiveKind::sphere, 0, object);
      a.a = object.radius_a;
      a.cam_from_local.t = {-h, 0, 0};
      Primitive b = make_part(PrimitiveKind::sphere, 1, object);
      b.a = object.radius_b;
      b.cam_from_local.t = {h, 0, 0};
      parts.push_back(a);
      parts.push_back(b);
      if (object.bar_radius > 0) {
        Primitive bar = make_part(PrimitiveKind::cylinder, 2, object);
        bar.cam_from_local = frame_with_z({1, 0, 0}, {0, 0, 0});
        bar.a = object.bar_radius;
        bar.b = -h;
        bar.c = h;
        parts.push_back(bar);
      }
      if (object.stand_radius > 0 && object.stand_height > 0) {
        Primitive stand = make_part(PrimitiveKind::cylinder, 3, object);
        stand.a = object.stand_radius;
        stand.b = -object.stand_height;
        stand.c = 0;
        parts.push_back(stand);
      }
      break;
    }
    case ObjectKind::plane: {
      Primitive p = make_part(PrimitiveKind::rect, 0, object);
      p.a = object.width / 2;
      p.b = object.height / 2;
      parts.push_back(p);
      break;
    }
    case ObjectKind::checkerboard: {
      Primitive p = make_part(PrimitiveKind::box, 0, object);
      const double s = object.square_mm;
      const double mx = (object.squares_x - 2) * s / 2, my = (object.squares_y - 2) * s / 2;
      p.lo = {mx - object.width / 2, my - object.height / 2, 0};
      p.hi = {mx + object.width / 2, my + object.height / 2, object.thickness};
      p.material.checker = true;
      p.material.square = s;
      p.material.dark_albedo = object.dark_albedo;
      p.material.squares_x = object.squares_x;
      p.material.squares_y = object.squares_y;
      parts.push_back(p);
      break;
    }
    case ObjectKind::blade: {
      Primitive p = make_part(PrimitiveKind::mesh, 0, object);
      p.mesh = std::make_shared<const Mesh>(blade_mesh(object));
      parts.push_back(p);
      break;
    }
    case ObjectKind::teacup: {
      Primitive cup = make_part(PrimitiveKind::mesh, 0, object);
      cup.mesh = std::make_shared<const Mesh>(teacup_mesh(object));
      parts.push_back(cup);
      Primitive handle = make_part(PrimitiveKind::mesh, 1, object);
      handle.mesh = std::make_shared<const Mesh>(teacup_handle_mesh(object));
      parts.push_back(handle);
      break;
    }
    case ObjectKind::mesh: {
      auto triangles = load_mesh_file(object.mesh_path);
      if (!triangles) return std::move(triangles).error();
      if (object.mesh_scale != 1.0)
        for (Triangle& t : *triangles) {
          t.a = object.mesh_scale * t.a;
          t.b = object.mesh_scale * t.b;
          t.c = object.mesh_scale * t.c;
        }
      Primitive p = make_part(PrimitiveKind::mesh, 0, object);
      p.mesh = std::make_shared<const Mesh>(std::move(*triangles));
      parts.push_back(p);
      break;
    }
  }
  return parts;
}

// The teacup handle's hidden part lies inside the wall; sample_object_surfaces needs it.
std::vector<Triangle> teacup_handle_triangles(const SceneObject& object) { return teacup_handle_mesh(object); }

slproto::RigidTransform actual_cam_from_table(const Scene& scene, double commanded_angle_deg, int view_index,
                                              double& actual_angle_deg) {
  const TurntableModel& tt = scene.turntable;
  double error = 0;
  if (tt.angle_error_sigma_deg > 0)
    error = tt.angle_error_sigma_deg *
            normal_from_hash(mix64(scene.sensor.seed * 0x2545F4914F6CDD1Dull + 0x7AB1Eull +
                                   static_cast<std::uint64_t>(view_index) * 0x9E3779B97F4A7C15ull));
  actual_angle_deg = commanded_angle_deg + error;
  const auto spin = slproto::RigidTransform::rotation_about_axis({0, 0, 1}, {0, 0, 0}, actual_angle_deg * kDeg);
  // Wobble: the platform is tilted against the true axis by a fixed angle, so its normal
  // precesses as it turns (the tilt axis turns with the platform).
  const auto tilt = slproto::RigidTransform::rotation_about_axis({1, 0, 0}, {0, 0, 0}, tt.axis_wobble_deg * kDeg);
  return tt.cam_from_table * spin * tilt;
}

slproto::RigidTransform cam_from_object(const SceneObject& object, const slproto::RigidTransform& cam_from_table) {
  return object.on_turntable ? cam_from_table * object.table_from_object : object.table_from_object;
}

slproto::Result<PreparedObjects> prepare_objects(const Scene& scene) {
  PreparedObjects out;
  for (std::size_t i = 0; i < scene.objects.size(); ++i) {
    auto parts = object_parts(scene.objects[i]);
    if (!parts) {
      auto error = std::move(parts).error();
      error.message = "objects[" + std::to_string(i) + "] (" + scene.objects[i].name + "): " + error.message;
      return error;
    }
    out.parts.push_back(std::move(*parts));
  }
  return out;
}

World build_world(const Scene& scene, const PreparedObjects& prepared, const slproto::RigidTransform& cam_from_table) {
  World world;
  const Frame table(cam_from_table);
  {
    Primitive disk;
    disk.kind = PrimitiveKind::disk;
    disk.object_id = kTurntableId;
    disk.part_id = 0;
    disk.material.albedo = scene.turntable.albedo;
    disk.cam_from_local = table;
    disk.a = scene.turntable.platform_radius_mm;
    world.primitives.push_back(disk);
    Primitive rim = disk;
    rim.kind = PrimitiveKind::cylinder;
    rim.part_id = 1;
    rim.b = -15;
    rim.c = 0;
    world.primitives.push_back(rim);
  }
  if (scene.background_wall) {
    // A vertical wall (fixed, not turning) facing the camera, wall_distance_mm behind the axis.
    const auto& nominal = scene.turntable.cam_from_table;
    const V3 camera_in_table(nominal.inverse().t);
    V3 toward{camera_in_table.x, camera_in_table.y, 0};
    if (norm(toward) < 1e-9) toward = {0, -1, 0};
    toward = normalized(toward);
    const Frame table_from_wall = frame_with_z(toward, -scene.wall_distance_mm * toward);
    Primitive wall;
    wall.kind = PrimitiveKind::plane;
    wall.object_id = kWallId;
    wall.material.albedo = scene.wall_albedo;
    const Frame nominal_frame(nominal);
    wall.cam_from_local.t = nominal_frame.apply(table_from_wall.t);
    for (int c = 0; c < 3; ++c) {
      const V3 col{table_from_wall.R[c], table_from_wall.R[3 + c], table_from_wall.R[6 + c]};
      const V3 rc = nominal_frame.rotate(col);
      wall.cam_from_local.R[c] = rc.x;
      wall.cam_from_local.R[3 + c] = rc.y;
      wall.cam_from_local.R[6 + c] = rc.z;
    }
    world.primitives.push_back(wall);
  }
  for (std::size_t i = 0; i < scene.objects.size(); ++i) {
    const Frame object_frame(cam_from_object(scene.objects[i], cam_from_table));
    for (Primitive part : prepared.parts[i]) {
      part.object_id = static_cast<std::int16_t>(kFirstObjectId + static_cast<int>(i));
      Frame composed;
      composed.t = object_frame.apply(part.cam_from_local.t);
      for (int c = 0; c < 3; ++c) {
        const V3 col{part.cam_from_local.R[c], part.cam_from_local.R[3 + c], part.cam_from_local.R[6 + c]};
        const V3 rc = object_frame.rotate(col);
        composed.R[c] = rc.x;
        composed.R[3 + c] = rc.y;
        composed.R[6 + c] = rc.z;
      }
      part.cam_from_local = composed;
      world.primitives.push_back(part);
    }
  }
  for (Primitive& p : world.primitives) compute_bounds(p);
  return world;
}

}  // namespace slrig::detail
