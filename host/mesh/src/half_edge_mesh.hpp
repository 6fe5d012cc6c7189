// CGAL's half-edge mesh as slscan_mesh's closure, simplification and checks use it (internal to
// host/mesh/src).
#pragma once

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Surface_mesh.h>

#include <cstddef>
#include <cstdint>
#include <vector>

#include "slscan/core/mesh.hpp"

namespace slscan::mesh::detail {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Point = Kernel::Point_3;
using Surface = CGAL::Surface_mesh<Point>;
using VertexIndex = Surface::Vertex_index;
using FaceIndex = Surface::Face_index;
using HalfedgeIndex = Surface::Halfedge_index;

// Our triangles into a half-edge mesh, in order (vertex i is VertexIndex(i), every vertex added);
// the ones it cannot hold (non-manifold edge or vertex) are counted and left out.
// `triangle_of_face`, when given: the triangle each face came from. `only`, when given: the
// triangles to add (non-zero entries), the others left out.
Surface to_surface(const core::TriangleMesh& mesh, std::size_t& rejected,
                   std::vector<std::size_t>* triangle_of_face = nullptr,
                   const std::vector<std::uint8_t>* only = nullptr);

}  // namespace slscan::mesh::detail
