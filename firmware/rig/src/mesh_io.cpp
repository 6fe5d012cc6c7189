// Scene meshes from PLY, OBJ and STL files through slproto's reader (the host reads nominals
// with the same one), as the triangle soup the ray caster builds its hierarchy from.
#include "scene_build.hpp"
#include "slproto/mesh_file.hpp"

namespace slrig::detail {

slproto::Result<std::vector<Triangle>> load_mesh_file(const std::string& path) {
  auto file = slproto::read_mesh_file(path);
  if (!file) return std::move(file).error();
  std::vector<Triangle> triangles;
  triangles.reserve(file->triangles.size());
  const auto& v = file->vertices;
  for (const auto& t : file->triangles) {
    const auto& a = v[t[0]];
    const auto& b = v[t[1]];
    const auto& c = v[t[2]];
    triangles.push_back({{a[0], a[1], a[2]}, {b[0], b[1], b[2]}, {c[0], c[1], c[2]}});
  }
  return triangles;
}

}  // namespace slrig::detail
