#include "slscan/core/point_cloud.hpp"

#include <algorithm>
#include <limits>
#include <stdexcept>
#include <string>

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

SparseOrganizedCloud SparseOrganizedCloud::of(const OrganizedCloud& cloud, bool with_intensity) {
  const auto size = static_cast<std::size_t>(cloud.width) * static_cast<std::size_t>(cloud.height);
  if (cloud.width < 0 || cloud.height < 0 || cloud.points.size() != size || cloud.quality.size() != size ||
      cloud.valid.size() != size || size > std::numeric_limits<std::uint32_t>::max())
    throw std::invalid_argument("sparse organised cloud: the grid's buffers do not match its " +
                                std::to_string(cloud.width) + " x " + std::to_string(cloud.height) + " size");
  SparseOrganizedCloud out;
  out.width = cloud.width;
  out.height = cloud.height;
  const std::size_t n = cloud.count_valid();
  const bool intensity = with_intensity && cloud.intensity.size() == size;
  out.slots.reserve(n);
  out.points.reserve(n);
  out.quality.reserve(n);
  if (intensity) out.intensity.reserve(n);
  out.row_begin.reserve(static_cast<std::size_t>(cloud.height) + 1);
  const auto width = static_cast<std::size_t>(cloud.width);
  for (std::size_t row = 0; row < static_cast<std::size_t>(cloud.height); ++row) {
    out.row_begin.push_back(static_cast<std::uint32_t>(out.slots.size()));
    for (std::size_t i = row * width; i < (row + 1) * width; ++i) {
      if (!cloud.valid[i]) continue;
      out.slots.push_back(static_cast<std::uint32_t>(i));
      out.points.push_back(cloud.points[i]);
      out.quality.push_back(cloud.quality[i]);
      if (intensity) out.intensity.push_back(cloud.intensity[i]);
    }
  }
  out.row_begin.push_back(static_cast<std::uint32_t>(out.slots.size()));
  return out;
}

OrganizedCloud SparseOrganizedCloud::to_organized() const {
  OrganizedCloud cloud;
  cloud.resize(width, height);
  if (intensity.empty()) cloud.intensity.clear();
  for (std::size_t k = 0; k < slots.size(); ++k) {
    const std::size_t i = slots[k];
    cloud.points[i] = points[k];
    cloud.quality[i] = quality[k];
    if (!intensity.empty()) cloud.intensity[i] = intensity[k];
    cloud.valid[i] = 1;
  }
  return cloud;
}

std::ptrdiff_t SparseOrganizedCloud::find(int u, int v) const {
  if (u < 0 || v < 0 || u >= width || v >= height) return -1;
  const std::uint32_t slot =
      static_cast<std::uint32_t>(v) * static_cast<std::uint32_t>(width) + static_cast<std::uint32_t>(u);
  const auto first = slots.begin() + row_begin[static_cast<std::size_t>(v)];
  const auto last = slots.begin() + row_begin[static_cast<std::size_t>(v) + 1];
  const auto at = std::lower_bound(first, last, slot);
  return at != last && *at == slot ? at - slots.begin() : -1;
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
