// Binary STL, the mesh format every slicer and CAD tool reads (millimetres, no units field).
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

namespace slscan::io {

// Binary STL of a triangle mesh (facet normals computed from the triangles), written atomically;
// throws IoError naming the file (a triangle that refers to a missing vertex, a failed write).
void write_stl(const std::string& path, const std::vector<Eigen::Vector3f>& vertices,
               const std::vector<Eigen::Vector3i>& triangles, const std::string& header = "slscan");

}  // namespace slscan::io
