// Meshes in (nominals: STL binary / ASCII, PLY with faces, OBJ, 3MF) and out (a scan's mesh as
// OBJ and 3MF; PLY and STL are in ply.hpp), and the inspection's per-point deviation cloud out.
// Errors are IoError naming the file and what was wrong where. Every write is atomic (a
// temporary file renamed when complete).
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "slscan/core/inspect.hpp"

namespace slscan::io {

// Reads a triangle mesh by its extension (.stl, .ply, .obj, .3mf; case-insensitive), polygons fanned
// into triangles, coincident vertices welded (an STL's triangle soup becomes an indexed mesh).
// The geometry is not checked here (core::check_nominal_mesh does that), but a file with no
// triangles or a vertex that does not parse is refused.
core::TriangleMesh read_mesh(const std::string& path);

// Wavefront OBJ, ASCII, mm (OBJ has no unit field: a comment says so): `v x y z`, `vn` when the
// mesh has one normal per vertex, faces `f a//a b//b c//c` (1-based, counter-clockwise seen
// from outside). Faces flagged in mesh.filled go in the group `filled`, the others in
// `measured`, so that inspection software can hide what closes a hole. Coordinates are the
// shortest text that reads back as the same float.
void write_obj(const std::string& path, const core::TriangleMesh& mesh, const std::vector<std::string>& comments = {});

// 3MF (3D Manufacturing Format, through lib3mf), unit millimetre: one mesh object named `name`
// and one build item. Its type is `model` when the mesh is closed and consistently oriented
// (core::mesh_topology), else `surface` (3MF's type for a mesh that need not be closed: a raw
// mesh). lib3mf prints coordinates with 6 decimals (1 nm); the object's and build's UUIDs are
// derived from the mesh, so the same mesh gives the same file.
void write_3mf(const std::string& path, const core::TriangleMesh& mesh, const std::string& name);

struct ThreeMfContents {
  core::TriangleMesh mesh;                // every mesh object's triangles, in mm
  std::string unit;                       // the file's unit ("millimeter", ...)
  std::vector<std::string> object_types;  // per mesh object: model, support, solidsupport, surface, other
  std::size_t build_items = 0;
};
// Reads a 3MF with lib3mf: its mesh objects (merged, coordinates scaled to mm; build-item
// transforms are not applied, as is right for our files and single-object nominals).
ThreeMfContents read_3mf(const std::string& path);

// deviation.ply: x, y, z (float), deviation (float, mm, NaN where unmatched), matched (uchar),
// red, green, blue (uchar). Binary little-endian, written atomically.
void write_deviation_ply(const std::string& path, const std::vector<Eigen::Vector3f>& points,
                         const std::vector<float>& deviation_mm,
                         const std::vector<std::array<std::uint8_t, 3>>& colours,
                         const std::vector<std::string>& comments = {});

}  // namespace slscan::io
