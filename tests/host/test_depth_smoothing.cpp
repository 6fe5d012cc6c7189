// Depth smoothing over the pixel grid against an analytic scene: a sphere in front of a plane,
// seen by a pinhole camera, with noise along each pixel's ray as triangulation makes it.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>
#include <vector>

#include "slscan/core/depth_smoothing.hpp"

namespace {

constexpr int kSize = 400;
constexpr float kFocal = 5000;  // px: 0.1 mm per pixel at 500 mm, a curved surface over the window
const Eigen::Vector3f kCentre(0, 0, 500);
constexpr float kRadius = 15;
constexpr float kWallZ = 520;

struct Scene {
  slscan::core::OrganizedCloud cloud;
  std::vector<std::uint8_t> on_sphere;
};

// Noise-free depths along each ray, then `sigma_mm` of Gaussian noise along the ray.
Scene render(float sigma_mm, unsigned seed) {
  Scene scene;
  scene.cloud.resize(kSize, kSize);
  scene.on_sphere.assign(scene.cloud.size(), 0);
  std::mt19937 rng(seed);
  std::normal_distribution<float> noise(0, sigma_mm);
  for (int v = 0; v < kSize; ++v)
    for (int u = 0; u < kSize; ++u) {
      const std::size_t i = static_cast<std::size_t>(v) * kSize + static_cast<std::size_t>(u);
      // In double: b * b - c cancels to the sphere's size and float would leave ~0.5 um of error.
      const Eigen::Vector3d ray =
          Eigen::Vector3d((u - kSize / 2.0) / kFocal, (v - kSize / 2.0) / kFocal, 1).normalized();
      const Eigen::Vector3d centre = kCentre.cast<double>();
      const double b = ray.dot(centre), c = centre.squaredNorm() - double(kRadius) * kRadius;
      const double disc = b * b - c;
      double t = kWallZ / ray.z();
      if (disc > 0) {
        t = b - std::sqrt(disc);
        scene.on_sphere[i] = 1;
      }
      scene.cloud.points[i] = (ray * (t + noise(rng))).cast<float>();
      scene.cloud.valid[i] = 1;
      scene.cloud.quality[i] = 1;
    }
  return scene;
}

// +-0.35 mm at 0.104 mm per pixel (the wall, most of the image): the 7 x 7 window the noise
// figures below are for.
slscan::core::DepthSmoothingOptions seven_by_seven() {
  slscan::core::DepthSmoothingOptions options;
  options.window_radius_mm = 0.35;
  return options;
}

float sphere_error(const Eigen::Vector3f& p) { return (p - kCentre).norm() - kRadius; }

struct Errors {
  double rms_um = 0, mean_um = 0, p999_um = 0;
};

Errors errors(const Scene& scene, bool sphere) {
  std::vector<double> e;
  for (std::size_t i = 0; i < scene.cloud.size(); ++i) {
    if (!scene.cloud.valid[i] || static_cast<bool>(scene.on_sphere[i]) != sphere) continue;
    const Eigen::Vector3f& p = scene.cloud.points[i];
    e.push_back(1000.0 * (sphere ? sphere_error(p) : p.z() - kWallZ));
  }
  Errors out;
  for (double x : e) {
    out.mean_um += x;
    out.rms_um += x * x;
  }
  out.mean_um /= static_cast<double>(e.size());
  out.rms_um = std::sqrt(out.rms_um / static_cast<double>(e.size()));
  for (double& x : e) x = std::fabs(x);
  const auto nth = e.begin() + static_cast<std::ptrdiff_t>(0.999 * static_cast<double>(e.size()));
  std::nth_element(e.begin(), nth, e.end());
  out.p999_um = *nth;
  return out;
}

TEST(DepthSmoothing, ANoiseFreeSphereAndPlaneKeepTheirShape) {
  Scene scene = render(0, 1);
  const auto counts = slscan::core::smooth_depth(scene.cloud, kFocal, seven_by_seven());
  EXPECT_EQ(counts.window_radius_px, 3);
  EXPECT_EQ(counts.input, scene.cloud.size());
  EXPECT_EQ(counts.full + counts.partial + counts.kept, counts.input);
  EXPECT_GT(counts.full, counts.input / 2);
  EXPECT_GT(counts.partial, 0u);  // the sphere's rim: the wall is across a depth edge
  // A quadratic over the window follows the sphere: no inward bias, nothing moved by the wall.
  const Errors sphere = errors(scene, true), wall = errors(scene, false);
  EXPECT_LT(std::fabs(sphere.mean_um), 0.2) << "bias on a noise-free sphere";
  // Toward the rim (incidence beyond 60 deg) depth grows faster than a quadratic over the
  // window follows: a few tenths of a micrometre there, well under the noise it removes.
  EXPECT_LT(sphere.p999_um, 2.5);
  double worst_facing_um = 0;
  for (std::size_t i = 0; i < scene.cloud.size(); ++i) {
    if (!scene.on_sphere[i]) continue;
    const Eigen::Vector3f& p = scene.cloud.points[i];
    if ((kCentre - p).normalized().dot(p.normalized()) < 0.5f) continue;  // incidence > 60 deg
    worst_facing_um = std::max(worst_facing_um, 1000.0 * std::fabs(sphere_error(p)));
  }
  EXPECT_LT(worst_facing_um, 0.1) << "where the sphere faces the camera the fit must be exact";
  EXPECT_LT(wall.p999_um, 0.05) << "the wall was pulled toward the sphere across the depth edge";
}

TEST(DepthSmoothing, NoiseAlongTheRaysIsReducedWithoutBiasOrLeakingAcrossEdges) {
  constexpr float kSigma = 0.005f;  // 5 um, the virtual rig's per-point noise
  Scene scene = render(kSigma, 7);
  const Scene measured = scene;
  const Errors before = errors(measured, true);
  const auto counts = slscan::core::smooth_depth(scene.cloud, kFocal, seven_by_seven());
  const Errors after = errors(scene, true), wall = errors(scene, false);
  // 7 x 7 quadratic: the centre's noise is sqrt(0.105) of a point's, 0.32 x (edges fit less).
  EXPECT_NEAR(before.rms_um, 5.0 / std::sqrt(2.0), 0.3);  // radial: along the ray x cos(incidence)
  EXPECT_LT(after.rms_um, 0.45 * before.rms_um) << after.rms_um << " um";
  EXPECT_LT(after.p999_um, 0.6 * before.p999_um) << after.p999_um << " um";
  EXPECT_LT(std::fabs(after.mean_um), 0.3) << "smoothing biased the sphere's radius";
  EXPECT_LT(wall.rms_um, 0.45 * 5.0) << "the wall";
  EXPECT_LT(wall.p999_um, 5.0 * 3.5) << "the wall's worst points were pulled across the depth edge";
  EXPECT_NEAR(counts.mean_shift_um, 5.0 * std::sqrt(2.0 / M_PI) * std::sqrt(1 - 0.105), 0.5);
  // Each point moved only along its own camera ray: the pixel's line of sight is unchanged.
  for (std::size_t i = 0; i < scene.cloud.size(); i += 97) {
    const Eigen::Vector3f a = measured.cloud.points[i].normalized(), b = scene.cloud.points[i].normalized();
    ASSERT_LT(a.cross(b).norm(), 1e-6f) << "point " << i << " left its ray";
  }
}

TEST(DepthSmoothing, IsolatedPointsAndHolesAreLeftAsMeasuredAndInvalidSlotsStayInvalid) {
  Scene scene = render(0.005f, 3);
  // Keep only a checkerboard of 3 x 3 blocks in one corner and a lone point.
  for (int v = 0; v < kSize; ++v)
    for (int u = 0; u < kSize; ++u) {
      const std::size_t i = static_cast<std::size_t>(v) * kSize + static_cast<std::size_t>(u);
      const bool keep = (u == 300 && v == 300) || (u < 60 && v < 60 && ((u / 3 + v / 3) % 2 == 0));
      if (!keep) {
        scene.cloud.valid[i] = 0;
        scene.cloud.points[i] = Eigen::Vector3f::Constant(std::nanf(""));
      }
    }
  const Scene measured = scene;
  const auto counts = slscan::core::smooth_depth(scene.cloud, kFocal, seven_by_seven());
  EXPECT_EQ(counts.input, 1u + 1800u);
  const std::size_t lone = 300u * kSize + 300u;
  EXPECT_EQ(scene.cloud.points[lone], measured.cloud.points[lone]) << "a lone point has nothing to fit";
  for (std::size_t i = 0; i < scene.cloud.size(); ++i) {
    ASSERT_EQ(scene.cloud.valid[i], measured.cloud.valid[i]);
    if (!scene.cloud.valid[i]) {
      ASSERT_TRUE(std::isnan(scene.cloud.points[i].x()));
    }
  }
  EXPECT_GT(counts.kept, 0u);
}

TEST(DepthSmoothing, TheWindowIsSetOnTheSurfaceAndACoarseCameraIsLeftAlone) {
  Scene scene = render(0.005f, 5);
  slscan::core::DepthSmoothingOptions options;  // +-0.5 mm, at most 4 pixels
  Scene fine = scene;
  EXPECT_EQ(slscan::core::smooth_depth(fine.cloud, kFocal, options).window_radius_px, 4);  // capped
  Scene mid = scene;
  EXPECT_EQ(slscan::core::smooth_depth(mid.cloud, kFocal / 2, options).window_radius_px, 2);  // 0.2 mm pixels
  // A camera whose pixel covers more than the window (0.8 mm here): nothing moves.
  const Scene measured = scene;
  const auto counts = slscan::core::smooth_depth(scene.cloud, kFocal / 8, options);
  EXPECT_EQ(counts.window_radius_px, 0);
  EXPECT_EQ(counts.kept, counts.input);
  for (std::size_t i = 0; i < scene.cloud.size(); i += 37) ASSERT_EQ(scene.cloud.points[i], measured.cloud.points[i]);
}

TEST(DepthSmoothing, BadOptionsAndInconsistentCloudsAreRefused) {
  Scene scene = render(0, 1);
  slscan::core::DepthSmoothingOptions options;
  options.window_radius_mm = 0;
  EXPECT_THROW(slscan::core::smooth_depth(scene.cloud, kFocal, options), std::invalid_argument);
  options = {};
  options.min_neighbors = 5;
  EXPECT_THROW(slscan::core::smooth_depth(scene.cloud, kFocal, options), std::invalid_argument);
  options = {};
  options.max_depth_slope = std::nanf("");
  EXPECT_THROW(slscan::core::smooth_depth(scene.cloud, kFocal, options), std::invalid_argument);
  EXPECT_THROW(slscan::core::smooth_depth(scene.cloud, 0.0), std::invalid_argument);
  scene.cloud.valid.pop_back();
  try {
    slscan::core::smooth_depth(scene.cloud, kFocal, seven_by_seven());
    FAIL() << "an inconsistent cloud was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("400x400"), std::string::npos) << e.what();
  }
}

}  // namespace
