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
#include <CGAL/Polygon_mesh_processing/self_intersections.h>
#include <CGAL/Polygon_mesh_processing/triangulate_hole.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/boost/graph/Euler_operations.h>
#include <CGAL/boost/graph/helpers.h>

#include <algorithm>
#include <map>
#include <set>
#include <vector>

#include "slscan/mesh/mesher.hpp"

namespace slscan::mesh {
namespace {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Point = Kernel::Point_3;
using Surface = CGAL::Surface_mesh<Point>;
using VertexIndex = Surface::Vertex_index;
using FaceIndex = Surface::Face_index;
using HalfedgeIndex = Surface::Halfedge_index;
namespace PMP = CGAL::Polygon_mesh_processing;

// Our triangles into a half-edge mesh, in order; the ones it cannot hold (non-manifold edge or
// vertex) are counted and left out.
Surface to_surface(const core::TriangleMesh& mesh, std::size_t& rejected) {
  Surface sm;
  std::vector<VertexIndex> v(mesh.vertices.size());
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i)
    v[i] = sm.add_vertex(Point(mesh.vertices[i].x(), mesh.vertices[i].y(), mesh.vertices[i].z()));
  rejected = 0;
  for (const auto& t : mesh.triangles)
    if (sm.add_face(v[t[0]], v[t[1]], v[t[2]]) == Surface::null_face()) ++rejected;
  return sm;
}

std::vector<HalfedgeIndex> border_cycles(const Surface& sm) {
  std::vector<HalfedgeIndex> cycles;
  PMP::extract_boundary_cycles(sm, std::back_inserter(cycles));
  return cycles;
}

double cycle_diameter(const Surface& sm, HalfedgeIndex h) {
  CGAL::Bbox_3 box;
  for (const HalfedgeIndex g : CGAL::halfedges_around_face(h, sm)) box += sm.point(sm.target(g)).bbox();
  const double dx = box.xmax() - box.xmin(), dy = box.ymax() - box.ymin(), dz = box.zmax() - box.zmin();
  return std::sqrt(dx * dx + dy * dy + dz * dz);
}

// The patch ids of faces in self-intersecting pairs (-1: an original face).
std::set<int> intersecting_patches(const Surface& sm, const Surface::Property_map<FaceIndex, int>& patch,
                                   std::size_t& pairs) {
  std::vector<std::pair<FaceIndex, FaceIndex>> found;
  PMP::self_intersections(sm, std::back_inserter(found));
  pairs = found.size();
  std::set<int> ids;
  for (const auto& [a, b] : found) {
    ids.insert(patch[a]);
    ids.insert(patch[b]);
  }
  return ids;
}

void remove_patches(Surface& sm, const Surface::Property_map<FaceIndex, int>& patch, const std::set<int>& ids) {
  std::vector<FaceIndex> doomed;
  for (const FaceIndex f : sm.faces())
    if (patch[f] >= 0 && ids.count(patch[f])) doomed.push_back(f);
  for (const FaceIndex f : doomed) CGAL::Euler::remove_face(sm.halfedge(f), sm);
}

}  // namespace

void close_holes(core::TriangleMesh& mesh, const core::MeshOptions& options, core::MeshStats& stats,
                 const core::InterruptionPoint& interrupt) {
  std::size_t rejected = 0;
  Surface sm = to_surface(mesh, rejected);
  stats.rejected_triangles = rejected;
  auto [normal, created] =
      sm.add_property_map<VertexIndex, Eigen::Vector3f>("v:slscan_normal", Eigen::Vector3f::Zero());
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i)
    normal[VertexIndex(static_cast<Surface::size_type>(i))] = mesh.normals[i];
  auto patch = sm.add_property_map<FaceIndex, int>("f:slscan_patch", -1).first;
  auto original = sm.add_property_map<VertexIndex, bool>("v:slscan_original", false).first;
  for (const VertexIndex v : sm.vertices()) original[v] = true;

  // First pass: every border cycle, faired when small, refined when large.
  int next_patch = 0;
  const auto cycles = border_cycles(sm);
  stats.holes = cycles.size();
  for (const HalfedgeIndex h : cycles) {
    core::interruption_point(interrupt);
    std::vector<FaceIndex> faces;
    std::vector<VertexIndex> added;
    const bool small = options.fill_holes_mm > 0 && cycle_diameter(sm, h) <= options.fill_holes_mm;
    if (small) {
      const auto [faired, fo, vo] =
          PMP::triangulate_refine_and_fair_hole(sm, h, std::back_inserter(faces), std::back_inserter(added));
      (void)fo;
      (void)vo;
      if (faired) ++stats.holes_faired;
    } else {
      PMP::triangulate_and_refine_hole(sm, h, std::back_inserter(faces), std::back_inserter(added));
    }
    for (const FaceIndex f : faces) patch[f] = next_patch;
    ++next_patch;
  }

  // Fills that made the mesh self-intersect: undone, retried once as plain patches, undone again
  // if they still intersect (the hole stays open).
  std::size_t pairs = 0;
  for (int attempt = 0; attempt < 2; ++attempt) {
    core::interruption_point(interrupt);
    std::set<int> bad = intersecting_patches(sm, patch, pairs);
    bad.erase(-1);
    if (bad.empty()) break;
    remove_patches(sm, patch, bad);
    if (attempt == 1) break;
    for (const HalfedgeIndex h : border_cycles(sm)) {
      std::vector<FaceIndex> faces;
      PMP::triangulate_hole(sm, h, std::back_inserter(faces));
      for (const FaceIndex f : faces) patch[f] = next_patch;
      ++next_patch;
    }
  }
  intersecting_patches(sm, patch, pairs);
  stats.self_intersections = pairs;
  stats.holes_left_open = border_cycles(sm).size();
  stats.holes_filled = stats.holes >= stats.holes_left_open ? stats.holes - stats.holes_left_open : 0;

  // Back to our arrays: vertices in the half-edge mesh's order (the original ones first, in
  // their order), normals kept for the original vertices and computed for the patches'.
  core::TriangleMesh out;
  std::vector<std::uint32_t> index(sm.number_of_vertices() + sm.number_of_removed_vertices(), UINT32_MAX);
  for (const VertexIndex v : sm.vertices()) {
    if (sm.is_isolated(v)) continue;
    index[v.idx()] = static_cast<std::uint32_t>(out.vertices.size());
    const Point& p = sm.point(v);
    out.vertices.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z()));
    if (original[v]) {
      out.normals.push_back(normal[v]);
    } else {
      const auto n = PMP::compute_vertex_normal(v, sm);
      out.normals.emplace_back(static_cast<float>(n.x()), static_cast<float>(n.y()), static_cast<float>(n.z()));
    }
  }
  for (const FaceIndex f : sm.faces()) {
    std::array<std::uint32_t, 3> t{};
    int k = 0;
    for (const VertexIndex v : CGAL::vertices_around_face(sm.halfedge(f), sm))
      t[static_cast<std::size_t>(k++)] = index[v.idx()];
    out.triangles.push_back(t);
    out.filled.push_back(patch[f] >= 0 ? 1 : 0);
    if (patch[f] >= 0) ++stats.filled_triangles;
  }
  mesh = std::move(out);
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
