// Acceptance quantities of an optical 3D measuring system: the paper's ball-bar uncertainty
// (Feng et al. 2023, section 3.1 and Table 1) and VDI/VDE 2634 Part 2's probing error form
// (PF) and size (PS), sphere-spacing error (SD) and flatness error (F). docs/accuracy.md says
// how each is measured on the virtual rig.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <span>
#include <vector>

#include "slscan/core/measure.hpp"

namespace slscan::core {

// The paper's reference-artefact terms for the ball bar (its values are the defaults).
struct BallBarReference {
  double length_mm = 150.1164;           // L_r, calibrated centre distance
  double expanded_uncertainty_um = 5.0;  // of L_r, coverage factor k = 2: u1 = U / k
  double coverage_factor = 2.0;
  double expansion_per_c = 8e-6;             // alpha of the bar
  double temperature_error_c = 0.5;          // dt: thermometer error, uniform: u2 = L alpha dt / sqrt(3)
  double expansion_half_width_per_c = 1e-6;  // d_alpha, uniform
  double temperature_offset_c = 5.0;         // t - 20 C in the lab: u3 = L (t - 20) d_alpha / sqrt(6)
};

struct BallBarUncertainty {
  std::vector<double> spacing_errors_um;  // SD_i = L_i - L_r
  double sd_um = 0;                       // SD = max |SD_i| (signed value of the largest)
  std::size_t sd_index = 0;
  double mean_mm = 0;
  double scatter_um = 0;  // sample standard deviation of the L_i (n - 1)
  double type_a_um = 0;   // u(L_ai) = sqrt(sum (s_i - mean)^2 / (n (n - 1)))
  double u1_um = 0, u2_um = 0, u3_um = 0;
  double reference_um = 0;  // u(L_r) = sqrt(u1^2 + u2^2 + u3^2)
  double combined_um = 0;   // u_c(SD) = sqrt(u(L_ai)^2 + u(L_r)^2)
};

// The paper's formulas, term for term. Throws std::invalid_argument for fewer than two
// lengths or a non-finite one (naming its index).
BallBarUncertainty ball_bar_uncertainty(std::span<const double> lengths_mm, const BallBarReference& reference = {});

// VDI/VDE 2634-2 allows up to 0.3 % of the points of a feature to be left out as outliers
// before its form is evaluated; `exclude_fraction` is that share (0 keeps every point).
struct ProbingError {
  SphereFit fit;             // unconstrained least-squares sphere on the points kept
  double form_um = 0;        // PF: range of the radial residuals of the points kept
  double size_um = 0;        // PS: fitted minus calibrated diameter
  double form_all_um = 0;    // PF with every point kept
  std::size_t excluded = 0;  // points left out (largest |residual| of the fit on all points)
};
ProbingError probing_error(const std::vector<Eigen::Vector3f>& points, double calibrated_diameter_mm,
                           double exclude_fraction = 0.003);

struct FlatnessError {
  PlaneFit fit;            // least-squares plane on the points kept
  double flatness_um = 0;  // F: range of the signed distances of the points kept
  double flatness_all_um = 0;
  std::size_t excluded = 0;
};
FlatnessError flatness_error(const std::vector<Eigen::Vector3f>& points, double exclude_fraction = 0.003);

}  // namespace slscan::core
