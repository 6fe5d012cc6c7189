// Neighbours of every point of an unorganised cloud at once, on a uniform grid of cells: the
// points sorted by cell, each cell's 3 x 3 x 3 block of cells gathered once into contiguous
// arrays and shared by all the points of the cell. For a scan's surface (a few points per cell)
// this does a k-d tree's work for all points at a fraction of its cost: no tree descent per
// query, distances computed in vector registers over a contiguous block. Exact: a point's
// k nearest are taken from its block only when the k-th lies closer than the block's nearest
// face; the rest (outliers far from the surface) go to the k-d tree. Private to slscan_core.
#pragma once

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Core>
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <span>
#include <vector>

#include "cloud_filters_kdtree.hpp"
#include "slscan/core/detail/large_array.hpp"

namespace slscan::core::detail {

// The points of a cell's 3 x 3 x 3 block of cells (the centre cell's first), coordinates as
// separate arrays so the distance loop vectorises. x, y, z are padded to a whole number of runs
// of kRun with points too far to be anyone's neighbour.
struct CellBlock {
  static constexpr std::size_t kRun = 8;
  static constexpr float kFar = 1e18f;  // squared distances ~1e36: finite, beyond any reach
  std::vector<float> x, y, z;
  std::vector<std::uint32_t> index;  // the points' indices in the cloud (not padded)
  // Every point of the cloud outside the block lies outside this box (infinite where the block
  // reaches the cloud's bounding box).
  Eigen::Vector3d lo, hi;
  double margin = 0;  // how far a point's cell may be off its coordinates by rounding, and more

  std::size_t size() const { return index.size(); }
  void pad() {
    const std::size_t padded = (x.size() + kRun - 1) / kRun * kRun;
    x.resize(padded, kFar);
    y.resize(padded, kFar);
    z.resize(padded, kFar);
  }
  void clear() {
    x.clear();
    y.clear();
    z.clear();
    index.clear();
  }
  // A distance from `p` (inside the box) that no point outside the block comes within.
  double reach(const Eigen::Vector3f& p) const {
    const Eigen::Vector3d q = p.cast<double>();
    return std::min((q - lo).minCoeff(), (hi - q).minCoeff()) - margin;
  }
};

class NeighbourGrid {
 public:
  // Throws std::invalid_argument if a point is not finite or `cell_size` is not a positive
  // number. The cells may come out larger than asked: at most 2^21 along an axis.
  NeighbourGrid(const std::vector<Eigen::Vector3f>& points, double cell_size);

  // A grid for the k nearest neighbours of every point: cells holding ~k/2.5 points each
  // (a surface crossing a block of 27 such cells holds ~3k), measured on the cloud itself.
  static NeighbourGrid for_k_nearest(const std::vector<Eigen::Vector3f>& points, std::size_t k);

  double cell_size() const { return cell_size_; }
  std::size_t cell_count() const { return cell_keys_.size(); }
  double points_per_cell() const;

  // The cloud indices of the points in cell `c`.
  std::span<const std::uint32_t> cell_points(std::size_t c) const {
    return {sorted_index_.get() + cell_start_[c], cell_start_[c + 1] - cell_start_[c]};
  }

  // Fills `block` with the points of cell `c`'s 3 x 3 x 3 block, centre cell first.
  void gather_block(std::size_t c, CellBlock& block) const;

  // For points whose k nearest reach past their cell's block (outliers, sparse regions): the
  // cells grouped 8 x 8 x 8, searched in growing blocks of groups. Call once before
  // k_nearest_in_groups.
  void group_cells();
  // The k nearest points to `p` (nearest first, ties by index) as (squared distance bits << 32 |
  // index) in keyed[0, k), from blocks of up to (2 max_rings + 1)^3 groups; false if that was not
  // far enough (a point far from everything: ask the k-d tree).
  bool k_nearest_in_groups(const Eigen::Vector3f& p, std::size_t k, int max_rings,
                           std::vector<std::uint64_t>& keyed) const;

 private:
  // Cell (or group) key -> its position in a sorted key array, by open addressing.
  struct KeyTable {
    std::vector<std::uint32_t> slots;
    int shift = 64;
    void build(const std::vector<std::uint64_t>& keys);
    std::int64_t find(const std::vector<std::uint64_t>& keys, std::uint64_t key) const;
  };

  static constexpr int kAxisBits = 21;
  static constexpr std::uint64_t kAxisMask = (std::uint64_t{1} << kAxisBits) - 1;
  static constexpr std::uint32_t kNoCell = 0xffffffffu;
  static constexpr int kGroupBits = 3;  // groups of 8 x 8 x 8 cells

  std::uint64_t cell_key(const Eigen::Vector3f& p) const;
  std::int64_t find_cell(std::uint64_t key) const { return table_.find(cell_keys_, key); }
  static std::uint64_t pack(const std::int64_t c[3]);
  static void unpack(std::uint64_t key, std::int64_t c[3]);
  void append_cell(std::size_t c, CellBlock& block) const;

  double cell_size_ = 0;
  Eigen::Vector3d origin_ = Eigen::Vector3d::Zero();
  std::int64_t max_cell_[3] = {0, 0, 0};
  std::vector<std::uint64_t> cell_keys_;   // sorted
  std::vector<std::uint32_t> cell_start_;  // points of cell c: sorted positions [start[c], start[c + 1])
  std::size_t size_ = 0;
  LargeArray<std::uint32_t> sorted_index_;  // cloud index of each sorted position
  LargeArray<float> x_, y_, z_;             // coordinates at the sorted positions
  KeyTable table_;
  std::vector<std::uint64_t> group_keys_;   // sorted; a group's key packs its cells' coordinates / 8
  std::vector<std::uint32_t> group_start_;  // cells of group g: group_cells_[start[g], start[g + 1])
  std::vector<std::uint32_t> group_cells_;
  KeyTable group_table_;
};

// A point's k nearest neighbours, in no particular order (the same on every run): their squared
// distances, and where to read their cloud indices and coordinates (at hand, where the cloud's
// own are scattered in memory), read only by the stages that need them.
struct KNearest {
  const float* squared_distance;
  const std::uint32_t* at;  // positions in the arrays below
  const std::uint32_t* cloud_index;
  const float *x, *y, *z;
  std::size_t count;      // k, or fewer only when the cloud has fewer than k points
  Eigen::Vector3f query;  // the point whose neighbours these are

  std::uint32_t index(std::size_t j) const { return cloud_index[at[j]]; }
  Eigen::Vector3f point(std::size_t j) const { return {x[at[j]], y[at[j]], z[at[j]]}; }
};

// Moves the k smallest of keys[0, count) (squared distance bits << 32 | id, every distance below
// `limit`) to keys[0, k), in no particular order. A scan's points spread evenly over area, so
// their squared distances spread evenly below the limit: one counting pass over 32 bands of it
// finds the band the k-th falls in; only that band (a point or two) is ordered. Few branches to
// mispredict, where nth_element's partitions mispredict half their compares.
inline void select_k_smallest(std::uint64_t* keys, std::size_t count, std::size_t k, float limit,
                              std::vector<std::uint64_t>& spill) {
  constexpr std::uint32_t kBands = 32;
  // One band for all when the limit is infinite or so small that the scale would overflow.
  const float raw_scale = limit > 0 ? kBands / limit : 0.0f;
  const float scale = std::isfinite(raw_scale) ? raw_scale : 0.0f;
  const auto band = [&](std::uint64_t key) {
    const float d2 = std::bit_cast<float>(static_cast<std::uint32_t>(key >> 32));
    return std::min(kBands - 1, static_cast<std::uint32_t>(d2 * scale));
  };
  std::uint32_t histogram[kBands] = {};
  for (std::size_t j = 0; j < count; ++j) ++histogram[band(keys[j])];
  std::uint32_t cut = 0;
  std::size_t below = 0;
  while (below + histogram[cut] < k) below += histogram[cut++];
  // keys[0, below): bands under the cut; spill: the cut band's, of which k - below are wanted.
  spill.clear();
  std::size_t kept = 0;
  for (std::size_t j = 0; j < count; ++j) {
    const std::uint64_t key = keys[j];
    const std::uint32_t b = band(key);
    if (b == cut) spill.push_back(key);
    keys[kept] = key;
    kept += b < cut ? 1 : 0;
  }
  const std::size_t wanted = k - below;
  if (wanted < spill.size())
    std::nth_element(spill.begin(), spill.begin() + static_cast<std::ptrdiff_t>(wanted - 1), spill.end());
  std::copy_n(spill.begin(), wanted, keys + below);
}

// Storage behind a KNearest.
struct KNearestBuffer {
  std::vector<float> d2;
  std::vector<std::uint32_t> at;
  explicit KNearestBuffer(std::size_t k) : d2(k), at(k) {}
  // From keys (squared distance bits << 32 | position in `arrays`' x, y, z and cloud_index).
  KNearest fill(const std::uint64_t* keys, std::size_t count, const KNearest& arrays, const Eigen::Vector3f& query) {
    for (std::size_t j = 0; j < count; ++j) {
      d2[j] = std::bit_cast<float>(static_cast<std::uint32_t>(keys[j] >> 32));
      at[j] = static_cast<std::uint32_t>(keys[j] & 0xffffffffu);
    }
    KNearest nearest = arrays;
    nearest.squared_distance = d2.data();
    nearest.at = at.data();
    nearest.count = count;
    nearest.query = query;
    return nearest;
  }
};

// Coordinates of scattered cloud points copied side by side, for the searches off the grid.
struct ScatteredPoints {
  std::vector<std::uint32_t> cloud_index;
  std::vector<float> x, y, z;
  explicit ScatteredPoints(std::size_t k) : cloud_index(k), x(k), y(k), z(k) {}
  // Rewrites keys (squared distance bits << 32 | cloud index) to address these arrays.
  KNearest gather(const std::vector<Eigen::Vector3f>& points, std::uint64_t* keys, std::size_t count) {
    for (std::size_t j = 0; j < count; ++j) {
      const auto i = static_cast<std::uint32_t>(keys[j] & 0xffffffffu);
      cloud_index[j] = i;
      x[j] = points[i].x();
      y[j] = points[i].y();
      z[j] = points[i].z();
      keys[j] = (keys[j] & ~std::uint64_t{0xffffffffu}) | j;
    }
    return {nullptr, nullptr, cloud_index.data(), x.data(), y.data(), z.data(), 0, {}};
  }
};

// Calls visit(i, const KNearest&) for every point i of `points` with its k nearest points (itself
// included). Calls come from several threads at once, one per point.
template <class Visit>
void for_each_k_nearest(const std::vector<Eigen::Vector3f>& points, std::size_t k, Visit&& visit) {
  const std::size_t n = points.size();
  if (n == 0 || k == 0) return;
  std::vector<std::uint8_t> needs_search(n, 0);
  std::optional<NeighbourGrid> grid;
  if (n > k) {
    grid = NeighbourGrid::for_k_nearest(points, k);
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, grid->cell_count(), 32), [&](const tbb::blocked_range<std::size_t>& cells) {
          CellBlock block;
          std::vector<float> d2_block;
          std::vector<std::uint64_t> keyed, spill;
          KNearestBuffer answer(k);
          for (std::size_t c = cells.begin(); c < cells.end(); ++c) {
            grid->gather_block(c, block);
            const std::size_t m = block.size();
            const std::span<const std::uint32_t> own = grid->cell_points(c);  // the block's first points
            for (std::size_t t = 0; t < own.size(); ++t) {
              const std::uint32_t i = own[t];
              if (m < k) {
                needs_search[i] = 1;
                continue;
              }
              const Eigen::Vector3f p(block.x[t], block.y[t], block.z[t]);
              // Only points nearer than the block's nearest face (less the float distance's own
              // rounding, a few parts in 10^7) are certain to be among the nearest: with k of
              // them, those are the k nearest.
              const double reach = block.reach(p) * (1 - 1e-6);
              const float reach2 = reach > 0 ? static_cast<float>(reach * reach) : 0.0f;
              // In runs of 8 (the block is padded to whole runs): vector instructions at -O2.
              d2_block.resize(block.x.size());
              for (std::size_t j = 0; j < block.x.size(); j += CellBlock::kRun)
                for (std::size_t l = j; l < j + CellBlock::kRun; ++l) {
                  const float dx = block.x[l] - p.x(), dy = block.y[l] - p.y(), dz = block.z[l] - p.z();
                  d2_block[l] = dx * dx + dy * dy + dz * dz;
                }
              // The squared distance's bits above the block position: non-negative floats order
              // as their bit patterns, so one integer order sorts by distance, then position.
              keyed.resize(m);
              std::size_t within = 0;
              for (std::size_t j = 0; j < m; ++j) {
                keyed[within] = (std::uint64_t{std::bit_cast<std::uint32_t>(d2_block[j])} << 32) | j;
                within += d2_block[j] < reach2 ? 1 : 0;
              }
              if (within < k) {
                needs_search[i] = 1;  // a nearer point may lie outside the block
                continue;
              }
              select_k_smallest(keyed.data(), within, k, reach2, spill);
              const KNearest arrays{
                  nullptr, nullptr, block.index.data(), block.x.data(), block.y.data(), block.z.data(), 0, {}};
              visit(static_cast<std::size_t>(i), answer.fill(keyed.data(), k, arrays, p));
            }
          }
        });
  } else {
    std::fill(needs_search.begin(), needs_search.end(), std::uint8_t{1});
  }
  std::vector<std::uint32_t> rest;
  for (std::size_t i = 0; i < n; ++i)
    if (needs_search[i]) rest.push_back(static_cast<std::uint32_t>(i));
  if (rest.empty()) return;
  std::vector<std::uint8_t> beyond_groups(rest.size(), 1);
  if (grid) {
    grid->group_cells();
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, rest.size(), 16),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                        std::vector<std::uint64_t> keyed;
                        KNearestBuffer answer(k);
                        ScatteredPoints scattered(k);
                        for (std::size_t q = r.begin(); q < r.end(); ++q) {
                          const std::size_t i = rest[q];
                          if (!grid->k_nearest_in_groups(points[i], k, 6, keyed)) continue;
                          beyond_groups[q] = 0;
                          const KNearest arrays = scattered.gather(points, keyed.data(), k);
                          visit(i, answer.fill(keyed.data(), k, arrays, points[i]));
                        }
                      });
  }
  std::vector<std::uint32_t> far;
  for (std::size_t q = 0; q < rest.size(); ++q)
    if (beyond_groups[q]) far.push_back(rest[q]);
  if (far.empty()) return;
  const KdTree tree(points);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, far.size(), 256), [&](const tbb::blocked_range<std::size_t>& r) {
    KNearestBuffer answer(k);
    ScatteredPoints scattered(k);
    std::vector<std::uint32_t> indices(k);
    std::vector<float> d2(k);
    std::vector<std::uint64_t> keyed(k);
    for (std::size_t q = r.begin(); q < r.end(); ++q) {
      const std::size_t i = far[q];
      const std::size_t found = tree.knn(points[i], k, indices.data(), d2.data());
      for (std::size_t j = 0; j < found; ++j)
        keyed[j] = (std::uint64_t{std::bit_cast<std::uint32_t>(d2[j])} << 32) | indices[j];
      const KNearest arrays = scattered.gather(points, keyed.data(), found);
      visit(i, answer.fill(keyed.data(), found, arrays, points[i]));
    }
  });
}

// For each point, min(stop_at, how many points lie strictly within `radius` of it, itself
// included). Exact: cells of at least `radius`, so the block holds every point within reach.
std::vector<std::uint32_t> count_within(const std::vector<Eigen::Vector3f>& points, float radius,
                                        std::uint32_t stop_at);

}  // namespace slscan::core::detail
