// Artefact measurement on a cloud: least-squares sphere and plane fits with their form errors,
// and the ball bar (two spheres of known nominal radius found in one cloud, and the distance
// between their centres). The figures VDI/VDE 2634-2 and the paper's Table 1 are built from.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <vector>

#include "slscan/core/point_cloud.hpp"

namespace slscan::core {

struct SphereFit {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  double radius_mm = 0;
  double rms_mm = 0;  // RMS of the radial residuals |p - c| - r
  double min_residual_mm = 0, max_residual_mm = 0;
  double form_error_mm = 0;  // max - min radial residual (VDI/VDE 2634-2 PF)
  std::size_t point_count = 0;
  int iterations = 0;  // Gauss-Newton iterations taken
};

// Geometric least squares: algebraic (linear) initial guess, then Gauss-Newton on the radial
// residuals. Throws std::invalid_argument for fewer than 4 points, non-finite points or a
// degenerate (coplanar) set.
SphereFit fit_sphere(const std::vector<Eigen::Vector3f>& points);
SphereFit fit_sphere(const std::vector<Eigen::Vector3f>& points, const std::vector<std::uint32_t>& indices);

struct PlaneFit {
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // unit; the plane is normal . x = offset
  double offset_mm = 0;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  double rms_mm = 0;
  double flatness_mm = 0;  // max - min signed distance (VDI/VDE 2634-2 F)
  std::size_t point_count = 0;
};
// Orthogonal least squares (PCA). Throws for fewer than 3 points or a collinear set.
PlaneFit fit_plane(const std::vector<Eigen::Vector3f>& points);

struct BallBarOptions {
  std::array<double, 2> nominal_radii_mm{15.0, 15.0};
  double radius_tolerance_mm = 0.5;  // RANSAC candidates farther from nominal are rejected
  double ransac_band_mm = 0.1;       // inlier band of the RANSAC score
  double refine_band_mm = 0.1;       // points within this of the refined sphere are refitted
  int ransac_iterations = 2000;
  std::size_t ransac_sample_points = 20000;  // the score is counted on this many random points
  std::size_t min_sphere_points = 100;
  std::uint64_t seed = 1;
};

struct BallBarResult {
  std::array<SphereFit, 2> spheres;                         // sphere 0 is the one matched to nominal_radii_mm[0]
  std::array<std::vector<std::uint32_t>, 2> sphere_points;  // indices into the cloud
  double centre_distance_mm = 0;
};

// Finds the two spheres (RANSAC with the nominal radii, then refinement on the points within a
// band, repeated until the inlier set settles) and measures them. Throws std::runtime_error
// naming what failed when a sphere cannot be found.
BallBarResult measure_ball_bar(const PointCloud& cloud, const BallBarOptions& options = {});

// One sphere of about `nominal_radius_mm` in the cloud, found as measure_ball_bar finds each of
// its spheres (RANSAC on the nominal radius, then least squares on the points within
// refine_band_mm until they settle). Throws std::runtime_error when there is none.
struct FoundSphere {
  SphereFit fit;
  std::vector<std::uint32_t> points;  // indices into the cloud
};
FoundSphere find_sphere(const PointCloud& cloud, double nominal_radius_mm, const BallBarOptions& options = {});

}  // namespace slscan::core
