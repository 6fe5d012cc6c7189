#include "slscan/io/mesh_file.hpp"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "slproto/mesh_file.hpp"
#include "slscan/io/ply.hpp"

namespace slscan::io {

namespace {

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

// STL, OBJ and PLY through slproto's reader (the one the virtual rig uses too).
core::TriangleMesh read_shared_format(const std::string& path) {
  auto file = slproto::read_mesh_file(path);
  if (!file) throw IoError(file.error().message);
  core::TriangleMesh mesh;
  mesh.vertices.reserve(file->vertices.size());
  for (const auto& v : file->vertices)
    mesh.vertices.emplace_back(static_cast<float>(v[0]), static_cast<float>(v[1]), static_cast<float>(v[2]));
  mesh.triangles.reserve(file->triangles.size());
  for (const auto& t : file->triangles) mesh.triangles.push_back({t[0], t[1], t[2]});
  return mesh;
}

}  // namespace

core::TriangleMesh read_mesh(const std::string& path) {
  const std::string ext = lower(std::filesystem::path(path).extension().string());
  core::TriangleMesh mesh;
  if (ext == ".stl" || ext == ".ply" || ext == ".obj")
    mesh = read_shared_format(path);
  else if (ext == ".3mf")
    mesh = read_3mf(path).mesh;
  else
    throw IoError(path + ": unknown mesh format '" + ext + "' (STL, PLY, OBJ or 3MF are read)");
  if (mesh.triangles.empty())
    throw IoError(path + ": no triangles (a nominal must be a surface mesh, not a point cloud)");
  // Also after slproto's check: a double that is finite may not be as a float.
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i)
    if (!mesh.vertices[i].allFinite())
      throw IoError(path + ": vertex " + std::to_string(i) + " is not finite (NaN or infinite coordinate)");
  core::TriangleMesh welded = core::weld_vertices(mesh);
  if (welded.triangles.empty()) throw IoError(path + ": every triangle is degenerate (no area)");
  return welded;
}

void write_obj(const std::string& path, const core::TriangleMesh& mesh, const std::vector<std::string>& comments) {
  const std::size_t n = mesh.vertices.size();
  const bool with_normals = !mesh.normals.empty() && mesh.normals.size() == n;
  const bool with_flags = !mesh.filled.empty();
  if (with_flags && mesh.filled.size() != mesh.triangles.size())
    throw IoError(path + ": " + std::to_string(mesh.filled.size()) + " face flags for " +
                  std::to_string(mesh.triangles.size()) + " triangles");
  std::string out;
  out.reserve(n * (with_normals ? 64 : 32) + mesh.triangles.size() * 40 + 256);
  for (const auto& c : comments) out += "# " + c + "\n";
  out += "# units: mm\n";
  char buffer[64];
  const auto number = [&](float v) {
    const auto end = std::to_chars(buffer, buffer + sizeof buffer, v).ptr;
    out.append(buffer, end);
  };
  const auto line = [&](const char* tag, const Eigen::Vector3f& v) {
    out += tag;
    for (int k = 0; k < 3; ++k) {
      out += ' ';
      number(v[k]);
    }
    out += '\n';
  };
  for (std::size_t i = 0; i < n; ++i) line("v", mesh.vertices[i]);
  if (with_normals)
    for (std::size_t i = 0; i < n; ++i) line("vn", mesh.normals[i]);
  int group = -1;  // the group of the faces being written: 0 measured, 1 filled
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    const int flag = with_flags && mesh.filled[t] ? 1 : 0;
    if (flag != group) {
      out += flag ? "g filled\n" : "g measured\n";
      group = flag;
    }
    out += 'f';
    for (const std::uint32_t v : mesh.triangles[t]) {
      if (v >= n)
        throw IoError(path + ": triangle " + std::to_string(t) + " refers to vertex " + std::to_string(v) + " of " +
                      std::to_string(n));
      const auto end = std::to_chars(buffer, buffer + sizeof buffer, std::uint64_t{v} + 1).ptr;
      out += ' ';
      out.append(buffer, end);
      if (with_normals) {
        out += "//";
        out.append(buffer, end);
      }
    }
    out += '\n';
  }
  write_file_atomically(path, out);
}

void write_deviation_ply(const std::string& path, const std::vector<Eigen::Vector3f>& points,
                         const std::vector<float>& deviation_mm,
                         const std::vector<std::array<std::uint8_t, 3>>& colours,
                         const std::vector<std::string>& comments) {
  if (deviation_mm.size() != points.size() || colours.size() != points.size())
    throw std::invalid_argument("write_deviation_ply: points, deviations and colours differ in size");
  std::string out = "ply\nformat binary_little_endian 1.0\n";
  for (const auto& c : comments) out += "comment " + c + "\n";
  out += "element vertex " + std::to_string(points.size()) +
         "\nproperty float x\nproperty float y\nproperty float z\nproperty float deviation\nproperty uchar "
         "matched\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n";
  const std::size_t header_size = out.size();
  out.resize(header_size + points.size() * 20);
  char* p = out.data() + header_size;
  for (std::size_t i = 0; i < points.size(); ++i) {
    const float values[4] = {points[i].x(), points[i].y(), points[i].z(), deviation_mm[i]};
    std::memcpy(p, values, sizeof values);
    p += sizeof values;
    *p++ = static_cast<char>(std::isfinite(deviation_mm[i]) ? 1 : 0);
    for (int k = 0; k < 3; ++k) *p++ = static_cast<char>(colours[i][static_cast<std::size_t>(k)]);
  }
  write_file_atomically(path, out);
}

}  // namespace slscan::io
