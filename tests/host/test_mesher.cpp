// The level-set mesher (slscan_mesh, docs/mesh.md) on synthetic clouds with a known surface:
// a sphere (fidelity, closure, orientation), a sphere with a hole, a sphere with outliers, and
// clouds it must refuse. CGAL's own checks decide "closed" and "self-intersecting".
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <atomic>
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

Eigen::Vector3f centre_point() { return {5, -3, 40}; }
constexpr float radius = 10;

// Points on the sphere with direction min_z <= d.z() <= max_z: a Fibonacci lattice of n points
// over the whole sphere (even spacing, as a scanner's pixel grid gives; random points leave
// gaps of several spacings that are holes to the trim), Gaussian radial noise.
PointCloud sphere(std::size_t n, float sigma, float min_z, float max_z, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
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
    cloud.points.push_back(centre_point() + d * (radius + sigma * noise));
    cloud.normals.push_back(d);
  }
  return cloud;
}

struct Fidelity {
  double rms = 0, worst = 0, bad_faces = 0;  // mm, mm, fraction of faces > 10 deg off radial
};

Fidelity fidelity(const slscan::core::TriangleMesh& mesh, bool skip_filled = true) {
  Fidelity f;
  for (const auto& v : mesh.vertices) {
    const double e = (v - centre_point()).norm() - radius;
    f.rms += e * e;
    f.worst = std::max(f.worst, std::abs(e));
  }
  f.rms = std::sqrt(f.rms / static_cast<double>(mesh.vertices.size()));
  std::size_t bad = 0, counted = 0;
  const double cos10 = std::cos(10 * std::numbers::pi / 180);
  for (std::size_t i = 0; i < mesh.triangles.size(); ++i) {
    if (skip_filled && !mesh.filled.empty() && mesh.filled[i]) continue;
    const auto& t = mesh.triangles[i];
    const Eigen::Vector3f a = mesh.vertices[t[0]], b = mesh.vertices[t[1]], c = mesh.vertices[t[2]];
    const Eigen::Vector3f n = (b - a).cross(c - a).normalized();
    const Eigen::Vector3f radial = ((a + b + c) / 3 - centre_point()).normalized();
    ++counted;
    if (n.dot(radial) < cos10) ++bad;
  }
  f.bad_faces = counted ? static_cast<double>(bad) / static_cast<double>(counted) : 1;
  return f;
}

TEST(Mesher, SphereRawIsOnTheSurfaceClosedAndOutward) {
  const auto cloud = sphere(40000, 0.010f, -2, 2, 1);
  MeshOptions options;
  options.mode = MeshMode::raw;
  const auto result = slscan::mesh::build_mesh(cloud, options);
  const auto& mesh = result.mesh;
  ASSERT_GT(mesh.triangles.size(), 5000u);
  // Spacing of 40000 points on 1257 mm^2: ~0.1 mm (median nearest neighbour of random points).
  EXPECT_GT(result.stats.spacing_mm, 0.05);
  EXPECT_LT(result.stats.spacing_mm, 0.2);
  const Fidelity f = fidelity(mesh);
  // The kernel averages ~100 points: the vertices sit far inside the 10 um noise.
  EXPECT_LT(f.rms, 0.005) << "cell " << result.cell_mm;
  EXPECT_LT(f.worst, 0.03);
  EXPECT_LT(f.bad_faces, 0.01);
  // A fully sampled sphere needs no trimming: closed, valid, outward, no self-intersection,
  // volume within 0.5 % of the sphere's.
  const auto check = slscan::mesh::check_mesh(mesh);
  EXPECT_TRUE(check.valid) << check.rejected_triangles << " triangles refused";
  const auto topo = slscan::core::mesh_topology(mesh);
  EXPECT_TRUE(check.closed) << topo.boundary_edges << " boundary edges, " << topo.non_manifold_edges
                            << " non-manifold, " << result.trimmed_triangles << " trimmed, "
                            << result.stats.dropped_piece_triangles << " in small pieces, "
                            << result.stats.isolated_points << " isolated points";
  EXPECT_EQ(check.self_intersections, 0u);
  EXPECT_TRUE(check.outward);
  const double volume = 4.0 / 3 * std::numbers::pi * radius * radius * radius;
  EXPECT_NEAR(check.volume, volume, 0.005 * volume);
  // Normals: unit, radial.
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i)
    ASSERT_GT(mesh.normals[i].dot((mesh.vertices[i] - centre_point()).normalized()), 0.98f) << "vertex " << i;
}

// Two materials (albedo 0.6 where d.y > 0, 0.2 below) with a ramp along x on top.
float albedo_of(const Eigen::Vector3f& direction) { return (direction.y() > 0 ? 0.6f : 0.2f) + 0.2f * direction.x(); }

void paint(PointCloud& cloud) {
  cloud.intensity.clear();
  for (const auto& p : cloud.points) cloud.intensity.push_back(albedo_of((p - centre_point()).normalized()));
}

TEST(Mesher, SameMeshOnOneAndTwoThreads) {
  auto cloud = sphere(20000, 0.010f, -0.5f, 2, 2);
  paint(cloud);
  slscan::core::MeshResult one, two;
  {
    tbb::global_control c(tbb::global_control::max_allowed_parallelism, 1);
    one = slscan::mesh::build_mesh(cloud, {});
  }
  {
    tbb::global_control c(tbb::global_control::max_allowed_parallelism, 2);
    two = slscan::mesh::build_mesh(cloud, {});
  }
  ASSERT_EQ(one.mesh.vertices.size(), two.mesh.vertices.size());
  ASSERT_EQ(one.mesh.triangles, two.mesh.triangles);
  ASSERT_EQ(one.mesh.filled, two.mesh.filled);
  for (std::size_t i = 0; i < one.mesh.vertices.size(); ++i) {
    ASSERT_EQ(one.mesh.vertices[i], two.mesh.vertices[i]) << "vertex " << i;
    ASSERT_EQ(one.mesh.normals[i], two.mesh.normals[i]) << "vertex " << i;
  }
  ASSERT_EQ(one.mesh.intensity.size(), one.mesh.vertices.size());
  ASSERT_EQ(one.mesh.intensity, two.mesh.intensity);
}

// Each vertex's intensity is the points' around it (Gaussian over the fit's kernel, support
// 3 sigma = 0.6 mm here): away from the materials' border it is the albedo at the vertex; on a
// patch that closes a hole it stays within what the points hold.
TEST(Mesher, VerticesCarryTheIntensityOfTheirPoints) {
  auto cloud = sphere(30000, 0.010f, -2, 0.95f, 7);
  paint(cloud);
  const auto result = slscan::mesh::build_mesh(cloud, {});
  const auto& mesh = result.mesh;
  ASSERT_GT(result.stats.filled_triangles, 0u);
  ASSERT_EQ(mesh.intensity.size(), mesh.vertices.size());
  const auto [lo, hi] = std::minmax_element(cloud.intensity.begin(), cloud.intensity.end());
  std::size_t checked = 0;
  double worst = 0;
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    const Eigen::Vector3f d = (mesh.vertices[i] - centre_point()).normalized();
    ASSERT_GE(mesh.intensity[i], *lo) << "vertex " << i;
    ASSERT_LE(mesh.intensity[i], *hi) << "vertex " << i;
    if (d.z() > 0.9f || std::abs(d.y()) < 0.1f) continue;  // the hole's patch, the materials' border (1 mm)
    ++checked;
    worst = std::max(worst, static_cast<double>(std::abs(mesh.intensity[i] - albedo_of(d))));
  }
  EXPECT_GT(checked, mesh.vertices.size() / 2);
  EXPECT_LT(worst, 0.005) << "the ramp moves 0.02 per mm; a vertex given a point 0.25 mm off reads 0.005";
  // Without the channel in the cloud the mesh has none (a coarser sphere: the check is of the
  // channel, not of its values, and the fine one costs ~2 min under ASan).
  auto plain = sphere(3000, 0.010f, -2, 0.95f, 7);
  ASSERT_TRUE(plain.intensity.empty());
  EXPECT_TRUE(slscan::mesh::build_mesh(plain, {}).mesh.intensity.empty());
}

// Ctrl-C inside the mesh stage (issue 17): the interrupt is called per block of points, voxel
// leaves and vertices (not only between the steps), from the worker threads too, and what it
// throws ends build_mesh; one that returns changes nothing.
TEST(Mesher, InterruptIsCheckedPerBlockAndWhatItThrowsEndsTheMesh) {
  const auto cloud = sphere(20000, 0.010f, -2, 2, 1);
  std::atomic<int> calls{0};
  const auto counted = slscan::mesh::build_mesh(cloud, {}, [&] { ++calls; });
  const int per_run = calls.load();
  EXPECT_GT(per_run, 20) << "checked only between the steps";
  const auto plain = slscan::mesh::build_mesh(cloud, {});
  EXPECT_EQ(counted.mesh.triangles, plain.mesh.triangles);

  struct Stop {};
  for (const int after : {1, per_run / 2}) {  // the chunking varies a little run to run
    calls = 0;
    EXPECT_THROW(slscan::mesh::build_mesh(cloud, {},
                                          [&] {
                                            if (++calls > after) throw Stop{};
                                          }),
                 Stop)
        << "after " << after << " of " << per_run << " calls";
  }
}

// A cap (direction z > 0.95: a hole ~6 mm across) without points.
TEST(Mesher, HoleStaysOpenInRawAndIsClosedAndFlaggedInWatertight) {
  const auto cloud = sphere(30000, 0.010f, -2, 0.95f, 3);
  MeshOptions options;
  options.mode = MeshMode::raw;
  const auto raw = slscan::mesh::build_mesh(cloud, options);
  const auto raw_check = slscan::mesh::check_mesh(raw.mesh);
  EXPECT_TRUE(raw_check.valid);
  EXPECT_FALSE(raw_check.closed);
  EXPECT_EQ(raw_check.self_intersections, 0u);
  // No raw surface well inside the hole (the trim allows 1.5 x spacing past the last points).
  for (const auto& v : raw.mesh.vertices) ASSERT_LT(((v - centre_point()) / radius).z(), 0.97f);
  EXPECT_LT(fidelity(raw.mesh).rms, 0.005);

  options.mode = MeshMode::watertight;
  const auto tight = slscan::mesh::build_mesh(cloud, options);
  const auto check = slscan::mesh::check_mesh(tight.mesh);
  EXPECT_TRUE(check.valid) << check.rejected_triangles << " triangles refused";
  EXPECT_TRUE(check.closed);
  EXPECT_EQ(check.self_intersections, 0u);
  EXPECT_TRUE(check.outward);
  EXPECT_TRUE(tight.stats.closed);
  EXPECT_EQ(tight.stats.holes_left_open, 0u);
  EXPECT_GE(tight.stats.holes_filled, 1u);
  ASSERT_EQ(tight.mesh.filled.size(), tight.mesh.triangles.size());
  // The filled faces are in the hole, and elsewhere only the pinholes' fans, which raw has too:
  // the surface elsewhere is raw's.
  std::size_t filled = 0, outside = 0;
  for (std::size_t i = 0; i < tight.mesh.triangles.size(); ++i) {
    if (!tight.mesh.filled[i]) continue;
    ++filled;
    const auto& t = tight.mesh.triangles[i];
    const Eigen::Vector3f mid = (tight.mesh.vertices[t[0]] + tight.mesh.vertices[t[1]] + tight.mesh.vertices[t[2]]) / 3;
    if (((mid - centre_point()) / radius).z() <= 0.9f) ++outside;
  }
  EXPECT_GT(filled, outside);
  EXPECT_EQ(filled, tight.stats.filled_triangles);
  EXPECT_EQ(raw.stats.filled_triangles,
            static_cast<std::size_t>(std::count(raw.mesh.filled.begin(), raw.mesh.filled.end(), 1)));
  EXPECT_LE(outside, raw.stats.filled_triangles) << "filled faces outside the hole that are not raw's pinhole fans";
  EXPECT_LT(outside, tight.mesh.triangles.size() / 50);
  // This lattice (0.2 mm apart, cell 0.2 mm) leaves pinholes where a cell of the surface reaches
  // out of the band: raw closes them with fans on the surface (checked above: no crossing pair,
  // every vertex within 5 um RMS of the sphere).
  EXPECT_GT(raw.stats.pinholes_filled, 0u);
  EXPECT_EQ(raw.stats.pinholes_filled, tight.stats.pinholes_filled);
  // The faired patch follows the sphere's curvature roughly: within 0.3 mm of it.
  for (std::size_t i = 0; i < tight.mesh.vertices.size(); ++i)
    ASSERT_LT(std::abs((tight.mesh.vertices[i] - centre_point()).norm() - radius), 0.3f) << "vertex " << i;
  // The steps' times: each step once, in the order run, adding up to the whole mesh's time (the
  // steps cover it but for a few statements between them).
  std::vector<std::string> names;
  double total = 0;
  for (const auto& [step, ms] : tight.stats.step_ms) {
    names.push_back(step);
    ASSERT_GE(ms, 0) << step;
    total += ms;
  }
  const std::vector<std::string> expected = {
      "spacing",   "band",    "fit_voxels", "flood_fill", "volume_to_mesh", "polygons",  "project_vertices", "trim",
      "crossings", "pinches", "pinholes",   "pieces",     "close_holes",    "intensity", "topology"};
  EXPECT_EQ(names, expected);
  EXPECT_LE(total, tight.stats.mesh_ms * 1.001 + 0.01);
  EXPECT_GE(total, tight.stats.mesh_ms * 0.9);
}

// Two thirds of a sphere: the opening (19 mm across) is larger than fill_holes_mm, closed with
// a refined but unfaired patch.
TEST(Mesher, LargeOpeningIsClosedWithoutSelfIntersection) {
  const auto cloud = sphere(20000, 0.010f, -0.33f, 2, 4);
  const auto result = slscan::mesh::build_mesh(cloud, {});
  const auto check = slscan::mesh::check_mesh(result.mesh);
  EXPECT_TRUE(check.valid) << check.rejected_triangles << " triangles refused";
  EXPECT_TRUE(check.closed);
  EXPECT_EQ(check.self_intersections, 0u);
  EXPECT_TRUE(check.outward);
  // The opening is refined but not faired (a small gap of the trim elsewhere may be).
  EXPECT_EQ(result.stats.holes_filled, result.stats.holes);
  EXPECT_LT(result.stats.holes_faired, result.stats.holes) << result.stats.holes << " holes";
  // Measured faces only (filled ones are flagged): the rim of the opening, where the fit sees
  // points on one side only, costs a little (measured 1.7 %).
  EXPECT_LT(fidelity(result.mesh).bad_faces, 0.03);
}

// The sphere's upper half open (a border 20 mm across) and a closed rod through the opening,
// not touching the sphere: the opening's patch would cut the rod. A long border's plain patch
// is tested before it is refined (docs/mesh.md, "Watertight"); the one that crosses is removed
// at once, the closure goes on as before (the crossed measured faces replaced, the hole filled
// again), and nothing crosses in the end.
TEST(Mesher, APatchAcrossAnotherPartIsRefusedBeforeRefinement) {
  PointCloud cloud = sphere(30000, 0.005f, -2, 0.f, 11);
  const float rod_radius = 1.5f, rod_bottom = 0, rod_top = 18, step = 0.2f;
  const auto steps_around = static_cast<int>(2 * std::numbers::pi * rod_radius / step);
  const auto rows = static_cast<int>(std::lround((rod_top - rod_bottom) / step));
  for (int row = 0; row <= rows; ++row)
    for (int k = 0; k < steps_around; ++k) {
      const float z = rod_bottom + step * static_cast<float>(row);
      const double a = 2 * std::numbers::pi * k / steps_around;
      const Eigen::Vector3f d(static_cast<float>(std::cos(a)), static_cast<float>(std::sin(a)), 0);
      cloud.points.push_back(centre_point() + rod_radius * d + Eigen::Vector3f(0, 0, z));
      cloud.normals.push_back(d);
    }
  const auto across = static_cast<int>(rod_radius / step);
  for (const float z : {rod_bottom, rod_top})
    for (int i = -across; i <= across; ++i)
      for (int j = -across; j <= across; ++j) {
        const float x = step * static_cast<float>(i), y = step * static_cast<float>(j);
        if (x * x + y * y > rod_radius * rod_radius) continue;
        cloud.points.push_back(centre_point() + Eigen::Vector3f(x, y, z));
        cloud.normals.emplace_back(0, 0, z == rod_top ? 1.f : -1.f);
      }
  const auto result = slscan::mesh::build_mesh(cloud, {});
  const auto check = slscan::mesh::check_mesh(result.mesh);
  EXPECT_TRUE(check.valid) << check.rejected_triangles << " triangles refused";
  EXPECT_EQ(check.self_intersections, 0u);
  EXPECT_GE(result.stats.holes_crossing_unrefined, 1u);
  EXPECT_TRUE(check.closed);
  EXPECT_GT(result.stats.crossed_faces_removed, 0u);
}

// A plate 0.6 mm thick (3 cells), both faces scanned, its four sides not (a cup's rim, a
// blade's thin edge): the kernel's support (0.9 mm) reaches across it, and a fit over both
// faces' points (normals opposite) pulled each face toward the middle. The fit takes one side's
// points, so each face stays where it is. Watertight closes the unseen sides: the two faces'
// borders are two cycles around one strip, bridged into one hole.
PointCloud plate(float half_thickness, float half_size, int steps, std::uint64_t seed) {
  const float step = 2 * half_size / static_cast<float>(steps);
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> g(0, 0.005f);
  PointCloud cloud;
  for (const float side : {1.f, -1.f})
    for (int i = 0; i <= steps; ++i)
      for (int j = 0; j <= steps; ++j) {
        const float x = -half_size + step * static_cast<float>(i), y = -half_size + step * static_cast<float>(j);
        cloud.points.emplace_back(x, y, side * half_thickness + g(rng));
        cloud.normals.emplace_back(0, 0, side);
      }
  return cloud;
}

TEST(Mesher, ThinPlateKeepsBothFacesAndIsClosed) {
  constexpr float half_thickness = 0.3f, half_size = 10;
  const auto cloud = plate(half_thickness, half_size, 133, 11);  // 0.15 mm apart
  MeshOptions options;
  options.mode = MeshMode::raw;
  const auto raw = slscan::mesh::build_mesh(cloud, options);
  double sum2 = 0, worst = 0;
  std::size_t inside = 0;
  for (const auto& v : raw.mesh.vertices) {
    if (std::abs(v.x()) > half_size - 1 || std::abs(v.y()) > half_size - 1) continue;  // away from the sides
    const double e = std::abs(v.z()) - half_thickness;
    sum2 += e * e;
    worst = std::max(worst, std::abs(e));
    ++inside;
  }
  ASSERT_GT(inside, 1000u);
  // Measured 0.7 um RMS, 2.8 um worst; a fit over both faces gave 8.0 um and 10.6 um (and its
  // watertight mesh 6 % too much volume).
  EXPECT_LT(std::sqrt(sum2 / static_cast<double>(inside)), 0.003) << "cell " << raw.cell_mm;
  EXPECT_LT(worst, 0.008);
  EXPECT_EQ(slscan::mesh::check_mesh(raw.mesh).self_intersections, 0u);
  options.mode = MeshMode::watertight;
  const auto tight = slscan::mesh::build_mesh(cloud, options);
  const auto check = slscan::mesh::check_mesh(tight.mesh);
  EXPECT_TRUE(check.closed) << tight.stats.holes_left_open << " holes left open of " << tight.stats.holes;
  EXPECT_EQ(check.self_intersections, 0u);
  EXPECT_TRUE(check.outward);
  EXPECT_TRUE(tight.stats.sides_separated);
  // The plate's volume, the sides closed flat (within 5 %: the faces reach a little past the
  // last points; measured +2.0 %).
  const double volume = 2.0 * half_thickness * (2 * half_size) * (2 * half_size);
  EXPECT_NEAR(check.volume, volume, 0.05 * volume);
}

// Points much denser than the cell (full resolution: 0.074 mm spacing, 0.2 mm cell floor) ending
// at a rim, where on the full-resolution sphere the fit, fed from one side, curled back into a
// fold crossing the surface (38 self-intersecting pairs in raw, its hole left open; now trimmed,
// checked by bench_mesh --size full: this synthetic rim did not reproduce the fold). Raw must
// not self-intersect, watertight must close.
TEST(Mesher, DenseCloudEndingAtARimHasNoFold) {
  auto cloud = sphere(64000, 0.005f, -2, 0.3f, 10);
  for (auto& p : cloud.points) p = centre_point() + (p - centre_point()) * 0.5f;  // r = 5 mm: spacing ~0.07 mm
  MeshOptions options;
  options.mode = MeshMode::raw;
  const auto raw = slscan::mesh::build_mesh(cloud, options);
  EXPECT_LT(raw.stats.spacing_mm, 0.1);
  EXPECT_DOUBLE_EQ(raw.cell_mm, options.min_cell_mm);
  const auto raw_check = slscan::mesh::check_mesh(raw.mesh);
  EXPECT_TRUE(raw_check.valid) << raw_check.rejected_triangles << " triangles refused";
  EXPECT_EQ(raw_check.self_intersections, 0u);
  options.mode = MeshMode::watertight;
  const auto tight = slscan::mesh::build_mesh(cloud, options);
  const auto check = slscan::mesh::check_mesh(tight.mesh);
  EXPECT_TRUE(check.closed) << tight.stats.holes_left_open << " holes left open";
  EXPECT_EQ(check.self_intersections, 0u);
  EXPECT_TRUE(check.outward);
}

TEST(Mesher, OutliersAreLeftOut) {
  auto cloud = sphere(30000, 0.010f, -2, 2, 5);
  std::mt19937_64 rng(6);
  std::uniform_real_distribution<float> u(-1, 1);
  for (int i = 0; i < 300; ++i) {  // scattered around the sphere, up to 5 mm off it
    Eigen::Vector3f d(u(rng), u(rng), u(rng));
    d.normalize();
    const float off = 1.0f + 4.0f * (u(rng) + 1) / 2;
    cloud.points.push_back(centre_point() + d * (radius + (u(rng) > 0 ? off : -off)));
    Eigen::Vector3f n(u(rng), u(rng), u(rng));
    cloud.normals.push_back(n.normalized());
  }
  MeshOptions options;
  options.mode = MeshMode::raw;
  const auto result = slscan::mesh::build_mesh(cloud, options);
  EXPECT_GE(result.stats.isolated_points, 250u);
  const Fidelity f = fidelity(result.mesh);
  EXPECT_LT(f.rms, 0.005);
  EXPECT_LT(f.worst, 0.05) << "a stray point grew a surface of its own";
  const auto check = slscan::mesh::check_mesh(result.mesh);
  EXPECT_TRUE(check.closed);
  EXPECT_EQ(check.self_intersections, 0u);
}

void expect_refused(const PointCloud& cloud, const std::string& words) {
  try {
    slscan::mesh::build_mesh(cloud, {});
    ADD_FAILURE() << "no error, expected one naming: " << words;
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
  }
}

TEST(Mesher, RefusesCloudsWithoutASurface) {
  expect_refused({}, "empty");
  PointCloud one;
  one.points.push_back({1, 2, 3});
  one.normals.push_back({0, 0, 1});
  expect_refused(one, "1 point(s)");
  auto nan_normal = sphere(1000, 0.01f, -2, 2, 7);
  nan_normal.normals[17] = Eigen::Vector3f(std::nanf(""), 0, 1);
  expect_refused(nan_normal, "normal of point 17");
  auto no_normals = sphere(1000, 0.01f, -2, 2, 8);
  no_normals.normals.clear();
  expect_refused(no_normals, "0 normals for 1000 points");
  PointCloud stacked;  // 200 points at one position
  for (int i = 0; i < 200; ++i) {
    stacked.points.push_back(Eigen::Vector3f(1, 2, 3));
    stacked.normals.push_back({0, 0, 1});
  }
  expect_refused(stacked, "one position");
  MeshOptions bad;
  bad.adaptivity = 2;
  EXPECT_THROW(slscan::mesh::build_mesh(sphere(1000, 0.01f, -2, 2, 9), bad), std::invalid_argument);
}

}  // namespace
