// Fewer triangles (slscan_mesh simplify_mesh, docs/mesh.md "Fewer triangles") on a sphere whose
// surface is known: a count target keeps the watertight promise (closed, outward, no
// self-intersection, filled faces still flagged where the hole was), and a tolerance keeps every
// face within it of the full mesh (the sphere's distance checked at each face's centre and edge
// midpoints, where a chord is farthest from the surface) while flat-enough regions coarsen.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "slscan/mesh/mesher.hpp"

namespace {

using slscan::core::MeshMode;
using slscan::core::MeshOptions;
using slscan::core::PointCloud;
using slscan::core::TriangleMesh;

const Eigen::Vector3f centre(5, -3, 40);
constexpr float radius = 10;

// A Fibonacci lattice on the sphere (directions with min_z <= z <= max_z), radial noise sigma.
PointCloud sphere(std::size_t n, float sigma, float min_z, float max_z) {
  std::mt19937_64 rng(7);
  std::normal_distribution<float> g(0, 1);
  PointCloud cloud;
  const double golden = std::numbers::pi * (3 - std::sqrt(5.0));
  for (std::size_t i = 0; i < n; ++i) {
    const double z = 1 - 2 * (static_cast<double>(i) + 0.5) / static_cast<double>(n);
    const double r = std::sqrt(1 - z * z), phi = golden * static_cast<double>(i);
    const Eigen::Vector3f d(static_cast<float>(r * std::cos(phi)), static_cast<float>(r * std::sin(phi)),
                            static_cast<float>(z));
    const float noise = g(rng);
    if (d.z() < min_z || d.z() > max_z) continue;
    cloud.points.push_back(centre + d * (radius + sigma * noise));
    cloud.normals.push_back(d);
    cloud.intensity.push_back(0.5f + 0.25f * d.x());
  }
  return cloud;
}

double off_sphere(const Eigen::Vector3f& p) { return std::abs((p - centre).norm() - radius); }

// The largest distance to the sphere over the measured faces' centres and edge midpoints.
double worst_face_distance(const TriangleMesh& mesh) {
  double worst = 0;
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    if (!mesh.filled.empty() && mesh.filled[t]) continue;
    const auto& tri = mesh.triangles[t];
    const Eigen::Vector3f a = mesh.vertices[tri[0]], b = mesh.vertices[tri[1]], c = mesh.vertices[tri[2]];
    for (const Eigen::Vector3f& p : {Eigen::Vector3f((a + b + c) / 3), Eigen::Vector3f((a + b) / 2),
                                     Eigen::Vector3f((b + c) / 2), Eigen::Vector3f((c + a) / 2), a, b, c})
      worst = std::max(worst, off_sphere(p));
  }
  return worst;
}

TEST(MeshSimplify, CountTargetKeepsTheWatertightMeshClosedAndItsFilledFacesFlagged) {
  const auto cloud = sphere(30000, 0.010f, -2, 0.95f);
  const auto full = slscan::mesh::build_mesh(cloud, {});
  ASSERT_TRUE(full.stats.closed);
  ASSERT_FALSE(full.stats.simplified);
  const std::size_t target = full.mesh.triangles.size() / 4;
  MeshOptions options;
  options.max_triangles = target;
  const auto result = slscan::mesh::build_mesh(cloud, options);
  const TriangleMesh& mesh = result.mesh;
  EXPECT_TRUE(result.stats.simplified) << result.stats.simplify_skipped;
  EXPECT_EQ(result.stats.triangles_before_simplify, full.mesh.triangles.size());
  EXPECT_LE(mesh.triangles.size(), target);
  EXPECT_GT(mesh.triangles.size(), target - 10);  // the count stops it, not a filter
  const auto check = slscan::mesh::check_mesh(mesh);
  EXPECT_TRUE(check.valid) << check.rejected_triangles << " refused";
  EXPECT_TRUE(check.closed);
  EXPECT_TRUE(result.stats.closed);
  EXPECT_EQ(check.self_intersections, 0u);
  EXPECT_TRUE(check.outward);
  // Every array per vertex / per face, normals unit and radial, intensity carried; every vertex
  // is one of the full mesh's, with its normal and intensity.
  ASSERT_EQ(mesh.normals.size(), mesh.vertices.size());
  ASSERT_EQ(mesh.intensity.size(), mesh.vertices.size());
  ASSERT_EQ(mesh.filled.size(), mesh.triangles.size());
  // The measured vertices' intensity is the points' around them (the patch's take the nearest
  // point's, far from them in the hole).
  std::vector<std::uint8_t> measured(mesh.vertices.size(), 0);
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
    if (!mesh.filled[t])
      for (const auto v : mesh.triangles[t]) measured[v] = 1;
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    ASSERT_NEAR(mesh.normals[i].norm(), 1.0f, 1e-4f) << "vertex " << i;
    ASSERT_GT(mesh.normals[i].dot((mesh.vertices[i] - centre).normalized()), 0.95f) << "vertex " << i;
    const float expected = 0.5f + 0.25f * (mesh.vertices[i] - centre).normalized().x();
    if (measured[i]) {
      ASSERT_NEAR(mesh.intensity[i], expected, 0.03f) << "vertex " << i;
    }
  }
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    const auto at = std::find(full.mesh.vertices.begin(), full.mesh.vertices.end(), mesh.vertices[i]);
    ASSERT_NE(at, full.mesh.vertices.end()) << "vertex " << i << " is new";
    const auto k = static_cast<std::size_t>(at - full.mesh.vertices.begin());
    ASSERT_EQ(mesh.normals[i], full.mesh.normals[k]) << "vertex " << i;
    ASSERT_EQ(mesh.intensity[i], full.mesh.intensity[k]) << "vertex " << i;
    if (i > 200) break;  // a sample: the search is linear
  }
  // The hole's patch is still flagged, and no more of the surface than before is.
  std::size_t filled = 0, filled_in_hole = 0;
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    if (!mesh.filled[t]) continue;
    ++filled;
    const auto& tri = mesh.triangles[t];
    const Eigen::Vector3f mid = (mesh.vertices[tri[0]] + mesh.vertices[tri[1]] + mesh.vertices[tri[2]]) / 3;
    if (((mid - centre) / radius).z() > 0.9f) ++filled_in_hole;
  }
  EXPECT_EQ(filled, result.stats.filled_triangles);
  EXPECT_GT(filled_in_hole, 0u);
  // 4x fewer faces on a 10 mm sphere: edges ~2x longer (~0.4 mm), chords ~2 um off it; the
  // measured surface stays within 30 um everywhere (the full mesh's worst vertex is ~20 um off).
  EXPECT_LT(worst_face_distance(mesh), 0.03);
  // The simplification has its own step, last, and counts in the mesh's time.
  ASSERT_FALSE(result.stats.step_ms.empty());
  EXPECT_EQ(result.stats.step_ms.back().first, "simplify");
}

TEST(MeshSimplify, ToleranceKeepsEveryFaceWithinItOfTheFullMesh) {
  const auto cloud = sphere(30000, 0.002f, -2, 2);
  MeshOptions options;
  options.mode = MeshMode::raw;
  const auto full = slscan::mesh::build_mesh(cloud, options);
  const double full_worst = worst_face_distance(full.mesh);
  ASSERT_LT(full_worst, 0.01);
  constexpr double tolerance = 0.004;  // mm
  options.simplify_tolerance_mm = tolerance;
  const auto result = slscan::mesh::build_mesh(cloud, options);
  EXPECT_TRUE(result.stats.simplified) << result.stats.simplify_skipped;
  // A 10 mm sphere at 4 um: chords up to sqrt(8 R t) ~ 0.57 mm, the cell's ~0.2 mm edges merge
  // into ~2.5x longer ones: several times fewer faces.
  EXPECT_LT(result.mesh.triangles.size(), full.mesh.triangles.size() / 3);
  // Every face point within the tolerance of the full mesh, which is within full_worst of the
  // sphere (its chords between vertices ~0.2 mm apart add < 1 um).
  EXPECT_LT(worst_face_distance(result.mesh), full_worst + tolerance + 0.001);
  const auto check = slscan::mesh::check_mesh(result.mesh);
  EXPECT_TRUE(check.valid);
  EXPECT_EQ(check.self_intersections, 0u);
  // A tighter tolerance keeps more faces: the bound, not a count, decides.
  options.simplify_tolerance_mm = tolerance / 4;
  const auto tighter = slscan::mesh::build_mesh(cloud, options);
  EXPECT_GT(tighter.mesh.triangles.size(), result.mesh.triangles.size());
  EXPECT_LT(worst_face_distance(tighter.mesh), full_worst + tolerance / 4 + 0.001);
}

TEST(MeshSimplify, NothingAskedNothingDoneAndAbsurdOptionsAreRefused) {
  const auto cloud = sphere(8000, 0.005f, -2, 2);
  MeshOptions options;
  options.max_triangles = 100000000;  // more than the mesh has: no change, no step
  const auto result = slscan::mesh::build_mesh(cloud, options);
  EXPECT_FALSE(result.stats.simplified);
  EXPECT_TRUE(result.stats.simplify_skipped.empty());
  EXPECT_EQ(result.stats.triangles_before_simplify, result.mesh.triangles.size());
  const auto plain = slscan::mesh::build_mesh(cloud, {});
  EXPECT_EQ(plain.mesh.triangles, result.mesh.triangles);

  MeshOptions bad;
  bad.max_triangles = 3;
  EXPECT_THROW(slscan::mesh::build_mesh(cloud, bad), std::invalid_argument);
  bad = {};
  bad.simplify_tolerance_mm = 2;
  EXPECT_THROW(slscan::mesh::build_mesh(cloud, bad), std::invalid_argument);
  bad.simplify_tolerance_mm = std::nan("");
  EXPECT_THROW(slscan::mesh::build_mesh(cloud, bad), std::invalid_argument);
}

}  // namespace
