// Inspection against a nominal mesh: see slscan/core/inspect.hpp and docs/inspection.md.
#include "slscan/core/inspect.hpp"

#include <CGAL/AABB_traits.h>
#include <CGAL/AABB_tree.h>
#include <CGAL/AABB_triangle_primitive.h>
#include <CGAL/Simple_cartesian.h>
#include <tbb/parallel_for.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <numeric>
#include <random>
#include <stdexcept>
#include <unordered_map>

namespace slscan::core {

namespace {

using Kernel = CGAL::Simple_cartesian<double>;
using CgalTriangle = Kernel::Triangle_3;
using CgalPoint = Kernel::Point_3;
using TriangleIterator = std::vector<CgalTriangle>::const_iterator;
using Primitive = CGAL::AABB_triangle_primitive<Kernel, TriangleIterator>;
using Tree = CGAL::AABB_tree<CGAL::AABB_traits<Kernel, Primitive>>;

std::string vec_text(const Eigen::Vector3f& v) {
  return "(" + std::to_string(v.x()) + ", " + std::to_string(v.y()) + ", " + std::to_string(v.z()) + ")";
}

std::uint64_t edge_key(std::uint32_t a, std::uint32_t b) {
  const auto lo = static_cast<std::uint64_t>(std::min(a, b)), hi = static_cast<std::uint64_t>(std::max(a, b));
  return (lo << 32) | hi;
}

// Closest point on triangle abc to p (Ericson, Real-Time Collision Detection 5.1.5), with the
// feature it lies on: 0 = face, 1..3 = edge (a,b), (b,c), (c,a), 4..6 = vertex a, b, c.
Eigen::Vector3d closest_on_triangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                                    const Eigen::Vector3d& c, int& feature) {
  const Eigen::Vector3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return feature = 4, a;
  const Eigen::Vector3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return feature = 5, b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) {
    feature = 1;
    return a + (d1 / (d1 - d3)) * ab;
  }
  const Eigen::Vector3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return feature = 6, c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) {
    feature = 3;
    return a + (d2 / (d2 - d6)) * ac;
  }
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    feature = 2;
    return b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * (c - b);
  }
  const double denom = 1.0 / (va + vb + vc);
  feature = 0;
  return a + ab * (vb * denom) + ac * (vc * denom);
}

Eigen::Matrix3d skew_free_rotation(const Eigen::Vector3d& omega) {
  const double angle = omega.norm();
  if (angle < 1e-15) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, omega / angle).toRotationMatrix();
}

double median_of(std::vector<double> v) {
  if (v.empty()) return 0;
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

}  // namespace

TriangleMesh weld_vertices(const TriangleMesh& mesh) {
  struct Key {
    float x, y, z;
    bool operator<(const Key& o) const {
      if (x != o.x) return x < o.x;
      if (y != o.y) return y < o.y;
      return z < o.z;
    }
  };
  constexpr auto unset = std::numeric_limits<std::uint32_t>::max();
  std::map<Key, std::uint32_t> index;
  TriangleMesh out;
  std::vector<std::uint32_t> remap(mesh.vertices.size(), unset);
  auto vertex_of = [&](std::uint32_t i) {
    if (remap[i] != unset) return remap[i];
    const Eigen::Vector3f& v = mesh.vertices[i];
    const auto [it, inserted] =
        index.try_emplace(Key{v.x(), v.y(), v.z()}, static_cast<std::uint32_t>(out.vertices.size()));
    if (inserted) out.vertices.push_back(v);
    return remap[i] = it->second;
  };
  const std::size_t n = mesh.vertices.size();
  for (const auto& t : mesh.triangles) {
    if (t[0] >= n || t[1] >= n || t[2] >= n) {
      out.triangles.push_back(t);  // check_nominal_mesh names it
      continue;
    }
    const std::array<std::uint32_t, 3> w{vertex_of(t[0]), vertex_of(t[1]), vertex_of(t[2])};
    if (w[0] == w[1] || w[1] == w[2] || w[2] == w[0]) continue;  // collapsed: no area
    out.triangles.push_back(w);
  }
  return out;
}

void check_nominal_mesh(const TriangleMesh& mesh, bool require_orientation) {
  if (mesh.triangles.empty()) throw std::invalid_argument("the nominal mesh has no triangles");
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i)
    if (!mesh.vertices[i].allFinite())
      throw std::invalid_argument("the nominal mesh's vertex " + std::to_string(i) + " is not finite " +
                                  vec_text(mesh.vertices[i]));
  const std::size_t n = mesh.vertices.size();
  // Directed use of each undirected edge: +1 for (lo -> hi), -1 for (hi -> lo).
  std::unordered_map<std::uint64_t, std::pair<int, int>> edges;  // key -> (uses, direction of the first)
  edges.reserve(mesh.triangles.size() * 2);
  for (std::size_t f = 0; f < mesh.triangles.size(); ++f) {
    const auto& t = mesh.triangles[f];
    for (int k = 0; k < 3; ++k)
      if (t[k] >= n)
        throw std::invalid_argument("the nominal mesh's triangle " + std::to_string(f) + " names vertex " +
                                    std::to_string(t[k]) + " of " + std::to_string(n));
    for (int k = 0; k < 3; ++k) {
      const std::uint32_t a = t[k], b = t[(k + 1) % 3];
      if (a == b) continue;
      const int direction = a < b ? 1 : -1;
      auto [it, inserted] = edges.try_emplace(edge_key(a, b), 1, direction);
      if (inserted) continue;
      auto& [uses, first] = it->second;
      ++uses;
      if (uses > 2)
        throw std::invalid_argument("the nominal mesh is not manifold: edge (" + std::to_string(a) + ", " +
                                    std::to_string(b) + ") is shared by more than two triangles (triangle " +
                                    std::to_string(f) + " is the third); repair it (e.g. MeshLab, " +
                                    "'Repair non-manifold edges') before inspecting");
      if (require_orientation && direction == first)
        throw std::invalid_argument("the nominal mesh's triangles are not consistently oriented: triangle " +
                                    std::to_string(f) + " runs edge (" + std::to_string(a) + ", " + std::to_string(b) +
                                    ") the same way as its neighbour, so inside and outside " +
                                    "(the sign of a deviation) are undefined");
    }
  }
}

struct NominalSurface::Impl {
  TriangleMesh mesh;
  std::vector<CgalTriangle> triangles;  // same order as mesh.triangles
  std::vector<Eigen::Vector3d> face_normals;
  std::vector<Eigen::Vector3d> vertex_normals;               // angle-weighted pseudo-normals
  std::vector<std::array<Eigen::Vector3d, 3>> edge_normals;  // per triangle, edges (a,b), (b,c), (c,a)
  std::vector<double> cumulative_area;
  Eigen::AlignedBox3d box;
  Tree tree;
  std::size_t reoriented = 0;
};

std::size_t orient_consistently(TriangleMesh& mesh) {
  check_nominal_mesh(mesh, false);
  // Each edge's triangles (at most two: checked) and the way each runs it.
  std::unordered_map<std::uint64_t, std::vector<std::pair<std::uint32_t, int>>> edges;
  const std::size_t nf = mesh.triangles.size();
  auto direction = [&](std::uint32_t a, std::uint32_t b) { return a < b ? 1 : -1; };
  for (std::size_t f = 0; f < nf; ++f) {
    const auto& t = mesh.triangles[f];
    for (int k = 0; k < 3; ++k)
      edges[edge_key(t[k], t[(k + 1) % 3])].emplace_back(static_cast<std::uint32_t>(f),
                                                         direction(t[k], t[(k + 1) % 3]));
  }
  // Flood each connected piece from its first triangle (kept as the file has it): a neighbour
  // must run the shared edge the other way.
  std::vector<int> flip(nf, -1);
  std::vector<std::uint32_t> queue;
  for (std::size_t seed = 0; seed < nf; ++seed) {
    if (flip[seed] >= 0) continue;
    flip[seed] = 0;
    queue.assign(1, static_cast<std::uint32_t>(seed));
    while (!queue.empty()) {
      const std::uint32_t f = queue.back();
      queue.pop_back();
      const auto& t = mesh.triangles[f];
      for (int k = 0; k < 3; ++k) {
        const int mine = direction(t[k], t[(k + 1) % 3]) * (flip[f] ? -1 : 1);
        for (const auto& [g, raw] : edges[edge_key(t[k], t[(k + 1) % 3])]) {
          if (g == f) continue;
          const int needed = raw == -mine ? 0 : 1;
          if (flip[g] < 0) {
            flip[g] = needed;
            queue.push_back(g);
          } else if (flip[g] != needed) {
            throw std::invalid_argument("the nominal mesh cannot be oriented (a one-sided surface): triangle " +
                                        std::to_string(g) + " would need both windings");
          }
        }
      }
    }
  }
  std::size_t flipped = 0;
  for (std::size_t f = 0; f < nf; ++f)
    if (flip[f] == 1) std::swap(mesh.triangles[f][1], mesh.triangles[f][2]), ++flipped;
  return flipped;
}

NominalSurface::NominalSurface(TriangleMesh mesh) : impl_(std::make_unique<Impl>()) {
  Impl& m = *impl_;
  m.reoriented = orient_consistently(mesh);
  // A closed mesh wound inside out (negative volume) is turned the right way: a closed nominal
  // has an outside whatever its file says.
  double volume = 0;
  for (const auto& t : mesh.triangles) {
    const Eigen::Vector3d a = mesh.vertices[(t[0])].cast<double>();
    const Eigen::Vector3d b = mesh.vertices[(t[1])].cast<double>();
    const Eigen::Vector3d c = mesh.vertices[(t[2])].cast<double>();
    volume += a.dot(b.cross(c)) / 6;
  }
  {
    std::unordered_map<std::uint64_t, int> uses;
    for (const auto& t : mesh.triangles)
      for (int k = 0; k < 3; ++k) ++uses[edge_key(t[k], t[(k + 1) % 3])];
    const bool closed = std::all_of(uses.begin(), uses.end(), [](const auto& e) { return e.second == 2; });
    if (closed && volume < 0)
      for (auto& t : mesh.triangles) std::swap(t[1], t[2]);
  }
  m.mesh = std::move(mesh);
  const auto& vertices = m.mesh.vertices;
  const std::size_t nf = m.mesh.triangles.size();
  m.triangles.reserve(nf);
  m.face_normals.resize(nf);
  m.vertex_normals.assign(vertices.size(), Eigen::Vector3d::Zero());
  m.edge_normals.resize(nf);
  m.cumulative_area.resize(nf);
  std::unordered_map<std::uint64_t, Eigen::Vector3d> edge_sum;
  double area = 0;
  for (std::size_t f = 0; f < nf; ++f) {
    const auto& t = m.mesh.triangles[f];
    const Eigen::Vector3d p[3] = {vertices[(t[0])].cast<double>(), vertices[(t[1])].cast<double>(),
                                  vertices[(t[2])].cast<double>()};
    m.triangles.emplace_back(CgalPoint(p[0].x(), p[0].y(), p[0].z()), CgalPoint(p[1].x(), p[1].y(), p[1].z()),
                             CgalPoint(p[2].x(), p[2].y(), p[2].z()));
    const Eigen::Vector3d cross = (p[1] - p[0]).cross(p[2] - p[0]);
    const double twice_area = cross.norm();
    const Eigen::Vector3d n = twice_area > 0 ? Eigen::Vector3d(cross / twice_area) : Eigen::Vector3d::Zero();
    m.face_normals[f] = n;
    area += twice_area / 2;
    m.cumulative_area[f] = area;
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector3d e1 = p[(k + 1) % 3] - p[k], e2 = p[(k + 2) % 3] - p[k];
      const double denom = e1.norm() * e2.norm();
      const double angle = denom > 0 ? std::acos(std::clamp(e1.dot(e2) / denom, -1.0, 1.0)) : 0.0;
      m.vertex_normals[t[k]] += angle * n;
      edge_sum[edge_key(t[k], t[(k + 1) % 3])] += n;
    }
    m.box.extend(p[0]);
    m.box.extend(p[1]);
    m.box.extend(p[2]);
  }
  for (auto& v : m.vertex_normals)
    if (v.norm() > 0) v.normalize();
  for (std::size_t f = 0; f < nf; ++f) {
    const auto& t = m.mesh.triangles[f];
    for (int k = 0; k < 3; ++k) {
      Eigen::Vector3d e = edge_sum[edge_key(t[k], t[(k + 1) % 3])];
      m.edge_normals[f][static_cast<std::size_t>(k)] = e.norm() > 0 ? Eigen::Vector3d(e.normalized()) : e;
    }
  }
  if (!(area > 0)) throw std::invalid_argument("the nominal mesh has no area (every triangle is degenerate)");
  m.tree.insert(m.triangles.cbegin(), m.triangles.cend());
  m.tree.build();
  m.tree.accelerate_distance_queries();
  (void)m.tree.closest_point(CgalPoint(0, 0, 0));  // any lazy structure built before concurrent queries
}

NominalSurface::~NominalSurface() = default;
NominalSurface::NominalSurface(NominalSurface&&) noexcept = default;
NominalSurface& NominalSurface::operator=(NominalSurface&&) noexcept = default;

NominalSurface::Closest NominalSurface::closest(const Eigen::Vector3d& query) const {
  const Impl& m = *impl_;
  const auto hit = m.tree.closest_point_and_primitive(CgalPoint(query.x(), query.y(), query.z()));
  const auto f = static_cast<std::size_t>(hit.second - m.triangles.cbegin());
  const auto& t = m.mesh.triangles[f];
  const auto& v = m.mesh.vertices;
  int feature = 0;
  const Eigen::Vector3d c =
      closest_on_triangle(query, v[(t[0])].cast<double>(), v[(t[1])].cast<double>(), v[(t[2])].cast<double>(), feature);
  Eigen::Vector3d pseudo = m.face_normals[f];
  if (feature >= 1 && feature <= 3) pseudo = m.edge_normals[f][static_cast<std::size_t>(feature - 1)];
  if (feature >= 4) pseudo = m.vertex_normals[(t[feature - 4])];
  Closest out;
  out.point = c;
  out.face_normal = m.face_normals[f];
  out.triangle = f;
  const Eigen::Vector3d d = query - c;
  out.signed_distance_mm = d.dot(pseudo) < 0 ? -d.norm() : d.norm();
  return out;
}

const TriangleMesh& NominalSurface::mesh() const { return impl_->mesh; }
std::size_t NominalSurface::reoriented_triangles() const { return impl_->reoriented; }
Eigen::AlignedBox3d NominalSurface::bounds() const { return impl_->box; }
double NominalSurface::area_mm2() const { return impl_->cumulative_area.back(); }

std::vector<Eigen::Vector3d> NominalSurface::sample(std::size_t count, std::uint64_t seed) const {
  const Impl& m = *impl_;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u01(0, 1);
  std::vector<Eigen::Vector3d> out;
  out.reserve(count);
  const double total = m.cumulative_area.back();
  for (std::size_t i = 0; i < count; ++i) {
    const double pick = u01(rng) * total;
    const auto f = static_cast<std::size_t>(std::min<std::ptrdiff_t>(
        std::lower_bound(m.cumulative_area.begin(), m.cumulative_area.end(), pick) - m.cumulative_area.begin(),
        static_cast<std::ptrdiff_t>(m.cumulative_area.size() - 1)));
    double r1 = u01(rng), r2 = u01(rng);
    if (r1 + r2 > 1) r1 = 1 - r1, r2 = 1 - r2;
    const auto& t = m.mesh.triangles[f];
    const Eigen::Vector3d a = m.mesh.vertices[(t[0])].cast<double>();
    const Eigen::Vector3d b = m.mesh.vertices[(t[1])].cast<double>();
    const Eigen::Vector3d c = m.mesh.vertices[(t[2])].cast<double>();
    out.push_back(a + r1 * (b - a) + r2 * (c - a));
  }
  return out;
}

double robust_extent(const std::vector<Eigen::Vector3f>& points) {
  if (points.empty()) return 0;
  Eigen::Vector3d lo, hi;
  std::vector<float> axis(points.size());
  for (int k = 0; k < 3; ++k) {
    for (std::size_t i = 0; i < points.size(); ++i) axis[i] = points[i][k];
    std::sort(axis.begin(), axis.end());
    const std::size_t n = axis.size();
    lo[k] = axis[n / 100];
    hi[k] = axis[std::min(n - 1, n - 1 - n / 100)];
  }
  return (hi - lo).norm();
}

UnitsDecision decide_nominal_units(double scan_extent_mm, double nominal_extent, NominalUnits requested) {
  switch (requested) {
    case NominalUnits::mm:
      return {1, "mm", "given (--nominal-units mm)"};
    case NominalUnits::m:
      return {1000, "m", "given (--nominal-units m)"};
    case NominalUnits::in:
      return {25.4, "in", "given (--nominal-units in)"};
    case NominalUnits::auto_detect:
      break;
  }
  if (!(scan_extent_mm > 0) || !(nominal_extent > 0))
    throw std::invalid_argument("cannot compare the sizes of the scan and the nominal (one of them has no extent)");
  const double ratio = scan_extent_mm / nominal_extent;
  struct Unit {
    const char* name;
    double scale;
  };
  constexpr Unit units[] = {{"mm", 1}, {"in", 25.4}, {"m", 1000}};
  constexpr double lo = 0.3, hi = 8, margin = 1.6;
  char text[300];
  for (const Unit& u : units) {
    const double r = ratio / u.scale;  // scan / nominal once the nominal is in mm
    if (r >= lo && r < hi) {
      // Near a border another unit is almost as plausible: refuse rather than guess.
      for (const Unit& other : units) {
        if (other.scale == u.scale) continue;
        const double r2 = ratio / other.scale;
        if (r2 >= lo / margin && r2 < hi * margin && (r < lo * margin || r >= hi / margin)) {
          std::snprintf(text, sizeof text,
                        "the nominal's unit is ambiguous: the scan is %.4g mm across, the nominal %.4g file units "
                        "(%s or %s would both fit); give --nominal-units mm|m|in",
                        scan_extent_mm, nominal_extent, u.name, other.name);
          throw std::invalid_argument(text);
        }
      }
      std::snprintf(text, sizeof text, "detected: the scan is %.4g mm across, the nominal %.4g %s (ratio %.2f)",
                    scan_extent_mm, nominal_extent, u.name, r);
      return {u.scale, u.name, text};
    }
  }
  std::snprintf(text, sizeof text,
                "the nominal's size does not match the scan's in mm, inches or metres: the scan is %.4g mm across, "
                "the nominal %.4g file units; give --nominal-units mm|m|in (or check the nominal is this part)",
                scan_extent_mm, nominal_extent);
  throw std::invalid_argument(text);
}

namespace {

struct FitOutcome {
  Eigen::Isometry3d transform = Eigen::Isometry3d::Identity();
  double rms_mm = 0;
  std::size_t inliers = 0;  // within the final gate and the robust band
  int iterations = 0;
};

// Robust point-to-plane ICP of `points` onto the nominal from `initial`: gates narrowing from
// `start_gate` to `final_gate` (x1/3 each time a gate converged), residuals beyond 3 robust
// sigmas (MAD) left out of each step.
FitOutcome fit_to_nominal(const std::vector<Eigen::Vector3d>& points, const NominalSurface& nominal,
                          const Eigen::Isometry3d& initial, double start_gate, double final_gate) {
  FitOutcome out;
  out.transform = initial;
  double gate = std::max(start_gate, final_gate);
  const std::size_t n = points.size();
  std::vector<Eigen::Vector3d> moved(n), target(n), normal(n);
  std::vector<double> distance(n);
  int stage_iterations = 0;
  double previous_rms = std::numeric_limits<double>::infinity();
  for (int iteration = 0; iteration < 200; ++iteration) {
    out.iterations = iteration + 1;
    tbb::parallel_for(std::size_t{0}, n, [&](std::size_t i) {
      moved[i] = out.transform * points[i];
      const NominalSurface::Closest c = nominal.closest(moved[i]);
      target[i] = c.point;
      normal[i] = c.face_normal;
      distance[i] = (moved[i] - c.point).norm();
    });
    std::vector<std::size_t> kept;
    std::vector<double> abs_residual;
    for (std::size_t i = 0; i < n; ++i)
      if (distance[i] <= gate) {
        kept.push_back(i);
        abs_residual.push_back(std::abs(normal[i].dot(moved[i] - target[i])));
      }
    if (kept.size() < 6) {
      out.inliers = kept.size();
      out.rms_mm = std::numeric_limits<double>::infinity();
      return out;
    }
    const double sigma = std::max(1.4826 * median_of(abs_residual), 1e-6);
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    for (std::size_t i : kept) centre += moved[i];
    centre /= static_cast<double>(kept.size());
    Eigen::Matrix<double, 6, 6> A = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 1> b = Eigen::Matrix<double, 6, 1>::Zero();
    double sum_sq = 0;
    std::size_t used = 0;
    for (std::size_t k = 0; k < kept.size(); ++k) {
      if (abs_residual[k] > 3 * sigma) continue;
      const std::size_t i = kept[k];
      const double r = normal[i].dot(moved[i] - target[i]);
      Eigen::Matrix<double, 6, 1> J;
      J << (moved[i] - centre).cross(normal[i]), normal[i];
      A += J * J.transpose();
      b -= J * r;
      sum_sq += r * r;
      ++used;
    }
    out.inliers = used;
    out.rms_mm = used > 0 ? std::sqrt(sum_sq / static_cast<double>(used)) : 0;
    // Directions the surface does not constrain (a sphere's rotations about its centre, a
    // plane's slides) stay put: the pseudo-inverse without eigenvalues below 1e-4 of the largest.
    // Rotations in radians about the centroid, translations in mm: scaled by the extent so that
    // both weigh alike.
    const double arm = std::max(
        1e-3, std::sqrt(A.topLeftCorner<3, 3>().trace() / std::max(1e-12, A.bottomRightCorner<3, 3>().trace())));
    Eigen::Matrix<double, 6, 1> scale;
    scale << 1 / arm, 1 / arm, 1 / arm, 1, 1, 1;
    const Eigen::Matrix<double, 6, 6> As = scale.asDiagonal() * A * scale.asDiagonal();
    const Eigen::Matrix<double, 6, 1> bs = scale.asDiagonal() * b;
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> eig(As);
    const double top = eig.eigenvalues().maxCoeff();
    Eigen::Matrix<double, 6, 1> y = Eigen::Matrix<double, 6, 1>::Zero();
    for (int k = 0; k < 6; ++k)
      if (eig.eigenvalues()(k) > 1e-4 * top)
        y += eig.eigenvectors().col(k) * (eig.eigenvectors().col(k).dot(bs) / eig.eigenvalues()(k));
    const Eigen::Matrix<double, 6, 1> x = scale.asDiagonal() * y;
    const Eigen::Matrix3d R = skew_free_rotation(x.head<3>());
    Eigen::Isometry3d step = Eigen::Isometry3d::Identity();
    step.linear() = R;
    step.translation() = centre - R * centre + x.tail<3>();
    out.transform = step * out.transform;
    const double step_deg = x.head<3>().norm() * 180 / M_PI, step_mm = x.tail<3>().norm();
    ++stage_iterations;
    const bool settled = stage_iterations >= 3 && std::abs(previous_rms - out.rms_mm) <= 1e-4 * out.rms_mm;
    previous_rms = out.rms_mm;
    const bool converged = (step_deg < 1e-4 && step_mm < 1e-5) || settled || stage_iterations >= 20;
    if (converged) {
      if (gate <= final_gate * 1.0001) break;
      gate = std::max(final_gate, gate / 3);
      stage_iterations = 0;
      previous_rms = std::numeric_limits<double>::infinity();
    }
  }
  return out;
}

// Mean and principal axes (columns, by decreasing variance) of a point set.
void principal_axes(const std::vector<Eigen::Vector3d>& points, Eigen::Vector3d& mean, Eigen::Matrix3d& axes) {
  mean = Eigen::Vector3d::Zero();
  for (const auto& p : points) mean += p;
  mean /= static_cast<double>(points.size());
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const auto& p : points) cov += (p - mean) * (p - mean).transpose();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
  axes = eig.eigenvectors().rowwise().reverse();  // decreasing
  if (axes.determinant() < 0) axes.col(2) *= -1;
}

std::vector<Eigen::Vector3d> subsample(const std::vector<Eigen::Vector3f>& points, std::size_t count,
                                       std::uint64_t seed) {
  std::vector<std::size_t> index(points.size());
  std::iota(index.begin(), index.end(), std::size_t{0});
  if (points.size() > count) {
    std::mt19937_64 rng(seed);
    std::shuffle(index.begin(), index.end(), rng);
    index.resize(count);
  }
  std::vector<Eigen::Vector3d> out;
  out.reserve(index.size());
  for (std::size_t i : index) out.push_back(points[i].cast<double>());
  return out;
}

double nice_ceiling(double value) {
  if (!(value > 0)) return 0.01;
  const double decade = std::pow(10.0, std::floor(std::log10(value)));
  for (double step : {1.0, 2.0, 5.0, 10.0})
    if (value <= step * decade * (1 + 1e-9)) return step * decade;
  return 10 * decade;
}

}  // namespace

std::vector<float> signed_deviations(const std::vector<Eigen::Vector3f>& points, const NominalSurface& nominal,
                                     double max_distance_mm) {
  std::vector<float> out(points.size());
  tbb::parallel_for(std::size_t{0}, points.size(), [&](std::size_t i) {
    const double d = nominal.closest(points[i].cast<double>()).signed_distance_mm;
    out[i] = std::abs(d) <= max_distance_mm ? static_cast<float>(d) : std::numeric_limits<float>::quiet_NaN();
  });
  return out;
}

DeviationStats deviation_stats(const std::vector<float>& deviation_mm, const InspectOptions& options) {
  DeviationStats s;
  s.points = deviation_mm.size();
  std::vector<double> d;
  d.reserve(deviation_mm.size());
  for (float v : deviation_mm)
    if (std::isfinite(v)) d.push_back(v);
  s.matched = d.size();
  s.unmatched = s.points - s.matched;
  if (d.empty()) return s;
  double sum = 0, sum_sq = 0;
  for (double v : d) sum += v, sum_sq += v * v;
  const auto n = static_cast<double>(d.size());
  s.mean_mm = sum / n;
  s.rms_mm = std::sqrt(sum_sq / n);
  s.std_mm = std::sqrt(std::max(0.0, sum_sq / n - s.mean_mm * s.mean_mm));
  std::sort(d.begin(), d.end());
  s.min_mm = d.front();
  s.max_mm = d.back();
  auto percentile = [](const std::vector<double>& sorted, double pct) {
    const double pos = pct / 100 * static_cast<double>(sorted.size() - 1);
    const auto lo = static_cast<std::size_t>(std::floor(pos));
    const std::size_t hi = std::min(lo + 1, sorted.size() - 1);
    return sorted[lo] + (pos - static_cast<double>(lo)) * (sorted[hi] - sorted[lo]);
  };
  for (double pct : {1.0, 5.0, 25.0, 50.0, 75.0, 95.0, 99.0}) s.percentiles_mm.emplace_back(pct, percentile(d, pct));
  std::vector<double> a(d.size());
  std::transform(d.begin(), d.end(), a.begin(), [](double v) { return std::abs(v); });
  std::sort(a.begin(), a.end());
  s.abs_p95_mm = percentile(a, 95);
  s.abs_p99_mm = percentile(a, 99);
  if (options.tolerance_mm) {
    const double tol = *options.tolerance_mm;
    const auto within = static_cast<double>(std::upper_bound(a.begin(), a.end(), tol) - a.begin());
    s.share_within = within / n;
    s.pass = *s.share_within >= options.pass_share;
  }
  return s;
}

Histogram deviation_histogram(const std::vector<float>& deviation_mm, double range_mm, int bins) {
  Histogram h;
  h.range_mm = range_mm;
  h.counts.assign(static_cast<std::size_t>(std::max(1, bins)), 0);
  const double width = 2 * range_mm / static_cast<double>(h.counts.size());
  for (float v : deviation_mm) {
    if (!std::isfinite(v)) continue;
    if (v < -range_mm) {
      ++h.below;
    } else if (v > range_mm) {
      ++h.above;
    } else {
      const auto bin = std::min(h.counts.size() - 1, static_cast<std::size_t>((v + range_mm) / width));
      ++h.counts[bin];
    }
  }
  return h;
}

InspectionResult inspect(const PointCloud& scan, const NominalSurface& nominal, const InspectOptions& options) {
  if (scan.points.empty()) throw std::invalid_argument("the scan has no points");
  for (std::size_t i = 0; i < scan.points.size(); ++i)
    if (!scan.points[i].allFinite())
      throw std::invalid_argument("the scan's point " + std::to_string(i) + " is not finite " +
                                  vec_text(scan.points[i]));
  if (!(options.max_distance_mm > 0)) throw std::invalid_argument("max distance must be positive");
  const std::vector<Eigen::Vector3d> fit_points = subsample(scan.points, options.fit_points, options.seed);
  const double extent = nominal.bounds().diagonal().norm();
  const double final_gate = options.max_distance_mm;

  InspectionResult result;
  // 1. The scan frame: the part where the nominal says, give or take a few mm.
  const double frame_gate = std::max(2.0, 0.05 * extent);
  FitOutcome best = fit_to_nominal(fit_points, nominal, Eigen::Isometry3d::Identity(), frame_gate, final_gate);
  std::string method = "scan frame";
  int tried = 1;
  const double needed = 0.5 * static_cast<double>(fit_points.size());
  if (options.coarse_search && static_cast<double>(best.inliers) < needed) {
    // 2. Elsewhere: centroids, then principal axes matched with the four proper sign choices,
    // each fitted on a quarter of the points; the best refined on all of them.
    const std::vector<Eigen::Vector3d> coarse_points(
        fit_points.begin(),
        fit_points.begin() + static_cast<std::ptrdiff_t>(std::min<std::size_t>(
                                 fit_points.size(), std::max<std::size_t>(2000, fit_points.size() / 4))));
    Eigen::Vector3d scan_mean, nominal_mean;
    Eigen::Matrix3d scan_axes, nominal_axes;
    principal_axes(fit_points, scan_mean, scan_axes);
    principal_axes(nominal.sample(20000, options.seed), nominal_mean, nominal_axes);
    std::vector<std::pair<std::string, Eigen::Isometry3d>> candidates;
    {
      Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
      t.translation() = nominal_mean - scan_mean;
      candidates.emplace_back("centroids", t);
    }
    const double signs[4][3] = {{1, 1, 1}, {1, -1, -1}, {-1, 1, -1}, {-1, -1, 1}};
    for (int k = 0; k < 4; ++k) {
      const Eigen::Matrix3d D = Eigen::Vector3d(signs[k][0], signs[k][1], signs[k][2]).asDiagonal();
      Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
      t.linear() = nominal_axes * D * scan_axes.transpose();
      t.translation() = nominal_mean - t.linear() * scan_mean;
      candidates.emplace_back("principal axes, sign choice " + std::to_string(k + 1) + " of 4", t);
    }
    FitOutcome best_candidate;
    std::string best_name;
    for (const auto& [name, initial] : candidates) {
      ++tried;
      const FitOutcome f = fit_to_nominal(coarse_points, nominal, initial, 0.25 * extent, final_gate);
      if (best_name.empty() || f.inliers > best_candidate.inliers ||
          (f.inliers == best_candidate.inliers && f.rms_mm < best_candidate.rms_mm))
        best_candidate = f, best_name = name;
    }
    const FitOutcome refined =
        fit_to_nominal(fit_points, nominal, best_candidate.transform, 2 * final_gate, final_gate);
    if (refined.inliers > best.inliers) best = refined, method = best_name;
  }
  const double share = static_cast<double>(best.inliers) / static_cast<double>(fit_points.size());
  if (share < options.min_overlap) {
    char text[400];
    std::snprintf(text, sizeof text,
                  "the scan does not overlap the nominal: after the best alignment found (%d tried: the scan frame%s) "
                  "only %.1f %% of the scan's points lie within %.2f mm of the nominal (%.0f %% needed); check that "
                  "the nominal is this part and its unit (--nominal-units)",
                  tried, tried > 1 ? ", centroids, principal axes" : "", 100 * share, options.max_distance_mm,
                  100 * options.min_overlap);
    throw std::runtime_error(text);
  }
  result.alignment.nominal_from_scan = best.transform;
  result.alignment.method = method;
  result.alignment.candidates_tried = tried;
  result.alignment.fit_rms_mm = best.rms_mm;
  result.alignment.fit_inliers = best.inliers;
  result.alignment.iterations = best.iterations;
  result.alignment.rotation_deg = Eigen::AngleAxisd(best.transform.linear()).angle() * 180 / M_PI;
  result.alignment.translation_mm = best.transform.translation().norm();

  result.aligned_points.resize(scan.points.size());
  for (std::size_t i = 0; i < scan.points.size(); ++i)
    result.aligned_points[i] = (best.transform * scan.points[i].cast<double>()).cast<float>();
  result.deviation_mm = signed_deviations(result.aligned_points, nominal, options.max_distance_mm);
  result.stats = deviation_stats(result.deviation_mm, options);
  result.display_range_mm = options.tolerance_mm ? *options.tolerance_mm : nice_ceiling(result.stats.abs_p99_mm);
  result.histogram = deviation_histogram(result.deviation_mm, result.display_range_mm, options.histogram_bins);
  return result;
}

}  // namespace slscan::core
