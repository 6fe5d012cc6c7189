// Simplification of a finished mesh by CGAL's edge collapse (docs/mesh.md, "Fewer triangles"):
// Garland-Heckbert's plane quadrics choose the cheapest collapse, and the merged vertex is the
// edge's end where the quadric's error is lower: every vertex stays one of the full mesh's, on
// the fitted surface, with its own normal and intensity (the simplified mesh differs from the
// full one by its chords only). A collapse that would turn a face by more than 90 deg is refused (CGAL's bounded normal
// change) and, with a tolerance, one that would leave a vertex of the full mesh farther than the
// tolerance from the new faces around the merged vertex (each vertex remembers the full mesh's
// vertices merged into it, which are dense enough on the surface that a face near all of them
// is near the surface). Flat regions lose their triangles first, curved ones and edges keep
// theirs. Edges between filled and measured faces are not collapsed, so the flagged invented
// surface keeps its border.
// GCC 12 at -O2 takes the default-constructed Eigen 4x4 quadric CGAL's Garland-Heckbert policy
// copies into its vertex property map for uninitialised (Eigen leaves a fixed-size matrix's
// storage so; CGAL assigns every vertex's quadric before reading it).
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include <CGAL/Polygon_mesh_processing/self_intersections.h>
#include <CGAL/Surface_mesh_simplification/Edge_collapse_visitor_base.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/Constrained_placement.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/GarlandHeckbert_plane_policies.h>
#include <CGAL/Surface_mesh_simplification/edge_collapse.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <string>
#include <vector>

#include "half_edge_mesh.hpp"
#include "slscan/mesh/mesher.hpp"

namespace slscan::mesh {
namespace {

using detail::FaceIndex;
using detail::HalfedgeIndex;
using detail::Kernel;
using detail::Point;
using detail::Surface;
using detail::VertexIndex;
namespace PMP = CGAL::Polygon_mesh_processing;
namespace SMS = CGAL::Surface_mesh_simplification;

// A collapse may turn a face of the merged vertex's star by at most this much: CGAL's bounded
// normal change (90 deg) let thin parts fold (the small rig's blade: 1.7 % of faces flipped,
// every watertight mesh self-intersecting); measured in docs/mesh.md.
constexpr double max_turn_deg = 20;
// Simplifications started before giving up (each after freezing where the last one crossed).
constexpr int max_attempts = 4;

// Stops at the target face count (0: never; the filters then end it, when no collapse is left
// that keeps the surface within its tolerance).
struct FaceCountStop {
  std::size_t max_faces = 0;
  template <typename FT, typename Profile>
  bool operator()(const FT& /*cost*/, const Profile& profile, std::size_t /*initial_edges*/,
                  std::size_t /*current_edges*/) const {
    return max_faces > 0 && profile.surface_mesh().number_of_faces() <= max_faces;
  }
};

// What the collapses carry along: the full mesh's vertex each vertex is (its position, normal
// and intensity), and the full mesh's vertices merged into it, as a linked list (head and tail
// by vertex index, next by the full mesh's vertex) so that a collapse joins two lists in O(1).
struct Merges {
  static constexpr std::uint32_t none = UINT32_MAX;
  Surface::Property_map<VertexIndex, std::uint32_t> original;
  std::vector<std::uint32_t> head, tail, next;
  std::vector<Eigen::Vector3f> positions;  // the full mesh's vertices

  explicit Merges(const std::vector<Eigen::Vector3f>& vertices) : positions(vertices) {
    const std::size_t n = vertices.size();
    head.resize(n);
    tail.resize(n);
    next.assign(n, none);
    for (std::size_t i = 0; i < n; ++i) head[i] = tail[i] = static_cast<std::uint32_t>(i);
  }
  template <class F>
  bool all_of(VertexIndex v, F&& f) const {
    for (std::uint32_t o = head[v.idx()]; o != none; o = next[o])
      if (!f(o)) return false;
    return true;
  }
  template <class F>
  void for_each(VertexIndex v, F&& f) const {
    for (std::uint32_t o = head[v.idx()]; o != none; o = next[o]) f(o);
  }
  void join(VertexIndex into, VertexIndex from) {
    next[tail[into.idx()]] = head[from.idx()];
    tail[into.idx()] = tail[from.idx()];
    head[from.idx()] = tail[from.idx()] = none;
  }
};

// The edge's end where the Garland-Heckbert quadric of the merged vertex is lower (the first on
// a tie): no new positions.
template <class Cost>
struct EndpointPlacement {
  Cost cost;
  template <typename Profile>
  boost::optional<typename Profile::Point> operator()(const Profile& profile) const {
    const auto c0 = cost(profile, boost::optional<typename Profile::Point>(profile.p0()));
    const auto c1 = cost(profile, boost::optional<typename Profile::Point>(profile.p1()));
    if (!c0 && !c1) return boost::none;
    if (!c1 || (c0 && *c0 <= *c1)) return profile.p0();
    return profile.p1();
  }
};

using Vec = Eigen::Vector3d;

Vec vec(const Point& p) { return {p.x(), p.y(), p.z()}; }

// Squared distance from p to the triangle abc (Ericson, Real-Time Collision Detection, 5.1.5).
double squared_distance_to_triangle(const Vec& p, const Vec& a, const Vec& b, const Vec& c) {
  const Vec ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return ap.squaredNorm();
  const Vec bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return bp.squaredNorm();
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return (p - (a + ab * (d1 / (d1 - d3)))).squaredNorm();
  const Vec cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return cp.squaredNorm();
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return (p - (a + ac * (d2 / (d2 - d6)))).squaredNorm();
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
    return (p - (b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))))).squaredNorm();
  const double denom = 1 / (va + vb + vc);
  return (p - (a + ab * (vb * denom) + ac * (vc * denom))).squaredNorm();
}

// Refuses a collapse that turns a face of the star around the merged vertex by more than
// max_turn_deg (a fold: where two sheets are close, a face turned far crosses the other one)
// and, with a tolerance, one that would leave one of the full mesh's vertices merged into the
// edge's two vertices farther than the tolerance from every new face of the star. The two faces
// that vanish with the edge are left out, as in CGAL's own filters.
struct CollapseFilter {
  double min_cosine = 1;
  double tolerance2 = 0;
  const Merges* merges = nullptr;

  template <typename Profile>
  boost::optional<typename Profile::Point> operator()(const Profile& profile,
                                                      boost::optional<typename Profile::Point> op) const {
    if (!op) return op;
    const auto& vpm = profile.vertex_point_map();
    const auto& triangles = profile.triangles();
    auto first = triangles.begin();
    if (profile.left_face_exists()) ++first;
    if (profile.right_face_exists()) ++first;
    const Vec placed = vec(*op);
    thread_local std::vector<std::array<Vec, 3>> star;
    star.clear();
    for (auto it = first; it != triangles.end(); ++it) {
      // The triangle's second vertex is the one placed (CGAL's Edge_profile).
      const Vec a = vec(get(vpm, it->v0)), before = vec(get(vpm, it->v1)), c = vec(get(vpm, it->v2));
      const Vec n1 = (before - a).cross(c - a), n2 = (placed - a).cross(c - a);
      const double n1n = n1.norm(), n2n = n2.norm();
      if (!(n2n > 0) || n1.dot(n2) < min_cosine * n1n * n2n) return boost::none;
      star.push_back({a, placed, c});
    }
    if (tolerance2 <= 0 || star.empty()) return op;
    const auto near = [&](std::uint32_t o) {
      const Vec q = merges->positions[o].cast<double>();
      for (const auto& t : star)
        if (squared_distance_to_triangle(q, t[0], t[1], t[2]) <= tolerance2) return true;
      return false;
    };
    if (!merges->all_of(profile.v0(), near) || !merges->all_of(profile.v1(), near)) return boost::none;
    return op;
  }
};

// Keeps Merges up to date and lets Ctrl-C end a long simplification (docs/faults.md): the
// interruption point every few thousand edges taken from the queue.
struct MergeVisitor : SMS::Edge_collapse_visitor_base<Surface> {
  const core::InterruptionPoint* interrupt = nullptr;
  Merges* merges = nullptr;
  std::size_t selected = 0;
  VertexIndex v0, v1;
  std::uint32_t original0 = 0, original1 = 0;
  Point p0;

  template <typename Profile, typename Cost>
  void OnSelected(const Profile& /*profile*/, const Cost& /*cost*/, std::size_t /*initial*/, std::size_t /*current*/) {
    if ((++selected & 4095u) == 0) core::interruption_point(*interrupt);
  }
  template <typename Profile, typename Placement>
  void OnCollapsing(const Profile& profile, const Placement& /*placement*/) {
    v0 = profile.v0();
    v1 = profile.v1();
    p0 = profile.p0();
    original0 = merges->original[v0];
    original1 = merges->original[v1];
  }
  // The vertex CGAL keeps may be either end, moved to the placement: it is the full mesh's
  // vertex whose position it took.
  template <typename Profile>
  void OnCollapsed(const Profile& profile, const VertexIndex& kept) {
    const bool at_first = profile.surface_mesh().point(kept) == p0;
    merges->original[kept] = at_first ? original0 : original1;
    merges->join(kept, kept == v0 ? v1 : v0);
  }
};

template <typename Filter>
void collapse(Surface& sm, const core::MeshOptions& options, const Filter& filter,
              const Surface::Property_map<Surface::Edge_index, bool>& constrained, Merges& merges,
              const core::InterruptionPoint& interrupt) {
  SMS::GarlandHeckbert_plane_policies<Surface, Kernel> quadrics(sm);
  using Cost = std::decay_t<decltype(quadrics.get_cost())>;
  const SMS::Constrained_placement<EndpointPlacement<Cost>, Surface::Property_map<Surface::Edge_index, bool>> placement(
      constrained, EndpointPlacement<Cost>{quadrics.get_cost()});
  MergeVisitor visitor;
  visitor.interrupt = &interrupt;
  visitor.merges = &merges;
  SMS::edge_collapse(sm, FaceCountStop{options.max_triangles},
                     CGAL::parameters::get_cost(quadrics.get_cost())
                         .get_placement(placement)
                         .filter(filter)
                         .edge_is_constrained_map(constrained)
                         .visitor(visitor));
}

// The simplified half-edge mesh back into our arrays: the surviving vertices in their order,
// each the full mesh's vertex it is (its position, normal and intensity).
void write_back(const Surface& sm, const Merges& merges, const Surface::Property_map<FaceIndex, std::uint8_t>& filled,
                bool with_filled, core::TriangleMesh& mesh, core::MeshStats& stats) {
  core::TriangleMesh out;
  const std::size_t vertex_count = mesh.vertices.size();
  const bool with_intensity = mesh.intensity.size() == vertex_count;
  const auto& original = merges.original;
  std::vector<std::uint32_t> index(sm.number_of_vertices() + sm.number_of_removed_vertices(), UINT32_MAX);
  for (const VertexIndex v : sm.vertices()) {
    if (sm.is_isolated(v)) continue;
    index[v.idx()] = static_cast<std::uint32_t>(out.vertices.size());
    const std::uint32_t from = original[v];
    const Point& p = sm.point(v);
    const Eigen::Vector3f& q = mesh.vertices[from];
    if (p != Point(q.x(), q.y(), q.z()))
      throw std::logic_error("simplify_mesh: vertex " + std::to_string(v.idx()) + " is not the full mesh's vertex " +
                             std::to_string(from));
    out.vertices.push_back(q);
    if (mesh.normals.size() == vertex_count) out.normals.push_back(mesh.normals[from]);
    if (with_intensity) out.intensity.push_back(mesh.intensity[from]);
  }
  stats.filled_triangles = 0;
  for (const FaceIndex f : sm.faces()) {
    std::array<std::uint32_t, 3> t{};
    std::size_t k = 0;
    for (const VertexIndex v : CGAL::vertices_around_face(sm.halfedge(f), sm)) t[k++] = index[v.idx()];
    out.triangles.push_back(t);
    out.filled.push_back(filled[f]);
    stats.filled_triangles += filled[f];
  }
  if (!with_filled) out.filled.clear();
  mesh = std::move(out);
  stats.simplified = true;
}

}  // namespace

void simplify_mesh(core::TriangleMesh& mesh, const core::MeshOptions& options, core::MeshStats& stats,
                   const core::InterruptionPoint& interrupt) {
  stats.triangles_before_simplify = mesh.triangles.size();
  const bool to_count = options.max_triangles > 0 && mesh.triangles.size() > options.max_triangles;
  if (!to_count && !(options.simplify_tolerance_mm > 0)) return;
  const std::size_t vertex_count = mesh.vertices.size();
  const bool with_filled = mesh.filled.size() == mesh.triangles.size();
  // Where a simplification crossed the surface, the full mesh's vertices merged into the crossing
  // faces are frozen (their edges not collapsed) and it starts again from the full mesh.
  std::vector<std::uint8_t> frozen(vertex_count, 0);
  std::size_t input_pairs = stats.closed ? stats.self_intersections : SIZE_MAX;  // SIZE_MAX: not known
  for (int attempt = 0;; ++attempt) {
    std::size_t rejected = 0;
    Surface sm = detail::to_surface(mesh, rejected);
    if (rejected > 0) {
      // The half-edge mesh would lose these triangles: the mesh stays as it is, and says why.
      stats.simplify_skipped = std::to_string(rejected) + " non-manifold triangles a half-edge mesh cannot hold";
      return;
    }
    Merges merges(mesh.vertices);
    merges.original = sm.add_property_map<VertexIndex, std::uint32_t>("v:slscan_original", UINT32_MAX).first;
    for (std::size_t i = 0; i < vertex_count; ++i)
      merges.original[VertexIndex(static_cast<Surface::size_type>(i))] = static_cast<std::uint32_t>(i);
    auto filled = sm.add_property_map<FaceIndex, std::uint8_t>("f:slscan_filled", 0).first;
    if (with_filled)
      for (const FaceIndex f : sm.faces()) filled[f] = mesh.filled[f.idx()];
    auto constrained = sm.add_property_map<Surface::Edge_index, bool>("e:slscan_constrained", false).first;
    for (const auto e : sm.edges()) {
      const HalfedgeIndex h = sm.halfedge(e), o = sm.opposite(h);
      bool keep = frozen[sm.source(h).idx()] || frozen[sm.target(h).idx()];
      if (with_filled && !sm.is_border(h) && !sm.is_border(o)) keep = keep || filled[sm.face(h)] != filled[sm.face(o)];
      constrained[e] = keep;
    }
    const CollapseFilter filter{std::cos(max_turn_deg * std::numbers::pi / 180),
                                options.simplify_tolerance_mm * options.simplify_tolerance_mm, &merges};
    collapse(sm, options, filter, constrained, merges, interrupt);
    core::interruption_point(interrupt);
    std::vector<std::pair<FaceIndex, FaceIndex>> pairs;
    PMP::self_intersections(sm, std::back_inserter(pairs));
    if (!pairs.empty() && input_pairs == SIZE_MAX) input_pairs = self_intersecting_triangles(mesh).empty() ? 0 : 1;
    if (pairs.empty() || (input_pairs > 0 && input_pairs != SIZE_MAX)) {
      // (A mesh that crossed itself before may still: only a clean one is kept clean.)
      write_back(sm, merges, filled, with_filled, mesh, stats);
      stats.simplify_attempts = static_cast<std::size_t>(attempt) + 1;
      return;
    }
    if (attempt + 1 == max_attempts) {
      stats.simplify_skipped = "the simplified mesh intersected itself (" + std::to_string(pairs.size()) +
                               " face pairs after " + std::to_string(max_attempts) + " attempts)";
      return;
    }
    for (const auto& [f, g] : pairs)
      for (const FaceIndex face : {f, g})
        for (const VertexIndex v : CGAL::vertices_around_face(sm.halfedge(face), sm))
          for (const VertexIndex w : CGAL::vertices_around_target(sm.halfedge(v), sm)) {
            merges.for_each(w, [&](std::uint32_t o) { frozen[o] = 1; });
          }
  }
}

}  // namespace slscan::mesh
