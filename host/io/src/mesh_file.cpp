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

#include "slscan/io/ply.hpp"

namespace slscan::io {

namespace {

constexpr std::size_t kMaxTriangles = 50'000'000;

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

std::string read_all(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw IoError(path + ": cannot open (" + std::strerror(errno) + ")");
  std::ostringstream ss;
  ss << in.rdbuf();
  if (in.bad()) throw IoError(path + ": read failed");
  return ss.str();
}

core::TriangleMesh read_stl(const std::string& path) {
  const std::string data = read_all(path);
  core::TriangleMesh soup;
  if (data.size() >= 84) {
    std::uint32_t count = 0;
    std::memcpy(&count, data.data() + 80, 4);
    if (data.size() == 84 + 50ull * count) {
      if (count > kMaxTriangles) throw IoError(path + ": more than 50 million triangles");
      soup.vertices.reserve(3ull * count);
      for (std::uint32_t i = 0; i < count; ++i) {
        float f[9];
        std::memcpy(f, data.data() + 84 + 50ull * i + 12, sizeof f);
        for (int k = 0; k < 3; ++k) soup.vertices.emplace_back(f[3 * k], f[3 * k + 1], f[3 * k + 2]);
        soup.triangles.push_back({3 * i, 3 * i + 1, 3 * i + 2});
      }
      return soup;
    }
  }
  if (lower(data.substr(0, 5)) != "solid")
    throw IoError(path +
                  ": neither a binary STL (the size does not match the triangle count at offset 80) nor "
                  "an ASCII one (no 'solid' at the start)");
  std::istringstream in(data);
  std::string word;
  while (in >> word) {
    if (lower(word) != "vertex") continue;
    double x, y, z;
    if (!(in >> x >> y >> z))
      throw IoError(path + ": ASCII STL: vertex " + std::to_string(soup.vertices.size()) + " does not parse");
    soup.vertices.emplace_back(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z));
    if (soup.vertices.size() > 3 * kMaxTriangles) throw IoError(path + ": more than 50 million triangles");
  }
  if (soup.vertices.size() % 3 != 0)
    throw IoError(path + ": ASCII STL: " + std::to_string(soup.vertices.size()) + " vertices, not a multiple of 3");
  for (std::size_t i = 0; i < soup.vertices.size(); i += 3) {
    const auto b = static_cast<std::uint32_t>(i);
    soup.triangles.push_back({b, b + 1, b + 2});
  }
  return soup;
}

core::TriangleMesh read_obj(const std::string& path) {
  const std::string data = read_all(path);
  core::TriangleMesh mesh;
  std::istringstream in(data);
  std::string line;
  std::size_t line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    std::istringstream ls(line);
    std::string tag;
    if (!(ls >> tag)) continue;
    const std::string where = path + ":" + std::to_string(line_no);
    if (tag == "v") {
      // strtod, not >>: "nan" and "inf" parse, and are then refused as not finite.
      float xyz[3];
      for (float& c : xyz) {
        std::string word;
        char* end = nullptr;
        if (!(ls >> word) || (c = std::strtof(word.c_str(), &end), end != word.c_str() + word.size()))
          throw IoError(where + ": vertex does not parse");
      }
      mesh.vertices.emplace_back(xyz[0], xyz[1], xyz[2]);
    } else if (tag == "f") {
      std::vector<std::uint32_t> face;
      std::string item;
      while (ls >> item) {
        long long index = 0;
        try {
          index = std::stoll(item.substr(0, item.find('/')));
        } catch (...) {
          throw IoError(where + ": bad face index '" + item + "'");
        }
        const auto n = static_cast<long long>(mesh.vertices.size());
        const long long resolved = index < 0 ? n + index : index - 1;
        if (resolved < 0 || resolved >= n)
          throw IoError(where + ": face index " + std::to_string(index) + " out of range (" + std::to_string(n) +
                        " vertices so far)");
        face.push_back(static_cast<std::uint32_t>(resolved));
      }
      if (face.size() < 3) throw IoError(where + ": face with fewer than 3 vertices");
      for (std::size_t k = 1; k + 1 < face.size(); ++k) mesh.triangles.push_back({face[0], face[k], face[k + 1]});
      if (mesh.triangles.size() > kMaxTriangles) throw IoError(path + ": more than 50 million triangles");
    }
  }
  return mesh;
}

core::TriangleMesh read_ply_mesh(const std::string& path) {
  const PlyTable table = read_ply_table(path);
  const auto& x = table.column("x");
  const auto& y = table.column("y");
  const auto& z = table.column("z");
  core::TriangleMesh mesh;
  mesh.vertices.resize(table.vertex_count);
  for (std::size_t i = 0; i < table.vertex_count; ++i)
    mesh.vertices[i] = {static_cast<float>(x[i]), static_cast<float>(y[i]), static_cast<float>(z[i])};
  for (const auto& face : table.faces) {
    if (face.size() < 3) continue;
    for (std::size_t k = 1; k + 1 < face.size(); ++k) mesh.triangles.push_back({face[0], face[k], face[k + 1]});
  }
  return mesh;
}

}  // namespace

core::TriangleMesh read_mesh(const std::string& path) {
  const std::string ext = lower(std::filesystem::path(path).extension().string());
  core::TriangleMesh mesh;
  if (ext == ".stl")
    mesh = read_stl(path);
  else if (ext == ".ply")
    mesh = read_ply_mesh(path);
  else if (ext == ".obj")
    mesh = read_obj(path);
  else if (ext == ".3mf")
    mesh = read_3mf(path).mesh;
  else
    throw IoError(path + ": unknown mesh format '" + ext + "' (STL, PLY, OBJ or 3MF are read)");
  if (mesh.triangles.empty())
    throw IoError(path + ": no triangles (a nominal must be a surface mesh, not a point cloud)");
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
