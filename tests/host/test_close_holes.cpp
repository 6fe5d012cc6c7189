// The watertight closure (slscan::mesh::close_holes) on hand-made meshes: it builds CGAL's
// half-edge mesh only around the holes (docs/mesh.md, "Closing only near the holes"), so a
// surface far from every border must still stop a patch that crosses it, the edge of the part
// it built must not count as a hole, and the triangles it did not build must come back as they
// were, where they were.
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cstdint>
#include <functional>
#include <map>
#include <vector>

#include "slscan/mesh/mesher.hpp"

namespace {

using slscan::core::TriangleMesh;

// A box's surface, each face an n x n grid of squares (two triangles each), counter-clockwise
// seen from outside; `skip(axis, side, u, v)` leaves a square out (a hole).
void add_box(TriangleMesh& mesh, const Eigen::Vector3f& lo, const Eigen::Vector3f& hi, int n,
             const std::function<bool(int, int, int, int)>& skip = {}) {
  std::map<std::array<int, 3>, std::uint32_t> index;
  const auto vertex = [&](std::array<int, 3> g) {
    const auto [it, added] = index.try_emplace(g, static_cast<std::uint32_t>(mesh.vertices.size()));
    if (added) {
      Eigen::Vector3f p;
      for (int a = 0; a < 3; ++a)
        p[a] = lo[a] + (hi[a] - lo[a]) * static_cast<float>(g[static_cast<std::size_t>(a)]) / static_cast<float>(n);
      mesh.vertices.push_back(p);
      mesh.normals.push_back((p - (lo + hi) / 2).normalized());
    }
    return it->second;
  };
  for (int a = 0; a < 3; ++a)
    for (const int side : {0, 1}) {
      const int b = (a + 1) % 3, c = (a + 2) % 3;
      for (int u = 0; u < n; ++u)
        for (int v = 0; v < n; ++v) {
          if (skip && skip(a, side, u, v)) continue;
          const auto at = [&](int du, int dv) {
            std::array<int, 3> g{};
            g[static_cast<std::size_t>(a)] = side * n;
            g[static_cast<std::size_t>(b)] = u + du;
            g[static_cast<std::size_t>(c)] = v + dv;
            return vertex(g);
          };
          const std::uint32_t p00 = at(0, 0), p10 = at(1, 0), p11 = at(1, 1), p01 = at(0, 1);
          // b x c = a: counter-clockwise seen from +a; the side at 0 looks the other way.
          if (side == 1) {
            mesh.triangles.push_back({p00, p10, p11});
            mesh.triangles.push_back({p00, p11, p01});
          } else {
            mesh.triangles.push_back({p00, p11, p10});
            mesh.triangles.push_back({p00, p01, p11});
          }
          mesh.filled.push_back(0);
          mesh.filled.push_back(0);
        }
    }
}

// A 20 mm box of 1 mm squares with a 4 x 4 mm opening in the middle of its top.
TriangleMesh box_with_opening() {
  TriangleMesh mesh;
  add_box(mesh, {0, 0, 0}, {20, 20, 20}, 20, [](int axis, int side, int u, int v) {
    return axis == 2 && side == 1 && u >= 8 && u < 12 && v >= 8 && v < 12;
  });
  return mesh;
}

struct Closure {
  slscan::core::MeshStats stats;
  std::vector<std::size_t> crossed;  // triangles of the mesh given that a patch crossed
};

Closure close(TriangleMesh& mesh) {
  Closure closure;
  slscan::core::MeshOptions options;
  options.fill_holes_mm = 10;
  slscan::mesh::close_holes(mesh, options, closure.stats, {}, &closure.crossed);
  return closure;
}

TEST(CloseHoles, OpeningIsClosedAndEveryOtherTriangleComesBackInPlace) {
  TriangleMesh mesh = box_with_opening();
  const TriangleMesh given = mesh;
  const auto [stats, crossed] = close(mesh);
  // One hole: the edge of the part built into the half-edge mesh is not one.
  EXPECT_EQ(stats.holes, 1u);
  EXPECT_EQ(stats.holes_left_open, 0u);
  EXPECT_TRUE(crossed.empty());
  const auto check = slscan::mesh::check_mesh(mesh);
  EXPECT_TRUE(check.closed);
  EXPECT_EQ(check.self_intersections, 0u);
  EXPECT_TRUE(check.outward);
  // The given vertices and triangles first, unchanged and in their order; the patch after them.
  ASSERT_GT(mesh.triangles.size(), given.triangles.size());
  ASSERT_GE(mesh.vertices.size(), given.vertices.size());
  for (std::size_t i = 0; i < given.vertices.size(); ++i) ASSERT_EQ(mesh.vertices[i], given.vertices[i]) << i;
  for (std::size_t t = 0; t < given.triangles.size(); ++t) {
    ASSERT_EQ(mesh.triangles[t], given.triangles[t]) << t;
    ASSERT_EQ(mesh.filled[t], 0) << t;
  }
  for (std::size_t t = given.triangles.size(); t < mesh.triangles.size(); ++t) EXPECT_EQ(mesh.filled[t], 1) << t;
  EXPECT_EQ(stats.filled_triangles, mesh.triangles.size() - given.triangles.size());
}

TEST(CloseHoles, APatchCrossingASurfaceFarFromEveryBorderIsUndone) {
  // A closed 1 mm post standing through the opening, touching nothing: no border, so none of its
  // triangles are near a hole; every patch of the opening (plain, faired, fanned) crosses it.
  TriangleMesh mesh = box_with_opening();
  const std::size_t box_triangles = mesh.triangles.size();
  add_box(mesh, {9.5f, 9.5f, 15}, {10.5f, 10.5f, 25}, 4);
  const TriangleMesh given = mesh;
  const auto [stats, crossed] = close(mesh);
  EXPECT_EQ(stats.holes, 1u);
  EXPECT_EQ(stats.holes_left_open, 1u);
  EXPECT_EQ(stats.self_intersections, 0u);
  const auto check = slscan::mesh::check_mesh(mesh);
  EXPECT_EQ(check.self_intersections, 0u);
  EXPECT_FALSE(check.closed);
  // What the patches crossed: the post's sides, named by their triangles in the mesh given.
  ASSERT_FALSE(crossed.empty());
  EXPECT_TRUE(std::is_sorted(crossed.begin(), crossed.end()));
  for (const std::size_t t : crossed) {
    EXPECT_GE(t, box_triangles);
    EXPECT_LT(t, given.triangles.size());
  }
  // Nothing added, nothing lost.
  EXPECT_EQ(mesh.triangles, given.triangles);
  EXPECT_EQ(stats.filled_triangles, 0u);
}

}  // namespace
