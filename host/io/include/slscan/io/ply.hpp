// PLY point clouds (binary little-endian by default, ASCII readable). Writes go to a temporary
// file and are renamed when complete, so a failed run never leaves a half-written model.
#pragma once

#include <string>
#include <vector>

#include "slproto/mesh_file.hpp"
#include "slscan/core/point_cloud.hpp"
#include "slscan/io/io_error.hpp"

namespace slscan::io {

// Every vertex property of a PLY file as a column of doubles, and its faces (slproto's reader,
// shared with the virtual rig).
struct PlyTable : slproto::PlyTable {
  // The column of a required property; throws IoError naming the property if it is absent.
  const std::vector<double>& column(const std::string& name) const;
};

// Throws IoError naming the file and what was wrong where.
PlyTable read_ply_table(const std::string& path);

// Reads x, y, z and, when present, nx/ny/nz, confidence, intensity and view_id.
core::PointCloud read_ply(const std::string& path);

struct PlyWriteOptions {
  bool binary = true;
  std::vector<std::string> comments;
};

// Writes x, y, z (float) and the cloud's optional channels: nx, ny, nz (float),
// confidence (float: the decode modulation, the per-point quality), intensity (float, albedo
// 0..1), view_id (ushort), and with intensity red, green, blue (uchar, all round(255 x
// intensity) clamped: the grey that MeshLab and CloudCompare show).
void write_ply(const std::string& path, const core::PointCloud& cloud, const PlyWriteOptions& options = {});

// Writes a triangle mesh: vertices (with normals when given) and faces; `face_filled`, when not
// empty, one flag per face written as the face property `uchar filled` (1: invented to close a
// hole, docs/mesh.md); `intensity`, when not empty, one albedo per vertex written as
// `float intensity` and its grey `uchar red, green, blue` (as write_ply).
void write_mesh_ply(const std::string& path, const std::vector<Eigen::Vector3f>& vertices,
                    const std::vector<Eigen::Vector3f>& normals, const std::vector<Eigen::Vector3i>& triangles,
                    const PlyWriteOptions& options = {}, const std::vector<std::uint8_t>& face_filled = {},
                    const std::vector<float>& intensity = {});

}  // namespace slscan::io
