// Feature measurement from the scan alone (no ground truth): which points of a cloud belong to
// a sphere or a plane, and the VDI/VDE 2634-2 figures on them (docs/inspection.md). This is the
// one procedure behind `slscan measure`, report.json / report.html and bench_metrology.
//
// The region rule, for a sphere found by a robust fit (RANSAC on the nominal radius, then least
// squares, core::find_sphere / measure_ball_bar):
//  1. the points within +-band_mm of that fit's surface;
//  2. minus the points inside a cone around each joint (the stand, the bar): the points just
//     outside the sphere (between band_mm and band_mm + attachment_shell_mm beyond its surface)
//     belong to whatever is attached to it; their directions from the centre are clustered, and
//     each cluster of at least min_attachment_points is a joint, its cone's axis the cluster's
//     mean direction and its half-angle the cluster's widest direction plus cone_margin_deg;
//  3. on what is left, the unconstrained least-squares sphere with up to exclude_fraction
//     (VDI/VDE 2634-2: at most 0.3 %) of the points left out, the figure with every point of
//     the region beside it (core::probing_error).
// A plane: RANSAC for the plane with most points within the band, least squares on them, the
// points within +-band_mm of that fit, then core::flatness_error.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cmath>
#include <cstdint>
#include <optional>
#include <vector>

#include "slscan/core/measure.hpp"
#include "slscan/core/metrology.hpp"
#include "slscan/core/point_cloud.hpp"

namespace slscan::core {

struct FeatureRule {
  double band_mm = 0.5;                    // region: within this of the robust fit's surface
  double attachment_shell_mm = 2.0;        // beyond the band, points this far out are attachments
  double cone_margin_deg = 3.0;            // added to each joint cone's half-angle
  std::size_t min_attachment_points = 20;  // fewer attached points are strays, not a joint
  double exclude_fraction = 0.003;         // VDI/VDE 2634-2 outlier share (0 .. 0.003)
};

struct JointCone {
  Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();  // unit, from the sphere's centre
  double half_angle_deg = 0;
  std::size_t attachment_points = 0;  // points just outside the sphere that made it
};

struct SphereFeature {
  ProbingError probing;         // PF, PS (and PF with every region point) on the region
  std::size_t band_points = 0;  // within the band of the robust fit
  std::size_t cone_points = 0;  // of those, inside a joint cone (not in the region)
  std::vector<JointCone> joints;
  std::vector<std::uint32_t> region;  // indices into the points
};

// The region of the sphere around `robust_fit` in `points` and its PF / PS against the
// calibrated diameter. Throws std::invalid_argument for bad rules, std::runtime_error when the
// region has fewer than 100 points.
SphereFeature sphere_feature(const std::vector<Eigen::Vector3f>& points, const SphereFit& robust_fit,
                             double calibrated_diameter_mm, const FeatureRule& rule = {});

struct BallBarFeatures {
  std::array<SphereFeature, 2> spheres;
  double centre_distance_mm = 0;  // between the region fits' centres
  double sd_um = 0;               // centre distance minus the reference length
};
// measure_ball_bar's spheres, each through sphere_feature; SD from the region fits.
BallBarFeatures ball_bar_features(const PointCloud& cloud, std::array<double, 2> calibrated_diameters_mm,
                                  double reference_length_mm, const FeatureRule& rule = {},
                                  const BallBarOptions& search = {});

struct PlaneFeature {
  FlatnessError flatness;  // F (and F with every region point)
  std::size_t region_points = 0;
  std::vector<std::uint32_t> region;
};
// The plane with the most points within the band (RANSAC over `iterations` triples, seeded),
// refined by least squares until its band settles, then F on the band's points. Throws
// std::runtime_error when no plane of at least 100 points is found.
PlaneFeature plane_feature(const PointCloud& cloud, const FeatureRule& rule = {}, int iterations = 1000,
                           std::uint64_t seed = 1);

// A figure against its maximum permissible error: nothing given = not judged.
struct Verdict {
  std::optional<double> mpe_um;
  bool pass = true;
};
inline Verdict judge(double value_um, std::optional<double> mpe_um) {
  return {mpe_um, !mpe_um || std::abs(value_um) <= *mpe_um};
}

}  // namespace slscan::core
