// The mesher's implicit-fit sums in SIMD lanes (host/mesh/src/fit_sums.cpp) against the same sums
// in double, scalar, on every SIMD target compiled and supported here.
#include <gtest/gtest.h>
#include <hwy/targets.h>

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "fit_sums.hpp"

namespace {

using slscan::mesh::detail::fit_sums;
using slscan::mesh::detail::FitCandidates;
using slscan::mesh::detail::FitQuery;
using slscan::mesh::detail::FitSums;

struct Point {
  float p[3], n[3], value;
  std::uint32_t index;
};

// The sums as fit_sums.hpp defines them, in double, one point after another.
FitSums reference_sums(const std::vector<Point>& points, const FitQuery& q) {
  FitSums s;
  const Point* nearest = nullptr;
  double nearest_d2 = 0;
  std::vector<double> d2(points.size());
  for (std::size_t i = 0; i < points.size(); ++i) {
    double r2 = 0;
    for (int a = 0; a < 3; ++a) r2 += std::pow(double(points[i].p[a]) - q.x[a], 2);
    d2[i] = r2;
    if (r2 < q.support2 &&
        (nearest == nullptr || r2 < nearest_d2 || (r2 == nearest_d2 && points[i].index < nearest->index))) {
      nearest = &points[i];
      nearest_d2 = r2;
    }
  }
  if (nearest == nullptr) return s;
  s.any = true;
  double side[3] = {q.facing[0], q.facing[1], q.facing[2]};
  if (side[0] == 0 && side[1] == 0 && side[2] == 0)
    for (int a = 0; a < 3; ++a) side[a] = nearest->n[a];
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (!(d2[i] < q.support2)) continue;
    const Point& pt = points[i];
    const double agreement = pt.n[0] * side[0] + pt.n[1] * side[1] + pt.n[2] * side[2];
    if (agreement < 0) s.two_sided = true;
    const double w = std::exp(-d2[i] * q.inv_two_sigma2);
    if (q.with_values) {
      s.value_weight += w;
      s.value_sum += w * pt.value;
    }
    if (!(agreement > q.normal_gate)) continue;
    double rel[3];
    for (int a = 0; a < 3; ++a) rel[a] = double(pt.p[a]) - q.x[a];
    s.weight += w;
    s.pp += w * d2[i];
    for (int a = 0; a < 3; ++a) {
      s.p[a] += w * rel[a];
      s.n[a] += w * pt.n[a];
      s.pn += w * rel[a] * pt.n[a];
    }
  }
  return s;
}

// A curved patch (a 5 mm sphere's cap) of `count` points around the origin, normals out, with a
// share facing the other way (a wall's far side 0.3 mm behind), none on the support's edge.
std::vector<Point> patch(std::size_t count, float support, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.2f * support, 1.2f * support);
  std::vector<Point> points;
  const double radius = 5;
  while (points.size() < count) {
    const float x = u(rng), y = u(rng);
    const bool far_side = points.size() % 7 == 3;
    const double z0 = radius - std::sqrt(radius * radius - x * x - y * y);
    const double z = far_side ? z0 - 0.3 : z0;
    const double r2 = x * x + y * y + z * z;
    if (std::abs(r2 - double(support) * support) < 1e-3) continue;
    Point pt{};
    pt.p[0] = x;
    pt.p[1] = y;
    pt.p[2] = static_cast<float>(z);
    // The outward normal of the sphere centred at (0, 0, radius), flipped on the far side.
    const double len = std::sqrt(x * x + y * y + (z0 - radius) * (z0 - radius));
    const double sign = far_side ? -1 : 1;
    pt.n[0] = static_cast<float>(sign * -x / len);
    pt.n[1] = static_cast<float>(sign * -y / len);
    pt.n[2] = static_cast<float>(sign * -(z0 - radius) / len);
    pt.value = static_cast<float>(points.size() % 13) * 0.1f;
    pt.index = static_cast<std::uint32_t>(points.size()) * 3 % 10007;
    points.push_back(pt);
  }
  return points;
}

void expect_close(const FitSums& got, const FitSums& want, const std::string& what) {
  SCOPED_TRACE(what);
  EXPECT_EQ(got.any, want.any);
  EXPECT_EQ(got.two_sided, want.two_sided);
  // Float lanes over ~10^3 terms of weight <= 1: relative 1e-5 of the largest term's scale.
  const double tolerance = 1e-5 * std::max(1.0, want.weight);
  EXPECT_NEAR(got.weight, want.weight, tolerance);
  EXPECT_NEAR(got.pp, want.pp, tolerance);
  EXPECT_NEAR(got.pn, want.pn, tolerance);
  for (int a = 0; a < 3; ++a) {
    EXPECT_NEAR(got.p[a], want.p[a], tolerance) << "axis " << a;
    EXPECT_NEAR(got.n[a], want.n[a], tolerance) << "axis " << a;
  }
  EXPECT_NEAR(got.value_weight, want.value_weight, tolerance);
  EXPECT_NEAR(got.value_sum, want.value_sum, tolerance);
}

class FitSumsTargets : public ::testing::Test {
 protected:
  void TearDown() override { hwy::SetSupportedTargetsForTest(0); }  // back to the CPU's own
};

TEST_F(FitSumsTargets, MatchTheScalarSumsInDoubleOnEveryTarget) {
  const float support = 0.6f, sigma = 0.2f;
  const std::vector<std::int64_t> targets = hwy::SupportedAndGeneratedTargets();
  ASSERT_FALSE(targets.empty());
  for (const std::int64_t target : targets) {
    hwy::SetSupportedTargetsForTest(target);
    for (const std::size_t count : {1u, 5u, 17u, 1000u, 1531u}) {
      const auto points = patch(count, support, static_cast<std::uint32_t>(count));
      FitCandidates candidates;
      for (const Point& pt : points) candidates.push(pt.p, pt.n, pt.value, pt.index);
      candidates.pad();
      ASSERT_EQ(candidates.size(), count);
      for (int variant = 0; variant < 4; ++variant) {
        FitQuery q;
        // Off-centre queries; one beside the patch, where nothing is within the support.
        const float offsets[4][3] = {{0.01f, -0.02f, 0.05f}, {0.2f, 0.1f, -0.1f}, {0.0f, 0.0f, 0.16f}, {0, 0, 3}};
        for (int a = 0; a < 3; ++a) q.x[a] = offsets[variant][a];
        q.support2 = support * support;
        q.inv_two_sigma2 = 1 / (2 * sigma * sigma);
        q.normal_gate = 0;
        q.with_values = variant != 1;
        // Variant 2 fits the far side: the side given, against the nearest point's own.
        if (variant == 2) {
          q.facing[2] = 1;
        }
        const FitSums want = reference_sums(points, q);
        const FitSums got = fit_sums(candidates, q);
        expect_close(got, want,
                     std::string(hwy::TargetName(target)) + ", " + std::to_string(count) + " points, query " +
                         std::to_string(variant));
        if (variant == 3) {
          EXPECT_FALSE(want.any);
        }
        if (count == 1000 && variant == 0) {
          // A query worth checking: hundreds of points count, both sides within the support.
          EXPECT_GT(want.weight, 50.0);
          EXPECT_TRUE(want.two_sided);
        }
      }
    }
  }
}

TEST_F(FitSumsTargets, NoCandidatesGiveNoSums) {
  FitCandidates candidates;
  candidates.pad();
  FitQuery q;
  q.support2 = 1;
  q.inv_two_sigma2 = 1;
  const FitSums got = fit_sums(candidates, q);
  EXPECT_FALSE(got.any);
  EXPECT_EQ(got.weight, 0);
}

TEST_F(FitSumsTargets, CandidatesPaddedForAnotherTargetAreRefused) {
  const std::vector<std::int64_t> targets = hwy::SupportedAndGeneratedTargets();
  if (targets.size() < 2) {
    GTEST_SKIP() << "one SIMD target here";
  }
  // The narrowest target pads least; the widest then cannot read whole vectors (x86: SSE4's 4
  // floats against AVX2's 8), unless they have the same width.
  hwy::SetSupportedTargetsForTest(targets.back());
  FitCandidates candidates;
  const float p[3] = {0, 0, 0}, n[3] = {0, 0, 1};
  candidates.push(p, n, 0, 0);
  candidates.pad();
  const std::size_t narrow = candidates.x.size();
  hwy::SetSupportedTargetsForTest(targets.front());
  FitCandidates probe;
  probe.push(p, n, 0, 0);
  probe.pad();
  if (probe.x.size() == narrow) {
    GTEST_SKIP() << "the targets here have the same width";
  }
  FitQuery q;
  q.support2 = 1;
  q.inv_two_sigma2 = 1;
  EXPECT_THROW(fit_sums(candidates, q), std::logic_error);
}

}  // namespace
