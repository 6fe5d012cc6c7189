// The rig's ray casting against brute force: the BVH must return exactly the nearest triangle
// a linear scan finds, for the procedural meshes the presets use.
#include <gtest/gtest.h>

#include <array>
#include <cmath>

#include "geometry.hpp"
#include "scene_build.hpp"

namespace slrig::detail {
namespace {

bool brute_force(const std::vector<Triangle>& tris, V3 o, V3 d, double& best) {
  bool found = false;
  best = 1e300;
  for (const Triangle& t : tris) {
    const V3 e1 = t.b - t.a, e2 = t.c - t.a, p = cross(d, e2);
    const double det = dot(e1, p);
    if (std::abs(det) < 1e-300) continue;
    const V3 s = o - t.a;
    const double u = dot(s, p) / det;
    if (u < 0 || u > 1) continue;
    const V3 q = cross(s, e1);
    const double v = dot(d, q) / det;
    if (v < 0 || u + v > 1) continue;
    const double tt = dot(e2, q) / det;
    if (tt > 0 && tt < best) {
      best = tt;
      found = true;
    }
  }
  return found;
}

void compare_with_brute_force(const std::vector<Triangle>& tris, V3 target, double spread) {
  const Mesh mesh(tris);
  std::uint64_t h = 12345;
  int hits = 0;
  for (int i = 0; i < 2000; ++i) {
    auto uniform = [&] {
      h = mix64(h);
      return static_cast<double>(h >> 11) / 9007199254740992.0 - 0.5;
    };
    const V3 origin{300 * uniform(), -400, 200 + 100 * uniform()};
    const V3 aim = target + V3{spread * uniform(), spread * uniform(), spread * uniform()};
    const V3 d = aim - origin;
    double t_bvh = 0, t_ref = 0;
    std::uint32_t tri = 0;
    const bool a = mesh.intersect(origin, d, 0, 1e300, t_bvh, tri);
    const bool b = brute_force(tris, origin, d, t_ref);
    ASSERT_EQ(a, b) << "ray " << i;
    if (a) {
      ++hits;
      ASSERT_NEAR(t_bvh, t_ref, 1e-12 * t_ref) << "ray " << i;
      ASSERT_EQ(mesh.occluded(origin, d, 0, t_ref * (1 + 1e-9)), true);
      ASSERT_EQ(mesh.occluded(origin, d, 0, t_ref * (1 - 1e-9)), false);
    }
  }
  EXPECT_GT(hits, 400);
}

TEST(Geometry, BladeBvhMatchesBruteForce) {
  SceneObject blade;
  blade.kind = ObjectKind::blade;
  blade.width = 120;
  blade.height = 60;
  compare_with_brute_force(blade_mesh(blade), {0, 0, 60}, 80);
}

TEST(Geometry, TeacupBvhMatchesBruteForce) {
  SceneObject cup;
  cup.kind = ObjectKind::teacup;
  cup.radius = 40;
  cup.height = 70;
  cup.thickness = 3;
  auto tris = teacup_mesh(cup);
  const auto handle = teacup_handle_triangles(cup);
  tris.insert(tris.end(), handle.begin(), handle.end());
  compare_with_brute_force(tris, {20, 0, 35}, 100);
}

TEST(Geometry, ClosedMeshesAreWatertightEnoughForShadows) {
  // A ray from inside the blade must leave through exactly one surface crossing per wall:
  // count crossings along +x from the centroid of a mid-span section.
  SceneObject blade;
  blade.kind = ObjectKind::blade;
  blade.width = 120;
  blade.height = 60;
  const Mesh mesh(blade_mesh(blade));
  int crossings = 0;
  V3 origin{0, 0.5, 60};
  double t_from = 0;
  for (;;) {
    double t;
    std::uint32_t tri;
    if (!mesh.intersect(origin, {1, 0.01, 0.003}, t_from, 1e9, t, tri)) break;
    ++crossings;
    t_from = t + 1e-9;
  }
  EXPECT_EQ(crossings % 2, 1) << "a point inside a closed surface sees an odd number of crossings";
}

TEST(Geometry, CylinderAndBoxHitsAreExact) {
  World world;
  Primitive cyl;
  cyl.kind = PrimitiveKind::cylinder;
  cyl.a = 5;
  cyl.b = -10;
  cyl.c = 10;
  cyl.cam_from_local.t = {0, 0, 100};
  Primitive box;
  box.kind = PrimitiveKind::box;
  box.lo = {-5, -5, 0};
  box.hi = {5, 5, 2};
  box.cam_from_local.t = {50, 0, 200};
  world.primitives = {cyl, box};
  for (Primitive& p : world.primitives) compute_bounds(p);
  Hit hit;
  // The cylinder's axis is camera z: a ray along z at x = 3 meets the side... never (parallel);
  // a ray along x at z = 100, y = 0 meets it at x = -5.
  ASSERT_TRUE(world.intersect({-50, 0, 100}, {1, 0, 0}, 0, 1e9, hit));
  EXPECT_NEAR(hit.t, 45, 1e-12);
  EXPECT_NEAR(hit.normal.x, -1, 1e-12);
  EXPECT_FALSE(world.intersect({-50, 0, 111}, {1, 0, 0}, 0, 1e9, hit)) << "beyond the open end";
  ASSERT_TRUE(world.intersect({50, 0, 0}, {0, 0, 1}, 0, 1e9, hit));
  EXPECT_NEAR(hit.t, 200, 1e-12);
  EXPECT_NEAR(hit.normal.z, -1, 1e-12);
  EXPECT_TRUE(world.occluded({50, 0, 0}, {0, 0, 1}, 0, 201));
  EXPECT_FALSE(world.occluded({50, 0, 0}, {0, 0, 1}, 0, 199));
}

// A camera pixel's albedo is the box-filtered checkerboard over its footprint: the exact
// clipping in footprint_albedo against a dense grid of albedo_at samples over the same
// quadrilateral (parallelograms, so the grid is uniform in area), on a tilted board.
TEST(Geometry, FootprintAlbedoIsTheMeanOverThePixel) {
  World world;
  Primitive board;
  board.kind = PrimitiveKind::box;
  board.lo = {-15, -15, 0};
  board.hi = {45, 35, 3};
  board.material.checker = true;
  board.material.square = 10;
  board.material.squares_x = 6;
  board.material.squares_y = 5;
  board.material.albedo = 0.8;
  board.material.dark_albedo = 0.05;
  const double c = std::cos(0.5), s = std::sin(0.5);  // tilted 29 deg about x
  board.cam_from_local.R[4] = c;
  board.cam_from_local.R[5] = -s;
  board.cam_from_local.R[7] = s;
  board.cam_from_local.R[8] = c;
  board.cam_from_local.t = {-10, -5, 300};
  world.primitives = {board};
  for (Primitive& p : world.primitives) compute_bounds(p);

  std::uint64_t h = 777;
  auto uniform = [&] {
    h = mix64(h);
    return static_cast<double>(h >> 11) / 9007199254740992.0;
  };
  int mixed = 0;
  for (int trial = 0; trial < 150; ++trial) {
    // A parallelogram about 0.5 .. 3 mm across, anywhere on the print and around it.
    const V3 centre{-20 + 70 * uniform(), -20 + 60 * uniform(), 0};
    const V3 e1{0.5 + 2.5 * uniform(), 1.5 * (uniform() - 0.5), 0};
    const V3 e2{1.5 * (uniform() - 0.5), 0.5 + 2.5 * uniform(), 0};
    const std::array<V3, 4> local{centre - 0.5 * e1 - 0.5 * e2, centre + 0.5 * e1 - 0.5 * e2,
                                  centre + 0.5 * e1 + 0.5 * e2, centre - 0.5 * e1 + 0.5 * e2};
    std::array<V3, 4> directions;
    for (std::size_t k = 0; k < 4; ++k) directions[k] = board.cam_from_local.apply(local[k]);
    Hit hit;
    const V3 centre_cam = board.cam_from_local.apply(centre);
    // Off the plate, or on its edge: no printed face there.
    if (!world.intersect({0, 0, 0}, centre_cam, 0, 1e9, hit) || std::abs(hit.local.z) > 1e-6) continue;
    const double exact = world.footprint_albedo(hit, {0, 0, 0}, directions);
    constexpr int kGrid = 200;
    double sum = 0;
    int dark = 0;
    Hit sample = hit;
    for (int i = 0; i < kGrid; ++i)
      for (int j = 0; j < kGrid; ++j) {
        const double a = (i + 0.5) / kGrid - 0.5, b = (j + 0.5) / kGrid - 0.5;
        sample.local = centre + a * e1 + b * e2;
        sample.local.z = 0;
        const double albedo = world.albedo_at(sample);
        sum += albedo;
        dark += albedo == board.material.dark_albedo ? 1 : 0;
      }
    const double brute = sum / (kGrid * kGrid);
    EXPECT_NEAR(exact, brute, 2e-3) << "trial " << trial;
    if (dark > 0 && dark < kGrid * kGrid)
      ++mixed;
    else
      EXPECT_EQ(exact, world.albedo_at(hit)) << "a footprint inside one square is that square's albedo";
  }
  EXPECT_GT(mixed, 20) << "too few footprints straddled an edge to test anything";
}

}  // namespace
}  // namespace slrig::detail
