// Grid (organised) and k-NN PCA normals against analytic surfaces.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <random>

#include "slscan/core/cloud_filters.hpp"
#include "slscan/core/normals.hpp"

namespace {

// An organised view of two planes at different depths, split at column 32: a depth edge.
slscan::core::OrganizedCloud two_planes(Eigen::Vector3f& near_normal, Eigen::Vector3f& far_normal) {
  slscan::core::OrganizedCloud cloud;
  cloud.resize(64, 48);
  // Plane z = z0 + a x + b y through rays (x, y, 1) * z: solve along each pixel ray.
  const float a = 0.2f, b = -0.1f;
  for (int v = 0; v < 48; ++v)
    for (int u = 0; u < 64; ++u) {
      const float x = (static_cast<float>(u) - 32) * 0.002f, y = (static_cast<float>(v) - 24) * 0.002f;
      const float z0 = u < 32 ? 100.0f : 130.0f;
      const float z = z0 / (1 - a * x - b * y);
      const std::size_t i = static_cast<std::size_t>(v) * 64 + static_cast<std::size_t>(u);
      cloud.points[i] = Eigen::Vector3f(x * z, y * z, z);
      cloud.valid[i] = (u + v) % 17 != 0;  // a few holes
      cloud.quality[i] = 1;
    }
  near_normal = Eigen::Vector3f(a, b, -1).normalized();  // toward the camera at the origin
  far_normal = near_normal;
  return cloud;
}

TEST(GridNormals, PlanesAcrossADepthEdgeStayExact) {
  Eigen::Vector3f n_near, n_far;
  const auto cloud = two_planes(n_near, n_far);
  const auto normals = slscan::core::grid_normals(cloud);
  ASSERT_EQ(normals.size(), cloud.size());
  std::size_t checked = 0;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!cloud.valid[i]) {
      EXPECT_FALSE(normals[i].allFinite());
      continue;
    }
    ASSERT_TRUE(normals[i].allFinite()) << i;
    // Neighbours across the 30 mm edge are gated out, so even edge pixels see one plane.
    EXPECT_GT(normals[i].dot(n_near), 0.99999f) << "pixel " << i;
    ++checked;
  }
  EXPECT_GT(checked, 2800u);
}

// What the reconstruction keeps of a view: its valid points with their grid normals, in one
// pass over the valid slots only. Must be what grid_normals then to_point_cloud give, bit for
// bit: a sparse cloud (an object in a corner, holes, a lone point whose normal is unsupported
// and so dropped), with and without intensity.
TEST(GridNormals, OrientedPointCloudIsGridNormalsThenToPointCloudBitForBit) {
  Eigen::Vector3f n_near, n_far;
  auto cloud = two_planes(n_near, n_far);
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const std::size_t u = i % 64, v = i / 64;
    if (u < 20 || v > 30) cloud.valid[i] = 0;  // a region, as after the platform is removed
    cloud.quality[i] = static_cast<float>(i % 7);
  }
  const std::size_t lone = 45 * 64 + 5;  // valid, no valid neighbour: NaN normal, dropped
  cloud.valid[lone] = 1;
  for (const bool with_intensity : {false, true}) {
    SCOPED_TRACE(with_intensity ? "with intensity" : "without intensity");
    cloud.intensity.clear();
    if (with_intensity)
      for (std::size_t i = 0; i < cloud.size(); ++i) cloud.intensity.push_back(0.001f * static_cast<float>(i));
    const Eigen::Vector3f viewpoint(1, 2, -3);
    const slscan::core::GridNormalOptions options{.window_radius = 2, .max_neighbor_distance_mm = 0.5f};
    const auto normals = slscan::core::grid_normals(cloud, viewpoint, options);
    ASSERT_FALSE(normals[lone].allFinite());
    const auto expected = slscan::core::to_point_cloud(cloud, 3, &normals);
    const auto got = slscan::core::oriented_point_cloud(cloud, 3, viewpoint, options);
    ASSERT_GT(expected.size(), 1000u);
    ASSERT_EQ(got.size(), expected.size());
    for (std::size_t k = 0; k < got.size(); ++k) {
      ASSERT_EQ(got.points[k], expected.points[k]) << k;
      ASSERT_EQ(got.normals[k], expected.normals[k]) << k;
      ASSERT_EQ(got.confidence[k], expected.confidence[k]) << k;
    }
    EXPECT_EQ(got.intensity, expected.intensity);
    EXPECT_EQ(got.view_id, expected.view_id);
  }
  cloud.quality.pop_back();
  EXPECT_THROW(slscan::core::oriented_point_cloud(cloud, 0), std::invalid_argument);
}

TEST(GridNormals, RejectsInconsistentCloud) {
  slscan::core::OrganizedCloud cloud;
  cloud.resize(4, 4);
  cloud.width = 5;
  EXPECT_THROW(slscan::core::grid_normals(cloud), std::invalid_argument);
}

slscan::core::PointCloud sphere(std::size_t n, const Eigen::Vector3f& c, float r, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> g(0, 1);
  slscan::core::PointCloud cloud;
  for (std::size_t i = 0; i < n; ++i) {
    Eigen::Vector3f d(g(rng), g(rng), g(rng));
    d.normalize();
    cloud.points.push_back(c + d * r);
  }
  return cloud;
}

TEST(PcaNormals, SphereNormalsPointOutwardFromTheAxis) {
  const Eigen::Vector3f c(0, 0, 30);
  const auto cloud = sphere(20000, c, 20, 1);
  const auto normals = slscan::core::pca_normals(cloud, {});
  std::size_t outward = 0;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const Eigen::Vector3f radial = (cloud.points[i] - c).normalized();
    // k = 20 random neighbours (~1.5 mm) on a 20 mm sphere: a lopsided neighbourhood tilts the
    // PCA plane by up to ~2 deg (measured 1.6); a wrong neighbour search would be far worse.
    EXPECT_GT(std::abs(normals[i].dot(radial)), std::cos(2.5f * static_cast<float>(M_PI) / 180)) << i;
    outward += normals[i].dot(radial) > 0;
  }
  // Orientation away from the z axis is ambiguous only right at the poles.
  EXPECT_GT(outward, cloud.size() * 998 / 1000);
}

TEST(PcaNormals, OrientTowardEachViewsCamera) {
  auto cloud = sphere(5000, Eigen::Vector3f(0, 0, 0), 20, 2);
  cloud.view_id.resize(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i) cloud.view_id[i] = cloud.points[i].x() > 0 ? 1 : 0;
  slscan::core::PcaNormalOptions options;
  options.orientation = slscan::core::NormalOrientation::toward_view_camera;
  options.view_camera_centres = {{-300, 0, 0}, {300, 0, 0}};
  const auto normals = slscan::core::pca_normals(cloud, options);
  for (std::size_t i = 0; i < cloud.size(); ++i)
    EXPECT_GT(normals[i].dot(options.view_camera_centres[cloud.view_id[i]] - cloud.points[i]), 0) << i;
  options.view_camera_centres.pop_back();
  EXPECT_THROW(slscan::core::pca_normals(cloud, options), std::invalid_argument);
  options.k = 2;
  EXPECT_THROW(slscan::core::pca_normals(cloud, options), std::invalid_argument);
}

}  // namespace
