// A 3-D k-d tree (nanoflann) over a contiguous array of points, shared by the stages that need
// neighbours across views: outlier removal, normals of the fused cloud, ICP correspondences.
// Private to slscan_core: the public headers stay free of nanoflann.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <memory>
#include <nanoflann.hpp>
#include <vector>

namespace slscan::core::detail {

class KdTree {
 public:
  // `points` must outlive the tree and must not move.
  explicit KdTree(const std::vector<Eigen::Vector3f>& points) : adaptor_{&points} {
    index_ = std::make_unique<Index>(3, adaptor_, nanoflann::KDTreeSingleIndexAdaptorParams(16));
    index_->buildIndex();
  }

  std::size_t size() const { return adaptor_.points->size(); }

  // Every point index, in the tree's leaf order: queries issued in this order touch the same
  // leaves one after another, which keeps the search in cache (2-3x over random order).
  const std::vector<std::uint32_t>& spatial_order() const { return index_->vAcc; }

  // The k nearest neighbours of `query` (itself included if it is in the cloud), nearest first.
  // Returns how many were found (< k only when the cloud is smaller than k).
  std::size_t knn(const Eigen::Vector3f& query, std::size_t k, std::uint32_t* indices, float* squared_distances) const {
    nanoflann::KNNResultSet<float, std::uint32_t, std::size_t> result(k);
    result.init(indices, squared_distances);
    index_->findNeighbors(result, query.data(), nanoflann::SearchParams(0, 0, true));
    return result.size();
  }

  // The nearest point within `max_distance`, or -1. The gate prunes the search, so a query far
  // from the cloud costs almost nothing (the lesson of PCL's ungated ICP).
  std::int64_t nearest_within(const Eigen::Vector3f& query, float max_distance, float& squared_distance) const {
    NearestWithin result(max_distance * max_distance);
    index_->findNeighbors(result, query.data(), nanoflann::SearchParams(0, 0, false));
    squared_distance = result.best_distance;
    return result.best_index;
  }

  // Counts the points within `radius`, stopping as soon as `stop_at` are found.
  std::size_t count_within(const Eigen::Vector3f& query, float radius, std::size_t stop_at) const {
    CountWithin result(radius * radius, stop_at);
    index_->findNeighbors(result, query.data(), nanoflann::SearchParams(0, 0, false));
    return result.count;
  }

 private:
  struct Adaptor {
    const std::vector<Eigen::Vector3f>* points;
    std::size_t kdtree_get_point_count() const { return points->size(); }
    float kdtree_get_pt(std::size_t i, std::size_t dim) const { return (*points)[i][static_cast<Eigen::Index>(dim)]; }
    template <class Box>
    bool kdtree_get_bbox(Box&) const {
      return false;
    }
  };
  using Index = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, Adaptor, float, std::uint32_t>,
                                                    Adaptor, 3, std::uint32_t>;

  struct NearestWithin {
    using DistanceType = float;
    using IndexType = std::uint32_t;
    explicit NearestWithin(float gate2) : best_distance(gate2) {}
    float best_distance;
    std::int64_t best_index = -1;
    bool addPoint(float d, std::uint32_t i) {
      if (d < best_distance) {
        best_distance = d;
        best_index = i;
      }
      return true;
    }
    float worstDist() const { return best_distance; }
    bool full() const { return true; }
    std::size_t size() const { return best_index < 0 ? 0 : 1; }
  };

  struct CountWithin {
    using DistanceType = float;
    using IndexType = std::uint32_t;
    CountWithin(float r2, std::size_t stop) : radius2(r2), stop_at(stop) {}
    float radius2;
    std::size_t stop_at;
    std::size_t count = 0;
    bool addPoint(float d, std::uint32_t) {
      if (d < radius2) ++count;
      return count < stop_at;
    }
    float worstDist() const { return radius2; }
    bool full() const { return true; }
    std::size_t size() const { return count; }
  };

  Adaptor adaptor_;
  std::unique_ptr<Index> index_;
};

}  // namespace slscan::core::detail
