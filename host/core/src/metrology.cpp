#include "slscan/core/metrology.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>
#include <string>

#include "slproto/number_text.hpp"

namespace slscan::core {

BallBarUncertainty ball_bar_uncertainty(std::span<const double> lengths_mm, const BallBarReference& reference) {
  const std::size_t n = lengths_mm.size();
  if (n < 2)
    throw std::invalid_argument("ball_bar_uncertainty: need at least two measured lengths, got " + std::to_string(n));
  for (std::size_t i = 0; i < n; ++i)
    if (!std::isfinite(lengths_mm[i]))
      throw std::invalid_argument("ball_bar_uncertainty: length " + std::to_string(i + 1) + " is not finite");
  BallBarUncertainty u;
  const double lr_um = 1e3 * reference.length_mm;
  for (std::size_t i = 0; i < n; ++i) {
    const double e = 1e3 * lengths_mm[i] - lr_um;
    u.spacing_errors_um.push_back(e);
    if (std::fabs(e) > std::fabs(u.sd_um)) {
      u.sd_um = e;
      u.sd_index = i;
    }
  }
  u.mean_mm = std::accumulate(lengths_mm.begin(), lengths_mm.end(), 0.0) / static_cast<double>(n);
  double sum_sq = 0;  // um^2
  for (const double l : lengths_mm) sum_sq += (1e3 * (l - u.mean_mm)) * (1e3 * (l - u.mean_mm));
  const double nd = static_cast<double>(n);
  u.scatter_um = std::sqrt(sum_sq / (nd - 1));
  u.type_a_um = std::sqrt(sum_sq / (nd * (nd - 1)));
  u.u1_um = reference.expanded_uncertainty_um / reference.coverage_factor;
  u.u2_um = lr_um * reference.expansion_per_c * reference.temperature_error_c / std::sqrt(3.0);
  u.u3_um = lr_um * reference.temperature_offset_c * reference.expansion_half_width_per_c / std::sqrt(6.0);
  u.reference_um = std::sqrt(u.u1_um * u.u1_um + u.u2_um * u.u2_um + u.u3_um * u.u3_um);
  u.combined_um = std::sqrt(u.type_a_um * u.type_a_um + u.reference_um * u.reference_um);
  return u;
}

namespace {

// The indices of all but the `drop` points with the largest |residual|.
std::vector<std::uint32_t> keep_smallest(const std::vector<double>& residuals, std::size_t drop) {
  std::vector<std::uint32_t> order(residuals.size());
  std::iota(order.begin(), order.end(), 0u);
  const std::size_t keep = residuals.size() - drop;
  std::nth_element(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(keep), order.end(),
                   [&](std::uint32_t a, std::uint32_t b) { return std::fabs(residuals[a]) < std::fabs(residuals[b]); });
  order.resize(keep);
  std::sort(order.begin(), order.end());
  return order;
}

std::size_t excluded_count(std::size_t n, double fraction, const char* what) {
  if (!(fraction >= 0 && fraction <= 0.003))
    throw std::invalid_argument(std::string(what) + ": exclude_fraction " + slproto::short_number(fraction) +
                                " is outside [0, 0.003] (VDI/VDE 2634-2 allows at most 0.3 %)");
  return static_cast<std::size_t>(std::floor(fraction * static_cast<double>(n)));
}

}  // namespace

ProbingError probing_error(const std::vector<Eigen::Vector3f>& points, double calibrated_diameter_mm,
                           double exclude_fraction) {
  const std::size_t drop = excluded_count(points.size(), exclude_fraction, "probing_error");
  ProbingError e;
  const SphereFit all = fit_sphere(points);
  e.form_all_um = 1e3 * all.form_error_mm;
  e.fit = all;
  if (drop > 0) {
    std::vector<double> residuals(points.size());
    for (std::size_t i = 0; i < points.size(); ++i)
      residuals[i] = (points[i].cast<double>() - all.centre).norm() - all.radius_mm;
    // The standard's fit stays unconstrained: refit on the points kept, then take their range.
    e.fit = fit_sphere(points, keep_smallest(residuals, drop));
    e.excluded = drop;
  }
  e.form_um = 1e3 * e.fit.form_error_mm;
  e.size_um = 1e3 * (2 * e.fit.radius_mm - calibrated_diameter_mm);
  return e;
}

FlatnessError flatness_error(const std::vector<Eigen::Vector3f>& points, double exclude_fraction) {
  const std::size_t drop = excluded_count(points.size(), exclude_fraction, "flatness_error");
  FlatnessError e;
  e.fit = fit_plane(points);
  e.flatness_all_um = 1e3 * e.fit.flatness_mm;
  if (drop > 0) {
    std::vector<double> residuals(points.size());
    for (std::size_t i = 0; i < points.size(); ++i)
      residuals[i] = e.fit.normal.dot(points[i].cast<double>()) - e.fit.offset_mm;
    const auto keep = keep_smallest(residuals, drop);
    std::vector<Eigen::Vector3f> kept;
    kept.reserve(keep.size());
    for (const auto i : keep) kept.push_back(points[i]);
    e.fit = fit_plane(kept);
    e.excluded = drop;
  }
  e.flatness_um = 1e3 * e.fit.flatness_mm;
  return e;
}

}  // namespace slscan::core
