// Ray casting for the virtual rig: analytic primitives and triangle meshes behind a BVH, in
// double precision (ground truth must be exact to well below a micrometre).
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

#include "slproto/calibration.hpp"

namespace slrig::detail {

struct V3 {
  double x = 0, y = 0, z = 0;
  V3() = default;
  constexpr V3(double ax, double ay, double az) : x(ax), y(ay), z(az) {}
  explicit V3(const slproto::Vec3& v) : x(v[0]), y(v[1]), z(v[2]) {}
  slproto::Vec3 arr() const { return {x, y, z}; }
  double operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
};
inline V3 operator+(V3 a, V3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
inline V3 operator-(V3 a, V3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
inline V3 operator-(V3 a) { return {-a.x, -a.y, -a.z}; }
inline V3 operator*(double s, V3 a) { return {s * a.x, s * a.y, s * a.z}; }
inline V3 operator*(V3 a, double s) { return {s * a.x, s * a.y, s * a.z}; }
inline double dot(V3 a, V3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline V3 cross(V3 a, V3 b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
inline double norm(V3 a) { return std::sqrt(dot(a, a)); }
inline V3 normalized(V3 a) { return (1.0 / norm(a)) * a; }

// A rigid transform target_from_source in doubles, with fast apply.
struct Frame {
  double R[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  V3 t;
  Frame() = default;
  explicit Frame(const slproto::RigidTransform& T) : t(T.t) {
    for (int i = 0; i < 9; ++i) R[i] = T.R[static_cast<std::size_t>(i)];
  }
  V3 rotate(V3 p) const {
    return {R[0] * p.x + R[1] * p.y + R[2] * p.z, R[3] * p.x + R[4] * p.y + R[5] * p.z,
            R[6] * p.x + R[7] * p.y + R[8] * p.z};
  }
  V3 rotate_inv(V3 p) const {
    return {R[0] * p.x + R[3] * p.y + R[6] * p.z, R[1] * p.x + R[4] * p.y + R[7] * p.z,
            R[2] * p.x + R[5] * p.y + R[8] * p.z};
  }
  V3 apply(V3 p) const { return rotate(p) + t; }
  V3 apply_inv(V3 p) const { return rotate_inv(p - t); }
};

struct Triangle {
  V3 a, b, c;
};

// A triangle mesh in its own frame with a bounding-volume hierarchy (median split on the
// longest axis; leaves of up to 4 triangles).
class Mesh {
 public:
  explicit Mesh(std::vector<Triangle> triangles);
  const std::vector<Triangle>& triangles() const { return triangles_; }
  // Nearest hit with t in (t_min, t_max): returns true and sets t, the triangle index.
  bool intersect(V3 origin, V3 direction, double t_min, double t_max, double& t, std::uint32_t& triangle) const;
  bool occluded(V3 origin, V3 direction, double t_min, double t_max) const;
  V3 face_normal(std::uint32_t triangle) const;  // unit, right-handed (a, b, c)
  V3 bounds_min() const { return nodes_.empty() ? V3{} : nodes_[0].lo; }
  V3 bounds_max() const { return nodes_.empty() ? V3{} : nodes_[0].hi; }

 private:
  struct Node {
    V3 lo, hi;
    std::uint32_t first = 0, second = 0, count = 0;  // leaf: triangles [first, first + count); else children
  };
  std::uint32_t build(std::uint32_t begin, std::uint32_t end, std::vector<V3>& centroids);
  template <bool kAnyHit>
  bool traverse(V3 origin, V3 direction, double t_min, double t_max, double& t, std::uint32_t& triangle) const;
  std::vector<Triangle> triangles_;
  std::vector<Node> nodes_;
};

enum class PrimitiveKind : std::uint8_t {
  sphere,    // centre = frame.t, radius a
  cylinder,  // local z axis from z = b to z = c, radius a, open ends
  disk,      // local z = 0, radius a
  rect,      // local z = 0, |x| <= a, |y| <= b
  plane,     // local z = 0, unbounded
  box,       // local [lo, hi]
  mesh,
};

struct Material {
  double albedo = 0.8;
  double specular = 0;
  double specular_power = 50;
  // Checkerboard texture on the local z = lo.z face of a box: squares of `square` mm, corner
  // (0, 0) at local (0, 0), squares_x by squares_y squares, `dark_albedo` on the dark ones.
  bool checker = false;
  double square = 10, dark_albedo = 0.05;
  int squares_x = 0, squares_y = 0;
};

struct Primitive {
  PrimitiveKind kind = PrimitiveKind::sphere;
  std::int16_t object_id = -1;
  std::uint8_t part_id = 0;
  Material material;
  Frame cam_from_local;
  double a = 0, b = 0, c = 0;
  V3 lo, hi;
  std::shared_ptr<const Mesh> mesh;
  // Bounding sphere in the camera frame (radius infinite for unbounded planes): most rays and
  // shadow rays are rejected by it before the exact test.
  V3 bound_centre;
  double bound_radius = std::numeric_limits<double>::infinity();
  // A ray leaving this surface on its visible side cannot meet it again (convex shapes and flat
  // ones), so shadow rays from it skip it.
  bool convex() const { return kind != PrimitiveKind::mesh; }
};

// Sets bound_centre / bound_radius from the shape and cam_from_local.
void compute_bounds(Primitive& p);

struct Hit {
  double t = std::numeric_limits<double>::infinity();
  int primitive = -1;
  V3 normal;  // camera frame, unit, outward (not yet flipped toward the viewer)
  V3 local;   // hit point in the primitive's frame (for textures)
};

// The scene of one view, in the camera frame.
class World {
 public:
  std::vector<Primitive> primitives;
  // Nearest hit with t in (t_min, t_max). Direction need not be unit.
  bool intersect(V3 origin, V3 direction, double t_min, double t_max, Hit& hit) const;
  // Any hit in (t_min, t_max), ignoring primitive `skip` (-1: none).
  bool occluded(V3 origin, V3 direction, double t_min, double t_max, int skip = -1) const;
  double albedo_at(const Hit& hit) const;
  // The mean albedo over a camera pixel's footprint: the quadrilateral where the rays from
  // `origin` along `corner_directions` (through the pixel's four corners, in order around it)
  // meet the plane of the hit's textured face; a box filter, as a sensor pixel integrates
  // light over its area. Exact for the checkerboard (the quadrilateral is clipped against each
  // dark square); untextured surfaces and degenerate footprints return albedo_at(hit).
  double footprint_albedo(const Hit& hit, V3 origin, const std::array<V3, 4>& corner_directions) const;
};

}  // namespace slrig::detail
