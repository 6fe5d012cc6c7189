#include "slscan/core/point_cloud.hpp"

#include <limits>

namespace slscan::core {

void OrganizedCloud::resize(int w, int h) {
  width = w;
  height = h;
  const auto n = static_cast<std::size_t>(w) * static_cast<std::size_t>(h);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  points.assign(n, Eigen::Vector3f(nan, nan, nan));
  quality.assign(n, 0.0f);
  intensity.assign(n, 0.0f);
  valid.assign(n, 0);
}

std::size_t OrganizedCloud::count_valid() const {
  std::size_t n = 0;
  for (auto v : valid) n += v != 0;
  return n;
}

PointCloud PointCloud::select(const std::vector<std::size_t>& indices) const {
  PointCloud out;
  out.points.reserve(indices.size());
  for (auto i : indices) out.points.push_back(points[i]);
  if (!normals.empty()) {
    out.normals.reserve(indices.size());
    for (auto i : indices) out.normals.push_back(normals[i]);
  }
  if (!confidence.empty()) {
    out.confidence.reserve(indices.size());
    for (auto i : indices) out.confidence.push_back(confidence[i]);
  }
  if (!intensity.empty()) {
    out.intensity.reserve(indices.size());
    for (auto i : indices) out.intensity.push_back(intensity[i]);
  }
  if (!view_id.empty()) {
    out.view_id.reserve(indices.size());
    for (auto i : indices) out.view_id.push_back(view_id[i]);
  }
  return out;
}

void PointCloud::append(const PointCloud& other) {
  auto join = [&](auto& mine, const auto& theirs, auto fill) {
    if (mine.empty() && theirs.empty()) return;
    if (mine.size() != points.size()) mine.resize(points.size(), fill);
    if (theirs.empty()) {
      mine.resize(points.size() + other.points.size(), fill);
    } else {
      mine.insert(mine.end(), theirs.begin(), theirs.end());
    }
  };
  join(normals, other.normals, Eigen::Vector3f::Zero().eval());
  join(confidence, other.confidence, 0.0f);
  join(intensity, other.intensity, 0.0f);
  join(view_id, other.view_id, std::uint16_t{0});
  points.insert(points.end(), other.points.begin(), other.points.end());
}

}  // namespace slscan::core
