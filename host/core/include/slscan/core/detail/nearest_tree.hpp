// The nearest point of a cloud within a gate, for many queries: ICP's correspondences, a
// scan's distance to a reference; and the points within a radius, for the mesher's sums. A
// balanced k-d tree kept implicitly (nodes numbered as in a heap, no pointers): each node
// splits its run of points at the median along the longest side of its box, and the points
// are copied side by side in tree order. Built by nth_element, the two halves of a node on two
// threads: at 1M points ~4x faster than nanoflann's build (which reads every point through an
// index at each of ~16 levels, on one thread), and a query scans a leaf's points from
// contiguous arrays. Shared by slscan_core and slscan_mesh; not part of the public API.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cstdint>
#include <vector>

#include "slscan/core/detail/large_array.hpp"

namespace slscan::core::detail {

class NearestTree {
 public:
  // Throws std::invalid_argument if a point is not finite or there are 2^32 or more points.
  explicit NearestTree(const std::vector<Eigen::Vector3f>& points);

  std::size_t size() const { return size_; }

  // The index of the nearest point strictly within `max_distance` and its squared distance, or
  // -1. Of points at the same distance, the same one on every run. The gate prunes the search:
  // a query far from the cloud visits a few nodes.
  std::int64_t nearest_within(const Eigen::Vector3f& query, float max_distance, float& squared_distance) const;

  // The points strictly within `result.worstDist()` (a squared distance; it may shrink as points
  // are added) of `query`, each given once as `result.addPoint(squared_distance, index)`, which
  // returns false to stop the search: a nanoflann-style result set. The points come in the
  // tree's fixed order, so sums over them do not depend on thread timing.
  template <class Result>
  void search(Result& result, const Eigen::Vector3f& query) const {
    if (size_ == 0 || !query.allFinite()) return;
    const float q[3] = {query.x(), query.y(), query.z()};
    float offset[3];
    for (int a = 0; a < 3; ++a) offset[a] = std::max({lo_[a] - q[a], q[a] - hi_[a], 0.0f});
    if (offset[0] * offset[0] + offset[1] * offset[1] + offset[2] * offset[2] > result.worstDist() * kPruneSlack)
      return;
    visit_all(result, q, 1, 0, 0, size_, offset);
  }

 private:
  // A node is pruned when its lower bound exceeds the radius by more than this factor: a point
  // whose rounded distance ties the radius is not lost to the rounding of the bound.
  static constexpr float kPruneSlack = 1.000001f;

  // search()'s descent: false when the result set asked to stop.
  template <class Result>
  bool visit_all(Result& result, const float q[3], std::size_t node, int depth, std::size_t begin, std::size_t end,
                 float offset[3]) const {
    if (depth == depth_) {
      for (std::size_t i = begin; i < end; ++i) {
        const Entry& e = entries_[i];
        const float dx = e.p[0] - q[0], dy = e.p[1] - q[1], dz = e.p[2] - q[2];
        const float d = dx * dx + dy * dy + dz * dz;
        if (d < result.worstDist() && !result.addPoint(d, e.index)) return false;
      }
      return true;
    }
    const int axis = axis_[node];
    const float diff = q[axis] - split_[node];
    const std::size_t middle = begin + (end - begin) / 2;
    const bool left_first = diff < 0;
    if (!(left_first ? visit_all(result, q, 2 * node, depth + 1, begin, middle, offset)
                     : visit_all(result, q, 2 * node + 1, depth + 1, middle, end, offset)))
      return false;
    const float saved = offset[axis];
    offset[axis] = diff;
    bool go_on = true;
    if (offset[0] * offset[0] + offset[1] * offset[1] + offset[2] * offset[2] <= result.worstDist() * kPruneSlack)
      go_on = left_first ? visit_all(result, q, 2 * node + 1, depth + 1, middle, end, offset)
                         : visit_all(result, q, 2 * node, depth + 1, begin, middle, offset);
    offset[axis] = saved;
    return go_on;
  }

  struct Search;
  // At most this many points in a leaf. Measured at 1M points: 32 builds ~15 % faster than 12 and
  // answers ~20 % faster (a contiguous scan beats another level of descent); 128 answers slower.
  static constexpr std::size_t kLeafSize = 32;

  std::size_t size_ = 0;
  int depth_ = 0;  // leaves are the nodes at this depth (the root: node 1, depth 0)
  struct Entry {
    float p[3];
    std::uint32_t index;  // in the cloud
  };
  LargeArray<Entry> entries_;                                                    // the points in tree order
  std::vector<float> split_;                                                     // node -> split coordinate
  std::vector<std::uint8_t> axis_;                                               // node -> split axis
  Eigen::Vector3f lo_ = Eigen::Vector3f::Zero(), hi_ = Eigen::Vector3f::Zero();  // the cloud's box
};

}  // namespace slscan::core::detail
