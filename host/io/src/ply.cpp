#include "slscan/io/ply.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <sstream>

#include "slproto/calibration.hpp"

namespace slscan::io {

namespace {

[[noreturn]] void fail(const std::string& path, const std::string& what) { throw IoError(path + ": " + what); }

}  // namespace

const std::vector<double>& PlyTable::column(const std::string& name) const {
  const int i = find(name);
  if (i < 0) throw IoError("PLY has no vertex property '" + name + "'");
  return columns[static_cast<std::size_t>(i)];
}

PlyTable read_ply_table(const std::string& path) {
  auto table = slproto::read_ply_table(path);
  if (!table) throw IoError(table.error().message);
  return PlyTable{std::move(table).value()};
}

core::PointCloud read_ply(const std::string& path) {
  const PlyTable table = read_ply_table(path);
  core::PointCloud cloud;
  const int ix = table.find("x"), iy = table.find("y"), iz = table.find("z");
  if (ix < 0 || iy < 0 || iz < 0) fail(path, "vertices lack x, y or z");
  const std::size_t n = table.vertex_count;
  cloud.points.resize(n);
  for (std::size_t i = 0; i < n; ++i)
    cloud.points[i] = {static_cast<float>(table.columns[ix][i]), static_cast<float>(table.columns[iy][i]),
                       static_cast<float>(table.columns[iz][i])};
  const int inx = table.find("nx"), iny = table.find("ny"), inz = table.find("nz");
  if (inx >= 0 && iny >= 0 && inz >= 0) {
    cloud.normals.resize(n);
    for (std::size_t i = 0; i < n; ++i)
      cloud.normals[i] = {static_cast<float>(table.columns[inx][i]), static_cast<float>(table.columns[iny][i]),
                          static_cast<float>(table.columns[inz][i])};
  }
  if (const int ic = table.find("confidence"); ic >= 0) {
    cloud.confidence.resize(n);
    for (std::size_t i = 0; i < n; ++i) cloud.confidence[i] = static_cast<float>(table.columns[ic][i]);
  }
  if (const int ii = table.find("intensity"); ii >= 0) {
    cloud.intensity.resize(n);
    for (std::size_t i = 0; i < n; ++i) cloud.intensity[i] = static_cast<float>(table.columns[ii][i]);
  }
  if (const int iv = table.find("view_id"); iv >= 0) {
    cloud.view_id.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
      const double view = table.columns[iv][i];
      // Written so that NaN fails too: the cast of anything outside 0..65535 is undefined.
      if (!(view >= 0 && view <= 65535) || view != std::floor(view))
        fail(path,
             "vertex " + std::to_string(i) + ": view_id " + std::to_string(view) + " is not an integer in 0..65535");
      cloud.view_id[i] = static_cast<std::uint16_t>(view);
    }
  }
  return cloud;
}

namespace {

template <class T>
void put(std::string& out, T value) {
  char bytes[sizeof(T)];
  std::memcpy(bytes, &value, sizeof(T));
  out.append(bytes, sizeof(T));
}

void put_ascii(std::string& out, double value) {
  char buffer[64];
  auto [end, ec] = std::to_chars(buffer, buffer + sizeof buffer, value);
  out.append(buffer, static_cast<std::size_t>(end - buffer));
}

// The grey level viewers show for an albedo of 0..1 (red = green = blue).
std::uint8_t grey_of(float intensity) {
  const float clamped = std::clamp(intensity, 0.0f, 1.0f);  // NaN -> 0 below
  return clamped >= 0.0f ? static_cast<std::uint8_t>(std::lround(255.0 * static_cast<double>(clamped)))
                         : std::uint8_t{0};
}

std::string header(const std::string& format, const std::vector<std::string>& comments) {
  std::string h = "ply\nformat " + format + " 1.0\n";
  for (const auto& c : comments) h += "comment " + c + "\n";
  return h;
}

}  // namespace

void write_ply(const std::string& path, const core::PointCloud& cloud, const PlyWriteOptions& options) {
  const std::size_t n = cloud.size();
  const bool normals = cloud.normals.size() == n && n > 0;
  const bool confidence = cloud.confidence.size() == n && n > 0;
  const bool intensity = cloud.intensity.size() == n && n > 0;
  const bool view = cloud.view_id.size() == n && n > 0;
  std::string out = header(options.binary ? "binary_little_endian" : "ascii", options.comments);
  out += "element vertex " + std::to_string(n) + "\nproperty float x\nproperty float y\nproperty float z\n";
  if (normals) out += "property float nx\nproperty float ny\nproperty float nz\n";
  if (confidence) out += "property float confidence\n";
  if (intensity) out += "property float intensity\n";
  if (view) out += "property ushort view_id\n";
  if (intensity) out += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  out += "end_header\n";
  out.reserve(out.size() + n * 36);
  for (std::size_t i = 0; i < n; ++i) {
    float values[8] = {cloud.points[i].x(), cloud.points[i].y(), cloud.points[i].z(), 0, 0, 0, 0, 0};
    int count = 3;
    if (normals) {
      values[3] = cloud.normals[i].x();
      values[4] = cloud.normals[i].y();
      values[5] = cloud.normals[i].z();
      count = 6;
    }
    if (confidence) values[count++] = cloud.confidence[i];
    if (intensity) values[count++] = cloud.intensity[i];
    const std::uint8_t grey = intensity ? grey_of(cloud.intensity[i]) : std::uint8_t{0};
    if (options.binary) {
      for (int k = 0; k < count; ++k) put(out, values[k]);
      if (view) put(out, cloud.view_id[i]);
      if (intensity)
        for (int k = 0; k < 3; ++k) put(out, grey);
    } else {
      for (int k = 0; k < count; ++k) {
        if (k) out += ' ';
        put_ascii(out, values[k]);
      }
      if (view) out += ' ' + std::to_string(cloud.view_id[i]);
      if (intensity)
        for (int k = 0; k < 3; ++k) out += ' ' + std::to_string(grey);
      out += '\n';
    }
  }
  write_file_atomically(path, out);
}

void write_mesh_ply(const std::string& path, const std::vector<Eigen::Vector3f>& vertices,
                    const std::vector<Eigen::Vector3f>& normals, const std::vector<Eigen::Vector3i>& triangles,
                    const PlyWriteOptions& options, const std::vector<std::uint8_t>& face_filled,
                    const std::vector<float>& intensity) {
  const bool with_normals = !normals.empty() && normals.size() == vertices.size();
  const bool with_intensity = !intensity.empty();
  if (with_intensity && intensity.size() != vertices.size())
    throw IoError(path + ": " + std::to_string(intensity.size()) + " intensities for " +
                  std::to_string(vertices.size()) + " vertices");
  std::string out = header("binary_little_endian", options.comments);
  out +=
      "element vertex " + std::to_string(vertices.size()) + "\nproperty float x\nproperty float y\nproperty float z\n";
  if (with_normals) out += "property float nx\nproperty float ny\nproperty float nz\n";
  if (with_intensity)
    out += "property float intensity\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n";
  const bool with_flags = !face_filled.empty();
  if (with_flags && face_filled.size() != triangles.size())
    throw IoError(path + ": " + std::to_string(face_filled.size()) + " face flags for " +
                  std::to_string(triangles.size()) + " triangles");
  out += "element face " + std::to_string(triangles.size()) + "\nproperty list uchar int vertex_indices\n";
  if (with_flags) out += "property uchar filled\n";
  out += "end_header\n";
  for (std::size_t i = 0; i < vertices.size(); ++i) {
    for (int k = 0; k < 3; ++k) put(out, vertices[i][k]);
    if (with_normals)
      for (int k = 0; k < 3; ++k) put(out, normals[i][k]);
    if (with_intensity) {
      put(out, intensity[i]);
      const std::uint8_t grey = grey_of(intensity[i]);
      for (int k = 0; k < 3; ++k) put(out, grey);
    }
  }
  for (const auto& t : triangles) {
    put(out, std::uint8_t{3});
    for (int k = 0; k < 3; ++k) {
      if (t[k] < 0 || static_cast<std::size_t>(t[k]) >= vertices.size())
        throw IoError(path + ": triangle refers to vertex " + std::to_string(t[k]) + " of " +
                      std::to_string(vertices.size()));
      put(out, static_cast<std::int32_t>(t[k]));
    }
    if (with_flags) put(out, face_filled[static_cast<std::size_t>(&t - triangles.data())]);
  }
  write_file_atomically(path, out);
}

}  // namespace slscan::io
