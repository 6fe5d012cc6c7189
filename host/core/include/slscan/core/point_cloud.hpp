// Point-cloud types shared by every host stage. Points are float (mm): at 1 m a float's
// resolution is ~0.06 um, far below what the scanner measures; accumulations use double.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

namespace slscan::core {

// One slot per camera pixel (row-major, index = v * width + u). Invalid slots hold NaN points.
struct OrganizedCloud {
  int width = 0, height = 0;
  std::vector<Eigen::Vector3f> points;
  std::vector<float> quality;  // decode modulation or fused confidence; 0 where invalid
  // Albedo (DecodedView::intensity: white - black as a fraction of full scale); empty: none.
  // Meaningful where valid.
  std::vector<float> intensity;
  std::vector<std::uint8_t> valid;  // 1 = the point is measured

  void resize(int w, int h);
  std::size_t size() const { return points.size(); }
  std::size_t count_valid() const;
};

// An unorganised cloud (fused, registered, cleaned). Optional channels are empty or size().
struct PointCloud {
  std::vector<Eigen::Vector3f> points;
  std::vector<Eigen::Vector3f> normals;
  std::vector<float> confidence;  // the decode modulation B (DN), summed over fused projectors
  std::vector<float> intensity;   // albedo, 0..1 of the camera's full scale (OrganizedCloud::intensity)
  std::vector<std::uint16_t> view_id;

  std::size_t size() const { return points.size(); }
  bool has_normals() const { return !normals.empty(); }
  // Keeps the points whose indices are listed (in order); every channel follows.
  PointCloud select(const std::vector<std::size_t>& indices) const;
  void append(const PointCloud& other);
};

}  // namespace slscan::core
