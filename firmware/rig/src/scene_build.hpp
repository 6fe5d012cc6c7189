// Turning a Scene into ray-castable geometry: each object's parts in its own frame, the meshes
// of the procedural shapes, and the world of one view in the camera frame.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "geometry.hpp"
#include "slrig/rig.hpp"

namespace slrig::detail {

// Object ids in ViewGroundTruth::object_id.
inline constexpr std::int16_t kTurntableId = 0;
inline constexpr std::int16_t kWallId = 1;
inline constexpr std::int16_t kFirstObjectId = 2;

// The parts of one object, each with cam_from_local meaning object_from_part.
slproto::Result<std::vector<Primitive>> object_parts(const SceneObject& object);

// Procedural meshes in the object frame (z up, base on z = 0).
std::vector<Triangle> blade_mesh(const SceneObject& object);
std::vector<Triangle> teacup_mesh(const SceneObject& object);
std::vector<Triangle> teacup_handle_triangles(const SceneObject& object);
// Triangle mesh from a PLY (ASCII or binary little-endian), OBJ or STL (ASCII or binary) file.
slproto::Result<std::vector<Triangle>> load_mesh_file(const std::string& path);

// The pose the table actually reaches for a commanded angle (angle error, wobble).
slproto::RigidTransform actual_cam_from_table(const Scene& scene, double commanded_angle_deg, int view_index,
                                              double& actual_angle_deg);

// cam_from_object for an object on a table at cam_from_table.
slproto::RigidTransform cam_from_object(const SceneObject& object, const slproto::RigidTransform& cam_from_table);

struct PreparedObjects {
  std::vector<std::vector<Primitive>> parts;  // per scene object, in the object frame
};
slproto::Result<PreparedObjects> prepare_objects(const Scene& scene);

// The world of one view in the camera frame: turntable, wall, objects.
World build_world(const Scene& scene, const PreparedObjects& prepared, const slproto::RigidTransform& cam_from_table);

// Small counter-based hash (SplitMix64 finaliser): the rig's only source of randomness.
inline std::uint64_t mix64(std::uint64_t z) {
  z += 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}
// A standard normal from a hash: Box-Muller on two 32-bit uniforms (exact, for the few draws
// outside the per-pixel loop).
double normal_from_hash(std::uint64_t h);

}  // namespace slrig::detail
