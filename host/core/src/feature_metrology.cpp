#include "slscan/core/feature_metrology.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>
#include <stdexcept>
#include <string>

namespace slscan::core {
namespace {

// A length for a message: the digits it was given with ("0.5", not "0.500000").
std::string mm_text(double mm) {
  char text[32];
  std::snprintf(text, sizeof text, "%g", mm);
  return text;
}

constexpr double kDeg = std::numbers::pi / 180.0;
constexpr std::size_t kMinRegionPoints = 100;

void check_rule(const FeatureRule& rule) {
  if (!(rule.band_mm > 0) || !std::isfinite(rule.band_mm))
    throw std::invalid_argument("feature region: band_mm must be > 0");
  if (!(rule.attachment_shell_mm >= 0) || !std::isfinite(rule.attachment_shell_mm))
    throw std::invalid_argument("feature region: attachment_shell_mm must be >= 0");
  if (!(rule.cone_margin_deg >= 0 && rule.cone_margin_deg < 90))
    throw std::invalid_argument("feature region: cone_margin_deg must be in [0, 90)");
  if (!(rule.exclude_fraction >= 0 && rule.exclude_fraction <= 0.003))
    throw std::invalid_argument("feature region: exclude_fraction must be in [0, 0.003] (VDI/VDE 2634-2)");
}

double angle_deg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::acos(std::clamp(a.dot(b), -1.0, 1.0)) / kDeg;
}

// Clusters of attachment directions (unit vectors from the centre): greedily the direction with
// the most others within 30 deg, its cluster = the directions within 45 deg of the cluster's
// mean; repeated on the rest while a cluster has at least `min_points`.
std::vector<JointCone> joint_cones(std::vector<Eigen::Vector3d> dirs, const FeatureRule& rule) {
  std::vector<JointCone> cones;
  // The seed search is quadratic: on at most 1500 evenly strided directions.
  while (dirs.size() >= rule.min_attachment_points && cones.size() < 8) {
    const std::size_t stride = std::max<std::size_t>(1, dirs.size() / 1500);
    const double near = std::cos(30 * kDeg);
    std::size_t best = 0, best_count = 0;
    for (std::size_t i = 0; i < dirs.size(); i += stride) {
      std::size_t count = 0;
      for (std::size_t j = 0; j < dirs.size(); j += stride) count += dirs[i].dot(dirs[j]) >= near ? 1 : 0;
      if (count > best_count) best_count = count, best = i;
    }
    Eigen::Vector3d axis = dirs[best];
    for (int round = 0; round < 5; ++round) {
      Eigen::Vector3d sum = Eigen::Vector3d::Zero();
      for (const auto& d : dirs)
        if (d.dot(axis) >= std::cos(45 * kDeg)) sum += d;
      if (sum.norm() == 0) break;
      axis = sum.normalized();
    }
    std::vector<Eigen::Vector3d> rest;
    std::vector<double> angles;
    for (const auto& d : dirs) {
      const double a = angle_deg(d, axis);
      if (a <= 45)
        angles.push_back(a);
      else
        rest.push_back(d);
    }
    if (angles.size() < rule.min_attachment_points) break;
    // The cluster's widest direction, robust to a stray or two: its 99th percentile.
    const std::size_t k = std::min(angles.size() - 1, angles.size() * 99 / 100);
    std::nth_element(angles.begin(), angles.begin() + static_cast<std::ptrdiff_t>(k), angles.end());
    cones.push_back({axis, std::min(89.0, angles[k] + rule.cone_margin_deg), angles.size()});
    dirs = std::move(rest);
  }
  return cones;
}

}  // namespace

SphereFeature sphere_feature(const std::vector<Eigen::Vector3f>& points, const SphereFit& robust_fit,
                             double calibrated_diameter_mm, const FeatureRule& rule) {
  check_rule(rule);
  if (!(calibrated_diameter_mm > 0) || !std::isfinite(calibrated_diameter_mm))
    throw std::invalid_argument("sphere_feature: the calibrated diameter must be > 0 mm");
  if (!robust_fit.centre.allFinite() || !(robust_fit.radius_mm > 0))
    throw std::invalid_argument("sphere_feature: the robust fit is not a sphere");
  const Eigen::Vector3d c = robust_fit.centre;
  const double r = robust_fit.radius_mm;
  SphereFeature out;
  std::vector<std::uint32_t> band;
  std::vector<Eigen::Vector3d> attached;
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (!points[i].allFinite()) continue;
    const Eigen::Vector3d q = points[i].cast<double>() - c;
    const double d = q.norm() - r;
    if (std::abs(d) <= rule.band_mm)
      band.push_back(static_cast<std::uint32_t>(i));
    else if (d > rule.band_mm && d <= rule.band_mm + rule.attachment_shell_mm)
      attached.push_back(q.normalized());
  }
  out.band_points = band.size();
  out.joints = joint_cones(std::move(attached), rule);
  for (const auto i : band) {
    const Eigen::Vector3d dir = (points[i].cast<double>() - c).normalized();
    bool in_cone = false;
    for (const auto& cone : out.joints) in_cone = in_cone || angle_deg(dir, cone.axis) <= cone.half_angle_deg;
    if (in_cone)
      ++out.cone_points;
    else
      out.region.push_back(i);
  }
  if (out.region.size() < kMinRegionPoints)
    throw std::runtime_error("sphere_feature: only " + std::to_string(out.region.size()) +
                             " points in the sphere's region (within " + mm_text(rule.band_mm) +
                             " mm of its fit, outside " + std::to_string(out.joints.size()) + " joint cone(s))");
  std::vector<Eigen::Vector3f> kept;
  kept.reserve(out.region.size());
  for (const auto i : out.region) kept.push_back(points[i]);
  out.probing = probing_error(kept, calibrated_diameter_mm, rule.exclude_fraction);
  return out;
}

BallBarFeatures ball_bar_features(const PointCloud& cloud, std::array<double, 2> calibrated_diameters_mm,
                                  double reference_length_mm, const FeatureRule& rule, const BallBarOptions& search) {
  BallBarOptions options = search;
  options.nominal_radii_mm = {calibrated_diameters_mm[0] / 2, calibrated_diameters_mm[1] / 2};
  const BallBarResult bar = measure_ball_bar(cloud, options);
  BallBarFeatures out;
  for (std::size_t s = 0; s < 2; ++s)
    out.spheres[s] = sphere_feature(cloud.points, bar.spheres[s], calibrated_diameters_mm[s], rule);
  out.centre_distance_mm = (out.spheres[0].probing.fit.centre - out.spheres[1].probing.fit.centre).norm();
  out.sd_um = 1e3 * (out.centre_distance_mm - reference_length_mm);
  return out;
}

PlaneFeature plane_feature(const PointCloud& cloud, const FeatureRule& rule, int iterations, std::uint64_t seed) {
  check_rule(rule);
  if (iterations < 1) throw std::invalid_argument("plane_feature: iterations must be >= 1");
  std::vector<std::uint32_t> finite;
  for (std::size_t i = 0; i < cloud.size(); ++i)
    if (cloud.points[i].allFinite()) finite.push_back(static_cast<std::uint32_t>(i));
  if (finite.size() < kMinRegionPoints)
    throw std::runtime_error("plane_feature: only " + std::to_string(finite.size()) + " finite points");
  std::mt19937_64 rng(seed);
  std::vector<std::uint32_t> sample = finite;
  std::shuffle(sample.begin(), sample.end(), rng);
  if (sample.size() > 20000) sample.resize(20000);
  std::uniform_int_distribution<std::size_t> pick(0, sample.size() - 1);
  const auto& pts = cloud.points;
  Eigen::Vector3d best_n = Eigen::Vector3d::UnitZ();
  double best_d = 0;
  std::size_t best_score = 0;
  for (int it = 0; it < iterations; ++it) {
    const Eigen::Vector3d a = pts[sample[pick(rng)]].cast<double>(), b = pts[sample[pick(rng)]].cast<double>(),
                          c = pts[sample[pick(rng)]].cast<double>();
    const Eigen::Vector3d n = (b - a).cross(c - a);
    if (!(n.norm() > 1e-6)) continue;
    const Eigen::Vector3d u = n.normalized();
    const double d = u.dot(a);
    std::size_t score = 0;
    for (const auto i : sample) score += std::abs(u.dot(pts[i].cast<double>()) - d) <= rule.band_mm ? 1 : 0;
    if (score > best_score) best_score = score, best_n = u, best_d = d;
  }
  std::vector<std::uint32_t> region;
  for (int round = 0; round < 20; ++round) {
    std::vector<std::uint32_t> next;
    for (const auto i : finite)
      if (std::abs(best_n.dot(pts[i].cast<double>()) - best_d) <= rule.band_mm) next.push_back(i);
    if (next.size() < kMinRegionPoints)
      throw std::runtime_error("plane_feature: no plane with " + std::to_string(kMinRegionPoints) + " points within " +
                               mm_text(rule.band_mm) + " mm found");
    if (next == region) break;
    region = std::move(next);
    std::vector<Eigen::Vector3f> kept;
    kept.reserve(region.size());
    for (const auto i : region) kept.push_back(pts[i]);
    const PlaneFit fit = fit_plane(kept);
    best_n = fit.normal;
    best_d = fit.offset_mm;
  }
  PlaneFeature out;
  out.region = region;
  out.region_points = region.size();
  std::vector<Eigen::Vector3f> kept;
  kept.reserve(region.size());
  for (const auto i : region) kept.push_back(pts[i]);
  out.flatness = flatness_error(kept, rule.exclude_fraction);
  return out;
}

}  // namespace slscan::core
