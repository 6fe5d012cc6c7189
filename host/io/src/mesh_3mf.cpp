// 3MF through lib3mf (Debian's lib3mf-dev 1.8: the C interface of NMR_DLLInterfaces.h). Every
// handle is released on every path (the ASan build's LeakSanitizer checks the tests).
#include <Model/COM/NMR_DLLInterfaces.h>

#include <array>
#include <cstdio>
#include <cstring>
#include <string>
#include <utility>

#include "slscan/io/io_error.hpp"
#include "slscan/io/mesh_file.hpp"

namespace slscan::io {

namespace {

// One lib3mf object handle, released when it goes out of scope.
class Handle {
 public:
  Handle() = default;
  Handle(const Handle&) = delete;
  Handle& operator=(const Handle&) = delete;
  ~Handle() {
    if (p_ != nullptr) NMR::lib3mf_release(p_);
  }
  NMR::PLib3MFBase* get() const { return p_; }
  NMR::PLib3MFBase** out() { return &p_; }

 private:
  NMR::PLib3MFBase* p_ = nullptr;
};

// lib3mf's own message for a failed call, prefixed with the file and what was being done.
void check(HRESULT result, NMR::PLib3MFBase* instance, const std::string& path, const char* what) {
  if (result == LIB3MF_OK) return;
  DWORD code = 0;
  LPCSTR message = nullptr;
  std::string detail;
  if (instance != nullptr && NMR::lib3mf_getlasterror(instance, &code, &message) == LIB3MF_OK && message != nullptr)
    detail = message;
  char hex[16];
  std::snprintf(hex, sizeof hex, "0x%08x", static_cast<unsigned>(result));
  throw IoError(path + ": 3MF: " + what + " failed (lib3mf " + hex + (detail.empty() ? "" : ": " + detail) + ")");
}

// UUIDs from the mesh's bytes (FNV-1a, 64 bit, two seeds) in the form of a random (version 4)
// UUID: the same mesh gives the same file, as for the PLY and STL.
std::string content_uuid(const core::TriangleMesh& mesh, std::uint64_t salt) {
  std::array<std::uint64_t, 2> h{0xcbf29ce484222325ull ^ salt, 0x84222325cbf29ce4ull ^ (salt * 0x9e3779b97f4a7c15ull)};
  const auto mix = [&](const void* data, std::size_t bytes) {
    const auto* p = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < bytes; ++i)
      for (auto& x : h) x = (x ^ p[i]) * 0x100000001b3ull;
  };
  mix(mesh.vertices.data(), mesh.vertices.size() * sizeof(Eigen::Vector3f));
  mix(mesh.triangles.data(), mesh.triangles.size() * sizeof(mesh.triangles[0]));
  std::array<unsigned char, 16> b{};
  std::memcpy(b.data(), h.data(), 16);
  b[6] = static_cast<unsigned char>((b[6] & 0x0f) | 0x40);
  b[8] = static_cast<unsigned char>((b[8] & 0x3f) | 0x80);
  char text[40];
  std::snprintf(text, sizeof text, "%02x%02x%02x%02x-%02x%02x-%02x%02x-%02x%02x-%02x%02x%02x%02x%02x%02x", b[0], b[1],
                b[2], b[3], b[4], b[5], b[6], b[7], b[8], b[9], b[10], b[11], b[12], b[13], b[14], b[15]);
  return text;
}

// The writer's output, in memory: the zip container seeks back to write its headers.
struct Sink {
  std::string bytes;
  std::size_t position = 0;
};

extern "C" unsigned sink_write(unsigned char* data, unsigned count, void* user) {
  auto* sink = static_cast<Sink*>(user);
  if (sink->position + count > sink->bytes.size()) sink->bytes.resize(sink->position + count);
  std::memcpy(sink->bytes.data() + sink->position, data, count);
  sink->position += count;
  return 0;
}

extern "C" unsigned sink_seek(unsigned long long position, void* user) {
  auto* sink = static_cast<Sink*>(user);
  if (position > sink->bytes.size()) return 1;
  sink->position = static_cast<std::size_t>(position);
  return 0;
}

const char* object_type_name(DWORD type) {
  switch (type) {
    case NMR::MODELOBJECTTYPE_MODEL:
      return "model";
    case NMR::MODELOBJECTTYPE_SUPPORT:
      return "support";
    case NMR::MODELOBJECTTYPE_SOLIDSUPPORT:
      return "solidsupport";
    case NMR::MODELOBJECTTYPE_SURFACE:
      return "surface";
    default:
      return "other";
  }
}

struct Unit {
  const char* name;
  double mm;
};
Unit unit_of(DWORD unit) {
  switch (unit) {
    case NMR::MODELUNIT_MICROMETER:
      return {"micron", 1e-3};
    case NMR::MODELUNIT_MILLIMETER:
      return {"millimeter", 1};
    case NMR::MODELUNIT_CENTIMETER:
      return {"centimeter", 10};
    case NMR::MODELUNIT_INCH:
      return {"inch", 25.4};
    case NMR::MODELUNIT_FOOT:
      return {"foot", 304.8};
    case NMR::MODELUNIT_METER:
      return {"meter", 1000};
    default:
      return {"unknown", 0};
  }
}

}  // namespace

void write_3mf(const std::string& path, const core::TriangleMesh& mesh, const std::string& name) {
  const std::size_t n = mesh.vertices.size();
  if (n > 0xffffffffu || mesh.triangles.size() > 0xffffffffu)
    throw IoError(path + ": 3MF: more than 2^32 vertices or triangles");
  std::vector<NMR::MODELMESHVERTEX> vertices(n);
  for (std::size_t i = 0; i < n; ++i)
    for (int k = 0; k < 3; ++k) vertices[i].m_fPosition[k] = mesh.vertices[i][k];
  std::vector<NMR::MODELMESHTRIANGLE> triangles(mesh.triangles.size());
  for (std::size_t t = 0; t < triangles.size(); ++t)
    for (std::size_t k = 0; k < 3; ++k) {
      if (mesh.triangles[t][k] >= n)
        throw IoError(path + ": triangle " + std::to_string(t) + " refers to vertex " +
                      std::to_string(mesh.triangles[t][k]) + " of " + std::to_string(n));
      triangles[t].m_nIndices[k] = mesh.triangles[t][k];
    }
  const core::MeshTopology topology = core::mesh_topology(mesh);
  const bool solid = topology.closed() && topology.inconsistent_edges == 0;

  Handle model, object, item, writer;
  check(NMR::lib3mf_createmodel(model.out()), nullptr, path, "creating the model");
  check(NMR::lib3mf_model_setunit(model.get(), NMR::MODELUNIT_MILLIMETER), model.get(), path, "setting the unit");
  check(NMR::lib3mf_model_addmeshobject(model.get(), object.out()), model.get(), path, "adding the mesh object");
  check(NMR::lib3mf_meshobject_setgeometry(object.get(), vertices.data(), static_cast<DWORD>(vertices.size()),
                                           triangles.data(), static_cast<DWORD>(triangles.size())),
        object.get(), path, "setting the mesh");
  check(NMR::lib3mf_object_settype(object.get(), solid ? NMR::MODELOBJECTTYPE_MODEL : NMR::MODELOBJECTTYPE_SURFACE),
        object.get(), path, "setting the object type");
  check(NMR::lib3mf_object_setnameutf8(object.get(), name.c_str()), object.get(), path, "naming the object");
  check(NMR::lib3mf_object_setuuidutf8(object.get(), content_uuid(mesh, 1).c_str()), object.get(), path,
        "setting the object's UUID");
  check(NMR::lib3mf_model_addbuilditem(model.get(), object.get(), nullptr, item.out()), model.get(), path,
        "adding the build item");
  check(NMR::lib3mf_builditem_setuuidutf8(item.get(), content_uuid(mesh, 2).c_str()), item.get(), path,
        "setting the build item's UUID");
  check(NMR::lib3mf_model_setbuilduuidutf8(model.get(), content_uuid(mesh, 3).c_str()), model.get(), path,
        "setting the build's UUID");
  check(NMR::lib3mf_model_querywriter(model.get(), "3mf", writer.out()), model.get(), path, "creating the writer");
  Sink sink;
  check(NMR::lib3mf_writer_writetocallback(writer.get(), reinterpret_cast<void*>(&sink_write),
                                           reinterpret_cast<void*>(&sink_seek), &sink),
        writer.get(), path, "writing");
  write_file_atomically(path, sink.bytes);
}

ThreeMfContents read_3mf(const std::string& path) {
  Handle model, reader, items;
  check(NMR::lib3mf_createmodel(model.out()), nullptr, path, "creating the model");
  check(NMR::lib3mf_model_queryreader(model.get(), "3mf", reader.out()), model.get(), path, "creating the reader");
  check(NMR::lib3mf_reader_readfromfileutf8(reader.get(), path.c_str()), reader.get(), path, "reading");
  ThreeMfContents contents;
  DWORD unit_code = 0;
  check(NMR::lib3mf_model_getunit(model.get(), &unit_code), model.get(), path, "reading the unit");
  const Unit unit = unit_of(unit_code);
  if (!(unit.mm > 0)) throw IoError(path + ": 3MF: unknown unit code " + std::to_string(unit_code));
  contents.unit = unit.name;
  // The build items say what is made, each an object placed by its transform.
  check(NMR::lib3mf_model_getbuilditems(model.get(), items.out()), model.get(), path, "listing the build items");
  for (;;) {
    BOOL more = 0;
    check(NMR::lib3mf_builditemiterator_movenext(items.get(), &more), items.get(), path, "listing the build items");
    if (!more) break;
    Handle item, object;
    check(NMR::lib3mf_builditemiterator_getcurrent(items.get(), item.out()), items.get(), path, "reading a build item");
    ++contents.build_items;
    check(NMR::lib3mf_builditem_getobjectresource(item.get(), object.out()), item.get(), path,
          "reading a build item's object");
    BOOL is_mesh = 0;
    check(NMR::lib3mf_object_ismeshobject(object.get(), &is_mesh), object.get(), path, "reading an object");
    if (!is_mesh)
      throw IoError(path + ": 3MF: build item " + std::to_string(contents.build_items) +
                    " is a components object (an assembly); only mesh objects are read");
    DWORD type = 0;
    check(NMR::lib3mf_object_gettype(object.get(), &type), object.get(), path, "reading an object's type");
    contents.object_types.emplace_back(object_type_name(type));
    NMR::MODELTRANSFORM transform{};
    for (int r = 0; r < 3; ++r) transform.m_fFields[r][r] = 1;
    BOOL has_transform = 0;
    check(NMR::lib3mf_builditem_hasobjecttransform(item.get(), &has_transform), item.get(), path,
          "reading a build item's transform");
    if (has_transform)
      check(NMR::lib3mf_builditem_getobjecttransform(item.get(), &transform), item.get(), path,
            "reading a build item's transform");
    DWORD vertex_count = 0, triangle_count = 0;
    check(NMR::lib3mf_meshobject_getvertexcount(object.get(), &vertex_count), object.get(), path, "reading a mesh");
    check(NMR::lib3mf_meshobject_gettrianglecount(object.get(), &triangle_count), object.get(), path, "reading a mesh");
    std::vector<NMR::MODELMESHVERTEX> vertices(vertex_count);
    std::vector<NMR::MODELMESHTRIANGLE> triangles(triangle_count);
    if (vertex_count > 0)
      check(NMR::lib3mf_meshobject_getvertices(object.get(), vertices.data(), vertex_count, nullptr), object.get(),
            path, "reading the vertices");
    if (triangle_count > 0)
      check(NMR::lib3mf_meshobject_gettriangleindices(object.get(), triangles.data(), triangle_count, nullptr),
            object.get(), path, "reading the triangles");
    const auto base = static_cast<std::uint32_t>(contents.mesh.vertices.size());
    for (const auto& v : vertices) {
      Eigen::Vector3f p;
      for (int r = 0; r < 3; ++r) {
        double x = transform.m_fFields[r][3];
        for (int c = 0; c < 3; ++c) x += static_cast<double>(transform.m_fFields[r][c]) * v.m_fPosition[c];
        p[r] = static_cast<float>(x * unit.mm);
      }
      contents.mesh.vertices.push_back(p);
    }
    for (std::size_t t = 0; t < triangles.size(); ++t) {
      std::array<std::uint32_t, 3> tri{};
      for (std::size_t k = 0; k < 3; ++k) {
        if (triangles[t].m_nIndices[k] >= vertex_count)
          throw IoError(path + ": 3MF: triangle " + std::to_string(t) + " refers to vertex " +
                        std::to_string(triangles[t].m_nIndices[k]) + " of " + std::to_string(vertex_count));
        tri[k] = base + triangles[t].m_nIndices[k];
      }
      contents.mesh.triangles.push_back(tri);
    }
  }
  return contents;
}

}  // namespace slscan::io
