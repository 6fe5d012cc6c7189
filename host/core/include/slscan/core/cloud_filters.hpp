// Cloud conversion and cleanup: organised view -> unorganised cloud, rigid transforms, and the
// final statistical/radius outlier removal and voxel thinning of the fused model.
// One k-d tree per call, contiguous buffers, TBB over points.
#pragma once

#include <Eigen/Geometry>
#include <cstdint>
#include <vector>

#include "slscan/core/point_cloud.hpp"

namespace slscan::core {

// The valid slots of an organised cloud as an unorganised cloud (row-major order), with
// confidence = quality, intensity = intensity (when the grid has it) and view id = `view_id`. If `normals` is given
// (one per slot, e.g. from grid_normals) the slots whose normal is not finite are dropped and normals are kept.
PointCloud to_point_cloud(const OrganizedCloud& cloud, std::uint16_t view_id,
                          const std::vector<Eigen::Vector3f>* normals = nullptr);

// target_from_source applied to the points (and rotated normals).
PointCloud transform_cloud(const PointCloud& cloud, const Eigen::Isometry3d& target_from_source);

struct FilterResult {
  PointCloud cloud;                         // the kept points, every channel following
  std::vector<std::uint32_t> kept_indices;  // into the input, increasing
  std::size_t removed = 0;
  double threshold = 0;  // SOR: the mean-distance cut (mm); radius: unused
};

struct StatisticalOutlierOptions {
  int k = 20;              // neighbours besides the point itself (PCL's meanK)
  double std_ratio = 2.0;  // cut at mean + std_ratio * std of the per-point mean distances
};
// PCL/Open3D semantics: a point goes if its mean distance to its k nearest neighbours exceeds
// the cloud-wide mean of that quantity by more than std_ratio standard deviations.
FilterResult statistical_outlier_removal(const PointCloud& cloud, const StatisticalOutlierOptions& options = {});

// The same statistic on an organised cloud (one view), with the neighbours taken from the
// image grid instead of a k-d tree: the k nearest (3-D distance) among the valid pixels of the
// (2 window_radius + 1)^2 window. Points within 3-D distance d of a point project within
// d f / z pixels of it, so where the window covers that reach (a surface facing the camera:
// the 20 nearest lie within ~2.5 px) this is exactly the k-d tree's answer; where it does not
// (grazing surfaces, specks with fewer than k valid pixels in the window) each missing
// neighbour counts at the window's edge, (window_radius + 1) z / focal_px, about the lower
// bound of its true distance, so where it differs from the k-d tree it errs toward keeping.
// No tree. Invalidates the removed slots.
struct OrganizedOutlierResult {
  OrganizedCloud cloud;
  std::size_t removed = 0;
  double threshold = 0;
};
// The cloud is taken by value: a caller that no longer needs its own moves it in.
OrganizedOutlierResult statistical_outlier_removal(OrganizedCloud cloud, double focal_px,
                                                   const StatisticalOutlierOptions& options = {},
                                                   int window_radius = 3);

struct RadiusOutlierOptions {
  double radius_mm = 0.5;
  int min_neighbors = 5;  // besides the point itself
};
FilterResult radius_outlier_removal(const PointCloud& cloud, const RadiusOutlierOptions& options = {});

// One point per occupied voxel (edge `voxel_mm`, grid anchored at the origin): the centroid of
// its points; normals averaged and renormalised, confidence and intensity averaged, view id of the most
// confident point. Output ordered by voxel key (deterministic).
PointCloud voxel_downsample(const PointCloud& cloud, double voxel_mm);

}  // namespace slscan::core
