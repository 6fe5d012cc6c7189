#include "neighbour_grid.hpp"

#include <tbb/parallel_reduce.h>
#include <tbb/parallel_sort.h>

#include <cmath>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>

#include "slproto/number_text.hpp"

namespace slscan::core::detail {
namespace {

struct Bounds {
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::infinity());
  Eigen::Vector3f hi = Eigen::Vector3f::Constant(-std::numeric_limits<float>::infinity());
  std::size_t first_not_finite = std::numeric_limits<std::size_t>::max();
};

// Exact (min, max and the first bad index do not depend on how the range was split).
Bounds bounds_of(const std::vector<Eigen::Vector3f>& points) {
  return tbb::parallel_reduce(
      tbb::blocked_range<std::size_t>(0, points.size(), 16384), Bounds{},
      [&](const tbb::blocked_range<std::size_t>& r, Bounds b) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
          const Eigen::Vector3f& p = points[i];
          if (!p.allFinite()) {
            b.first_not_finite = std::min(b.first_not_finite, i);
            continue;
          }
          b.lo = b.lo.cwiseMin(p);
          b.hi = b.hi.cwiseMax(p);
        }
        return b;
      },
      [](Bounds a, const Bounds& b) {
        a.lo = a.lo.cwiseMin(b.lo);
        a.hi = a.hi.cwiseMax(b.hi);
        a.first_not_finite = std::min(a.first_not_finite, b.first_not_finite);
        return a;
      });
}

// Sorts (cell number << 32 | index), the indices ascending, by cell number: three stable counting
// passes over 11-bit digits (the indices keep their order within a cell). ~4x faster than a
// comparison sort on two threads.
void sort_by_cell_number(LargeArray<std::uint64_t>& keys, std::size_t n) {
  constexpr int kDigitBits = 11;
  constexpr std::size_t kDigits = std::size_t{1} << kDigitBits;
  std::vector<std::uint32_t> counts(3 * kDigits, 0);
  for (std::size_t i = 0; i < n; ++i)
    for (int pass = 0; pass < 3; ++pass)
      ++counts[pass * kDigits + ((keys[i] >> (32 + pass * kDigitBits)) & (kDigits - 1))];
  auto scratch = make_large_array<std::uint64_t>(n);
  for (int pass = 0; pass < 3; ++pass) {
    std::uint32_t* start = counts.data() + pass * kDigits;
    std::uint32_t sum = 0;
    for (std::size_t d = 0; d < kDigits; ++d) sum += std::exchange(start[d], sum);
    for (std::size_t i = 0; i < n; ++i)
      scratch[start[(keys[i] >> (32 + pass * kDigitBits)) & (kDigits - 1)]++] = keys[i];
    std::swap(keys, scratch);
  }
}

std::uint64_t hash_slot(std::uint64_t key, int shift) { return (key * 0x9E3779B97F4A7C15ull) >> shift; }

}  // namespace

NeighbourGrid::NeighbourGrid(const std::vector<Eigen::Vector3f>& points, double cell_size) {
  if (!(cell_size > 0) || !std::isfinite(cell_size))
    throw std::invalid_argument("neighbour grid: the cell size must be a positive number, got " +
                                slproto::short_number(cell_size));
  const std::size_t n = points.size();
  if (n >= kNoCell)
    throw std::invalid_argument("neighbour grid: " + std::to_string(n) + " points, at most " +
                                std::to_string(kNoCell - 1));
  cell_start_.assign(1, 0);
  if (n == 0) return;
  const Bounds bounds = bounds_of(points);
  if (bounds.first_not_finite < n)
    throw std::invalid_argument("neighbour grid: point " + std::to_string(bounds.first_not_finite) + " is not finite");
  origin_ = bounds.lo.cast<double>();
  const Eigen::Vector3d extent = bounds.hi.cast<double>() - origin_;
  // Keep every cell coordinate below 2^21 - 1 so that a neighbour's +1 still fits its field.
  cell_size_ = std::max(cell_size, extent.maxCoeff() / static_cast<double>(kAxisMask - 2));
  for (int a = 0; a < 3; ++a) max_cell_[a] = static_cast<std::int64_t>(std::floor(extent[a] / cell_size_));

  // Sorted by (cell, index): one order whatever the threads. When the grid's cells can be
  // numbered in 32 bits (nearly always), by counting; otherwise (key, index) pairs by comparison.
  const std::uint64_t ny = static_cast<std::uint64_t>(max_cell_[1]) + 1,
                      nz = static_cast<std::uint64_t>(max_cell_[2]) + 1;
  const bool numbered =
      static_cast<double>(max_cell_[0] + 1) * static_cast<double>(ny) * static_cast<double>(nz) < 4294967296.0;
  // Written in full before read: no zero-filling of fresh memory; in 2 MB pages (large_array.hpp).
  LargeArray<std::uint64_t> numbered_keys;
  std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed;
  if (numbered) {
    numbered_keys = make_large_array<std::uint64_t>(n);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 16384), [&](const tbb::blocked_range<std::size_t>& r) {
      for (std::size_t i = r.begin(); i < r.end(); ++i) {
        std::int64_t c[3];
        unpack(cell_key(points[i]), c);
        const std::uint64_t number = (static_cast<std::uint64_t>(c[0]) * ny + static_cast<std::uint64_t>(c[1])) * nz +
                                     static_cast<std::uint64_t>(c[2]);
        numbered_keys[i] = (number << 32) | i;
      }
    });
    sort_by_cell_number(numbered_keys, n);
  } else {
    keyed.resize(n);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 16384), [&](const tbb::blocked_range<std::size_t>& r) {
      for (std::size_t i = r.begin(); i < r.end(); ++i) keyed[i] = {cell_key(points[i]), static_cast<std::uint32_t>(i)};
    });
    tbb::parallel_sort(keyed.begin(), keyed.end());
  }
  const auto index_at = [&](std::size_t s) {
    return numbered ? static_cast<std::uint32_t>(numbered_keys[s] & 0xffffffffu) : keyed[s].second;
  };
  const auto cell_at = [&](std::size_t s) { return numbered ? numbered_keys[s] >> 32 : keyed[s].first; };

  for (std::size_t s = 0; s < n; ++s)
    if (s == 0 || cell_at(s) != cell_at(s - 1)) {
      std::uint64_t key = cell_at(s);
      if (numbered) {
        const std::int64_t c[3] = {static_cast<std::int64_t>(key / (ny * nz)), static_cast<std::int64_t>(key / nz % ny),
                                   static_cast<std::int64_t>(key % nz)};
        key = pack(c);
      }
      cell_keys_.push_back(key);
      if (s > 0) cell_start_.push_back(static_cast<std::uint32_t>(s));
    }
  cell_start_.push_back(static_cast<std::uint32_t>(n));

  size_ = n;
  sorted_index_ = make_large_array<std::uint32_t>(n);
  x_ = make_large_array<float>(n);
  y_ = make_large_array<float>(n);
  z_ = make_large_array<float>(n);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 16384), [&](const tbb::blocked_range<std::size_t>& r) {
    for (std::size_t s = r.begin(); s < r.end(); ++s) {
      const std::uint32_t i = index_at(s);
      sorted_index_[s] = i;
      x_[s] = points[i].x();
      y_[s] = points[i].y();
      z_[s] = points[i].z();
    }
  });

  table_.build(cell_keys_);
}

void NeighbourGrid::KeyTable::build(const std::vector<std::uint64_t>& keys) {
  const std::size_t capacity = std::bit_ceil(std::max<std::size_t>(2 * keys.size(), 2));
  shift = 64 - std::countr_zero(capacity);
  slots.assign(capacity, kNoCell);
  const std::uint64_t mask = capacity - 1;
  for (std::size_t c = 0; c < keys.size(); ++c) {
    std::uint64_t slot = hash_slot(keys[c], shift);
    while (slots[slot] != kNoCell) slot = (slot + 1) & mask;
    slots[slot] = static_cast<std::uint32_t>(c);
  }
}

std::int64_t NeighbourGrid::KeyTable::find(const std::vector<std::uint64_t>& keys, std::uint64_t key) const {
  const std::uint64_t mask = slots.size() - 1;
  for (std::uint64_t slot = hash_slot(key, shift);; slot = (slot + 1) & mask) {
    const std::uint32_t c = slots[slot];
    if (c == kNoCell) return -1;
    if (keys[c] == key) return c;
  }
}

std::uint64_t NeighbourGrid::pack(const std::int64_t c[3]) {
  return (static_cast<std::uint64_t>(c[0]) << (2 * kAxisBits)) | (static_cast<std::uint64_t>(c[1]) << kAxisBits) |
         static_cast<std::uint64_t>(c[2]);
}

void NeighbourGrid::unpack(std::uint64_t key, std::int64_t c[3]) {
  c[0] = static_cast<std::int64_t>((key >> (2 * kAxisBits)) & kAxisMask);
  c[1] = static_cast<std::int64_t>((key >> kAxisBits) & kAxisMask);
  c[2] = static_cast<std::int64_t>(key & kAxisMask);
}

void NeighbourGrid::group_cells() {
  if (!group_keys_.empty() || cell_keys_.empty()) return;
  std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed(cell_keys_.size());
  for (std::size_t c = 0; c < cell_keys_.size(); ++c) {
    std::int64_t cell[3];
    unpack(cell_keys_[c], cell);
    for (auto& a : cell) a >>= kGroupBits;
    keyed[c] = {pack(cell), static_cast<std::uint32_t>(c)};
  }
  tbb::parallel_sort(keyed.begin(), keyed.end());  // distinct pairs: one order
  group_cells_.resize(keyed.size());
  for (std::size_t s = 0; s < keyed.size(); ++s) {
    if (s == 0 || keyed[s].first != keyed[s - 1].first) {
      group_keys_.push_back(keyed[s].first);
      group_start_.push_back(static_cast<std::uint32_t>(s));
    }
    group_cells_[s] = keyed[s].second;
  }
  group_start_.push_back(static_cast<std::uint32_t>(keyed.size()));
  group_table_.build(group_keys_);
}

bool NeighbourGrid::k_nearest_in_groups(const Eigen::Vector3f& p, std::size_t k, int max_rings,
                                        std::vector<std::uint64_t>& keyed) const {
  std::int64_t centre[3];
  unpack(cell_key(p), centre);
  std::int64_t last[3];
  for (int a = 0; a < 3; ++a) {
    centre[a] >>= kGroupBits;
    last[a] = max_cell_[a] >> kGroupBits;
  }
  const double group_size = cell_size_ * (1 << kGroupBits);
  const double inf = std::numeric_limits<double>::infinity();
  const Eigen::Vector3d q = p.cast<double>();
  // Squared distance from q to the box of cells [lo, lo + extent) (cell units), less a margin
  // for rounding: a box no nearer than the k-th best so far cannot improve it.
  auto box_d2 = [&](const std::int64_t lo[3], double extent_cells) {
    double d2 = 0;
    for (int a = 0; a < 3; ++a) {
      const double from = origin_[a] + static_cast<double>(lo[a]) * cell_size_;
      const double to = from + extent_cells * cell_size_;
      const double gap = std::max({from - q[a], q[a] - to, 0.0});
      d2 += gap * gap;
    }
    const double gap = std::max(0.0, std::sqrt(d2) - 1e-6 * cell_size_);
    return gap * gap * (1 - 1e-5);
  };
  // The k best so far, as a max-heap of (squared distance bits << 32 | index).
  keyed.clear();
  auto worst_d2 = [&] {
    return keyed.size() < k
               ? inf
               : static_cast<double>(std::bit_cast<float>(static_cast<std::uint32_t>(keyed.front() >> 32)));
  };
  std::vector<std::pair<double, std::uint32_t>> ring_groups;
  for (std::int64_t ring = 0; ring <= max_rings; ++ring) {
    // The groups at Chebyshev distance `ring` from the centre one, nearest first: the k best
    // fill with near points early and prune the rest.
    ring_groups.clear();
    for (std::int64_t dx = -ring; dx <= ring; ++dx)
      for (std::int64_t dy = -ring; dy <= ring; ++dy)
        for (std::int64_t dz = -ring; dz <= ring; ++dz) {
          if (std::max({std::abs(dx), std::abs(dy), std::abs(dz)}) != ring) continue;  // inner rings done
          const std::int64_t g[3] = {centre[0] + dx, centre[1] + dy, centre[2] + dz};
          if (g[0] < 0 || g[1] < 0 || g[2] < 0 || g[0] > last[0] || g[1] > last[1] || g[2] > last[2]) continue;
          const std::int64_t found = group_table_.find(group_keys_, pack(g));
          if (found < 0) continue;
          const std::int64_t group_lo[3] = {g[0] << kGroupBits, g[1] << kGroupBits, g[2] << kGroupBits};
          ring_groups.emplace_back(box_d2(group_lo, 1 << kGroupBits), static_cast<std::uint32_t>(found));
        }
    std::sort(ring_groups.begin(), ring_groups.end());
    for (const auto& [group_d2, group] : ring_groups) {
      if (group_d2 >= worst_d2()) break;
      for (std::uint32_t s = group_start_[group]; s < group_start_[group + 1]; ++s) {
        const std::uint32_t c = group_cells_[s];
        std::int64_t cell[3];
        unpack(cell_keys_[c], cell);
        if (box_d2(cell, 1) >= worst_d2()) continue;
        for (std::uint32_t j = cell_start_[c]; j < cell_start_[c + 1]; ++j) {
          const float ex = x_[j] - p.x(), ey = y_[j] - p.y(), ez = z_[j] - p.z();
          const float d = ex * ex + ey * ey + ez * ez;
          const std::uint64_t key = (std::uint64_t{std::bit_cast<std::uint32_t>(d)} << 32) | sorted_index_[j];
          if (keyed.size() < k) {
            keyed.push_back(key);
            std::push_heap(keyed.begin(), keyed.end());
          } else if (key < keyed.front()) {
            std::pop_heap(keyed.begin(), keyed.end());
            keyed.back() = key;
            std::push_heap(keyed.begin(), keyed.end());
          }
        }
      }
    }
    if (keyed.size() < k) continue;
    // Certain once the k-th best lies nearer than every face of the block searched.
    double reach = inf;
    for (int a = 0; a < 3; ++a) {
      if (centre[a] - ring > 0)
        reach = std::min(reach, q[a] - (origin_[a] + static_cast<double>(centre[a] - ring) * group_size));
      if (centre[a] + ring < last[a])
        reach = std::min(reach, origin_[a] + static_cast<double>(centre[a] + ring + 1) * group_size - q[a]);
    }
    reach = (reach - 1e-6 * cell_size_) * (1 - 1e-6);
    if (reach > 0 && worst_d2() < reach * reach) {
      std::sort_heap(keyed.begin(), keyed.end());
      return true;
    }
  }
  return false;
}

NeighbourGrid NeighbourGrid::for_k_nearest(const std::vector<Eigen::Vector3f>& points, std::size_t k) {
  const double target = std::max(2.0, static_cast<double>(k) / 2.5);
  const auto n = static_cast<double>(std::max<std::size_t>(points.size(), 1));
  // First guess: a surface of half the bounding box's area (a scanned part's is of that order),
  // then the cell size corrected by the points per cell measured, as for a surface (~ size^2).
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::infinity()), hi = -lo;
  for (const auto& p : points)
    if (p.allFinite()) {
      lo = lo.cwiseMin(p);
      hi = hi.cwiseMax(p);
    }
  const Eigen::Vector3d e = (hi - lo).cast<double>().cwiseMax(0.0);
  double area = e.x() * e.y() + e.y() * e.z() + e.z() * e.x();
  if (!(area > 0)) area = e.maxCoeff() * e.maxCoeff();
  double cell = std::sqrt(target * area / n);
  if (!(cell > 0) || !std::isfinite(cell)) cell = 1.0;
  for (int attempt = 0;; ++attempt) {
    NeighbourGrid grid(points, cell);
    const double m = grid.points_per_cell();
    if (attempt == 3 || (m >= target / 2 && m <= target * 2)) return grid;
    cell = grid.cell_size() * std::clamp(std::sqrt(target / m), 0.125, 8.0);
  }
}

double NeighbourGrid::points_per_cell() const {
  return cell_keys_.empty() ? 0.0 : static_cast<double>(size_) / static_cast<double>(cell_keys_.size());
}

std::uint64_t NeighbourGrid::cell_key(const Eigen::Vector3f& p) const {
  std::int64_t c[3];
  for (int a = 0; a < 3; ++a)
    c[a] = std::clamp<std::int64_t>(
        static_cast<std::int64_t>(std::floor((static_cast<double>(p[a]) - origin_[a]) / cell_size_)), 0, max_cell_[a]);
  return pack(c);
}

void NeighbourGrid::append_cell(std::size_t c, CellBlock& block) const {
  const std::size_t b = cell_start_[c], e = cell_start_[c + 1];
  block.x.insert(block.x.end(), &x_[b], &x_[0] + e);
  block.y.insert(block.y.end(), &y_[b], &y_[0] + e);
  block.z.insert(block.z.end(), &z_[b], &z_[0] + e);
  block.index.insert(block.index.end(), &sorted_index_[b], &sorted_index_[0] + e);
}

void NeighbourGrid::gather_block(std::size_t c, CellBlock& block) const {
  block.clear();
  append_cell(c, block);
  const std::uint64_t key = cell_keys_[c];
  const std::int64_t centre[3] = {static_cast<std::int64_t>((key >> (2 * kAxisBits)) & kAxisMask),
                                  static_cast<std::int64_t>((key >> kAxisBits) & kAxisMask),
                                  static_cast<std::int64_t>(key & kAxisMask)};
  const double inf = std::numeric_limits<double>::infinity();
  block.margin = 1e-6 * cell_size_;  // cell coordinates are below 2^21: their rounding is ~1e-9 cells
  for (int a = 0; a < 3; ++a) {
    // No point lies below cell 0 or above the last cell: the block's box is open there.
    block.lo[a] = centre[a] <= 1 ? -inf : origin_[a] + static_cast<double>(centre[a] - 1) * cell_size_;
    block.hi[a] = centre[a] + 1 >= max_cell_[a] ? inf : origin_[a] + static_cast<double>(centre[a] + 2) * cell_size_;
  }
  for (std::int64_t dx = -1; dx <= 1; ++dx)
    for (std::int64_t dy = -1; dy <= 1; ++dy)
      for (std::int64_t dz = -1; dz <= 1; ++dz) {
        if (dx == 0 && dy == 0 && dz == 0) continue;
        const std::int64_t cx = centre[0] + dx, cy = centre[1] + dy, cz = centre[2] + dz;
        if (cx < 0 || cy < 0 || cz < 0 || cx > max_cell_[0] || cy > max_cell_[1] || cz > max_cell_[2]) continue;
        const std::uint64_t neighbour = (static_cast<std::uint64_t>(cx) << (2 * kAxisBits)) |
                                        (static_cast<std::uint64_t>(cy) << kAxisBits) | static_cast<std::uint64_t>(cz);
        const std::int64_t found = find_cell(neighbour);
        if (found >= 0) append_cell(static_cast<std::size_t>(found), block);
      }
  block.pad();
}

std::vector<std::uint32_t> count_within(const std::vector<Eigen::Vector3f>& points, float radius,
                                        std::uint32_t stop_at) {
  if (!(radius > 0) || !std::isfinite(radius))
    throw std::invalid_argument("count_within: the radius must be a positive number, got " +
                                slproto::short_number(radius));
  std::vector<std::uint32_t> counts(points.size(), 0);
  if (points.empty() || stop_at == 0) return counts;
  // Cells a hair wider than the radius: a point within it is never two cells away, whatever the
  // rounding of the cell coordinates.
  const NeighbourGrid grid(points, static_cast<double>(radius) * (1 + 1e-6));
  const float r2 = radius * radius;
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, grid.cell_count(), 32),
                    [&](const tbb::blocked_range<std::size_t>& cells) {
                      CellBlock block;
                      for (std::size_t c = cells.begin(); c < cells.end(); ++c) {
                        grid.gather_block(c, block);
                        const std::size_t m = block.size();
                        const std::span<const std::uint32_t> own = grid.cell_points(c);  // the block's first
                        for (std::size_t t = 0; t < own.size(); ++t) {
                          const std::uint32_t i = own[t];
                          const Eigen::Vector3f p(block.x[t], block.y[t], block.z[t]);
                          std::uint32_t count = 0;
                          // In runs of 64 (the centre cell's points first): most points reach
                          // `stop_at` in the first run.
                          for (std::size_t begin = 0; begin < m && count < stop_at; begin += 64) {
                            const std::size_t end = std::min(m, begin + 64);
                            std::uint32_t run = 0;
                            for (std::size_t j = begin; j < end; ++j) {
                              const float dx = block.x[j] - p.x(), dy = block.y[j] - p.y(), dz = block.z[j] - p.z();
                              run += (dx * dx + dy * dy + dz * dz) < r2 ? 1u : 0u;
                            }
                            count += run;
                          }
                          counts[i] = std::min(count, stop_at);
                        }
                      }
                    });
  return counts;
}

}  // namespace slscan::core::detail
