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

double read_binary(const char* p, PlyType t) {
  switch (t) {
    case PlyType::i8:
      return static_cast<double>(*reinterpret_cast<const std::int8_t*>(p));
    case PlyType::u8:
      return static_cast<double>(*reinterpret_cast<const std::uint8_t*>(p));
    case PlyType::i16: {
      std::int16_t v;
      std::memcpy(&v, p, 2);
      return v;
    }
    case PlyType::u16: {
      std::uint16_t v;
      std::memcpy(&v, p, 2);
      return v;
    }
    case PlyType::i32: {
      std::int32_t v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case PlyType::u32: {
      std::uint32_t v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case PlyType::f32: {
      float v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case PlyType::f64: {
      double v;
      std::memcpy(&v, p, 8);
      return v;
    }
  }
  return 0;
}

[[noreturn]] void fail(const std::string& path, const std::string& what) { throw IoError(path + ": " + what); }

// Lists longer than this are not faces of any mesh we read: a corrupt count, refused before
// it allocates.
constexpr double kMaxListItems = 1024;

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

}  // namespace

int PlyTable::find(const std::string& name) const {
  for (std::size_t i = 0; i < property_names.size(); ++i)
    if (property_names[i] == name) return static_cast<int>(i);
  return -1;
}

const std::vector<double>& PlyTable::column(const std::string& name) const {
  const int i = find(name);
  if (i < 0) throw IoError("PLY has no vertex property '" + name + "'");
  return columns[static_cast<std::size_t>(i)];
}

PlyTable read_ply_table(const std::string& path) {
  static_assert(std::endian::native == std::endian::little, "binary PLY reading assumes a little-endian host");
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(path, std::string("cannot open (") + std::strerror(errno) + ")");
  std::string line;
  if (!std::getline(in, line) || line.rfind("ply", 0) != 0) fail(path, "not a PLY file (no 'ply' magic on line 1)");
  std::string format;
  std::vector<PlyElement> elements;
  PlyTable table;
  int line_no = 1;
  bool header_done = false;
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream words(line);
    std::string keyword;
    words >> keyword;
    const std::string where = "header line " + std::to_string(line_no);
    if (keyword == "format") {
      std::string version;
      words >> format >> version;
      if (format != "ascii" && format != "binary_little_endian")
        fail(path, where + ": format '" + format + "' is not supported (ascii or binary_little_endian)");
    } else if (keyword == "comment" || keyword == "obj_info") {
      table.comments.push_back(line.size() > keyword.size() + 1 ? line.substr(keyword.size() + 1) : "");
    } else if (keyword == "element") {
      PlyElement element;
      long long count = -1;
      // A count that does not parse leaves 0 in `count`, so the extraction itself is checked.
      if (!(words >> element.name >> count) || count < 0 || count > (1LL << 32))
        fail(path, where + ": malformed element line '" + line + "'");
      // The columns are the vertex element's: a second one would index past them.
      for (const PlyElement& earlier : elements) {
        if (earlier.name == element.name && (element.name == "vertex" || element.name == "face"))
          fail(path, where + ": a second '" + element.name + "' element");
      }
      element.count = static_cast<std::size_t>(count);
      elements.push_back(element);
    } else if (keyword == "property") {
      if (elements.empty()) fail(path, where + ": property before any element");
      PlyProperty property;
      std::string type;
      words >> type;
      if (type == "list") {
        std::string count_type, item_type;
        words >> count_type >> item_type >> property.name;
        property.is_list = true;
        if (!parse_type(count_type, property.count_type) || !parse_type(item_type, property.type))
          fail(path, where + ": unknown list types in '" + line + "'");
      } else {
        words >> property.name;
        if (!parse_type(type, property.type)) fail(path, where + ": unknown property type '" + type + "'");
      }
      if (property.name.empty()) fail(path, where + ": property without a name");
      elements.back().properties.push_back(property);
    } else if (keyword == "end_header") {
      header_done = true;
      break;
    } else if (!keyword.empty()) {
      fail(path, where + ": unknown keyword '" + keyword + "'");
    }
  }
  if (!header_done) fail(path, "header has no end_header");
  if (format.empty()) fail(path, "header has no format line");

  // The header's counts size the columns: a short corrupt header must not allocate gigabytes.
  // Each record needs at least its fixed bytes (binary) or one character and a separator per
  // value (ASCII), so the counts are checked against what the file still holds.
  {
    const std::streampos body = in.tellg();
    in.seekg(0, std::ios::end);
    const std::streamoff remaining = in.tellg() - body;
    in.seekg(body);
    if (!in || remaining < 0) fail(path, "cannot determine the file's size");
    long double needed = 0;
    for (const PlyElement& element : elements) {
      long double per_record = 0;
      bool all_fixed = true;
      for (const auto& p : element.properties) {
        per_record += format == "ascii" ? 2 : type_size(p.is_list ? p.count_type : p.type);
        all_fixed = all_fixed && !p.is_list;
      }
      const long double before = needed;
      needed += per_record * static_cast<long double>(element.count);
      if (needed <= static_cast<long double>(remaining) + 1) continue;  // + 1: the last ASCII value needs no separator
      const std::string promised = "the header promises at least " + std::to_string(static_cast<double>(needed)) +
                                   " bytes of elements, the file has " + std::to_string(remaining) + " after it";
      if (format != "ascii" && all_fixed && per_record > 0) {
        const auto index = static_cast<std::size_t>(
            std::max<long double>(0, static_cast<long double>(remaining) - before) / per_record);
        fail(path, "file ends in " + element.name + " " + std::to_string(index) + " of " +
                       std::to_string(element.count) + " (truncated: " + promised + ")");
      }
      fail(path, promised + " (truncated?)");
    }
  }

  for (const PlyElement& element : elements) {
    // An element without properties has no bytes to read (the fuzzer gave one 4 billion records).
    if (element.properties.empty()) continue;
    const bool is_vertex = element.name == "vertex";
    const bool is_face = element.name == "face";
    if (is_vertex) {
      table.vertex_count = element.count;
      for (const auto& p : element.properties) {
        if (p.is_list) fail(path, "vertex list properties are not supported ('" + p.name + "')");
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
      if (format == "ascii") {
        if (!std::getline(in, line))
          fail(path, "file ends in " + where + " (expected " + std::to_string(element.count) + ")");
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
          fail(path, "file ends in " + where + " of " + std::to_string(element.count) + " (truncated)");
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
            fail(path, "file ends in " + where + " (truncated)");
          if (!prop.is_list) continue;
          std::vector<std::uint32_t> items(list_length(path, where, prop.name, read_binary(buffer, prop.count_type)));
          const std::size_t item_size = type_size(prop.type);
          for (auto& item : items) {
            if (!in.read(buffer, static_cast<std::streamsize>(item_size)))
              fail(path, "file ends in " + where + " (truncated)");
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
