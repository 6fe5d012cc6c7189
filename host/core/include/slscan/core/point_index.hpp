// Nearest-neighbour queries over a fixed set of points, for code outside slscan_core (benches
// comparing a model with the rig's true surface, tests). The same tree ICP uses for its
// correspondences (a balanced k-d tree with its points in tree order), behind a small header.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <vector>

namespace slscan::core {

namespace detail {
class NearestTree;
}

class PointIndex {
 public:
  // Copies the points. Throws std::invalid_argument if one is not finite (naming it).
  explicit PointIndex(const std::vector<Eigen::Vector3f>& points);
  ~PointIndex();
  PointIndex(PointIndex&&) noexcept;
  PointIndex& operator=(PointIndex&&) noexcept;

  std::size_t size() const;

  // The index of the nearest point within `max_distance` (and its squared distance), or -1.
  std::int64_t nearest_within(const Eigen::Vector3f& query, float max_distance, float& squared_distance) const;

 private:
  std::unique_ptr<detail::NearestTree> tree_;
};

}  // namespace slscan::core
