#include "slscan/core/point_index.hpp"

#include "slscan/core/detail/nearest_tree.hpp"

namespace slscan::core {

PointIndex::PointIndex(const std::vector<Eigen::Vector3f>& points)
    : tree_(std::make_unique<detail::NearestTree>(points)) {}
PointIndex::~PointIndex() = default;
PointIndex::PointIndex(PointIndex&&) noexcept = default;
PointIndex& PointIndex::operator=(PointIndex&&) noexcept = default;

std::size_t PointIndex::size() const { return tree_->size(); }

std::int64_t PointIndex::nearest_within(const Eigen::Vector3f& query, float max_distance,
                                        float& squared_distance) const {
  return tree_->nearest_within(query, max_distance, squared_distance);
}

}  // namespace slscan::core
