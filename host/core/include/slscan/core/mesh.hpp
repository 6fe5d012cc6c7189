// Surface reconstruction (pipeline stage 6): screened Poisson on a regular grid. The oriented
// points define a vector field (the smoothed gradient of the object's indicator function); the
// indicator chi solves the screened Poisson equation, chi is pulled toward the iso value at the
// samples, and its iso-surface is extracted by marching tetrahedra on the Freudenthal split of
// the grid, which gives a closed, consistently oriented mesh (no ambiguous cases to resolve).
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <vector>

#include "slscan/core/point_cloud.hpp"

namespace slscan::core {

struct TriangleMesh {
  std::vector<Eigen::Vector3f> vertices;
  std::vector<Eigen::Vector3f> normals;                 // per vertex, unit, outward
  std::vector<std::array<std::uint32_t, 3>> triangles;  // counter-clockwise seen from outside
};

struct PoissonOptions {
  int resolution = 128;           // grid cells along the longest side of the padded bounds
  double padding_ratio = 0.1;     // empty margin around the points, as a fraction of their extent
  double screening_weight = 4.0;  // alpha: how hard chi is pulled to the iso value at the samples
  int area_neighbors = 8;         // k of the k-NN estimate of each sample's surface area
  int max_cg_iterations = 2000;
  double cg_tolerance = 1e-7;  // relative residual |r| / |b|
  // Triangles with a vertex whose (smoothed) sample density is below this fraction of the
  // median density at the samples are dropped: removes surface invented far from the data (the
  // result is then open there). 0 keeps the closed surface.
  double density_trim_ratio = 0.0;
};

struct MeshResult {
  TriangleMesh mesh;
  std::array<int, 3> grid_nodes{0, 0, 0};
  double cell_mm = 0;
  double iso_value = 0;
  int cg_iterations = 0;
  double cg_relative_residual = 0;
  std::size_t trimmed_triangles = 0;
};

// Needs a cloud with one finite, unit-ish outward normal per point (pca_normals). Throws
// std::invalid_argument on bad input, std::runtime_error if the solver fails.
MeshResult poisson_mesh(const PointCloud& cloud, const PoissonOptions& options = {});

struct MeshTopology {
  std::size_t edges = 0;
  std::size_t boundary_edges = 0;      // used by one triangle
  std::size_t non_manifold_edges = 0;  // used by more than two
  std::size_t inconsistent_edges = 0;  // two triangles traversing the edge the same way
  bool closed() const { return edges > 0 && boundary_edges == 0 && non_manifold_edges == 0; }
};
MeshTopology mesh_topology(const TriangleMesh& mesh);

}  // namespace slscan::core
