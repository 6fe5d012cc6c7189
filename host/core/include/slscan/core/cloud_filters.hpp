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
// confidence = quality and view id = `view_id`. If `normals` is given (one per slot, e.g. from
// grid_normals) the slots whose normal is not finite are dropped and normals are kept.
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

struct RadiusOutlierOptions {
  double radius_mm = 0.5;
  int min_neighbors = 5;  // besides the point itself
};
FilterResult radius_outlier_removal(const PointCloud& cloud, const RadiusOutlierOptions& options = {});

// One point per occupied voxel (edge `voxel_mm`, grid anchored at the origin): the centroid of
// its points; normals averaged and renormalised, confidence averaged, view id of the most
// confident point. Output ordered by voxel key (deterministic).
PointCloud voxel_downsample(const PointCloud& cloud, double voxel_mm);

}  // namespace slscan::core
