// Surface normals: per view from the camera's pixel grid (no k-d tree), and for the fused cloud
// from k-nearest-neighbour PCA with an outward orientation.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "slscan/core/point_cloud.hpp"

namespace slscan::core {

struct GridNormalOptions {
  int window_radius = 2;                  // PCA over a (2r+1)^2 pixel window
  float max_neighbor_distance_mm = 1.0f;  // farther grid neighbours lie across a depth edge
  int min_neighbors = 5;                  // fewer (with the centre) leaves the normal NaN
};

// One normal per slot of an organised cloud (NaN where invalid or unsupported), from PCA over
// the pixel window, oriented toward `viewpoint` (the camera centre: the origin of the camera
// frame the organised cloud is expressed in). Threads over rows.
std::vector<Eigen::Vector3f> grid_normals(const OrganizedCloud& cloud,
                                          const Eigen::Vector3f& viewpoint = Eigen::Vector3f::Zero(),
                                          const GridNormalOptions& options = {});

// The valid points of an organised cloud with their grid normals, as an unorganised cloud (the
// points whose normal is unsupported dropped): bit for bit what
// to_point_cloud(cloud, view_id, &grid_normals(cloud, viewpoint, options)) gives, without a
// normal for every slot of the grid. A view's cloud once the turntable's platform is removed
// holds ~2.5 % of its 5 MP grid; the per-slot normals were a 60 MB array to fill and fault in.
PointCloud oriented_point_cloud(const OrganizedCloud& cloud, std::uint16_t view_id,
                                const Eigen::Vector3f& viewpoint = Eigen::Vector3f::Zero(),
                                const GridNormalOptions& options = {});

enum class NormalOrientation {
  away_from_axis,      // outwards from a line (the turntable axis): for objects on the table
  toward_view_camera,  // toward the camera centre of the point's view (`view_id` indexes it)
};

struct PcaNormalOptions {
  int k = 20;  // neighbours, the point itself included
  NormalOrientation orientation = NormalOrientation::away_from_axis;
  Eigen::Vector3f axis_point = Eigen::Vector3f::Zero();       // turntable frame: the origin ...
  Eigen::Vector3f axis_direction = Eigen::Vector3f::UnitZ();  // ... and +z
  std::vector<Eigen::Vector3f> view_camera_centres;           // for toward_view_camera
};

// k-NN PCA normals for an unorganised cloud (one k-d tree, TBB over points). Throws
// std::invalid_argument on bad options (k < 3, missing view ids or camera centres).
std::vector<Eigen::Vector3f> pca_normals(const PointCloud& cloud, const PcaNormalOptions& options = {});

}  // namespace slscan::core
