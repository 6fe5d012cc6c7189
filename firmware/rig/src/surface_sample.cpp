// Dense samples of the objects' true surfaces in the turntable frame (for point-to-surface
// error). Parts hidden inside other parts of the same object (the ball bar's rod inside its
// spheres, the teacup handle's ends inside the wall) are left out: no scan can see them.
#include <cmath>
#include <numbers>

#include "scene_build.hpp"

namespace slrig {

namespace {

using detail::Frame;
using detail::Primitive;
using detail::PrimitiveKind;
using detail::V3;

constexpr double kPi = std::numbers::pi;

// True if the object-frame point lies strictly inside the solid of a sphere or cylinder part.
bool inside_solid(const Primitive& part, V3 p) {
  const V3 q = part.cam_from_local.apply_inv(p);
  const double margin = 1e-6;
  if (part.kind == PrimitiveKind::sphere) return detail::dot(q, q) < (part.a - margin) * (part.a - margin);
  if (part.kind == PrimitiveKind::cylinder)
    return q.x * q.x + q.y * q.y < (part.a - margin) * (part.a - margin) && q.z > part.b + margin &&
           q.z < part.c - margin;
  return false;
}

struct Sampler {
  double spacing;
  std::vector<std::pair<V3, V3>> out;  // local point, local normal
  void add(V3 p, V3 n) { out.emplace_back(p, n); }

  void sphere(double r) {
    const auto n = static_cast<int>(std::ceil(4 * kPi * r * r / (spacing * spacing)));
    const double golden = kPi * (3 - std::sqrt(5.0));
    for (int i = 0; i < n; ++i) {
      const double z = 1 - 2 * (i + 0.5) / n, rho = std::sqrt(1 - z * z), phi = golden * i;
      const V3 d{rho * std::cos(phi), rho * std::sin(phi), z};
      add(r * d, d);
    }
  }
  void cylinder(double r, double z0, double z1) {
    const int around = std::max(8, static_cast<int>(std::ceil(2 * kPi * r / spacing)));
    const int along = std::max(2, static_cast<int>(std::ceil((z1 - z0) / spacing)) + 1);
    for (int j = 0; j < along; ++j)
      for (int i = 0; i < around; ++i) {
        const double a = 2 * kPi * i / around, z = z0 + (z1 - z0) * j / (along - 1);
        const V3 d{std::cos(a), std::sin(a), 0};
        add({r * d.x, r * d.y, z}, d);
      }
  }
  // Grid over a rectangle: origin + s u + t v, s in [0, 1], t in [0, 1].
  void rect(V3 origin, V3 u, V3 v, V3 normal) {
    const int nu = std::max(2, static_cast<int>(std::ceil(detail::norm(u) / spacing)) + 1);
    const int nv = std::max(2, static_cast<int>(std::ceil(detail::norm(v) / spacing)) + 1);
    for (int j = 0; j < nv; ++j)
      for (int i = 0; i < nu; ++i)
        add(origin + (static_cast<double>(i) / (nu - 1)) * u + (static_cast<double>(j) / (nv - 1)) * v, normal);
  }
  void box(V3 lo, V3 hi) {
    const V3 d = hi - lo;
    rect(lo, {d.x, 0, 0}, {0, d.y, 0}, {0, 0, -1});
    rect({lo.x, lo.y, hi.z}, {d.x, 0, 0}, {0, d.y, 0}, {0, 0, 1});
    rect(lo, {d.x, 0, 0}, {0, 0, d.z}, {0, -1, 0});
    rect({lo.x, hi.y, lo.z}, {d.x, 0, 0}, {0, 0, d.z}, {0, 1, 0});
    rect(lo, {0, d.y, 0}, {0, 0, d.z}, {-1, 0, 0});
    rect({hi.x, lo.y, lo.z}, {0, d.y, 0}, {0, 0, d.z}, {1, 0, 0});
  }
  void mesh(const detail::Mesh& m, std::uint64_t seed) {
    const auto& tris = m.triangles();
    for (std::size_t t = 0; t < tris.size(); ++t) {
      const V3 e1 = tris[t].b - tris[t].a, e2 = tris[t].c - tris[t].a;
      const V3 cr = detail::cross(e1, e2);
      const double area = 0.5 * detail::norm(cr);
      if (area <= 0) continue;
      const V3 n = detail::normalized(cr);
      const double expected = area / (spacing * spacing);
      std::uint64_t h = detail::mix64(seed + t * 0x9E3779B97F4A7C15ull);
      // Stochastic rounding keeps the density right for triangles smaller than a sample.
      const double u0 = static_cast<double>(h >> 11) / 9007199254740992.0;
      const auto count = static_cast<int>(std::floor(expected + u0));
      for (int k = 0; k < count; ++k) {
        h = detail::mix64(h);
        double a = static_cast<double>(h >> 40) / 16777216.0, b = static_cast<double>(h & 0xFFFFFF) / 16777216.0;
        if (a + b > 1) {
          a = 1 - a;
          b = 1 - b;
        }
        add(tris[t].a + a * e1 + b * e2, n);
      }
    }
  }
};

}  // namespace

SurfaceSample sample_object_surfaces(const Scene& scene, double spacing_mm) {
  SurfaceSample out;
  if (!(spacing_mm > 0) || !std::isfinite(spacing_mm)) return out;
  auto prepared = detail::prepare_objects(scene);
  if (!prepared) return out;
  const Frame table_from_cam(scene.turntable.cam_from_table.inverse());
  for (std::size_t i = 0; i < scene.objects.size(); ++i) {
    const SceneObject& object = scene.objects[i];
    const Frame table_from_object(object.on_turntable
                                      ? object.table_from_object
                                      : scene.turntable.cam_from_table.inverse() * object.table_from_object);
    const auto& parts = prepared->parts[i];
    for (std::size_t k = 0; k < parts.size(); ++k) {
      const Primitive& part = parts[k];
      Sampler sampler{spacing_mm, {}};
      switch (part.kind) {
        case PrimitiveKind::sphere:
          sampler.sphere(part.a);
          break;
        case PrimitiveKind::cylinder:
          sampler.cylinder(part.a, part.b, part.c);
          break;
        case PrimitiveKind::rect:
          sampler.rect({-part.a, -part.b, 0}, {2 * part.a, 0, 0}, {0, 2 * part.b, 0}, {0, 0, 1});
          break;
        case PrimitiveKind::disk:
          break;
        case PrimitiveKind::plane:
          break;
        case PrimitiveKind::box:
          sampler.box(part.lo, part.hi);
          break;
        case PrimitiveKind::mesh:
          sampler.mesh(*part.mesh, scene.sensor.seed ^ (i << 20) ^ k);
          break;
      }
      for (const auto& [local, local_normal] : sampler.out) {
        const V3 p = part.cam_from_local.apply(local);  // object frame
        bool hidden = false;
        for (std::size_t other = 0; other < parts.size() && !hidden; ++other)
          if (other != k) hidden = inside_solid(parts[other], p);
        if (object.kind == ObjectKind::teacup && part.part_id == 1 &&
            p.x * p.x + p.y * p.y < object.radius * object.radius)
          hidden = true;  // the handle's ends are buried in the wall
        if (hidden) continue;
        const V3 pt = table_from_object.apply(p);
        const V3 nt = table_from_object.rotate(part.cam_from_local.rotate(local_normal));
        out.points.insert(out.points.end(),
                          {static_cast<float>(pt.x), static_cast<float>(pt.y), static_cast<float>(pt.z)});
        out.normals.insert(out.normals.end(),
                           {static_cast<float>(nt.x), static_cast<float>(nt.y), static_cast<float>(nt.z)});
        out.object_id.push_back(static_cast<std::int16_t>(detail::kFirstObjectId + static_cast<int>(i)));
        out.part_id.push_back(part.part_id);
      }
    }
  }
  return out;
}

}  // namespace slrig
