#include "slproto/mesh_file.hpp"

#include <algorithm>
#include <bit>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>

#include "slproto/file_util.hpp"

namespace slproto {

namespace {

constexpr std::size_t kMaxTriangles = 50'000'000;
// The largest file of a format with 50 million triangles (binary STL: 50 bytes each); anything
// bigger is not a mesh we can hold.
constexpr std::size_t kMaxMeshFileBytes =
    static_cast<std::size_t>(std::min<std::uint64_t>(std::uint64_t{4} << 30, std::numeric_limits<std::size_t>::max()));
// Lists longer than this are not faces of any mesh we read: a corrupt count, refused before it
// allocates.
constexpr double kMaxListItems = 1024;

// The parsers below stop at the first fault by throwing this; it never leaves this file (the
// public functions turn it into a Result).
struct ParseFailure {
  Errc code;
  std::string message;
};

[[noreturn]] void fail(const std::string& path, const std::string& what, Errc code = Errc::malformed) {
  throw ParseFailure{code, path + ": " + what};
}

// "PATH: part part ...": appended in place (no temporaries).
template <class... Parts>
[[noreturn]] void fail_with(const std::string& path, const Parts&... parts) {
  std::string message = path;
  message += ": ";
  ((message += parts), ...);
  throw ParseFailure{Errc::malformed, std::move(message)};
}

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

enum class PlyType : std::uint8_t { i8, u8, i16, u16, i32, u32, f32, f64 };

struct PlyProperty {
  std::string name;
  PlyType type = PlyType::f32;
  bool is_list = false;
  PlyType count_type = PlyType::u8;
};

struct PlyElement {
  std::string name;
  std::size_t count = 0;
  std::vector<PlyProperty> properties;
};

std::size_t type_size(PlyType t) {
  switch (t) {
    case PlyType::i8:
    case PlyType::u8:
      return 1;
    case PlyType::i16:
    case PlyType::u16:
      return 2;
    case PlyType::i32:
    case PlyType::u32:
    case PlyType::f32:
      return 4;
    case PlyType::f64:
      return 8;
  }
  return 0;
}

bool parse_type(const std::string& s, PlyType& t) {
  static const std::pair<const char*, PlyType> names[] = {
      {"char", PlyType::i8},   {"int8", PlyType::i8},     {"uchar", PlyType::u8},   {"uint8", PlyType::u8},
      {"short", PlyType::i16}, {"int16", PlyType::i16},   {"ushort", PlyType::u16}, {"uint16", PlyType::u16},
      {"int", PlyType::i32},   {"int32", PlyType::i32},   {"uint", PlyType::u32},   {"uint32", PlyType::u32},
      {"float", PlyType::f32}, {"float32", PlyType::f32}, {"double", PlyType::f64}, {"float64", PlyType::f64}};
  for (const auto& [name, type] : names)
    if (s == name) {
      t = type;
      return true;
    }
  return false;
}

template <class T>
double load(const char* p) {
  T v;
  std::memcpy(&v, p, sizeof v);
  return static_cast<double>(v);
}

double read_binary(const char* p, PlyType t) {
  switch (t) {
    case PlyType::i8:
      return load<std::int8_t>(p);
    case PlyType::u8:
      return load<std::uint8_t>(p);
    case PlyType::i16:
      return load<std::int16_t>(p);
    case PlyType::u16:
      return load<std::uint16_t>(p);
    case PlyType::i32:
      return load<std::int32_t>(p);
    case PlyType::u32:
      return load<std::uint32_t>(p);
    case PlyType::f32:
      return load<float>(p);
    case PlyType::f64:
      return load<double>(p);
  }
  return 0;
}

std::size_t list_length(const std::string& path, const std::string& where, const std::string& name, double count) {
  if (!(count >= 0 && count <= kMaxListItems) || count != std::floor(count))
    fail(path, where + ": list '" + name + "' of " + std::to_string(count) + " items is implausible");
  return static_cast<std::size_t>(count);
}

std::uint32_t list_index(const std::string& path, const std::string& where, const std::string& name, double value) {
  if (!(value >= 0 && value <= 4294967295.0) || value != std::floor(value))
    fail(path, where + ": list '" + name + "' has the item " + std::to_string(value) + ", not a vertex index");
  return static_cast<std::uint32_t>(value);
}

struct PlyHeader {
  std::string format;
  std::vector<PlyElement> elements;
  std::vector<std::string> comments;
};

PlyHeader parse_ply_header(const std::string& path, std::istream& in) {
  std::string line;
  if (!std::getline(in, line) || line.rfind("ply", 0) != 0) fail(path, "not a PLY file (no 'ply' magic on line 1)");
  PlyHeader header;
  int line_no = 1;
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream words(line);
    std::string keyword;
    words >> keyword;
    const std::string where = "header line " + std::to_string(line_no);
    if (keyword == "format") {
      std::string version;
      words >> header.format >> version;
      if (header.format != "ascii" && header.format != "binary_little_endian")
        fail(path, where + ": format '" + header.format + "' is not supported (ascii or binary_little_endian)",
             Errc::unsupported);
    } else if (keyword == "comment" || keyword == "obj_info") {
      header.comments.push_back(line.size() > keyword.size() + 1 ? line.substr(keyword.size() + 1) : "");
    } else if (keyword == "element") {
      PlyElement element;
      long long count = -1;
      // A count that does not parse leaves 0 in `count`, so the extraction itself is checked.
      if (!(words >> element.name >> count) || count < 0 || count > (1LL << 32))
        fail_with(path, where, ": malformed element line '", line, "'");
      // The columns are the vertex element's: a second one would index past them.
      for (const PlyElement& earlier : header.elements) {
        if (earlier.name == element.name && (element.name == "vertex" || element.name == "face"))
          fail(path, where + ": a second '" + element.name + "' element");
      }
      element.count = static_cast<std::size_t>(count);
      header.elements.push_back(element);
    } else if (keyword == "property") {
      if (header.elements.empty()) fail(path, where + ": property before any element");
      PlyProperty property;
      std::string type;
      words >> type;
      if (type == "list") {
        std::string count_type, item_type;
        words >> count_type >> item_type >> property.name;
        property.is_list = true;
        if (!parse_type(count_type, property.count_type) || !parse_type(item_type, property.type))
          fail_with(path, where, ": unknown list types in '", line, "'");
      } else {
        words >> property.name;
        if (!parse_type(type, property.type)) fail_with(path, where, ": unknown property type '", type, "'");
      }
      if (property.name.empty()) fail(path, where + ": property without a name");
      header.elements.back().properties.push_back(property);
    } else if (keyword == "end_header") {
      if (header.format.empty()) fail(path, "header has no format line");
      return header;
    } else if (!keyword.empty()) {
      fail_with(path, where, ": unknown keyword '", keyword, "'");
    }
  }
  fail(path, "header has no end_header", Errc::truncated);
}

// The header's counts size the columns: a short corrupt header must not allocate gigabytes.
// Each record needs at least its fixed bytes (binary) or one character and a separator per
// value (ASCII), so the counts are checked against what the file still holds.
void check_body_size(const std::string& path, const PlyHeader& header, std::istream& in) {
  const std::streampos body = in.tellg();
  in.seekg(0, std::ios::end);
  const std::streamoff remaining = in.tellg() - body;
  in.seekg(body);
  if (!in || remaining < 0) fail(path, "cannot determine the file's size", Errc::io_error);
  const bool ascii = header.format == "ascii";
  long double needed = 0;
  for (const PlyElement& element : header.elements) {
    long double per_record = 0;
    bool all_fixed = true;
    for (const auto& p : element.properties) {
      per_record += ascii ? 2 : type_size(p.is_list ? p.count_type : p.type);
      all_fixed = all_fixed && !p.is_list;
    }
    const long double before = needed;
    needed += per_record * static_cast<long double>(element.count);
    if (needed <= static_cast<long double>(remaining) + 1) continue;  // + 1: the last ASCII value needs no separator
    const std::string promised = "the header promises at least " + std::to_string(static_cast<double>(needed)) +
                                 " bytes of elements, the file has " + std::to_string(remaining) + " after it";
    if (!ascii && all_fixed && per_record > 0) {
      const auto index =
          static_cast<std::size_t>(std::max<long double>(0, static_cast<long double>(remaining) - before) / per_record);
      fail(path,
           "file ends in " + element.name + " " + std::to_string(index) + " of " + std::to_string(element.count) +
               " (truncated: " + promised + ")",
           Errc::truncated);
    }
    fail(path, promised + " (truncated?)", Errc::truncated);
  }
}

PlyTable parse_ply(const std::string& path) {
  static_assert(std::endian::native == std::endian::little, "binary PLY reading assumes a little-endian host");
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(path, "cannot open (" + errno_text(errno) + ")", Errc::io_error);
  const PlyHeader header = parse_ply_header(path, in);
  check_body_size(path, header, in);
  PlyTable table;
  table.comments = header.comments;
  const bool ascii = header.format == "ascii";
  std::string line;
  for (const PlyElement& element : header.elements) {
    // An element without properties has no bytes to read (the fuzzer gave one 4 billion records).
    if (element.properties.empty()) continue;
    const bool is_vertex = element.name == "vertex";
    const bool is_face = element.name == "face";
    if (is_vertex) {
      table.vertex_count = element.count;
      for (const auto& p : element.properties) {
        if (p.is_list) fail(path, "vertex list properties are not supported ('" + p.name + "')", Errc::unsupported);
        table.property_names.push_back(p.name);
        table.columns.emplace_back(element.count);
      }
    }
    std::size_t fixed_size = 0;
    for (const auto& p : element.properties) fixed_size += p.is_list ? 0 : type_size(p.type);
    const bool all_fixed =
        std::none_of(element.properties.begin(), element.properties.end(), [](const auto& p) { return p.is_list; });
    std::vector<char> record(fixed_size);
    for (std::size_t i = 0; i < element.count; ++i) {
      const std::string where = element.name + " " + std::to_string(i);
      if (ascii) {
        if (!std::getline(in, line))
          fail(path, "file ends in " + where + " (expected " + std::to_string(element.count) + ")", Errc::truncated);
        std::istringstream values(line);
        for (std::size_t p = 0; p < element.properties.size(); ++p) {
          const PlyProperty& prop = element.properties[p];
          double v = 0;
          if (!(values >> v)) fail(path, where + ": missing value for '" + prop.name + "'");
          if (prop.is_list) {
            std::vector<std::uint32_t> items(list_length(path, where, prop.name, v));
            for (auto& item : items) {
              double x = 0;
              if (!(values >> x)) fail(path, where + ": short list '" + prop.name + "'");
              item = list_index(path, where, prop.name, x);
            }
            if (is_face) table.faces.push_back(std::move(items));
          } else if (is_vertex) {
            table.columns[p][i] = v;
          }
        }
      } else if (all_fixed) {
        if (!in.read(record.data(), static_cast<std::streamsize>(fixed_size)))
          fail(path, "file ends in " + where + " of " + std::to_string(element.count) + " (truncated)",
               Errc::truncated);
        if (is_vertex) {
          std::size_t offset = 0;
          for (std::size_t p = 0; p < element.properties.size(); ++p) {
            table.columns[p][i] = read_binary(record.data() + offset, element.properties[p].type);
            offset += type_size(element.properties[p].type);
          }
        }
      } else {
        for (const PlyProperty& prop : element.properties) {
          char buffer[8];
          const std::size_t size = type_size(prop.is_list ? prop.count_type : prop.type);
          if (!in.read(buffer, static_cast<std::streamsize>(size)))
            fail(path, "file ends in " + where + " (truncated)", Errc::truncated);
          if (!prop.is_list) continue;
          std::vector<std::uint32_t> items(list_length(path, where, prop.name, read_binary(buffer, prop.count_type)));
          const std::size_t item_size = type_size(prop.type);
          for (auto& item : items) {
            if (!in.read(buffer, static_cast<std::streamsize>(item_size)))
              fail(path, "file ends in " + where + " (truncated)", Errc::truncated);
            item = list_index(path, where, prop.name, read_binary(buffer, prop.type));
          }
          if (is_face) table.faces.push_back(std::move(items));
        }
      }
    }
  }
  // Faces may come before the vertices in the file; their indices are checked once both are read.
  for (std::size_t f = 0; f < table.faces.size(); ++f) {
    for (const std::uint32_t index : table.faces[f]) {
      if (index >= table.vertex_count)
        fail(path, "face " + std::to_string(f) + " names vertex " + std::to_string(index) + " but the file has " +
                       std::to_string(table.vertex_count) + " vertices");
    }
  }
  return table;
}

std::string read_mesh_bytes(const std::string& path) {
  auto bytes = read_whole_file(path, kMaxMeshFileBytes);
  if (!bytes) throw ParseFailure{bytes.error().code, bytes.error().message};
  return std::move(bytes).value();
}

void add_triangle(const std::string& path, MeshFileContents& mesh, std::uint32_t a, std::uint32_t b, std::uint32_t c) {
  if (mesh.triangles.size() >= kMaxTriangles) fail(path, "more than 50 million triangles", Errc::oversized);
  mesh.triangles.push_back({a, b, c});
}

MeshFileContents parse_stl(const std::string& path) {
  const std::string data = read_mesh_bytes(path);
  MeshFileContents soup;
  if (data.size() >= 84) {
    std::uint32_t count = 0;
    std::memcpy(&count, data.data() + 80, 4);
    if (data.size() == 84 + 50ULL * count) {
      if (count > kMaxTriangles) fail(path, "more than 50 million triangles", Errc::oversized);
      soup.vertices.reserve(3ULL * count);
      soup.triangles.reserve(count);
      for (std::uint32_t i = 0; i < count; ++i) {
        float f[9];
        std::memcpy(f, data.data() + 84 + 50ULL * i + 12, sizeof f);
        for (int k = 0; k < 3; ++k) soup.vertices.push_back({f[3 * k], f[3 * k + 1], f[3 * k + 2]});
        soup.triangles.push_back({3 * i, 3 * i + 1, 3 * i + 2});
      }
      return soup;
    }
  }
  if (lower(data.substr(0, 5)) != "solid")
    fail(path,
         "neither a binary STL (the size does not match the triangle count at offset 80) nor an ASCII one (no "
         "'solid' at the start)");
  std::istringstream in(data);
  std::string word;
  while (in >> word) {
    if (lower(word) != "vertex") continue;
    std::array<double, 3> v{};
    if (!(in >> v[0] >> v[1] >> v[2]))
      fail(path, "ASCII STL: vertex " + std::to_string(soup.vertices.size()) + " does not parse");
    soup.vertices.push_back(v);
    if (soup.vertices.size() > 3 * kMaxTriangles) fail(path, "more than 50 million triangles", Errc::oversized);
  }
  if (soup.vertices.size() % 3 != 0)
    fail(path, "ASCII STL: " + std::to_string(soup.vertices.size()) + " vertices, not a multiple of 3");
  soup.triangles.reserve(soup.vertices.size() / 3);
  for (std::size_t i = 0; i < soup.vertices.size(); i += 3) {
    const auto b = static_cast<std::uint32_t>(i);
    soup.triangles.push_back({b, b + 1, b + 2});
  }
  return soup;
}

MeshFileContents parse_obj(const std::string& path) {
  const std::string data = read_mesh_bytes(path);
  MeshFileContents mesh;
  std::istringstream in(data);
  std::string line;
  std::size_t line_no = 0;
  std::vector<std::uint32_t> face;
  while (std::getline(in, line)) {
    ++line_no;
    std::istringstream ls(line);
    std::string tag;
    if (!(ls >> tag)) continue;
    const std::string where = path + ":" + std::to_string(line_no);
    if (tag == "v") {
      // strtod, not >>: "nan" and "inf" parse, and are then refused as not finite by name.
      std::array<double, 3> v{};
      for (double& c : v) {
        std::string word;
        char* end = nullptr;
        if (!(ls >> word) || (c = std::strtod(word.c_str(), &end), end != word.c_str() + word.size()))
          throw ParseFailure{Errc::malformed, where + ": vertex does not parse"};
      }
      mesh.vertices.push_back(v);
    } else if (tag == "f") {
      face.clear();
      std::string item;
      while (ls >> item) {
        long long index = 0;
        const std::string number = item.substr(0, item.find('/'));
        char* end = nullptr;
        errno = 0;
        index = std::strtoll(number.c_str(), &end, 10);
        if (number.empty() || end != number.c_str() + number.size() || errno == ERANGE)
          fail_with(path + ":" + std::to_string(line_no), "bad face index '", item, "'");
        const auto n = static_cast<long long>(mesh.vertices.size());
        const long long resolved = index < 0 ? n + index : index - 1;
        if (resolved < 0 || resolved >= n)
          throw ParseFailure{Errc::malformed, where + ": face index " + std::to_string(index) + " out of range (" +
                                                  std::to_string(n) + " vertices so far)"};
        face.push_back(static_cast<std::uint32_t>(resolved));
      }
      if (face.size() < 3) throw ParseFailure{Errc::malformed, where + ": face with fewer than 3 vertices"};
      for (std::size_t k = 1; k + 1 < face.size(); ++k) add_triangle(path, mesh, face[0], face[k], face[k + 1]);
    }
  }
  return mesh;
}

MeshFileContents parse_ply_mesh(const std::string& path) {
  const PlyTable table = parse_ply(path);
  const int ix = table.find("x"), iy = table.find("y"), iz = table.find("z");
  if (ix < 0 || iy < 0 || iz < 0) fail(path, "the vertices lack x, y or z");
  MeshFileContents mesh;
  mesh.vertices.resize(table.vertex_count);
  for (std::size_t i = 0; i < table.vertex_count; ++i)
    mesh.vertices[i] = {table.columns[static_cast<std::size_t>(ix)][i], table.columns[static_cast<std::size_t>(iy)][i],
                        table.columns[static_cast<std::size_t>(iz)][i]};
  for (const auto& f : table.faces)
    for (std::size_t k = 1; k + 1 < f.size(); ++k) add_triangle(path, mesh, f[0], f[k], f[k + 1]);
  return mesh;
}

}  // namespace

int PlyTable::find(const std::string& name) const {
  for (std::size_t i = 0; i < property_names.size(); ++i)
    if (property_names[i] == name) return static_cast<int>(i);
  return -1;
}

Result<PlyTable> read_ply_table(const std::string& path) {
  try {
    return parse_ply(path);
  } catch (ParseFailure& failure) {
    return make_error(failure.code, std::move(failure.message));
  }
}

Result<MeshFileContents> read_mesh_file(const std::string& path) {
  const std::size_t dot = path.find_last_of("./");
  const std::string ext = dot == std::string::npos || path[dot] != '.' ? "" : lower(path.substr(dot));
  try {
    MeshFileContents mesh;
    if (ext == ".stl")
      mesh = parse_stl(path);
    else if (ext == ".obj")
      mesh = parse_obj(path);
    else if (ext == ".ply")
      mesh = parse_ply_mesh(path);
    else
      fail(path, "unknown mesh extension '" + ext + "' (STL, OBJ or PLY are read)", Errc::unsupported);
    for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
      const auto& v = mesh.vertices[i];
      if (!std::isfinite(v[0]) || !std::isfinite(v[1]) || !std::isfinite(v[2]))
        fail(path, "vertex " + std::to_string(i) + " is not finite (NaN or infinite coordinate)");
    }
    if (mesh.triangles.empty()) fail(path, "no triangles (a point cloud, or an empty mesh)");
    return mesh;
  } catch (ParseFailure& failure) {
    return make_error(failure.code, std::move(failure.message));
  }
}

}  // namespace slproto
