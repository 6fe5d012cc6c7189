#include "slscan/core/measure.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>
#include <string>

#include "slproto/number_text.hpp"

namespace slscan::core {
namespace {

template <class Visit>
void for_each_point(const std::vector<Eigen::Vector3f>& points, const std::vector<std::uint32_t>* indices,
                    Visit&& visit) {
  if (indices) {
    for (auto i : *indices) visit(points[i].cast<double>());
  } else {
    for (const auto& p : points) visit(p.cast<double>());
  }
}

SphereFit fit_sphere_impl(const std::vector<Eigen::Vector3f>& points, const std::vector<std::uint32_t>* indices) {
  const std::size_t n = indices ? indices->size() : points.size();
  if (n < 4) throw std::invalid_argument("fit_sphere: needs at least 4 points, got " + std::to_string(n));
  if (indices)
    for (auto i : *indices)
      if (i >= points.size())
        throw std::invalid_argument("fit_sphere: index " + std::to_string(i) + " is beyond the " +
                                    std::to_string(points.size()) + " points");
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  bool finite = true;
  for_each_point(points, indices, [&](const Eigen::Vector3d& p) {
    finite = finite && p.allFinite();
    mean += p;
  });
  if (!finite) throw std::invalid_argument("fit_sphere: a point is not finite");
  mean /= static_cast<double>(n);
  // Algebraic fit about the centroid: |q|^2 = 2 c.q + d, with r^2 = d + |c|^2.
  Eigen::Matrix4d ata = Eigen::Matrix4d::Zero();
  Eigen::Vector4d atb = Eigen::Vector4d::Zero();
  for_each_point(points, indices, [&](const Eigen::Vector3d& p) {
    const Eigen::Vector3d q = p - mean;
    const Eigen::Vector4d row(2 * q.x(), 2 * q.y(), 2 * q.z(), 1.0);
    ata.noalias() += row * row.transpose();
    atb += row * q.squaredNorm();
  });
  Eigen::LDLT<Eigen::Matrix4d> algebraic(ata);
  const Eigen::Vector4d diag = algebraic.vectorD().cwiseAbs();
  if (algebraic.info() != Eigen::Success || diag.minCoeff() <= 1e-12 * diag.maxCoeff())
    throw std::invalid_argument("fit_sphere: the " + std::to_string(n) +
                                " points are degenerate (coplanar or repeated)");
  const Eigen::Vector4d sol = algebraic.solve(atb);
  Eigen::Vector3d c = sol.head<3>();
  double r = std::sqrt(std::max(0.0, sol[3] + c.squaredNorm()));

  SphereFit fit;
  fit.point_count = n;
  // Gauss-Newton on r_i = |q_i - c| - r.
  for (int it = 0; it < 100; ++it) {
    Eigen::Matrix4d jtj = Eigen::Matrix4d::Zero();
    Eigen::Vector4d jtr = Eigen::Vector4d::Zero();
    for_each_point(points, indices, [&](const Eigen::Vector3d& p) {
      const Eigen::Vector3d d = p - mean - c;
      const double len = d.norm();
      if (len == 0) return;
      const Eigen::Vector3d u = d / len;
      const Eigen::Vector4d j(-u.x(), -u.y(), -u.z(), -1.0);
      jtj.noalias() += j * j.transpose();
      jtr += j * (len - r);
    });
    const Eigen::Vector4d step = jtj.ldlt().solve(-jtr);
    if (!step.allFinite()) throw std::invalid_argument("fit_sphere: Gauss-Newton diverged (degenerate points)");
    c += step.head<3>();
    r += step[3];
    fit.iterations = it + 1;
    if (step.norm() < 1e-13 * std::max(1.0, r)) break;
  }
  fit.centre = c + mean;
  fit.radius_mm = std::abs(r);
  double sum2 = 0, lo = INFINITY, hi = -INFINITY;
  for_each_point(points, indices, [&](const Eigen::Vector3d& p) {
    const double e = (p - fit.centre).norm() - fit.radius_mm;
    sum2 += e * e;
    lo = std::min(lo, e);
    hi = std::max(hi, e);
  });
  fit.rms_mm = std::sqrt(sum2 / static_cast<double>(n));
  fit.min_residual_mm = lo;
  fit.max_residual_mm = hi;
  fit.form_error_mm = hi - lo;
  return fit;
}

// The sphere through 4 points (false if they are nearly coplanar).
bool sphere_through(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                    const Eigen::Vector3d& d, Eigen::Vector3d& centre, double& radius) {
  Eigen::Matrix3d m;
  m.row(0) = (b - a).transpose();
  m.row(1) = (c - a).transpose();
  m.row(2) = (d - a).transpose();
  const Eigen::Vector3d rhs(0.5 * (b - a).squaredNorm(), 0.5 * (c - a).squaredNorm(), 0.5 * (d - a).squaredNorm());
  const double det = m.determinant();
  const double scale = m.row(0).norm() * m.row(1).norm() * m.row(2).norm();
  if (!(std::abs(det) > 1e-3 * scale)) return false;
  const Eigen::Vector3d offset = m.inverse() * rhs;
  centre = a + offset;
  radius = offset.norm();
  return true;
}

struct SphereSearch {
  const std::vector<Eigen::Vector3f>& points;
  const std::vector<std::uint32_t>& candidates;  // the points still unassigned
  const BallBarOptions& options;
  std::mt19937_64& rng;

  std::vector<std::uint32_t> within_band(const Eigen::Vector3d& c, double r, double band) const {
    std::vector<std::uint32_t> out;
    for (auto i : candidates)
      if (std::abs((points[i].cast<double>() - c).norm() - r) <= band) out.push_back(i);
    return out;
  }

  std::pair<SphereFit, std::vector<std::uint32_t>> find(double nominal_radius, const char* which) const {
    if (candidates.size() < options.min_sphere_points)
      throw std::runtime_error(std::string("measure_ball_bar: only ") + std::to_string(candidates.size()) +
                               " points left to search for the " + which + " sphere");
    std::vector<std::uint32_t> sample = candidates;
    std::shuffle(sample.begin(), sample.end(), rng);
    if (sample.size() > options.ransac_sample_points) sample.resize(options.ransac_sample_points);
    std::uniform_int_distribution<std::size_t> pick(0, sample.size() - 1);
    const double reach2 = 4 * nominal_radius * nominal_radius;
    Eigen::Vector3d best_centre = Eigen::Vector3d::Zero();
    std::size_t best_score = 0;
    for (int it = 0; it < options.ransac_iterations; ++it) {
      // Draw the other three points near the first: a sphere's points lie within its diameter.
      const Eigen::Vector3d a = points[sample[pick(rng)]].cast<double>();
      Eigen::Vector3d others[3];
      int got = 0;
      for (int tries = 0; tries < 64 && got < 3; ++tries) {
        const Eigen::Vector3d q = points[sample[pick(rng)]].cast<double>();
        const double d2 = (q - a).squaredNorm();
        if (d2 <= reach2 && d2 > 0.01 * reach2) others[got++] = q;
      }
      if (got < 3) continue;
      Eigen::Vector3d centre;
      double radius = 0;
      if (!sphere_through(a, others[0], others[1], others[2], centre, radius)) continue;
      if (std::abs(radius - nominal_radius) > options.radius_tolerance_mm) continue;
      std::size_t score = 0;
      for (auto i : sample)
        score += std::abs((points[i].cast<double>() - centre).norm() - nominal_radius) <= options.ransac_band_mm;
      if (score > best_score) {
        best_score = score;
        best_centre = centre;
      }
    }
    if (best_score == 0)
      throw std::runtime_error(std::string("measure_ball_bar: no sphere of radius ") +
                               slproto::short_number(nominal_radius) + " mm found for the " + which + " sphere");
    // Refine: refit on the band around the current sphere until the inlier set settles.
    std::vector<std::uint32_t> inliers = within_band(best_centre, nominal_radius, options.ransac_band_mm);
    SphereFit fit;
    for (int round = 0; round < 20; ++round) {
      if (inliers.size() < std::max<std::size_t>(options.min_sphere_points, 4))
        throw std::runtime_error(std::string("measure_ball_bar: the ") + which + " sphere has only " +
                                 std::to_string(inliers.size()) + " points within the band");
      fit = fit_sphere_impl(points, &inliers);
      auto next = within_band(fit.centre, fit.radius_mm, options.refine_band_mm);
      if (next == inliers) break;
      inliers = std::move(next);
    }
    return {fit, inliers};
  }
};

}  // namespace

SphereFit fit_sphere(const std::vector<Eigen::Vector3f>& points) { return fit_sphere_impl(points, nullptr); }

SphereFit fit_sphere(const std::vector<Eigen::Vector3f>& points, const std::vector<std::uint32_t>& indices) {
  return fit_sphere_impl(points, &indices);
}

PlaneFit fit_plane(const std::vector<Eigen::Vector3f>& points) {
  const std::size_t n = points.size();
  if (n < 3) throw std::invalid_argument("fit_plane: needs at least 3 points, got " + std::to_string(n));
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < n; ++i) {
    if (!points[i].allFinite()) throw std::invalid_argument("fit_plane: point " + std::to_string(i) + " is not finite");
    mean += points[i].cast<double>();
  }
  mean /= static_cast<double>(n);
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const auto& p : points) {
    const Eigen::Vector3d q = p.cast<double>() - mean;
    cov.noalias() += q * q.transpose();
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(cov);
  const Eigen::Vector3d ev = solver.eigenvalues();
  if (!(ev[1] > 1e-12 * ev[2])) throw std::invalid_argument("fit_plane: the points are collinear or repeated");
  PlaneFit fit;
  fit.normal = solver.eigenvectors().col(0).normalized();
  fit.centroid = mean;
  fit.offset_mm = fit.normal.dot(mean);
  fit.point_count = n;
  double sum2 = 0, lo = INFINITY, hi = -INFINITY;
  for (const auto& p : points) {
    const double e = fit.normal.dot(p.cast<double>()) - fit.offset_mm;
    sum2 += e * e;
    lo = std::min(lo, e);
    hi = std::max(hi, e);
  }
  fit.rms_mm = std::sqrt(sum2 / static_cast<double>(n));
  fit.flatness_mm = hi - lo;
  return fit;
}

namespace {
void check_options(const BallBarOptions& options) {
  for (double r : options.nominal_radii_mm)
    if (!(r > 0)) throw std::invalid_argument("measure_ball_bar: nominal radii must be > 0");
  if (!(options.ransac_band_mm > 0) || !(options.refine_band_mm > 0) || !(options.radius_tolerance_mm > 0))
    throw std::invalid_argument("measure_ball_bar: bands and radius tolerance must be > 0");
  if (options.ransac_iterations < 1 || options.ransac_sample_points < 4)
    throw std::invalid_argument("measure_ball_bar: ransac_iterations must be >= 1 and ransac_sample_points >= 4");
}
}  // namespace

FoundSphere find_sphere(const PointCloud& cloud, double nominal_radius_mm, const BallBarOptions& options) {
  check_options(options);
  if (!(nominal_radius_mm > 0) || !std::isfinite(nominal_radius_mm))
    throw std::invalid_argument("find_sphere: the nominal radius must be > 0 mm");
  std::vector<std::uint32_t> candidates;
  candidates.reserve(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i)
    if (cloud.points[i].allFinite()) candidates.push_back(static_cast<std::uint32_t>(i));
  std::mt19937_64 rng(options.seed);
  const SphereSearch search{cloud.points, candidates, options, rng};
  auto [fit, inliers] = search.find(nominal_radius_mm, "one");
  return {fit, std::move(inliers)};
}

BallBarResult measure_ball_bar(const PointCloud& cloud, const BallBarOptions& options) {
  check_options(options);
  std::vector<std::uint32_t> candidates;
  candidates.reserve(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i)
    if (cloud.points[i].allFinite()) candidates.push_back(static_cast<std::uint32_t>(i));
  std::mt19937_64 rng(options.seed);
  BallBarResult result;
  const char* names[2] = {"first", "second"};
  for (int s = 0; s < 2; ++s) {
    const SphereSearch search{cloud.points, candidates, options, rng};
    auto [fit, inliers] = search.find(options.nominal_radii_mm[static_cast<std::size_t>(s)], names[s]);
    // Take the sphere (and whatever lies inside it or on its band) out of the second search.
    const double exclusion = fit.radius_mm + options.radius_tolerance_mm + options.ransac_band_mm;
    // Captured by copy of the centre: clang 14 (the fuzz build) cannot capture a structured binding.
    const Eigen::Vector3d centre = fit.centre;
    std::erase_if(candidates,
                  [&](std::uint32_t i) { return (cloud.points[i].cast<double>() - centre).norm() <= exclusion; });
    result.spheres[static_cast<std::size_t>(s)] = fit;
    result.sphere_points[static_cast<std::size_t>(s)] = std::move(inliers);
  }
  result.centre_distance_mm = (result.spheres[0].centre - result.spheres[1].centre).norm();
  return result;
}

}  // namespace slscan::core
