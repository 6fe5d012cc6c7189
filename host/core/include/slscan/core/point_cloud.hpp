// Point-cloud types shared by every host stage. Points are float (mm): at 1 m a float's
// resolution is ~0.06 um, far below what the scanner measures; accumulations use double.
#pragma once

#include <Eigen/Core>
#include <cstddef>
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

// An organised cloud's valid slots only, in grid order: what a view keeps once it is cleaned.
// After the turntable denoise ~2 % of a 5 MP grid is left, so this holds ~2.4 MB where the
// grid took 85 MB a view (docs/scale.md "Memory a scan keeps").
struct SparseOrganizedCloud {
  int width = 0, height = 0;
  std::vector<std::uint32_t> slots;  // v * width + u, ascending
  std::vector<Eigen::Vector3f> points;
  std::vector<float> quality;
  std::vector<float> intensity;          // empty, or one per slot
  std::vector<std::uint32_t> row_begin;  // height + 1: row v's samples are [row_begin[v], row_begin[v + 1])

  // The valid slots of `cloud` (its intensity too when `with_intensity` and it has one).
  static SparseOrganizedCloud of(const OrganizedCloud& cloud, bool with_intensity = true);
  // The whole grid again: NaN points, zero quality and intensity where not valid.
  OrganizedCloud to_organized() const;
  // The sample at pixel (u, v) (in the grid), or -1 where that slot is not valid.
  std::ptrdiff_t find(int u, int v) const;
  std::size_t size() const { return slots.size(); }
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
