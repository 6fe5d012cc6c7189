// The acceptance formulas of bench_metrology: the paper's ball-bar uncertainty (Table 1) and
// VDI/VDE 2634-2's PF, PS and F on synthetic points whose form error is known.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <array>
#include <cmath>
#include <numbers>
#include <random>
#include <stdexcept>

#include "slscan/core/metrology.hpp"

namespace {

using slscan::core::ball_bar_uncertainty;

// Feng et al. 2023, Table 1: the ball bar at 7 positions and poses (mm).
constexpr std::array<double, 7> kPaperLengths{150.155, 150.169, 150.141, 150.110, 150.122, 150.139, 150.130};

TEST(BallBarUncertainty, PaperTable1) {
  const auto u = ball_bar_uncertainty(kPaperLengths);
  EXPECT_NEAR(u.sd_um, 52.6, 1e-6);  // pose 2: 150.169 - 150.1164
  EXPECT_EQ(u.sd_index, 1u);
  EXPECT_NEAR(u.mean_mm, 150.138, 1e-9);
  EXPECT_NEAR(u.scatter_um, 19.85, 0.005);  // the paper's "19.9 um"
  // sum (s_i - mean)^2 = 2364 um^2, / (7 * 6).
  EXPECT_NEAR(u.type_a_um, std::sqrt(2364.0 / 42.0), 1e-9);
  EXPECT_NEAR(u.u1_um, 2.5, 1e-12);
  EXPECT_NEAR(u.u2_um, 150116.4 * 8e-6 * 0.5 / std::sqrt(3.0), 1e-9);  // 0.347 um
  EXPECT_NEAR(u.u3_um, 150116.4 * 5 * 1e-6 / std::sqrt(6.0), 1e-9);    // 0.306 um
  // The paper prints 7.938 um; its formulas as printed give 7.9215 um (docs/accuracy.md: the
  // 0.017 um gap is in the paper's arithmetic, no reading of its divisors gives 7.938 exactly).
  EXPECT_NEAR(u.combined_um, 7.9215, 5e-4);
  EXPECT_NEAR(u.combined_um, 7.938, 0.02);
}

TEST(BallBarUncertainty, SignedSdAndBadInput) {
  const std::array<double, 3> lengths{150.1164 - 0.004, 150.1164 + 0.001, 150.1164 - 0.0025};
  const auto u = ball_bar_uncertainty(lengths);
  EXPECT_NEAR(u.sd_um, -4.0, 1e-6);  // the largest magnitude keeps its sign
  EXPECT_EQ(u.sd_index, 0u);
  EXPECT_THROW(ball_bar_uncertainty(std::span<const double>(lengths.data(), 1)), std::invalid_argument);
  const std::array<double, 2> bad{150.1, std::nan("")};
  try {
    ball_bar_uncertainty(bad);
    FAIL() << "no throw";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("length 2"), std::string::npos) << e.what();
  }
}

// A sphere whose radius carries a known bump: r(theta) = R + a cos(2 theta) (theta from +z).
// Its least-squares form error is 2 a (range of the residuals), its size R (the bump averages out
// over a full sphere only approximately: PS is checked against a fit-free bound).
std::vector<Eigen::Vector3f> bumpy_sphere(const Eigen::Vector3d& c, double r, double a, std::size_t n) {
  std::vector<Eigen::Vector3f> pts;
  std::mt19937_64 rng(7);
  std::normal_distribution<double> g(0, 1);
  while (pts.size() < n) {
    const Eigen::Vector3d d = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
    const double cos2 = 2 * d.z() * d.z() - 1;
    pts.push_back((c + d * (r + a * cos2)).cast<float>());
  }
  return pts;
}

TEST(ProbingError, KnownFormAndSize) {
  const Eigen::Vector3d c(10, -20, 400);
  auto pts = bumpy_sphere(c, 15.0, 0.004, 20000);
  const auto e = slscan::core::probing_error(pts, 30.0, 0.0);
  // Residuals span [-a, +a] about a best radius within a of R: PF = 2a = 8 um (sampling leaves
  // the extremes a hair short), PS within 2a.
  EXPECT_NEAR(e.form_um, 8.0, 0.15);
  EXPECT_LT(std::fabs(e.size_um), 8.0);
  EXPECT_EQ(e.excluded, 0u);
  // 0.2 % gross outliers (0.1 mm out): all kept they dominate PF; the standard's 0.3 % takes
  // them out and PF returns to the form.
  for (std::size_t i = 0; i < 40; ++i) {
    const Eigen::Vector3d p = pts[i * 97].cast<double>();
    pts.push_back((c + (p - c).normalized() * ((p - c).norm() + 0.1)).cast<float>());
  }
  const auto with_outliers = slscan::core::probing_error(pts, 30.0);
  EXPECT_GT(with_outliers.form_all_um, 100.0);
  EXPECT_EQ(with_outliers.excluded, pts.size() * 3 / 1000);
  EXPECT_NEAR(with_outliers.form_um, 8.0, 0.3);
  EXPECT_THROW(slscan::core::probing_error(pts, 30.0, 0.01), std::invalid_argument);
}

TEST(ProbingError, SizeErrorIsDiameterMinusCalibrated) {
  const auto pts = bumpy_sphere({0, 0, 0}, 15.0004, 0, 5000);
  const auto e = slscan::core::probing_error(pts, 30.0, 0.0);
  EXPECT_NEAR(e.size_um, 0.8, 0.01);  // 2 x 15.0004 - 30.0
  EXPECT_LT(e.form_um, 0.02);         // float rounding only
}

TEST(FlatnessError, KnownWaveOnATiltedPlate) {
  // A 100 x 60 mm plate tilted 30 deg, with a +-5 um cosine wave across it: F = 10 um.
  const double tilt = 30 * std::numbers::pi / 180;
  const Eigen::Vector3d u(1, 0, 0), v(0, std::cos(tilt), std::sin(tilt)), n = u.cross(v);
  const Eigen::Vector3d origin(5, 10, 300);
  std::vector<Eigen::Vector3f> pts;
  for (int i = 0; i <= 200; ++i)
    for (int j = 0; j <= 120; ++j) {
      const double x = -50 + 0.5 * i, y = -30 + 0.5 * j;
      // Even in x, so uncorrelated with the plate's own coordinates: the fit does not tilt into it.
      const double h = 0.005 * std::cos(2 * std::numbers::pi * x / 25.0);
      pts.push_back((origin + x * u + y * v + h * n).cast<float>());
    }
  const auto f = slscan::core::flatness_error(pts, 0.0);
  EXPECT_NEAR(f.flatness_um, 10.0, 0.1);
  EXPECT_NEAR(std::fabs(f.fit.normal.dot(n)), 1.0, 1e-9);
  // One spike of 50 um: F with every point reads it; the 0.3 % exclusion drops it.
  pts.push_back((origin + 0.05 * n).cast<float>());
  const auto spiked = slscan::core::flatness_error(pts);
  EXPECT_GT(spiked.flatness_all_um, 50.0);
  EXPECT_NEAR(spiked.flatness_um, 10.0, 0.1);
  EXPECT_EQ(spiked.excluded, pts.size() * 3 / 1000);
}

}  // namespace
