// The surface mesher (docs/mesh.md): an implicit surface of the oriented points (algebraic
// spheres fitted to one side's points, Gaussian weights), sampled on a sparse OpenVDB level set
// around the points, meshed by volumeToMesh, vertices projected onto the implicit surface, and
// trimmed to where the points are (raw) or closed with CGAL's hole filling (watertight). Deterministic: the same cloud
// gives the same mesh on any number of threads.
#pragma once

#include <vector>

#include "slscan/core/interruption.hpp"
#include "slscan/core/mesh.hpp"
#include "slscan/core/point_cloud.hpp"

namespace slscan::mesh {

// Needs points with one finite outward normal each. Throws std::invalid_argument naming what is
// wrong (empty cloud, missing or non-finite normal at index i, too few points with neighbours).
// `interrupt` is called between the steps and per block of points, voxel leaves and vertices
// (and per hole in close_holes); what it throws ends the mesh (Ctrl-C: docs/faults.md).
core::MeshResult build_mesh(const core::PointCloud& cloud, const core::MeshOptions& options = {},
                            const core::InterruptionPoint& interrupt = {});

// Watertight closure of a raw mesh (consistently oriented triangles): border cycles closed with
// CGAL, filled faces flagged in mesh.filled, self-intersecting fills undone. Updates stats.
// mesh.intensity, when it has one value per vertex, is kept for the vertices given and NaN for
// the patches' new vertices.
// `crossed`, when given: the triangles (indices into the mesh given) that a patch crossed.
void close_holes(core::TriangleMesh& mesh, const core::MeshOptions& options, core::MeshStats& stats,
                 const core::InterruptionPoint& interrupt = {}, std::vector<std::size_t>* crossed = nullptr);

// Fewer triangles (options.max_triangles, options.simplify_tolerance_mm; nothing when neither
// asks for it): CGAL's edge collapse, cheapest first by Garland-Heckbert quadrics, each edge
// merged into its better end (every vertex stays one of the mesh's, with its normal and
// intensity); faces turned by more than 90 deg refused; with a tolerance, no vertex of the mesh
// given left farther than it from the simplified faces; the border between filled and measured
// faces kept. A closed mesh without self-intersections stays so or is left as it was
// (stats.simplify_skipped says why). Updates stats (filled_triangles, simplified). build_mesh
// calls it last.
void simplify_mesh(core::TriangleMesh& mesh, const core::MeshOptions& options, core::MeshStats& stats,
                   const core::InterruptionPoint& interrupt = {});

// CGAL's checks of a mesh (for reports and tests): closed 2-manifold (every triangle accepted
// by a half-edge mesh, no border), self-intersecting face pairs, outward orientation.
struct MeshCheck {
  bool valid = false;  // every triangle accepted, CGAL::is_valid_polygon_mesh
  std::size_t rejected_triangles = 0;
  bool closed = false;
  std::size_t self_intersections = 0;
  bool outward = false;  // PMP::is_outward_oriented (closed meshes only)
  double volume = 0;     // mm^3 (closed meshes only)
};
// The triangles (indices into mesh.triangles) in a self-intersecting pair, by CGAL's
// PMP::self_intersections, ascending. Triangles a half-edge mesh cannot hold are not tested.
std::vector<std::size_t> self_intersecting_triangles(const core::TriangleMesh& mesh);

MeshCheck check_mesh(const core::TriangleMesh& mesh, bool count_self_intersections = true);

}  // namespace slscan::mesh
