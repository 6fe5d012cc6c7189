#include "slscan/core/detail/nearest_tree.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include <algorithm>
#include <atomic>
#include <stdexcept>
#include <string>

namespace slscan::core::detail {
namespace {

// Below this many points a node's halves are built on the calling thread.
constexpr std::size_t kParallelBuild = 1 << 15;
// A node with fewer points takes its box from its parent's box and split instead of a pass
// over its points (measured: as fast to search, and the build ~20 % faster).
constexpr std::size_t kMeasuredBox = 1 << 16;

}  // namespace

struct NearestTree::Search {
  const NearestTree& tree;
  float q[3];
  float best;  // squared distance to beat
  std::int64_t best_position = -1;

  void scan_leaf(std::size_t begin, std::size_t end) {
    for (std::size_t i = begin; i < end; ++i) {
      const float* p = tree.entries_[i].p;
      const float dx = p[0] - q[0], dy = p[1] - q[1], dz = p[2] - q[2];
      const float d = dx * dx + dy * dy + dz * dz;
      if (d < best) {
        best = d;
        best_position = static_cast<std::int64_t>(i);
      }
    }
  }

  // `offset`: per axis, how far the query lies outside this node's region (a lower bound of the
  // distance to any of its points, summed in squares).
  void visit(std::size_t node, int depth, std::size_t begin, std::size_t end, float offset[3]) {
    if (depth == tree.depth_) {
      scan_leaf(begin, end);
      return;
    }
    const int axis = tree.axis_[node];
    const float diff = q[axis] - tree.split_[node];
    const std::size_t middle = begin + (end - begin) / 2;
    // Left holds coordinates <= split, right >= split: the far side is at least |diff| away.
    if (diff < 0)
      visit(2 * node, depth + 1, begin, middle, offset);
    else
      visit(2 * node + 1, depth + 1, middle, end, offset);
    const float saved = offset[axis];
    offset[axis] = diff;
    const float far = offset[0] * offset[0] + offset[1] * offset[1] + offset[2] * offset[2];
    // The slack keeps a point whose rounded distance ties the best from being pruned by the
    // rounding of the bound: the answer is the brute-force one to the last bit.
    if (far <= best * kPruneSlack) {
      if (diff < 0)
        visit(2 * node + 1, depth + 1, middle, end, offset);
      else
        visit(2 * node, depth + 1, begin, middle, offset);
    }
    offset[axis] = saved;
  }
};

NearestTree::NearestTree(const std::vector<Eigen::Vector3f>& points) : size_(points.size()) {
  if (size_ >= (std::size_t{1} << 32))
    throw std::invalid_argument("nearest tree: " + std::to_string(size_) + " points, at most 2^32 - 1 supported");
  while (((size_ + (std::size_t{1} << depth_) - 1) >> depth_) > kLeafSize) ++depth_;
  entries_ = make_large_array<Entry>(size_);
  Entry* entries = entries_.get();
  std::atomic<bool> all_finite{true};
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, size_, 1 << 15), [&](const tbb::blocked_range<std::size_t>& r) {
    bool finite = true;
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      const Eigen::Vector3f& p = points[i];
      finite = finite && p.allFinite();
      entries[i] = {{p.x(), p.y(), p.z()}, static_cast<std::uint32_t>(i)};
    }
    if (!finite) all_finite = false;
  });
  if (!all_finite)
    for (std::size_t i = 0; i < size_; ++i)
      if (!points[i].allFinite())
        throw std::invalid_argument("nearest tree: point " + std::to_string(i) + " of " + std::to_string(size_) +
                                    " is not finite");
  for (std::size_t i = 0; i < size_; ++i) {
    lo_ = i == 0 ? points[i] : lo_.cwiseMin(points[i]);
    hi_ = i == 0 ? points[i] : hi_.cwiseMax(points[i]);
  }
  const std::size_t nodes = std::size_t{1} << depth_;
  split_.assign(nodes, 0.0f);
  axis_.assign(nodes, 0);

  // Each node splits its points at the median along the longest side of their box.
  auto build = [&](auto&& self, std::size_t node, int depth, std::size_t begin, std::size_t end, Eigen::Vector3f lo,
                   Eigen::Vector3f hi) -> void {
    // Every node above the leaves holds > kLeafSize points (depth_ is the least depth whose
    // nodes hold <= kLeafSize): there is always something to split.
    if (depth == depth_) return;
    if (end - begin >= kMeasuredBox) {
      lo = hi = Eigen::Vector3f(entries[begin].p);
      for (std::size_t i = begin + 1; i < end; ++i) {
        const Eigen::Vector3f p(entries[i].p);
        lo = lo.cwiseMin(p);
        hi = hi.cwiseMax(p);
      }
    }
    int axis = 0;
    (hi - lo).maxCoeff(&axis);
    const std::size_t middle = begin + (end - begin) / 2;
    std::nth_element(entries + begin, entries + middle, entries + end,
                     [axis](const Entry& a, const Entry& b) { return a.p[axis] < b.p[axis]; });
    const float split = entries[middle].p[axis];
    split_[node] = split;
    axis_[node] = static_cast<std::uint8_t>(axis);
    Eigen::Vector3f left_hi = hi, right_lo = lo;
    left_hi[axis] = split;
    right_lo[axis] = split;
    if (end - begin >= kParallelBuild)
      tbb::parallel_invoke([&] { self(self, 2 * node, depth + 1, begin, middle, lo, left_hi); },
                           [&] { self(self, 2 * node + 1, depth + 1, middle, end, right_lo, hi); });
    else {
      self(self, 2 * node, depth + 1, begin, middle, lo, left_hi);
      self(self, 2 * node + 1, depth + 1, middle, end, right_lo, hi);
    }
  };
  build(build, 1, 0, 0, size_, lo_, hi_);
}

std::int64_t NearestTree::nearest_within(const Eigen::Vector3f& query, float max_distance,
                                         float& squared_distance) const {
  squared_distance = max_distance * max_distance;
  if (size_ == 0 || !(max_distance > 0) || !query.allFinite()) return -1;
  Search search{*this, {query.x(), query.y(), query.z()}, squared_distance};
  float offset[3];
  for (int a = 0; a < 3; ++a) offset[a] = std::max({lo_[a] - query[a], query[a] - hi_[a], 0.0f});
  if (offset[0] * offset[0] + offset[1] * offset[1] + offset[2] * offset[2] > search.best * kPruneSlack) return -1;
  search.visit(1, 0, 0, size_, offset);
  squared_distance = search.best;
  return search.best_position < 0 ? -1 : static_cast<std::int64_t>(entries_[search.best_position].index);
}

}  // namespace slscan::core::detail
