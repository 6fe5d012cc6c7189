// Sphere, plane and ball-bar fits against synthetic samples with known answers.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <numbers>
#include <random>

#include "slscan/core/measure.hpp"

namespace {

using slscan::core::PointCloud;

Eigen::Vector3d random_direction(std::mt19937_64& rng) {
  std::normal_distribution<double> g(0, 1);
  Eigen::Vector3d d(g(rng), g(rng), g(rng));
  return d.normalized();
}

// Points on a sphere, optionally only where the direction's z is above `min_z` (a cap).
std::vector<Eigen::Vector3f> sphere_points(const Eigen::Vector3d& c, double r, std::size_t n, double sigma,
                                           std::uint64_t seed, double min_z = -1.0) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0, sigma > 0 ? sigma : 1);
  std::vector<Eigen::Vector3f> pts;
  while (pts.size() < n) {
    const Eigen::Vector3d d = random_direction(rng);
    if (d.z() < min_z) continue;
    pts.push_back((c + d * (r + (sigma > 0 ? noise(rng) : 0.0))).cast<float>());
  }
  return pts;
}

TEST(FitSphere, NoiseFreeFullSphereIsExact) {
  const Eigen::Vector3d c(12.3, -45.6, 300.7);
  const auto pts = sphere_points(c, 15.0004, 5000, 0, 1);
  const auto fit = slscan::core::fit_sphere(pts);
  // Float storage near 300 mm rounds each point by up to ~15 nm; the fit averages it away.
  EXPECT_NEAR(fit.radius_mm, 15.0004, 2e-6);
  EXPECT_LT((fit.centre - c).norm(), 2e-6);
  EXPECT_LT(fit.form_error_mm, 1e-4);
  EXPECT_LT(fit.rms_mm, 2e-5);
  EXPECT_EQ(fit.point_count, 5000u);
}

TEST(FitSphere, NoisySphereRecoversRadiusCentreAndNoise) {
  const Eigen::Vector3d c(-20, 10, 250);
  const double sigma = 0.01;
  const auto pts = sphere_points(c, 15.00075, 20000, sigma, 2);
  const auto fit = slscan::core::fit_sphere(pts);
  // Standard error of radius and centre ~ sigma / sqrt(n) ~ 0.1 um: 1 um is 10 of them.
  EXPECT_NEAR(fit.radius_mm, 15.00075, 1e-3);
  EXPECT_LT((fit.centre - c).norm(), 1e-3);
  EXPECT_NEAR(fit.rms_mm, sigma, 0.05 * sigma);
  // Max - min of 20000 normal residuals is about 7.5-9 sigma.
  EXPECT_GT(fit.form_error_mm, 6 * sigma);
  EXPECT_LT(fit.form_error_mm, 11 * sigma);
}

TEST(FitSphere, CapOnlyStillConverges) {
  const Eigen::Vector3d c(5, 5, 100);
  const auto pts = sphere_points(c, 15, 8000, 0.002, 3, 0.5);  // a 60 deg half-angle cap
  const auto fit = slscan::core::fit_sphere(pts);
  EXPECT_NEAR(fit.radius_mm, 15, 2e-3);
  EXPECT_LT((fit.centre - c).norm(), 3e-3);
}

TEST(FitSphere, RejectsTooFewOrDegeneratePoints) {
  std::vector<Eigen::Vector3f> three{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  EXPECT_THROW(slscan::core::fit_sphere(three), std::invalid_argument);
  std::vector<Eigen::Vector3f> plane;
  for (int i = 0; i < 10; ++i)
    for (int j = 0; j < 10; ++j) plane.emplace_back(static_cast<float>(i), static_cast<float>(j), 0.0f);
  EXPECT_THROW(slscan::core::fit_sphere(plane), std::invalid_argument);
  auto pts = sphere_points(Eigen::Vector3d::Zero(), 10, 100, 0, 4);
  pts[7].x() = NAN;
  EXPECT_THROW(slscan::core::fit_sphere(pts), std::invalid_argument);
  EXPECT_THROW(slscan::core::fit_sphere(pts, {0, 1, 2, 1000}), std::invalid_argument);
}

TEST(FitPlane, RecoversTiltedPlaneAndRippleFlatness) {
  const Eigen::Vector3d n = Eigen::Vector3d(0.1, -0.2, 1).normalized();
  const Eigen::Vector3d u = n.unitOrthogonal(), v = n.cross(u);
  const Eigen::Vector3d origin(3, 4, 200);
  const double amplitude = 0.004;
  std::vector<Eigen::Vector3f> pts;
  for (int i = 0; i < 100; ++i)
    for (int j = 0; j < 100; ++j) {
      const double a = i - 49.5, b = j - 49.5;
      // A ripple of whole periods along u: peak-to-valley 2 * amplitude, zero mean.
      const double ripple = amplitude * std::cos(2 * std::numbers::pi * a / 25.0);
      pts.push_back((origin + a * u + b * v + ripple * n).cast<float>());
    }
  const auto fit = slscan::core::fit_plane(pts);
  EXPECT_GT(std::abs(fit.normal.dot(n)), 1 - 1e-9);
  EXPECT_NEAR(std::abs(fit.normal.dot(origin) - fit.offset_mm), 0, 1e-4);
  EXPECT_NEAR(fit.flatness_mm, 2 * amplitude, 1e-4);
  EXPECT_NEAR(fit.rms_mm, amplitude / std::sqrt(2.0), 1e-4);
}

TEST(FitPlane, RejectsCollinearPoints) {
  std::vector<Eigen::Vector3f> line;
  for (int i = 0; i < 10; ++i) line.emplace_back(static_cast<float>(i), 2.0f * static_cast<float>(i), 1.0f);
  EXPECT_THROW(slscan::core::fit_plane(line), std::invalid_argument);
  EXPECT_THROW(slscan::core::fit_plane({{0, 0, 0}, {1, 0, 0}}), std::invalid_argument);
}

// The paper's ball bar: two spheres joined by a rod, standing above a platform, with stray
// outliers. Sphere points inside the rod and under each ball (hidden by the mount) are absent.
struct BallBar {
  Eigen::Vector3d c0, c1;
  double r0 = 15.0004, r1 = 15.00075;
  PointCloud cloud;
};

BallBar make_ball_bar(double sigma, std::uint64_t seed) {
  BallBar bar;
  const Eigen::Vector3d axis = Eigen::Vector3d(0.8, 0.5, 0.33).normalized();
  const Eigen::Vector3d mid(10, -5, 60);
  bar.c0 = mid - axis * (150.1164 / 2);
  bar.c1 = mid + axis * (150.1164 / 2);
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0, sigma > 0 ? sigma : 1);
  auto jitter = [&] { return sigma > 0 ? noise(rng) : 0.0; };
  const double rod_radius = 5;
  auto inside_rod = [&](const Eigen::Vector3d& p) {
    const double t = (p - bar.c0).dot(axis);
    return t > 0 && t < 150.1164 && ((p - bar.c0) - t * axis).norm() < rod_radius;
  };
  for (int s = 0; s < 2; ++s) {
    const Eigen::Vector3d c = s ? bar.c1 : bar.c0;
    const double r = s ? bar.r1 : bar.r0;
    int made = 0;
    while (made < 12000) {
      const Eigen::Vector3d d = random_direction(rng);
      if (d.z() < -0.8) continue;  // the mount hides the bottom
      const Eigen::Vector3d p = c + d * r;
      if (inside_rod(p)) continue;
      bar.cloud.points.push_back((c + d * (r + jitter())).cast<float>());
      ++made;
    }
  }
  std::uniform_real_distribution<double> along(15, 150.1164 - 15), angle(0, 2 * std::numbers::pi);
  const Eigen::Vector3d e1 = axis.unitOrthogonal(), e2 = axis.cross(e1);
  for (int i = 0; i < 6000; ++i) {
    const double t = along(rng), a = angle(rng);
    const Eigen::Vector3d p = bar.c0 + t * axis + (rod_radius + jitter()) * (std::cos(a) * e1 + std::sin(a) * e2);
    bar.cloud.points.push_back(p.cast<float>());
  }
  std::uniform_real_distribution<double> xy(-150, 150), box(-150, 150), zbox(0, 150);
  for (int i = 0; i < 8000; ++i) bar.cloud.points.emplace_back(xy(rng), xy(rng), static_cast<float>(jitter()));
  for (int i = 0; i < 300; ++i) bar.cloud.points.emplace_back(box(rng), box(rng), zbox(rng));
  return bar;
}

TEST(BallBar, NoiseFreeDistanceWithinOneMicrometre) {
  const BallBar bar = make_ball_bar(0, 5);
  const auto result = slscan::core::measure_ball_bar(bar.cloud);
  // Sphere 0 is whichever sphere RANSAC found first: match them by centre.
  const bool swapped = (result.spheres[0].centre - bar.c1).norm() < (result.spheres[0].centre - bar.c0).norm();
  const auto& s0 = result.spheres[swapped ? 1 : 0];
  const auto& s1 = result.spheres[swapped ? 0 : 1];
  EXPECT_NEAR(result.centre_distance_mm, 150.1164, 1e-3);
  EXPECT_NEAR(s0.radius_mm, bar.r0, 1e-4);
  EXPECT_NEAR(s1.radius_mm, bar.r1, 1e-4);
  EXPECT_LT((s0.centre - bar.c0).norm(), 1e-4);
  EXPECT_LT((s1.centre - bar.c1).norm(), 1e-4);
  // The refined inlier sets are the spheres' own points, not the rod or the platform.
  EXPECT_GT(s0.point_count, 11000u);
  EXPECT_LT(s0.point_count, 12400u);
  EXPECT_LT(s0.form_error_mm, 1e-3);
}

TEST(BallBar, NoisyBarWithinTwoMicrometres) {
  const double sigma = 0.01;
  const BallBar bar = make_ball_bar(sigma, 6);
  const auto result = slscan::core::measure_ball_bar(bar.cloud);
  // Each centre's standard error ~ sigma / sqrt(12000) * ~1.7 ~ 0.15 um.
  EXPECT_NEAR(result.centre_distance_mm, 150.1164, 2e-3);
  for (const auto& s : result.spheres) {
    EXPECT_NEAR(s.radius_mm, 15.0006, 2e-3);
    EXPECT_NEAR(s.rms_mm, sigma, 0.2 * sigma);
  }
}

TEST(BallBar, FailsClearlyWithoutSpheres) {
  PointCloud plane;
  for (int i = 0; i < 100; ++i)
    for (int j = 0; j < 100; ++j) plane.points.emplace_back(static_cast<float>(i), static_cast<float>(j), 0.0f);
  slscan::core::BallBarOptions options;
  options.ransac_iterations = 200;
  EXPECT_THROW(slscan::core::measure_ball_bar(plane, options), std::runtime_error);
  options.nominal_radii_mm[1] = -1;
  EXPECT_THROW(slscan::core::measure_ball_bar(plane, options), std::invalid_argument);
}

}  // namespace
