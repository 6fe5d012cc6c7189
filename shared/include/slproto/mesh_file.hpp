// Triangle meshes and PLY tables from files: the one reader of STL, OBJ and PLY that the virtual
// rig (scene meshes) and the host (nominals, its own models) share. No exceptions cross it:
// errors name the file and what was wrong where (header line, element and record, OBJ line,
// byte counts of a cut file). Sizes a header promises are checked against the bytes the file
// still holds before anything is allocated.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "slproto/result.hpp"

namespace slproto {

// Every vertex property of a PLY file as a column of doubles, in file order; faces as index
// lists (every list property of the `face` element), each index checked against the vertices.
struct PlyTable {
  std::size_t vertex_count = 0;
  std::vector<std::string> property_names;
  std::vector<std::vector<double>> columns;  // columns[p][i] = property p of vertex i
  std::vector<std::vector<std::uint32_t>> faces;
  std::vector<std::string> comments;

  // Index of a property by name, or -1.
  int find(const std::string& name) const;
};

// ASCII or binary little-endian PLY.
Result<PlyTable> read_ply_table(const std::string& path);

// A triangle mesh as a file holds it: polygons fanned into triangles, vertices not welded (an
// STL's triangle soup keeps three vertices per triangle). Every vertex is finite and there is
// at least one triangle.
struct MeshFileContents {
  std::vector<std::array<double, 3>> vertices;
  std::vector<std::array<std::uint32_t, 3>> triangles;
};

// By the extension (case-insensitive): .stl (binary or ASCII), .obj, .ply (x, y, z and a face
// list). At most 50 million triangles.
Result<MeshFileContents> read_mesh_file(const std::string& path);

}  // namespace slproto
