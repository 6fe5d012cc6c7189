// Watertight closure and mesh checks with CGAL (docs/mesh.md, "Watertight"). Our triangles are
// already consistently oriented: they go into a Surface_mesh as they are (no polygon-soup
// re-orientation, which splits non-manifold vertices and may flip pieces), and every border
// cycle is closed by CGAL's hole filling. A fill that makes the mesh self-intersect is undone
// and retried as a plain (unrefined) patch; if that fails too the hole stays open.
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Polygon_mesh_processing/border.h>
#include <CGAL/Polygon_mesh_processing/compute_normal.h>
#include <CGAL/Polygon_mesh_processing/measure.h>
#include <CGAL/Polygon_mesh_processing/orientation.h>
#include <CGAL/Polygon_mesh_processing/refine.h>
#include <CGAL/Polygon_mesh_processing/self_intersections.h>
#include <CGAL/Polygon_mesh_processing/triangulate_hole.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/boost/graph/Euler_operations.h>
#include <CGAL/boost/graph/helpers.h>
#include <CGAL/box_intersection_d.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <iterator>
#include <limits>
#include <map>
#include <set>
#include <unordered_set>
#include <vector>

#include "half_edge_mesh.hpp"
#include "slscan/mesh/mesher.hpp"

namespace slscan::mesh {

namespace detail {

Surface to_surface(const core::TriangleMesh& mesh, std::size_t& rejected, std::vector<std::size_t>* triangle_of_face,
                   const std::vector<std::uint8_t>* only) {
  const std::size_t faces =
      only == nullptr
          ? mesh.triangles.size()
          : static_cast<std::size_t>(std::count_if(only->begin(), only->end(), [](std::uint8_t b) { return b != 0; }));
  Surface sm;
  sm.reserve(static_cast<Surface::size_type>(mesh.vertices.size()), static_cast<Surface::size_type>(3 * faces / 2 + 64),
             static_cast<Surface::size_type>(faces));
  std::vector<VertexIndex> v(mesh.vertices.size());
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i)
    v[i] = sm.add_vertex(Point(mesh.vertices[i].x(), mesh.vertices[i].y(), mesh.vertices[i].z()));
  rejected = 0;
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    if (only != nullptr && (*only)[t] == 0) continue;
    const auto& tri = mesh.triangles[t];
    if (sm.add_face(v[tri[0]], v[tri[1]], v[tri[2]]) == Surface::null_face()) {
      ++rejected;
    } else if (triangle_of_face != nullptr) {
      triangle_of_face->push_back(t);
    }
  }
  return sm;
}

}  // namespace detail

namespace {

using detail::FaceIndex;
using detail::HalfedgeIndex;
using detail::Kernel;
using detail::Point;
using detail::Surface;
using detail::to_surface;
using detail::VertexIndex;
namespace PMP = CGAL::Polygon_mesh_processing;

constexpr std::size_t max_cubic_hole_edges = 150;
// Borders at least this long have their plain patch tested for crossings before it is refined:
// refined, a long border's patch has 10^4-10^5 faces, which are costly to make and to test,
// and it crosses the surface wherever the plain one does (the unseen inside of a cup).
constexpr std::size_t precheck_hole_edges = 200;
// CGAL's refinement density for holes larger than fill_holes_mm (not faired: the plain patch
// subdivided, flat where it was flat): 1 instead of CGAL's sqrt(2), triangles ~1.4x longer on
// invented surface (the unseen bottom of a part), made and tested for crossings in about half
// the time (docs/mesh.md step 7). Faired patches keep CGAL's density: their shape needs it.
constexpr double unfaired_patch_density = 1.0;
// A large hole's plain patch is left as it is when refining it would make more faces than this
// many equilateral triangles of the border's mean edge (refine makes 0.4-0.5x that): the
// teacup's unseen bottoms (4,400-5,000 mm^2) refined into 112k-213k faces that crossed the cup,
// were removed and closed plain again, 1.5 s of refining and 0.7 s of crossing tests thrown away
// (docs/mesh.md step 7). The 50 mm sphere's 1,000 mm^2 bottom (~73k: 35k faces) is refined.
constexpr double max_refined_patch_triangles = 100000;

// The part of a mesh the closure works on: the triangles within two rings of a border (or of an
// edge the half-edge mesh cannot hold: used other than once each way, or degenerate). The rest,
// "far" (~95 % of a scan's mesh), is only tested against the patches for crossings: building it
// into CGAL's half-edge mesh and back was half of the closure's time (docs/mesh.md, "Closing
// only near the holes"). Two rings keep every border vertex's whole fan in the half-edge mesh
// (what refining and fairing a patch read), so the patches are the ones the whole mesh gives.
struct Neighbourhood {
  std::vector<std::uint8_t> near;      // per triangle
  std::vector<std::uint8_t> cut;       // per vertex: of a near and a far triangle (its border in the
                                       // half-edge mesh is the cut, not a hole)
  std::vector<std::uint8_t> used_far;  // per vertex: of a far triangle
};

Neighbourhood neighbourhood_of_borders(const core::TriangleMesh& mesh) {
  const std::size_t n = mesh.vertices.size();
  // Outgoing edges per vertex (compressed rows): edge a->b is regular when it occurs once and
  // b->a once.
  std::vector<std::uint32_t> start(n + 1, 0);
  for (const auto& t : mesh.triangles)
    for (int k = 0; k < 3; ++k) ++start[t[static_cast<std::size_t>(k)] + 1];
  for (std::size_t i = 0; i < n; ++i) start[i + 1] += start[i];
  std::vector<std::uint32_t> target(start[n]);
  std::vector<std::uint32_t> fill(start.begin(), start.end() - 1);
  for (const auto& t : mesh.triangles)
    for (std::size_t k = 0; k < 3; ++k) target[fill[t[k]]++] = t[(k + 1) % 3];
  const auto count = [&](std::uint32_t from, std::uint32_t to) {
    return std::count(target.begin() + start[from], target.begin() + start[from + 1], to);
  };
  std::vector<std::uint8_t> level(n, 0);  // 2: on a border or irregular edge, 1: next to one
  for (const auto& t : mesh.triangles) {
    const bool degenerate = t[0] == t[1] || t[1] == t[2] || t[0] == t[2];
    for (std::size_t k = 0; k < 3; ++k) {
      const std::uint32_t a = t[k], b = t[(k + 1) % 3];
      if (degenerate || count(a, b) != 1 || count(b, a) != 1) level[a] = level[b] = 2;
    }
  }
  for (const auto& t : mesh.triangles)
    if (level[t[0]] == 2 || level[t[1]] == 2 || level[t[2]] == 2)
      for (const std::uint32_t v : t) level[v] = std::max<std::uint8_t>(level[v], 1);
  Neighbourhood out;
  out.near.resize(mesh.triangles.size());
  out.cut.assign(n, 0);
  out.used_far.assign(n, 0);
  std::vector<std::uint8_t> used_near(n, 0);
  for (std::size_t i = 0; i < mesh.triangles.size(); ++i) {
    const auto& t = mesh.triangles[i];
    out.near[i] = level[t[0]] != 0 || level[t[1]] != 0 || level[t[2]] != 0;
    for (const std::uint32_t v : t) (out.near[i] ? used_near : out.used_far)[v] = 1;
  }
  for (std::size_t v = 0; v < n; ++v) out.cut[v] = used_near[v] && out.used_far[v];
  return out;
}

using IndexBox = CGAL::Box_intersection_d::Box_with_info_d<double, 3, std::size_t>;

// The holes: border cycles other than the cut (whose vertices are all cut vertices, those of a
// hole none: a hole's vertices have their whole fan near).
std::vector<HalfedgeIndex> border_cycles(const Surface& sm, const std::vector<std::uint8_t>& cut) {
  std::vector<HalfedgeIndex> cycles;
  PMP::extract_boundary_cycles(sm, std::back_inserter(cycles));
  std::erase_if(cycles, [&](HalfedgeIndex h) {
    const VertexIndex v = sm.target(h);
    return v.idx() < cut.size() && cut[v.idx()] != 0;
  });
  return cycles;
}

double cycle_diameter(const Surface& sm, HalfedgeIndex h) {
  CGAL::Bbox_3 box;
  for (const HalfedgeIndex g : CGAL::halfedges_around_face(h, sm)) box += sm.point(sm.target(g)).bbox();
  const double dx = box.xmax() - box.xmin(), dy = box.ymax() - box.ymin(), dz = box.zmax() - box.zmin();
  return std::sqrt(dx * dx + dy * dy + dz * dz);
}

// The cells of a uniform grid that a set of boxes touch (cells ~4 times the boxes' mean size);
// with more than max_cells of them, every box touches (the set is not worth a grid).
class BoxGrid {
 public:
  template <class Box>
  explicit BoxGrid(const std::vector<Box>& boxes) {
    double size = 0;
    for (const Box& b : boxes)
      size += std::max(
          {b.bbox().xmax() - b.bbox().xmin(), b.bbox().ymax() - b.bbox().ymin(), b.bbox().zmax() - b.bbox().zmin()});
    cell_ = std::max(4 * size / static_cast<double>(boxes.size()), 1e-9);
    for (const Box& b : boxes) {
      if (!for_each_cell(b.bbox(), [&](std::uint64_t key) {
            cells_.insert(key);
            return cells_.size() <= max_cells;
          })) {
        cells_.clear();
        everywhere_ = true;
        return;
      }
    }
  }

  bool touches(const CGAL::Bbox_3& box) const {
    if (everywhere_) return true;
    return !for_each_cell(box, [&](std::uint64_t key) { return cells_.count(key) == 0; });
  }

 private:
  static constexpr std::size_t max_cells = std::size_t{1} << 22;

  // `visit` on the key of each cell `box` touches while it returns true; false when it stopped.
  template <class Visit>
  bool for_each_cell(const CGAL::Bbox_3& box, Visit&& visit) const {
    const auto lo = [&](double v) { return static_cast<std::int64_t>(std::floor(v / cell_)); };
    const std::int64_t x0 = lo(box.xmin()), x1 = lo(box.xmax()), y0 = lo(box.ymin()), y1 = lo(box.ymax()),
                       z0 = lo(box.zmin()), z1 = lo(box.zmax());
    if ((x1 - x0 + 1) * (y1 - y0 + 1) * (z1 - z0 + 1) > static_cast<std::int64_t>(max_cells)) return false;
    for (std::int64_t x = x0; x <= x1; ++x)
      for (std::int64_t y = y0; y <= y1; ++y)
        for (std::int64_t z = z0; z <= z1; ++z) {
          const std::uint64_t key = (static_cast<std::uint64_t>(x) & 0x1fffff) << 42 |
                                    (static_cast<std::uint64_t>(y) & 0x1fffff) << 21 |
                                    (static_cast<std::uint64_t>(z) & 0x1fffff);
          if (!visit(key)) return false;
        }
    return true;
  }

  double cell_ = 1;
  bool everywhere_ = false;
  std::unordered_set<std::uint64_t> cells_;
};

// Self-intersecting pairs: within the half-edge mesh, and between a patch's face and a far
// triangle; degenerate far triangles near a patch on their own (as CGAL reports a degenerate face).
struct Crossings {
  std::set<std::pair<FaceIndex, FaceIndex>> near;
  std::set<std::pair<FaceIndex, std::size_t>> far;
  std::set<std::size_t> degenerate_far;
  std::size_t size() const { return near.size() + far.size() + degenerate_far.size(); }
};

// The far triangles the patches are tested against, filed once per closure in a uniform grid by
// the cell of their box's low corner (cells the size of the largest far triangle's box, at most
// ~2M of them; larger triangles, from an earlier closure's patches, in a list tested always):
// scanning every far triangle on each of a closure's ~10 crossing tests took 0.15 s of the blade's.
class FarTriangles {
 public:
  FarTriangles(const core::TriangleMesh& mesh, const Neighbourhood& region) : mesh_(mesh) {
    std::vector<std::uint32_t> far;
    CGAL::Bbox_3 all;
    double total = 0;
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
      if (region.near[t]) continue;
      far.push_back(static_cast<std::uint32_t>(t));
      const CGAL::Bbox_3 b = box(t);
      all += b;
      total += std::max({b.xmax() - b.xmin(), b.ymax() - b.ymin(), b.zmax() - b.zmin()});
    }
    if (far.empty()) return;
    // Cells twice the mean triangle's box; a triangle whose box is wider than a cell is "big".
    cell_ = std::max(2 * total / static_cast<double>(far.size()), 1e-6);
    const double extent = std::max({all.xmax() - all.xmin(), all.ymax() - all.ymin(), all.zmax() - all.zmin()});
    cell_ = std::max(cell_, extent / 128);  // <= ~2M cells
    origin_ = {all.xmin(), all.ymin(), all.zmin()};
    for (int a = 0; a < 3; ++a)
      size_[static_cast<std::size_t>(a)] = static_cast<std::int64_t>(std::floor((all.max(a) - all.min(a)) / cell_)) + 1;
    std::vector<std::uint32_t> cell_of(far.size());
    start_.assign(static_cast<std::size_t>(size_[0] * size_[1] * size_[2]) + 1, 0);
    for (std::size_t i = 0; i < far.size(); ++i) {
      const CGAL::Bbox_3 b = box(far[i]);
      if (std::max({b.xmax() - b.xmin(), b.ymax() - b.ymin(), b.zmax() - b.zmin()}) > cell_) {
        big_.push_back(far[i]);
        cell_of[i] = UINT32_MAX;
        continue;
      }
      cell_of[i] = static_cast<std::uint32_t>(index(cell(b.xmin(), 0), cell(b.ymin(), 1), cell(b.zmin(), 2)));
      ++start_[cell_of[i] + 1];
    }
    for (std::size_t c = 1; c < start_.size(); ++c) start_[c] += start_[c - 1];
    filed_.resize(start_.back());
    std::vector<std::uint32_t> next(start_.begin(), start_.end() - 1);
    for (std::size_t i = 0; i < far.size(); ++i)
      if (cell_of[i] != UINT32_MAX) filed_[next[cell_of[i]]++] = far[i];
    seen_.assign(mesh.triangles.size(), 0);
  }

  CGAL::Bbox_3 box(std::size_t t) const {
    const auto& tri = mesh_.triangles[t];
    const Eigen::Vector3f& a = mesh_.vertices[tri[0]];
    const Eigen::Vector3f lo = a.cwiseMin(mesh_.vertices[tri[1]]).cwiseMin(mesh_.vertices[tri[2]]);
    const Eigen::Vector3f hi = a.cwiseMax(mesh_.vertices[tri[1]]).cwiseMax(mesh_.vertices[tri[2]]);
    return {lo.x(), lo.y(), lo.z(), hi.x(), hi.y(), hi.z()};
  }

  // The far triangles whose box may overlap one of `boxes` (every one that does), each once, as
  // boxes with the triangle's index.
  template <class Box>
  std::vector<IndexBox> near(const std::vector<Box>& boxes) {
    std::vector<IndexBox> out;
    ++stamp_;
    const auto take = [&](std::uint32_t t) {
      if (seen_[t] == stamp_) return;
      seen_[t] = stamp_;
      out.emplace_back(box(t), t);
    };
    for (const std::uint32_t t : big_) take(t);
    if (filed_.empty()) return out;
    for (const Box& b : boxes) {
      // A triangle filed at cell c has its box within [c, c + 2) cells: one cell lower reaches
      // it, two whatever the rounding of the cell numbers.
      const std::int64_t x0 = std::max<std::int64_t>(cell(b.bbox().xmin(), 0) - 2, 0),
                         y0 = std::max<std::int64_t>(cell(b.bbox().ymin(), 1) - 2, 0),
                         z0 = std::max<std::int64_t>(cell(b.bbox().zmin(), 2) - 2, 0);
      const std::int64_t x1 = std::min(cell(b.bbox().xmax(), 0), size_[0] - 1),
                         y1 = std::min(cell(b.bbox().ymax(), 1), size_[1] - 1),
                         z1 = std::min(cell(b.bbox().zmax(), 2), size_[2] - 1);
      for (std::int64_t x = x0; x <= x1; ++x)
        for (std::int64_t y = y0; y <= y1; ++y)
          for (std::int64_t z = z0; z <= z1; ++z) {
            const std::size_t c = index(x, y, z);
            for (std::uint32_t k = start_[c]; k < start_[c + 1]; ++k) take(filed_[k]);
          }
    }
    return out;
  }

  const core::TriangleMesh& mesh() const { return mesh_; }

 private:
  std::int64_t cell(double v, int axis) const {
    return static_cast<std::int64_t>(std::floor((v - origin_[static_cast<std::size_t>(axis)]) / cell_));
  }
  std::size_t index(std::int64_t x, std::int64_t y, std::int64_t z) const {
    return static_cast<std::size_t>((x * size_[1] + y) * size_[2] + z);
  }

  const core::TriangleMesh& mesh_;
  double cell_ = 1;
  std::array<double, 3> origin_{};
  std::array<std::int64_t, 3> size_{};
  std::vector<std::uint32_t> start_, filed_, big_;
  std::vector<std::uint32_t> seen_;
  std::uint32_t stamp_ = 0;
};

// The patch ids of faces in self-intersecting pairs (-1: an original face).
// Self-intersecting pairs with a face of the patches numbered `since` or later in them: only
// those patches and the faces whose bounding box overlaps one of their faces' are tested (the raw
// mesh has had its own crossings cut, docs/mesh.md step 5, the earlier patches were tested when
// they were made, and testing the whole mesh costs ~0.6 us a face on every closure). The pairs
// found are added to `found`; original faces that a patch crosses to `crossed` (face indices),
// far triangles to `crossed_far` (triangle indices).
std::set<int> intersecting_patches(const Surface& sm, const Surface::Property_map<FaceIndex, int>& patch, int since,
                                   FarTriangles& far, Crossings& found, std::vector<std::size_t>* crossed = nullptr,
                                   std::vector<std::size_t>* crossed_far = nullptr) {
  using Box = CGAL::Box_intersection_d::Box_with_info_d<double, 3, FaceIndex>;
  const auto box_of = [&](FaceIndex f) {
    CGAL::Bbox_3 b;
    for (const VertexIndex v : CGAL::vertices_around_face(sm.halfedge(f), sm)) b += sm.point(v).bbox();
    return Box(b, f);
  };
  std::vector<Box> patch_boxes, other_boxes;
  CGAL::Bbox_3 reach;  // of the patches tested: faces outside it cannot cross them
  for (const FaceIndex f : sm.faces())
    if (patch[f] >= since) {
      patch_boxes.push_back(box_of(f));
      reach += patch_boxes.back().bbox();
    }
  if (patch_boxes.empty()) return {};
  // Patches spread over the part have a reach of nearly the whole mesh (the blade's: 850k of its
  // 950k faces, 1.7 s of box intersection): the faces kept for the box test are those touching a
  // grid cell one of the patches' boxes touches.
  const BoxGrid near_patches(patch_boxes);
  for (const FaceIndex f : sm.faces())
    if (patch[f] < since) {
      const Box box = box_of(f);
      if (CGAL::do_overlap(box.bbox(), reach) && near_patches.touches(box.bbox())) other_boxes.push_back(box);
    }
  std::vector<std::uint8_t> near(sm.number_of_faces() + sm.number_of_removed_faces(), 0);
  CGAL::box_intersection_d(patch_boxes.begin(), patch_boxes.end(), other_boxes.begin(), other_boxes.end(),
                           [&](const Box&, const Box& other) { near[other.info().idx()] = 1; });
  std::vector<FaceIndex> range;
  for (const FaceIndex f : sm.faces())
    if (patch[f] >= since || near[f.idx()]) range.push_back(f);
  std::vector<std::pair<FaceIndex, FaceIndex>> pairs;
  PMP::self_intersections(range, sm, std::back_inserter(pairs));
  std::set<int> ids;
  for (const auto& [a, b] : pairs) {
    found.near.insert(std::minmax(a, b));
    ids.insert(patch[a]);
    ids.insert(patch[b]);
    if (crossed != nullptr && (patch[a] < 0) != (patch[b] < 0)) crossed->push_back(patch[a] < 0 ? a.idx() : b.idx());
  }

  // The far triangles: they share no vertex with a patch (a hole's vertices have all their
  // triangles near), so two of them cross exactly when the triangles intersect.
  std::vector<IndexBox> patch_index_boxes;
  patch_index_boxes.reserve(patch_boxes.size());
  for (const Box& b : patch_boxes) patch_index_boxes.emplace_back(b.bbox(), b.info().idx());
  std::vector<IndexBox> far_near = far.near(patch_boxes);
  std::vector<std::pair<std::size_t, std::size_t>> candidates;  // (patch face, far triangle)
  CGAL::box_intersection_d(patch_index_boxes.begin(), patch_index_boxes.end(), far_near.begin(), far_near.end(),
                           [&](const IndexBox& a, const IndexBox& b) { candidates.emplace_back(a.info(), b.info()); });
  std::sort(candidates.begin(), candidates.end());
  const auto point = [&](std::uint32_t v) {
    const Eigen::Vector3f& p = far.mesh().vertices[v];
    return Point(p.x(), p.y(), p.z());
  };
  for (const auto& [face_index, t] : candidates) {
    const auto& tri = far.mesh().triangles[t];
    const Kernel::Triangle_3 other(point(tri[0]), point(tri[1]), point(tri[2]));
    if (other.is_degenerate()) {
      found.degenerate_far.insert(t);
      ids.insert(-1);
      continue;
    }
    const FaceIndex f(static_cast<Surface::size_type>(face_index));
    const HalfedgeIndex h = sm.halfedge(f);
    const Kernel::Triangle_3 mine(sm.point(sm.target(h)), sm.point(sm.target(sm.next(h))),
                                  sm.point(sm.target(sm.prev(h))));
    if (mine.is_degenerate() || !CGAL::do_intersect(mine, other)) continue;
    found.far.insert({f, t});
    ids.insert(patch[f]);
    ids.insert(-1);
    if (crossed_far != nullptr) crossed_far->push_back(t);
  }
  return ids;
}

// CGAL's hole filling searches the 3-D Delaunay triangulation of the border first and, when
// that has no valid patch, every triangulation (cubic in the border's length: 4 s for a
// 600-edge border here). Long borders skip the cubic search: a hole it cannot fill stays open
// rather than stalling the scan. Near-planar borders try a 2-D constrained Delaunay first.
auto hole_options(const Surface& sm, HalfedgeIndex h) {
  std::size_t edges = 0;
  for (const HalfedgeIndex g : CGAL::halfedges_around_face(h, sm)) {
    (void)g;
    ++edges;
  }
  return CGAL::parameters::use_2d_constrained_delaunay_triangulation(true).do_not_use_cubic_algorithm(
      edges > max_cubic_hole_edges);
}

// The border cycle through h as its halfedges.
std::vector<HalfedgeIndex> cycle_of(const Surface& sm, HalfedgeIndex h) {
  std::vector<HalfedgeIndex> out;
  for (const HalfedgeIndex g : CGAL::halfedges_around_face(h, sm)) out.push_back(g);
  return out;
}

// Two border cycles joined by a bridge of two triangles (a, a', b), (a, b, b') between their
// closest facing edges a->a' and b->b', the single cycle left filled as one hole: the two rims
// of an unseen strip (a cup's rim seen only at its edges) are two cycles, and each alone has
// no patch that does not cover the other. Returns the patch's faces (none when it failed).
std::vector<FaceIndex> bridge_and_fill(Surface& sm, HalfedgeIndex one, HalfedgeIndex other) {
  const auto first = cycle_of(sm, one), second = cycle_of(sm, other);
  double best = std::numeric_limits<double>::max();
  HalfedgeIndex h1, h2;
  for (const HalfedgeIndex g1 : first)
    for (const HalfedgeIndex g2 : second) {
      const double cost = CGAL::squared_distance(sm.point(sm.target(g1)), sm.point(sm.source(g2))) +
                          CGAL::squared_distance(sm.point(sm.target(g2)), sm.point(sm.source(g1)));
      if (cost < best) {
        best = cost;
        h1 = g1;
        h2 = g2;
      }
    }
  if (h1 == Surface::null_halfedge()) return {};
  const VertexIndex a = sm.source(h1), a2 = sm.target(h1), b = sm.source(h2), b2 = sm.target(h2);
  if (a == b || a == b2 || a2 == b || a2 == b2) return {};
  std::vector<FaceIndex> faces;
  const std::array<VertexIndex, 3> t1{a, a2, b}, t2{a, b, b2};
  const FaceIndex f1 = CGAL::Euler::add_face(t1, sm);
  if (f1 == Surface::null_face()) return {};
  const FaceIndex f2 = CGAL::Euler::add_face(t2, sm);
  if (f2 == Surface::null_face()) {
    CGAL::Euler::remove_face(sm.halfedge(f1), sm);
    return {};
  }
  faces = {f1, f2};
  const HalfedgeIndex border = sm.halfedge(b, a2);
  if (border != Surface::null_halfedge() && sm.is_border(border))
    PMP::triangulate_hole(sm, border, std::back_inserter(faces), hole_options(sm, border));
  return faces;
}

// A fan from the border's centroid, refined: for a large hole whose border has no patch in
// the Delaunay search space (the unseen root of a blade whose border runs up a thin edge).
std::vector<FaceIndex> fan_fill(Surface& sm, HalfedgeIndex h) {
  const auto border = cycle_of(sm, h);
  Kernel::Vector_3 sum(0, 0, 0);
  for (const HalfedgeIndex g : border) sum = sum + (sm.point(sm.target(g)) - CGAL::ORIGIN);
  const Point centroid = CGAL::ORIGIN + sum / static_cast<double>(border.size());
  CGAL::Euler::fill_hole(h, sm);
  const HalfedgeIndex spoke = CGAL::Euler::add_center_vertex(h, sm);
  sm.point(sm.target(spoke)) = centroid;
  std::vector<FaceIndex> fan;
  for (const FaceIndex f : CGAL::faces_around_target(spoke, sm))
    if (f != Surface::null_face()) fan.push_back(f);
  std::vector<FaceIndex> refined;
  std::vector<VertexIndex> added;
  PMP::refine(sm, fan, std::back_inserter(refined), std::back_inserter(added));
  fan.insert(fan.end(), refined.begin(), refined.end());
  return fan;
}

void remove_patches(Surface& sm, const Surface::Property_map<FaceIndex, int>& patch, const std::set<int>& ids) {
  std::vector<FaceIndex> doomed;
  for (const FaceIndex f : sm.faces())
    if (patch[f] >= 0 && ids.count(patch[f])) doomed.push_back(f);
  for (const FaceIndex f : doomed) CGAL::Euler::remove_face(sm.halfedge(f), sm);
}

}  // namespace

void close_holes(core::TriangleMesh& mesh, const core::MeshOptions& options, core::MeshStats& stats,
                 const core::InterruptionPoint& interrupt, std::vector<std::size_t>* crossed) {
  std::size_t rejected = 0;
  // Face index -> our triangle (the half-edge mesh refuses non-manifold triangles).
  std::vector<std::size_t> triangle_of_face;
  if (crossed != nullptr) crossed->clear();
  std::vector<std::size_t> crossed_far;
  const Neighbourhood region = neighbourhood_of_borders(mesh);
  FarTriangles far(mesh, region);
  Surface sm = to_surface(mesh, rejected, &triangle_of_face, &region.near);
  const auto original_faces = static_cast<Surface::size_type>(sm.number_of_faces());
  stats.rejected_triangles = rejected;
  auto [normal, created] =
      sm.add_property_map<VertexIndex, Eigen::Vector3f>("v:slscan_normal", Eigen::Vector3f::Zero());
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i)
    normal[VertexIndex(static_cast<Surface::size_type>(i))] = mesh.normals[i];
  // Per-vertex intensity of the measured vertices carried through; the patches' get NaN (the
  // mesher fills them in from the points).
  const bool with_intensity = mesh.intensity.size() == mesh.vertices.size();
  auto intensity =
      sm.add_property_map<VertexIndex, float>("v:slscan_intensity", std::numeric_limits<float>::quiet_NaN()).first;
  if (with_intensity)
    for (std::size_t i = 0; i < mesh.vertices.size(); ++i)
      intensity[VertexIndex(static_cast<Surface::size_type>(i))] = mesh.intensity[i];
  auto patch = sm.add_property_map<FaceIndex, int>("f:slscan_patch", -1).first;
  // Faces already filled by an earlier closure (mesh.filled): kept as they are, still flagged.
  auto earlier = sm.add_property_map<FaceIndex, bool>("f:slscan_earlier", false).first;
  const bool with_filled = mesh.filled.size() == mesh.triangles.size();
  if (with_filled)
    for (std::size_t f = 0; f < triangle_of_face.size(); ++f)
      earlier[FaceIndex(static_cast<Surface::size_type>(f))] = mesh.filled[triangle_of_face[f]] != 0;
  auto original = sm.add_property_map<VertexIndex, bool>("v:slscan_original", false).first;
  for (const VertexIndex v : sm.vertices()) original[v] = true;

  // First pass: every border cycle, faired when small, refined when large.
  int next_patch = 0;
  const auto cycles = border_cycles(sm, region.cut);
  stats.holes = cycles.size();
  stats.filled_triangles = 0;
  stats.holes_faired = 0;
  Crossings prechecked;  // of patches removed at once
  for (const HalfedgeIndex h : cycles) {
    core::interruption_point(interrupt);
    std::vector<FaceIndex> faces;
    std::vector<VertexIndex> added;
    const bool small = options.fill_holes_mm > 0 && cycle_diameter(sm, h) <= options.fill_holes_mm;
    const auto fill_options = hole_options(sm, h);
    const auto border = cycle_of(sm, h);
    double border_edge = 0;  // the border's mean edge length
    for (const HalfedgeIndex g : border) border_edge += PMP::edge_length(g, sm);
    border_edge /= static_cast<double>(border.size());
    if (border.size() >= precheck_hole_edges) {
      // What triangulate_(refine_and_fair_)hole do, with the plain patch tested in between: one
      // that crosses is removed at once and the hole left to the retries below, as a refined
      // one that crossed would have been.
      PMP::triangulate_hole(sm, h, std::back_inserter(faces), fill_options);
      for (const FaceIndex f : faces) patch[f] = next_patch;
      if (intersecting_patches(sm, patch, next_patch, far, prechecked, crossed, &crossed_far).count(next_patch) != 0) {
        remove_patches(sm, patch, {next_patch});
        ++stats.holes_crossing_unrefined;
        ++next_patch;
        continue;
      }
      const std::vector<FaceIndex> plain = faces;
      double area = 0;
      for (const FaceIndex f : plain) area += PMP::face_area(f, sm);
      if (small) {
        PMP::refine(sm, plain, std::back_inserter(faces), std::back_inserter(added), fill_options);
        if (PMP::fair(sm, added, fill_options)) ++stats.holes_faired;
      } else if (area / (std::sqrt(3.0) / 4 * border_edge * border_edge) > max_refined_patch_triangles) {
        ++stats.holes_left_plain;
      } else {
        PMP::refine(sm, plain, std::back_inserter(faces), std::back_inserter(added),
                    fill_options.density_control_factor(unfaired_patch_density));
      }
    } else if (small) {
      const auto [faired, fo, vo] = PMP::triangulate_refine_and_fair_hole(sm, h, std::back_inserter(faces),
                                                                          std::back_inserter(added), fill_options);
      (void)fo;
      (void)vo;
      if (faired) ++stats.holes_faired;
    } else {
      PMP::triangulate_and_refine_hole(sm, h, std::back_inserter(faces), std::back_inserter(added),
                                       fill_options.density_control_factor(unfaired_patch_density));
    }
    for (const FaceIndex f : faces) patch[f] = next_patch;
    ++next_patch;
  }

  // Fills that made the mesh self-intersect: undone, retried once as plain patches, undone again
  // if they still intersect (the hole stays open).
  // Every crossing pair found; those of removed faces are dropped as the patches go.
  Crossings pairs;
  const auto forget_removed = [&] {
    std::erase_if(pairs.near, [&](const auto& p) { return sm.is_removed(p.first) || sm.is_removed(p.second); });
    std::erase_if(pairs.far, [&](const auto& p) { return sm.is_removed(p.first); });
  };
  int checked = 0;  // patches below this id have been tested
  for (int attempt = 0; attempt < 2; ++attempt) {
    core::interruption_point(interrupt);
    std::set<int> bad = intersecting_patches(sm, patch, checked, far, pairs, crossed, &crossed_far);
    checked = next_patch;
    bad.erase(-1);
    if (bad.empty()) break;
    remove_patches(sm, patch, bad);
    forget_removed();
    if (attempt == 1) break;
    for (const HalfedgeIndex h : border_cycles(sm, region.cut)) {
      std::vector<FaceIndex> faces;
      PMP::triangulate_hole(sm, h, std::back_inserter(faces), hole_options(sm, h));
      for (const FaceIndex f : faces) patch[f] = next_patch;
      ++next_patch;
    }
  }
  // Last resorts for the holes still open: bridged to the nearest other open border when that
  // is close (nearer than a quarter of either's diameter), else fanned; undone if they cross.
  for (int resort = 0; resort < 2; ++resort) {
    const auto open = border_cycles(sm, region.cut);
    if (open.empty()) break;
    std::set<int> tried;
    std::vector<std::uint8_t> used(open.size(), 0);
    for (std::size_t i = 0; i < open.size(); ++i) {
      if (used[i]) continue;
      core::interruption_point(interrupt);
      std::vector<FaceIndex> faces;
      if (resort == 0) {
        const double diameter = cycle_diameter(sm, open[i]);
        std::size_t partner = open.size();
        double nearest = std::numeric_limits<double>::max();
        for (std::size_t j = i + 1; j < open.size(); ++j) {
          if (used[j]) continue;
          const double limit = 0.25 * std::min(diameter, cycle_diameter(sm, open[j]));
          for (const HalfedgeIndex g1 : cycle_of(sm, open[i]))
            for (const HalfedgeIndex g2 : cycle_of(sm, open[j])) {
              const double d = std::sqrt(CGAL::squared_distance(sm.point(sm.target(g1)), sm.point(sm.target(g2))));
              if (d < limit && d < nearest) {
                nearest = d;
                partner = j;
              }
            }
        }
        if (partner == open.size()) continue;
        used[i] = used[partner] = 1;
        faces = bridge_and_fill(sm, open[i], open[partner]);
      } else {
        used[i] = 1;
        faces = fan_fill(sm, open[i]);
      }
      for (const FaceIndex f : faces) patch[f] = next_patch;
      tried.insert(next_patch++);
    }
    std::set<int> bad = intersecting_patches(sm, patch, checked, far, pairs, crossed, &crossed_far);
    checked = next_patch;
    std::set<int> undo;
    std::set_intersection(bad.begin(), bad.end(), tried.begin(), tried.end(), std::inserter(undo, undo.end()));
    remove_patches(sm, patch, undo);
    forget_removed();
  }
  stats.self_intersections = pairs.size();
  if (crossed != nullptr) {
    for (auto& f : *crossed) f = triangle_of_face[f];
    crossed->insert(crossed->end(), crossed_far.begin(), crossed_far.end());
    std::sort(crossed->begin(), crossed->end());
    crossed->erase(std::unique(crossed->begin(), crossed->end()), crossed->end());
  }
  stats.holes_left_open = border_cycles(sm, region.cut).size();
  stats.holes_filled = stats.holes >= stats.holes_left_open ? stats.holes - stats.holes_left_open : 0;

  // Back to our arrays: vertices in the half-edge mesh's order (the original ones first, in
  // their order, the patches' after them), normals kept for the original vertices and computed
  // for the patches'; triangles in their order, the far ones where they were, the patches' last.
  core::TriangleMesh out;
  std::vector<std::uint32_t> index(sm.number_of_vertices() + sm.number_of_removed_vertices(), UINT32_MAX);
  for (const VertexIndex v : sm.vertices()) {
    if (sm.is_isolated(v) && !(v.idx() < region.used_far.size() && region.used_far[v.idx()])) continue;
    index[v.idx()] = static_cast<std::uint32_t>(out.vertices.size());
    const Point& p = sm.point(v);
    out.vertices.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z()));
    if (with_intensity) out.intensity.push_back(intensity[v]);
    if (original[v]) {
      out.normals.push_back(normal[v]);
    } else {
      const auto n = PMP::compute_vertex_normal(v, sm);
      out.normals.emplace_back(static_cast<float>(n.x()), static_cast<float>(n.y()), static_cast<float>(n.z()));
    }
  }
  const auto add_face = [&](FaceIndex f) {
    std::array<std::uint32_t, 3> t{};
    int k = 0;
    for (const VertexIndex v : CGAL::vertices_around_face(sm.halfedge(f), sm))
      t[static_cast<std::size_t>(k++)] = index[v.idx()];
    out.triangles.push_back(t);
    const bool filled = patch[f] >= 0 || earlier[f];
    out.filled.push_back(filled ? 1 : 0);
    if (filled) ++stats.filled_triangles;
  };
  std::size_t next_face = 0;  // of the original faces, in their triangles' order
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    if (region.near[t]) {
      if (next_face < triangle_of_face.size() && triangle_of_face[next_face] == t)
        add_face(FaceIndex(static_cast<Surface::size_type>(next_face++)));
      continue;
    }
    const auto& tri = mesh.triangles[t];
    out.triangles.push_back({index[tri[0]], index[tri[1]], index[tri[2]]});
    const bool filled = with_filled && mesh.filled[t] != 0;
    out.filled.push_back(filled ? 1 : 0);
    if (filled) ++stats.filled_triangles;
  }
  for (const FaceIndex f : sm.faces())
    if (f.idx() >= original_faces) add_face(f);
  mesh = std::move(out);
}

std::vector<std::size_t> self_intersecting_triangles(const core::TriangleMesh& mesh) {
  Surface sm;
  std::vector<VertexIndex> v(mesh.vertices.size());
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i)
    v[i] = sm.add_vertex(Point(mesh.vertices[i].x(), mesh.vertices[i].y(), mesh.vertices[i].z()));
  std::vector<std::size_t> triangle_of_face;
  triangle_of_face.reserve(mesh.triangles.size());
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    const auto& tri = mesh.triangles[t];
    if (sm.add_face(v[tri[0]], v[tri[1]], v[tri[2]]) != Surface::null_face()) triangle_of_face.push_back(t);
  }
  std::vector<std::pair<FaceIndex, FaceIndex>> pairs;
  PMP::self_intersections(sm, std::back_inserter(pairs));
  std::vector<std::size_t> out;
  out.reserve(2 * pairs.size());
  for (const auto& [a, b] : pairs) {
    out.push_back(triangle_of_face[a.idx()]);
    out.push_back(triangle_of_face[b.idx()]);
  }
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

MeshCheck check_mesh(const core::TriangleMesh& mesh, bool count_self_intersections) {
  MeshCheck check;
  Surface sm = to_surface(mesh, check.rejected_triangles);
  check.valid = check.rejected_triangles == 0 && CGAL::is_valid_polygon_mesh(sm);
  check.closed = check.valid && !sm.is_empty() && CGAL::is_closed(sm);
  if (count_self_intersections) {
    std::vector<std::pair<FaceIndex, FaceIndex>> pairs;
    PMP::self_intersections(sm, std::back_inserter(pairs));
    check.self_intersections = pairs.size();
  }
  if (check.closed) {
    check.outward = PMP::is_outward_oriented(sm);
    check.volume = PMP::volume(sm);
  }
  return check;
}

}  // namespace slscan::mesh
