// Surface reconstruction (pipeline stage 6): the mesh type, the mesher's options and results, and
// a topology check. The mesher itself is slscan_mesh (host/mesh, docs/mesh.md), kept out of core
// so that slscan_core does not link OpenVDB or CGAL.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "slscan/core/point_cloud.hpp"

namespace slscan::core {

struct TriangleMesh {
  std::vector<Eigen::Vector3f> vertices;
  std::vector<Eigen::Vector3f> normals;                 // per vertex, unit, outward
  std::vector<std::array<std::uint32_t, 3>> triangles;  // counter-clockwise seen from outside
  std::vector<std::uint8_t> filled;                     // per triangle, 1 = invented to close a hole (empty: none)
  // Per vertex: the albedo of the points around it (PointCloud::intensity, Gaussian-weighted over
  // the mesher's kernel; the nearest point's beyond it, e.g. on a filled patch). Empty: the cloud
  // had none.
  std::vector<float> intensity;
};

// The mesher (slscan_mesh, host/mesh: an OpenVDB level set of the points' implicit surface,
// docs/mesh.md). Plain options here so that core's ReconstructionOptions can hold them without
// linking OpenVDB or CGAL.
enum class MeshMode : std::uint8_t {
  raw,         // only where points are: the level set trimmed to the data, holes left open
  watertight,  // raw's surface with every hole closed (filled faces flagged): closed 2-manifold
};
const char* mesh_mode_name(MeshMode mode);
bool parse_mesh_mode(const std::string& name, MeshMode& mode);

struct MeshOptions {
  MeshMode mode = MeshMode::watertight;
  double cell_mm = 0;              // > 0: the level set's voxel; 0: cell_spacing_factor x point spacing
  double cell_spacing_factor = 1;  // cell from the median nearest-neighbour spacing
  // Floor of the cell taken from the spacing (not of an explicit cell_mm): at full resolution the
  // points are 0.074 mm apart and a cell that fine gives 5 M triangles in over a minute and 1 GB
  // more memory, for detail below the scanner's lateral resolution (docs/mesh.md).
  double min_cell_mm = 0.2;
  double kernel_factor = 2;          // Gaussian sigma = kernel_factor x max(cell, spacing), support 3 sigma
  int min_neighbors = 4;             // points with fewer neighbours within the support are left out
  double adaptivity = 0;             // OpenVDB volumeToMesh adaptivity (0..1; 0 = uniform)
  double trim_factor = 1.5;          // triangles with a vertex farther than this x max(cell, spacing) from
                                     // every point are not surface (the level set's own closure)
  double min_piece_fraction = 0.01;  // pieces with fewer triangles than this fraction of the largest are dropped
  // Watertight: holes whose border fits in this diameter (mm) are closed with a smooth (faired)
  // patch; larger ones with a minimal-area refined patch. 0: no fairing.
  double fill_holes_mm = 10;
  // Fewer triangles (docs/mesh.md, "Fewer triangles"): at most this many (0: as many as the cell
  // gives), and/or as few as keep every vertex of the full mesh within this distance (mm) of the
  // simplified faces (0: no bound; with max_triangles 0, collapse until the bound stops it:
  // coarse where flat, fine where curved).
  std::size_t max_triangles = 0;
  double simplify_tolerance_mm = 0;

  void check() const;  // throws std::invalid_argument naming the field
};

// The mesh files a run writes (app/outputs.cpp), all in mm. Here, beside the mesher's options,
// so that the config's mesh section (ReconstructionOptions) holds them and report.json records
// them. Default: what a run wrote before OBJ and 3MF existed, so a default run is no slower.
struct MeshFormats {
  bool ply = true, stl = true, obj = false, three_mf = false;
  bool any() const { return ply || stl || obj || three_mf; }
  bool operator==(const MeshFormats&) const = default;
};
// "ply,stl,obj,3mf" order, the chosen ones.
std::string mesh_formats_text(const MeshFormats& formats);
// A comma-separated list of ply, stl, obj, 3mf (each at most once, case as written, no spaces):
// "" when parsed, else why not (naming the word).
std::string parse_mesh_formats(const std::string& list, MeshFormats& formats);

struct MeshStats {
  double spacing_mm = 0;  // median nearest-neighbour distance of the points
  std::size_t points_used = 0, isolated_points = 0;
  std::size_t voxels = 0, leaves = 0;
  std::size_t dropped_piece_triangles = 0;  // in pieces below min_piece_fraction
  std::size_t crossing_triangles = 0;       // in self-intersecting pairs of the level set's mesh, cut
  std::size_t pinholes_filled = 0;          // holes a few cells across amid the points, fanned (flagged filled)
  std::size_t pinholes_crossing = 0;        // pinholes whose fan crossed the surface, left to watertight
  std::size_t rejected_triangles = 0;       // watertight: non-manifold triangles the half-edge mesh refused
  std::size_t holes = 0, holes_filled = 0, holes_faired = 0, holes_left_open = 0;
  std::size_t filled_triangles = 0;
  // watertight: long borders whose plain patch crossed the surface, removed before refinement
  // (over every closure)
  std::size_t holes_crossing_unrefined = 0;
  // watertight: holes larger than fill_holes_mm whose plain patch was too large to refine, kept
  // plain (over every closure)
  std::size_t holes_left_plain = 0;
  std::size_t crossed_faces_removed = 0;  // watertight: measured faces a fill crossed, replaced by the refill
  std::size_t self_intersections = 0;     // watertight: face pairs left (0 unless a hole stayed open)
  bool closed = false;
  // The fit took one side's points only (thin edges kept); false: watertight fell back to the
  // fit over both sides because a hole stayed open with one side's (docs/mesh.md).
  bool sides_separated = true;
  // Simplification (max_triangles / simplify_tolerance_mm): the count before it, whether it
  // changed the mesh, and why not when it was asked for and did not ("" otherwise).
  std::size_t triangles_before_simplify = 0;
  bool simplified = false;
  std::size_t simplify_attempts = 0;  // each after freezing where the last one crossed the surface
  std::string simplify_skipped;
  double mesh_ms = 0;  // meshing alone (wall)
  // Wall time of each step, in order (docs/mesh.md names them); a step run twice (watertight's
  // fall back to the fit over both sides) is summed.
  std::vector<std::pair<std::string, double>> step_ms;
  void add_step_ms(const std::string& step, double ms);
};

struct MeshResult {
  TriangleMesh mesh;
  double cell_mm = 0;                 // the level set's voxel
  std::size_t trimmed_triangles = 0;  // farther than trim_factor from every point (raw's trimming)
  MeshMode mode = MeshMode::raw;
  MeshStats stats;  // the level-set mesher's (slscan_mesh)
};

struct MeshTopology {
  std::size_t edges = 0;
  std::size_t boundary_edges = 0;      // used by one triangle
  std::size_t non_manifold_edges = 0;  // used by more than two
  std::size_t inconsistent_edges = 0;  // two triangles traversing the edge the same way
  bool closed() const { return edges > 0 && boundary_edges == 0 && non_manifold_edges == 0; }
};
MeshTopology mesh_topology(const TriangleMesh& mesh);

}  // namespace slscan::core
