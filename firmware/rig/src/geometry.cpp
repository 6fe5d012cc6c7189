#include "geometry.hpp"

#include <algorithm>
#include <numeric>

namespace slrig::detail {

namespace {

V3 vmin(V3 a, V3 b) { return {std::min(a.x, b.x), std::min(a.y, b.y), std::min(a.z, b.z)}; }
V3 vmax(V3 a, V3 b) { return {std::max(a.x, b.x), std::max(a.y, b.y), std::max(a.z, b.z)}; }

// Slab test; inv = 1 / direction (inf for zero components is fine with IEEE arithmetic).
inline bool ray_box(V3 o, V3 inv, V3 lo, V3 hi, double t_min, double t_max, double& t_enter) {
  double t0 = t_min, t1 = t_max;
  for (int axis = 0; axis < 3; ++axis) {
    const double oa = o[axis], ia = inv[axis];
    double tn = (lo[axis] - oa) * ia, tf = (hi[axis] - oa) * ia;
    if (tn > tf) std::swap(tn, tf);
    // NaN from 0 * inf (origin on a slab plane, parallel ray) must not reject: keep bounds.
    if (tn > t0) t0 = tn;
    if (tf < t1) t1 = tf;
    if (t0 > t1) return false;
  }
  t_enter = t0;
  return true;
}

inline bool ray_triangle(const Triangle& tri, V3 o, V3 d, double t_min, double t_max, double& t) {
  const V3 e1 = tri.b - tri.a, e2 = tri.c - tri.a;
  const V3 p = cross(d, e2);
  const double det = dot(e1, p);
  if (std::abs(det) < 1e-300) return false;
  const double inv = 1.0 / det;
  const V3 s = o - tri.a;
  const double u = dot(s, p) * inv;
  if (u < 0.0 || u > 1.0) return false;
  const V3 q = cross(s, e1);
  const double v = dot(d, q) * inv;
  if (v < 0.0 || u + v > 1.0) return false;
  const double tt = dot(e2, q) * inv;
  if (tt <= t_min || tt >= t_max) return false;
  t = tt;
  return true;
}

// Smallest root of a t^2 + 2 b t + c = 0 in (t_min, t_max), numerically stable.
inline bool quadratic_first(double a, double b, double c, double t_min, double t_max, double& t0, double& t1) {
  const double disc = b * b - a * c;
  if (disc < 0 || a == 0) return false;
  const double s = std::sqrt(disc);
  const double q = b >= 0 ? -(b + s) : -(b - s);
  double r0 = q / a, r1 = q != 0 ? c / q : r0;
  if (r0 > r1) std::swap(r0, r1);
  t0 = r0;
  t1 = r1;
  return r1 > t_min && r0 < t_max;
}

}  // namespace

// ---------------------------------------------------------------- Mesh

Mesh::Mesh(std::vector<Triangle> triangles) : triangles_(std::move(triangles)) {
  if (triangles_.empty()) return;
  std::vector<V3> centroids(triangles_.size());
  for (std::size_t i = 0; i < triangles_.size(); ++i) {
    const Triangle& t = triangles_[i];
    centroids[i] = (1.0 / 3.0) * (t.a + t.b + t.c);
  }
  nodes_.reserve(triangles_.size() / 2 + 1);
  build(0, static_cast<std::uint32_t>(triangles_.size()), centroids);
}

std::uint32_t Mesh::build(std::uint32_t begin, std::uint32_t end, std::vector<V3>& centroids) {
  const auto index = static_cast<std::uint32_t>(nodes_.size());
  nodes_.push_back({});
  V3 lo{1e300, 1e300, 1e300}, hi{-1e300, -1e300, -1e300}, clo = lo, chi = hi;
  for (std::uint32_t i = begin; i < end; ++i) {
    const Triangle& t = triangles_[i];
    lo = vmin(lo, vmin(t.a, vmin(t.b, t.c)));
    hi = vmax(hi, vmax(t.a, vmax(t.b, t.c)));
    clo = vmin(clo, centroids[i]);
    chi = vmax(chi, centroids[i]);
  }
  nodes_[index].lo = lo;
  nodes_[index].hi = hi;
  const std::uint32_t count = end - begin;
  const V3 extent = chi - clo;
  if (count <= 4 || std::max({extent.x, extent.y, extent.z}) <= 0) {
    nodes_[index].first = begin;
    nodes_[index].count = count;
    return index;
  }
  const int axis = extent.x >= extent.y && extent.x >= extent.z ? 0 : (extent.y >= extent.z ? 1 : 2);
  const std::uint32_t mid = begin + count / 2;
  // Partition a permutation, then apply it to both arrays.
  std::vector<std::uint32_t> order(count);
  std::iota(order.begin(), order.end(), begin);
  std::nth_element(order.begin(), order.begin() + (mid - begin), order.end(),
                   [&](std::uint32_t a, std::uint32_t b) { return centroids[a][axis] < centroids[b][axis]; });
  std::vector<Triangle> tris(count);
  std::vector<V3> cents(count);
  for (std::uint32_t i = 0; i < count; ++i) {
    tris[i] = triangles_[order[i]];
    cents[i] = centroids[order[i]];
  }
  std::copy(tris.begin(), tris.end(), triangles_.begin() + begin);
  std::copy(cents.begin(), cents.end(), centroids.begin() + begin);
  const std::uint32_t left = build(begin, mid, centroids);
  const std::uint32_t right = build(mid, end, centroids);
  nodes_[index].first = left;
  nodes_[index].second = right;
  nodes_[index].count = 0;
  return index;
}

template <bool kAnyHit>
bool Mesh::traverse(V3 o, V3 d, double t_min, double t_max, double& t, std::uint32_t& triangle) const {
  if (nodes_.empty()) return false;
  const V3 inv{1.0 / d.x, 1.0 / d.y, 1.0 / d.z};
  std::uint32_t stack[64];
  int top = 0;
  stack[top++] = 0;
  bool found = false;
  double best = t_max;
  while (top > 0) {
    const Node& node = nodes_[stack[--top]];
    double enter;
    if (!ray_box(o, inv, node.lo, node.hi, t_min, best, enter)) continue;
    if (node.count > 0) {
      for (std::uint32_t i = node.first; i < node.first + node.count; ++i) {
        double tt;
        if (ray_triangle(triangles_[i], o, d, t_min, best, tt)) {
          if constexpr (kAnyHit) return true;
          best = tt;
          triangle = i;
          found = true;
        }
      }
    } else if (top < 62) {
      // Visit the nearer child first so `best` shrinks early.
      const Node& l = nodes_[node.first];
      const Node& r = nodes_[node.second];
      double el = 0, er = 0;
      const bool hl = ray_box(o, inv, l.lo, l.hi, t_min, best, el);
      const bool hr = ray_box(o, inv, r.lo, r.hi, t_min, best, er);
      if (hl && hr) {
        if (el <= er) {
          stack[top++] = node.second;
          stack[top++] = node.first;
        } else {
          stack[top++] = node.first;
          stack[top++] = node.second;
        }
      } else if (hl) {
        stack[top++] = node.first;
      } else if (hr) {
        stack[top++] = node.second;
      }
    }
  }
  if (found) t = best;
  return found;
}

bool Mesh::intersect(V3 origin, V3 direction, double t_min, double t_max, double& t, std::uint32_t& triangle) const {
  return traverse<false>(origin, direction, t_min, t_max, t, triangle);
}

bool Mesh::occluded(V3 origin, V3 direction, double t_min, double t_max) const {
  double t;
  std::uint32_t tri;
  return traverse<true>(origin, direction, t_min, t_max, t, tri);
}

V3 Mesh::face_normal(std::uint32_t triangle) const {
  const Triangle& t = triangles_[triangle];
  const V3 n = cross(t.b - t.a, t.c - t.a);
  const double len = norm(n);
  return len > 0 ? (1.0 / len) * n : V3{0, 0, 1};
}

// ---------------------------------------------------------------- World

namespace {

// Nearest hit of one primitive in (t_min, t_max); sets t and the local normal / point.
bool intersect_primitive(const Primitive& p, V3 o, V3 d, double t_min, double t_max, double& t, V3& normal_cam,
                         V3& local) {
  if (p.kind == PrimitiveKind::sphere) {
    const V3 oc = o - p.cam_from_local.t;
    double t0, t1;
    if (!quadratic_first(dot(d, d), dot(oc, d), dot(oc, oc) - p.a * p.a, t_min, t_max, t0, t1)) return false;
    const double tt = t0 > t_min ? t0 : t1;
    if (tt <= t_min || tt >= t_max) return false;
    t = tt;
    const V3 hit = o + tt * d;
    normal_cam = (1.0 / p.a) * (hit - p.cam_from_local.t);
    local = hit - p.cam_from_local.t;
    return true;
  }
  const V3 lo = p.cam_from_local.apply_inv(o);
  const V3 ld = p.cam_from_local.rotate_inv(d);
  V3 ln;
  switch (p.kind) {
    case PrimitiveKind::cylinder: {
      double t0, t1;
      const double a = ld.x * ld.x + ld.y * ld.y;
      if (!quadratic_first(a, lo.x * ld.x + lo.y * ld.y, lo.x * lo.x + lo.y * lo.y - p.a * p.a, t_min, t_max, t0, t1))
        return false;
      double tt = -1;
      for (double cand : {t0, t1}) {
        if (cand <= t_min || cand >= t_max) continue;
        const double z = lo.z + cand * ld.z;
        if (z >= p.b && z <= p.c) {
          tt = cand;
          break;
        }
      }
      if (tt < 0) return false;
      t = tt;
      local = lo + tt * ld;
      ln = {local.x / p.a, local.y / p.a, 0};
      break;
    }
    case PrimitiveKind::disk:
    case PrimitiveKind::rect:
    case PrimitiveKind::plane: {
      if (ld.z == 0) return false;
      const double tt = -lo.z / ld.z;
      if (tt <= t_min || tt >= t_max) return false;
      const V3 q = lo + tt * ld;
      if (p.kind == PrimitiveKind::disk && q.x * q.x + q.y * q.y > p.a * p.a) return false;
      if (p.kind == PrimitiveKind::rect && (std::abs(q.x) > p.a || std::abs(q.y) > p.b)) return false;
      t = tt;
      local = {q.x, q.y, 0};
      ln = {0, 0, 1};
      break;
    }
    case PrimitiveKind::box: {
      double t_near = t_min, t_far = t_max;
      int near_axis = -1, far_axis = -1;
      double near_sign = 0, far_sign = 0;
      for (int axis = 0; axis < 3; ++axis) {
        const double oa = lo[axis], da = ld[axis], lo_a = p.lo[axis], hi_a = p.hi[axis];
        if (da == 0) {
          if (oa < lo_a || oa > hi_a) return false;
          continue;
        }
        double tn = (lo_a - oa) / da, tf = (hi_a - oa) / da;
        double sn = -1, sf = 1;
        if (tn > tf) {
          std::swap(tn, tf);
          std::swap(sn, sf);
        }
        if (tn > t_near) {
          t_near = tn;
          near_axis = axis;
          near_sign = sn;
        }
        if (tf < t_far) {
          t_far = tf;
          far_axis = axis;
          far_sign = sf;
        }
        if (t_near > t_far) return false;
      }
      int axis;
      double sign;
      if (near_axis >= 0 && t_near > t_min) {
        t = t_near;
        axis = near_axis;
        sign = near_sign;
      } else if (far_axis >= 0 && t_far < t_max) {
        t = t_far;
        axis = far_axis;
        sign = far_sign;
      } else {
        return false;
      }
      local = lo + t * ld;
      ln = {axis == 0 ? sign : 0.0, axis == 1 ? sign : 0.0, axis == 2 ? sign : 0.0};
      break;
    }
    case PrimitiveKind::mesh: {
      std::uint32_t tri = 0;
      if (!p.mesh->intersect(lo, ld, t_min, t_max, t, tri)) return false;
      local = lo + t * ld;
      ln = p.mesh->face_normal(tri);
      break;
    }
    case PrimitiveKind::sphere:
      return false;
  }
  normal_cam = p.cam_from_local.rotate(ln);
  return true;
}

}  // namespace

void compute_bounds(Primitive& p) {
  V3 local_centre{0, 0, 0};
  double radius = std::numeric_limits<double>::infinity();
  switch (p.kind) {
    case PrimitiveKind::sphere:
      radius = p.a;
      break;
    case PrimitiveKind::cylinder:
      local_centre = {0, 0, 0.5 * (p.b + p.c)};
      radius = std::sqrt(p.a * p.a + 0.25 * (p.c - p.b) * (p.c - p.b));
      break;
    case PrimitiveKind::disk:
      radius = p.a;
      break;
    case PrimitiveKind::rect:
      radius = std::sqrt(p.a * p.a + p.b * p.b);
      break;
    case PrimitiveKind::plane:
      break;
    case PrimitiveKind::box:
      local_centre = 0.5 * (p.lo + p.hi);
      radius = 0.5 * norm(p.hi - p.lo);
      break;
    case PrimitiveKind::mesh:
      local_centre = 0.5 * (p.mesh->bounds_min() + p.mesh->bounds_max());
      radius = 0.5 * norm(p.mesh->bounds_max() - p.mesh->bounds_min());
      break;
  }
  p.bound_centre = p.kind == PrimitiveKind::sphere ? p.cam_from_local.t : p.cam_from_local.apply(local_centre);
  p.bound_radius = radius * (1 + 1e-9) + 1e-9;
}

namespace {

// False when the ray segment (t_min, t_max) certainly misses the bounding sphere.
inline bool may_hit(const Primitive& p, V3 o, V3 d, double inv_dd, double t_min, double t_max) {
  if (!std::isfinite(p.bound_radius)) return true;
  const V3 oc = p.bound_centre - o;
  const double along = dot(oc, d);
  const double r2 = p.bound_radius * p.bound_radius;
  const double miss2 = dot(oc, oc) - along * along * inv_dd;  // squared distance to the line
  if (miss2 > r2) return false;
  // Chord of the sphere along the ray, in units of t.
  const double half = std::sqrt((r2 - std::max(miss2, 0.0)) * inv_dd);
  const double centre_t = along * inv_dd;
  return centre_t + half > t_min && centre_t - half < t_max;
}

}  // namespace

bool World::intersect(V3 origin, V3 direction, double t_min, double t_max, Hit& hit) const {
  bool found = false;
  double best = t_max;
  const double inv_dd = 1.0 / dot(direction, direction);
  for (std::size_t i = 0; i < primitives.size(); ++i) {
    if (!may_hit(primitives[i], origin, direction, inv_dd, t_min, best)) continue;
    double t;
    V3 n, local;
    if (intersect_primitive(primitives[i], origin, direction, t_min, best, t, n, local)) {
      best = t;
      hit.t = t;
      hit.primitive = static_cast<int>(i);
      hit.normal = n;
      hit.local = local;
      found = true;
    }
  }
  return found;
}

bool World::occluded(V3 origin, V3 direction, double t_min, double t_max, int skip) const {
  const double inv_dd = 1.0 / dot(direction, direction);
  for (std::size_t i = 0; i < primitives.size(); ++i) {
    const Primitive& p = primitives[i];
    if (static_cast<int>(i) == skip || !may_hit(p, origin, direction, inv_dd, t_min, t_max)) continue;
    if (p.kind == PrimitiveKind::mesh) {
      const V3 lo = p.cam_from_local.apply_inv(origin);
      const V3 ld = p.cam_from_local.rotate_inv(direction);
      if (p.mesh->occluded(lo, ld, t_min, t_max)) return true;
      continue;
    }
    double t;
    V3 n, local;
    if (intersect_primitive(p, origin, direction, t_min, t_max, t, n, local)) return true;
  }
  return false;
}

double World::albedo_at(const Hit& hit) const {
  const Primitive& p = primitives[static_cast<std::size_t>(hit.primitive)];
  const Material& m = p.material;
  if (!m.checker) return m.albedo;
  // Only the printed face (local z = lo.z) carries the pattern.
  if (std::abs(hit.local.z - p.lo.z) > 1e-9 * (1 + std::abs(p.lo.z))) return m.albedo;
  const double fx = std::floor(hit.local.x / m.square), fy = std::floor(hit.local.y / m.square);
  // Squares span i = -1 .. squares_x - 2 (the corner grid starts at the first inner corner).
  if (fx < -1 || fy < -1 || fx > m.squares_x - 2 || fy > m.squares_y - 2) return m.albedo;
  const auto parity = static_cast<long long>(fx) + static_cast<long long>(fy);
  return (parity % 2 == 0) ? m.dark_albedo : m.albedo;
}

namespace {

struct P2 {
  double x, y;
};

// Sutherland-Hodgman clip of a convex polygon against one half-plane (keep where
// sign * (coordinate `axis` - bound) <= 0); at most 8 vertices (a quadrilateral cut by 4 lines).
int clip_half_plane(const P2* in, int n, P2* out, int axis, double bound, double sign) {
  int m = 0;
  for (int i = 0; i < n; ++i) {
    const P2& a = in[i];
    const P2& b = in[(i + 1) % n];
    const double da = sign * ((axis == 0 ? a.x : a.y) - bound);
    const double db = sign * ((axis == 0 ? b.x : b.y) - bound);
    if (da <= 0) out[m++] = a;
    if ((da < 0 && db > 0) || (da > 0 && db < 0)) {
      const double s = da / (da - db);
      out[m++] = {a.x + s * (b.x - a.x), a.y + s * (b.y - a.y)};
    }
  }
  return m;
}

double polygon_area(const P2* p, int n) {
  double twice = 0;
  for (int i = 0; i < n; ++i) {
    const P2& a = p[i];
    const P2& b = p[(i + 1) % n];
    twice += a.x * b.y - b.x * a.y;
  }
  return std::abs(twice) / 2;
}

// Area of a convex quadrilateral inside the rectangle [x0, x1] x [y0, y1].
double clipped_area(const std::array<P2, 4>& quad, double x0, double x1, double y0, double y1) {
  P2 a[12], b[12];
  int n = clip_half_plane(quad.data(), 4, a, 0, x0, -1);
  n = clip_half_plane(a, n, b, 0, x1, 1);
  n = clip_half_plane(b, n, a, 1, y0, -1);
  n = clip_half_plane(a, n, b, 1, y1, 1);
  return n >= 3 ? polygon_area(b, n) : 0.0;
}

}  // namespace

double World::footprint_albedo(const Hit& hit, V3 origin, const std::array<V3, 4>& corner_directions) const {
  const Primitive& p = primitives[static_cast<std::size_t>(hit.primitive)];
  const Material& m = p.material;
  const double centre = albedo_at(hit);
  if (!m.checker || std::abs(hit.local.z - p.lo.z) > 1e-9 * (1 + std::abs(p.lo.z))) return centre;
  // The footprint on the printed face's plane, in the board's frame.
  const V3 o = p.cam_from_local.apply_inv(origin);
  std::array<P2, 4> quad{};
  double lo_x = std::numeric_limits<double>::infinity(), lo_y = lo_x, hi_x = -lo_x, hi_y = -lo_x;
  for (std::size_t k = 0; k < 4; ++k) {
    const V3 d = p.cam_from_local.rotate_inv(corner_directions[k]);
    if (std::abs(d.z) < 1e-12) return centre;  // grazing: the footprint is unbounded
    const double t = (p.lo.z - o.z) / d.z;
    if (!(t > 0)) return centre;
    quad[k] = {o.x + t * d.x, o.y + t * d.y};
    lo_x = std::min(lo_x, quad[k].x);
    hi_x = std::max(hi_x, quad[k].x);
    lo_y = std::min(lo_y, quad[k].y);
    hi_y = std::max(hi_y, quad[k].y);
  }
  const double s = m.square;
  // Squares span i = -1 .. squares_x - 2 (as in albedo_at); only the dark ones need clipping.
  const double i0 = std::max(std::floor(lo_x / s), -1.0), i1 = std::min(std::floor(hi_x / s), m.squares_x - 2.0);
  const double j0 = std::max(std::floor(lo_y / s), -1.0), j1 = std::min(std::floor(hi_y / s), m.squares_y - 2.0);
  // Inside one square (most pixels) or off the printed squares: nothing to integrate.
  if (std::floor(lo_x / s) == std::floor(hi_x / s) && std::floor(lo_y / s) == std::floor(hi_y / s)) return centre;
  if (i0 > i1 || j0 > j1) return centre;
  const double total = polygon_area(quad.data(), 4);
  if (!(total > 0)) return centre;
  double dark = 0;
  for (double i = i0; i <= i1; ++i)
    for (double j = j0; j <= j1; ++j) {
      const auto parity = static_cast<long long>(i) + static_cast<long long>(j);
      if (parity % 2 != 0) continue;
      dark += clipped_area(quad, i * s, (i + 1) * s, j * s, (j + 1) * s);
    }
  const double fraction = std::clamp(dark / total, 0.0, 1.0);
  return m.albedo + fraction * (m.dark_albedo - m.albedo);
}

}  // namespace slrig::detail
