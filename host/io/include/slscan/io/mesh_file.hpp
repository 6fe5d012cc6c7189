// Nominal meshes (STL binary / ASCII, PLY with faces, OBJ) in, and the inspection's per-point
// deviation cloud out. Errors are IoError naming the file and what was wrong where.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "slscan/core/inspect.hpp"

namespace slscan::io {

// Reads a triangle mesh by its extension (.stl, .ply, .obj; case-insensitive), polygons fanned
// into triangles, coincident vertices welded (an STL's triangle soup becomes an indexed mesh).
// The geometry is not checked here (core::check_nominal_mesh does that), but a file with no
// triangles or a vertex that does not parse is refused.
core::TriangleMesh read_mesh(const std::string& path);

// deviation.ply: x, y, z (float), deviation (float, mm, NaN where unmatched), matched (uchar),
// red, green, blue (uchar). Binary little-endian, written atomically.
void write_deviation_ply(const std::string& path, const std::vector<Eigen::Vector3f>& points,
                         const std::vector<float>& deviation_mm,
                         const std::vector<std::array<std::uint8_t, 3>>& colours,
                         const std::vector<std::string>& comments = {});

}  // namespace slscan::io
