// Triangle meshes from PLY, OBJ and STL files. Errors name the file and what was wrong where.
#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <fstream>
#include <sstream>

#include "scene_build.hpp"

namespace slrig::detail {

namespace {

using slproto::Errc;
using slproto::make_error;

constexpr std::size_t kMaxTriangles = 50'000'000;

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

slproto::Result<std::string> read_all(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return make_error(Errc::io_error, path + ": cannot open (" + std::strerror(errno) + ")");
  std::ostringstream ss;
  ss << in.rdbuf();
  if (in.bad()) return make_error(Errc::io_error, path + ": read failed");
  return ss.str();
}

bool finite(const V3& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

slproto::Result<std::vector<Triangle>> parse_stl(const std::string& path, const std::string& data) {
  std::vector<Triangle> out;
  if (data.size() >= 84) {
    std::uint32_t count;
    std::memcpy(&count, data.data() + 80, 4);
    if (data.size() == 84 + 50ull * count) {
      out.reserve(count);
      for (std::uint32_t i = 0; i < count; ++i) {
        float f[9];
        std::memcpy(f, data.data() + 84 + 50ull * i + 12, sizeof f);
        Triangle t{{f[0], f[1], f[2]}, {f[3], f[4], f[5]}, {f[6], f[7], f[8]}};
        if (!finite(t.a) || !finite(t.b) || !finite(t.c))
          return make_error(Errc::malformed, path + ": triangle " + std::to_string(i) + " has a non-finite vertex");
        out.push_back(t);
      }
      return out;
    }
  }
  if (lower(data.substr(0, 5)) != "solid")
    return make_error(Errc::malformed,
                      path + ": neither a binary STL (size does not match the triangle count) nor ASCII");
  std::istringstream in(data);
  std::string word;
  std::vector<V3> corners;
  while (in >> word) {
    if (lower(word) != "vertex") continue;
    V3 v;
    if (!(in >> v.x >> v.y >> v.z) || !finite(v))
      return make_error(Errc::malformed, path + ": bad vertex after vertex " + std::to_string(corners.size()));
    corners.push_back(v);
  }
  if (corners.size() % 3 != 0)
    return make_error(Errc::malformed,
                      path + ": vertex count " + std::to_string(corners.size()) + " is not a multiple of 3");
  for (std::size_t i = 0; i < corners.size(); i += 3) out.push_back({corners[i], corners[i + 1], corners[i + 2]});
  return out;
}

slproto::Result<std::vector<Triangle>> parse_obj(const std::string& path, const std::string& data) {
  std::vector<V3> vertices;
  std::vector<Triangle> out;
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
      V3 v;
      if (!(ls >> v.x >> v.y >> v.z) || !finite(v)) return make_error(Errc::malformed, where + ": bad vertex");
      vertices.push_back(v);
    } else if (tag == "f") {
      std::vector<std::size_t> face;
      std::string item;
      while (ls >> item) {
        long long index = 0;
        try {
          index = std::stoll(item.substr(0, item.find('/')));
        } catch (...) {
          return make_error(Errc::malformed, where + ": bad face index '" + item + "'");
        }
        const long long n = static_cast<long long>(vertices.size());
        const long long resolved = index < 0 ? n + index : index - 1;
        if (resolved < 0 || resolved >= n)
          return make_error(Errc::malformed, where + ": face index " + std::to_string(index) + " out of range");
        face.push_back(static_cast<std::size_t>(resolved));
      }
      if (face.size() < 3) return make_error(Errc::malformed, where + ": face with fewer than 3 vertices");
      for (std::size_t k = 1; k + 1 < face.size(); ++k)
        out.push_back({vertices[face[0]], vertices[face[k]], vertices[face[k + 1]]});
      if (out.size() > kMaxTriangles) return make_error(Errc::oversized, path + ": more than 50 million triangles");
    }
  }
  return out;
}

// PLY scalar types.
int ply_type_size(const std::string& t) {
  if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
  if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
  if (t == "int" || t == "uint" || t == "int32" || t == "uint32" || t == "float" || t == "float32") return 4;
  if (t == "double" || t == "float64") return 8;
  return 0;
}

double ply_read_binary(const char* p, const std::string& t) {
  if (t == "char" || t == "int8") return static_cast<std::int8_t>(*p);
  if (t == "uchar" || t == "uint8") return static_cast<std::uint8_t>(*p);
  if (t == "short" || t == "int16") {
    std::int16_t v;
    std::memcpy(&v, p, 2);
    return v;
  }
  if (t == "ushort" || t == "uint16") {
    std::uint16_t v;
    std::memcpy(&v, p, 2);
    return v;
  }
  if (t == "int" || t == "int32") {
    std::int32_t v;
    std::memcpy(&v, p, 4);
    return v;
  }
  if (t == "uint" || t == "uint32") {
    std::uint32_t v;
    std::memcpy(&v, p, 4);
    return v;
  }
  if (t == "float" || t == "float32") {
    float v;
    std::memcpy(&v, p, 4);
    return v;
  }
  double v;
  std::memcpy(&v, p, 8);
  return v;
}

struct PlyProperty {
  std::string name, type, count_type;  // count_type non-empty for lists
};
struct PlyElement {
  std::string name;
  std::size_t count = 0;
  std::vector<PlyProperty> properties;
};

slproto::Result<std::vector<Triangle>> parse_ply(const std::string& path, const std::string& data) {
  const std::size_t header_end = data.find("end_header");
  if (header_end == std::string::npos) return make_error(Errc::malformed, path + ": PLY without end_header");
  std::size_t body = data.find('\n', header_end);
  if (body == std::string::npos) return make_error(Errc::truncated, path + ": PLY ends after its header");
  ++body;
  std::istringstream header(data.substr(0, header_end));
  std::string line, format;
  std::vector<PlyElement> elements;
  while (std::getline(header, line)) {
    std::istringstream ls(line);
    std::string tag;
    ls >> tag;
    if (tag == "format") {
      ls >> format;
    } else if (tag == "element") {
      PlyElement e;
      long long count = -1;
      ls >> e.name >> count;
      if (count < 0) return make_error(Errc::malformed, path + ": bad element line '" + line + "'");
      e.count = static_cast<std::size_t>(count);
      elements.push_back(e);
    } else if (tag == "property") {
      if (elements.empty()) return make_error(Errc::malformed, path + ": property before any element");
      PlyProperty p;
      std::string type;
      ls >> type;
      if (type == "list") {
        ls >> p.count_type >> p.type >> p.name;
        if (ply_type_size(p.count_type) == 0 || ply_type_size(p.type) == 0)
          return make_error(Errc::malformed, path + ": bad list property '" + line + "'");
      } else {
        p.type = type;
        ls >> p.name;
        if (ply_type_size(p.type) == 0)
          return make_error(Errc::malformed, path + ": unknown property type '" + type + "'");
      }
      elements.back().properties.push_back(p);
    }
  }
  const bool ascii = format == "ascii";
  if (!ascii && format != "binary_little_endian")
    return make_error(Errc::unsupported,
                      path + ": PLY format '" + format + "' (ascii and binary_little_endian are read)");
  std::vector<V3> vertices;
  std::vector<Triangle> out;
  std::istringstream text(ascii ? data.substr(body) : std::string());
  std::size_t offset = body;
  for (const PlyElement& e : elements) {
    const bool is_vertex = e.name == "vertex", is_face = e.name == "face";
    int ix = -1, iy = -1, iz = -1, ilist = -1;
    for (std::size_t k = 0; k < e.properties.size(); ++k) {
      const auto& name = e.properties[k].name;
      if (name == "x") ix = static_cast<int>(k);
      if (name == "y") iy = static_cast<int>(k);
      if (name == "z") iz = static_cast<int>(k);
      if (!e.properties[k].count_type.empty() && (name == "vertex_indices" || name == "vertex_index"))
        ilist = static_cast<int>(k);
    }
    if (is_vertex && (ix < 0 || iy < 0 || iz < 0))
      return make_error(Errc::malformed, path + ": vertex element lacks x, y or z");
    if (is_face && ilist < 0) return make_error(Errc::malformed, path + ": face element lacks vertex_indices");
    if (e.count > kMaxTriangles) return make_error(Errc::oversized, path + ": element '" + e.name + "' is too large");
    std::vector<double> values;
    std::vector<std::size_t> face;
    for (std::size_t r = 0; r < e.count; ++r) {
      values.assign(e.properties.size(), 0);
      face.clear();
      for (std::size_t k = 0; k < e.properties.size(); ++k) {
        const PlyProperty& p = e.properties[k];
        auto read_one = [&](const std::string& type, double& v) -> bool {
          if (ascii) return static_cast<bool>(text >> v);
          const auto size = static_cast<std::size_t>(ply_type_size(type));
          if (offset + size > data.size()) return false;
          v = ply_read_binary(data.data() + offset, type);
          offset += size;
          return true;
        };
        const std::string where = path + ": element '" + e.name + "' " + std::to_string(r);
        if (p.count_type.empty()) {
          if (!read_one(p.type, values[k])) return make_error(Errc::truncated, where + " ends early");
        } else {
          double count;
          // Written so that NaN fails too (a NaN count or index would be cast to an int).
          if (!read_one(p.count_type, count) || !(count >= 0 && count <= 1000))
            return make_error(Errc::malformed, where + ": bad list length");
          for (int c = 0; c < static_cast<int>(count); ++c) {
            double v;
            if (!read_one(p.type, v)) return make_error(Errc::truncated, where + " ends early");
            if (static_cast<int>(k) == ilist) {
              if (!(v >= 0 && v < static_cast<double>(vertices.size())))
                return make_error(Errc::malformed, where + ": vertex index " + std::to_string(v) + " out of range");
              face.push_back(static_cast<std::size_t>(v));
            }
          }
        }
      }
      if (is_vertex) {
        V3 v{values[static_cast<std::size_t>(ix)], values[static_cast<std::size_t>(iy)],
             values[static_cast<std::size_t>(iz)]};
        if (!finite(v)) return make_error(Errc::malformed, path + ": vertex " + std::to_string(r) + " is not finite");
        vertices.push_back(v);
      } else if (is_face) {
        for (std::size_t c = 1; c + 1 < face.size(); ++c)
          out.push_back({vertices[face[0]], vertices[face[c]], vertices[face[c + 1]]});
      }
    }
  }
  return out;
}

}  // namespace

slproto::Result<std::vector<Triangle>> load_mesh_file(const std::string& path) {
  auto data = read_all(path);
  if (!data) return std::move(data).error();
  const std::string ext =
      lower(path.substr(path.find_last_of('.') == std::string::npos ? path.size() : path.find_last_of('.')));
  slproto::Result<std::vector<Triangle>> mesh = make_error(Errc::unsupported, "");
  if (ext == ".stl") {
    mesh = parse_stl(path, *data);
  } else if (ext == ".obj") {
    mesh = parse_obj(path, *data);
  } else if (ext == ".ply") {
    mesh = parse_ply(path, *data);
  } else {
    return make_error(Errc::unsupported, path + ": unknown mesh extension '" + ext + "' (PLY, OBJ or STL)");
  }
  if (mesh && mesh->empty()) return make_error(Errc::malformed, path + ": the mesh has no triangles");
  return mesh;
}

}  // namespace slrig::detail
