// Nearest-neighbour queries over a fixed set of points, for code outside slscan_core (benches
// comparing a model with the rig's true surface, tests). The same k-d tree the stages use
// (nanoflann), behind a header that stays free of nanoflann.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <vector>

namespace slscan::core {

namespace detail {
class KdTree;
}

class PointIndex {
 public:
  // `points` must outlive the index and must not move.
  explicit PointIndex(const std::vector<Eigen::Vector3f>& points);
  ~PointIndex();
  PointIndex(PointIndex&&) noexcept;
  PointIndex& operator=(PointIndex&&) noexcept;

  std::size_t size() const;

  // The index of the nearest point within `max_distance` (and its squared distance), or -1.
  std::int64_t nearest_within(const Eigen::Vector3f& query, float max_distance, float& squared_distance) const;

 private:
  std::unique_ptr<detail::KdTree> tree_;
};

}  // namespace slscan::core
