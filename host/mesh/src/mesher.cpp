// The level-set mesher (docs/mesh.md, "What the mesher does").
#include "slscan/mesh/mesher.hpp"

#include <openvdb/openvdb.h>
#include <openvdb/tools/Morphology.h>
#include <openvdb/tools/SignedFloodFill.h>
#include <openvdb/tools/VolumeToMesh.h>
#include <openvdb/tree/LeafManager.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <mutex>
#include <numeric>
#include <stdexcept>
#include <string>
#include <unordered_set>
#include <vector>

#include "fit_sums.hpp"
#include "slscan/core/detail/nearest_tree.hpp"

namespace slscan::mesh {
namespace {

// Watertight: closures started again after removing the measured triangles a patch crossed.
constexpr int max_reclosures = 4;
// The fit takes the points whose normal is within 90 deg of the query's side (docs/mesh.md step 2).
constexpr float side_agreement_cosine = 0;
// The level set's voxels are fitted in blocks of fit_block^3 sharing one neighbour search. With
// the fit's sums in SIMD lanes (fit_sums.hpp) the search is the larger cost: 4 fits the
// full-resolution blade's voxels in 0.37 s, 2 in 0.46 s, 8 in 0.48 s (docs/mesh.md, "Speed").
constexpr int fit_block = 4;
// Pinholes (border cycles of at most this many edges, at most this many cells across) are closed
// in raw mode too (docs/mesh.md step 6).
constexpr std::size_t pinhole_max_edges = 40;
constexpr double pinhole_max_cells = 6;
// The mesh's vertices are projected in blocks of this many cells across sharing one search (the
// blade: 2 cells 0.34 s, 3 0.29 s, 4 0.26 s).
constexpr int project_block = 4;
constexpr int blocks_per_leaf = openvdb::FloatTree::LeafNodeType::DIM / fit_block;

// A k-d tree over a point array (core's NearestTree: built on two threads, points copied side by
// side in tree order), with the result sets the mesher needs. Searched without sorting: every
// query visits the points in the tree's fixed order, so the sums below do not depend on thread
// timing.
class Tree {
 public:
  explicit Tree(const std::vector<Eigen::Vector3f>& points) : index_(points) {}

  template <class Result>
  void search(Result& result, const Eigen::Vector3f& query) const {
    index_.search(result, query);
  }

  // The nearest point within `gate` (or -1) and its squared distance.
  std::int64_t nearest(const Eigen::Vector3f& query, float gate, float& d2) const {
    Nearest result(gate * gate);
    search(result, query);
    d2 = result.best;
    return result.index;
  }

  struct Nearest {
    using DistanceType = float;
    using IndexType = std::uint32_t;
    explicit Nearest(float gate2) : best(gate2) {}
    float best;
    std::int64_t index = -1;
    bool addPoint(float d, std::uint32_t i) {
      if (d < best || (d == best && index >= 0 && i < index)) {
        best = d;
        index = i;
      }
      return true;
    }
    float worstDist() const { return best; }
    bool full() const { return true; }
    std::size_t size() const { return index < 0 ? 0 : 1; }
  };

  // The second-nearest distance (the nearest is the query point itself).
  struct TwoNearest {
    using DistanceType = float;
    using IndexType = std::uint32_t;
    float d[2] = {std::numeric_limits<float>::max(), std::numeric_limits<float>::max()};
    bool addPoint(float dist, std::uint32_t) {
      if (dist < d[0]) {
        d[1] = d[0];
        d[0] = dist;
      } else if (dist < d[1]) {
        d[1] = dist;
      }
      return true;
    }
    float worstDist() const { return d[1]; }
    bool full() const { return true; }
    std::size_t size() const { return 2; }
  };

  // The Gaussian-weighted mean of a per-point value within 3 sigma, in the tree's fixed order.
  struct WeightedMean {
    using DistanceType = float;
    using IndexType = std::uint32_t;
    WeightedMean(const std::vector<float>& v, double sigma)
        : values(v), radius2(static_cast<float>(9 * sigma * sigma)), inv_two_sigma2(1 / (2 * sigma * sigma)) {}
    const std::vector<float>& values;
    float radius2;
    double inv_two_sigma2;
    double weight = 0, sum = 0;
    bool addPoint(float d2, std::uint32_t i) {
      if (d2 >= radius2) return true;
      const double w = std::exp(-static_cast<double>(d2) * inv_two_sigma2);
      weight += w;
      sum += w * static_cast<double>(values[i]);
      return true;
    }
    float worstDist() const { return radius2; }
    bool full() const { return true; }
    std::size_t size() const { return 0; }
  };

  // The centroid of the points within a radius (unweighted, in the tree's fixed order).
  struct Centroid {
    using DistanceType = float;
    using IndexType = std::uint32_t;
    explicit Centroid(float r2) : radius2(r2) {}
    float radius2;
    Eigen::Vector3f sum = Eigen::Vector3f::Zero();
    std::size_t count = 0;
    const std::vector<Eigen::Vector3f>* points = nullptr;
    bool addPoint(float d2, std::uint32_t i) {
      if (d2 < radius2) {
        sum += (*points)[i];
        ++count;
      }
      return true;
    }
    float worstDist() const { return radius2; }
    bool full() const { return true; }
    std::size_t size() const { return count; }
  };

  struct Count {
    using DistanceType = float;
    using IndexType = std::uint32_t;
    Count(float r2, std::size_t stop) : radius2(r2), stop_at(stop) {}
    float radius2;
    std::size_t stop_at, count = 0;
    bool addPoint(float d, std::uint32_t) {
      if (d < radius2) ++count;
      return count < stop_at;
    }
    float worstDist() const { return radius2; }
    bool full() const { return true; }
    std::size_t size() const { return count; }
  };

 private:
  core::detail::NearestTree index_;
};

// The implicit surface: an algebraic sphere fitted to the points and normals around x (APSS,
// Guennebaud & Gross 2007), Gaussian weights w_i = exp(-|x - p_i|^2 / 2 sigma^2) over the points
// within 3 sigma. f(x) is the fitted u0 + u.x + u4 |x|^2 at x, ~ the signed distance near the
// surface, positive outside (normals point outward). A plane fit (IMLS, Kolluri 2005) would put
// a curved surface sigma^2 / R inside itself (11 um on a 10 mm sphere at 0.17 mm spacing); the
// sphere fit has no such bias.
class Implicit {
 public:
  // `tree` indexes `points` (or an array of the same points in the same order).
  Implicit(const std::vector<Eigen::Vector3f>& points, const std::vector<Eigen::Vector3f>& normals, const Tree& tree,
           double sigma, double normal_gate)
      : points_(points),
        normals_(normals),
        tree_(tree),
        sigma_(sigma),
        support_(3 * sigma),
        normal_gate_(static_cast<float>(normal_gate)) {}

  struct Value {
    double f = 0;
    Eigen::Vector3d normal = Eigen::Vector3d::Zero();  // gradient of the fit at x
    double weight = 0;                                 // 0: no point within the support
    bool two_sided = false;  // points facing the other way within the support (a thin wall or edge)
    // The Gaussian-weighted mean of `values` (at()'s argument) over every point within the
    // support, either side; NaN when none is or no values were given.
    float value_mean = std::numeric_limits<float>::quiet_NaN();
  };

  // `facing`: the side whose points count (normals within the gate of it); zero: the nearest
  // point's normal. `values`: a per-point value to average too (Value::value_mean).
  Value at(const Eigen::Vector3d& x, const Eigen::Vector3f& facing = Eigen::Vector3f::Zero(),
           const std::vector<float>* values = nullptr) const {
    thread_local detail::FitCandidates found;
    found.clear();
    Gather gather(*this, found, static_cast<float>(support_ * support_), values);
    tree_.search(gather, x.cast<float>());
    found.pad();
    return fit(x, found, facing, values != nullptr);
  }

  // at() for the active voxels of a block of cells: the points within the support of any of
  // `voxels` (centres within `half_diagonal` of `centre`) gathered once, then each voxel's fit
  // over them, the points beyond its support weighing nothing (one tree search per block
  // instead of per voxel: the search was most of the fit's time).
  // `facing` and `values` as at(): empty `facing`, the nearest point's side for every query.
  void at_block(const Eigen::Vector3d& centre, double half_diagonal, const std::vector<Eigen::Vector3d>& voxels,
                std::vector<Value>& out, const std::vector<Eigen::Vector3f>& facing = {},
                const std::vector<float>* values = nullptr) const {
    thread_local detail::FitCandidates candidates;
    candidates.clear();
    const double reach = support_ + half_diagonal;
    Gather gather(*this, candidates, static_cast<float>(reach * reach), values);
    tree_.search(gather, centre.cast<float>());
    candidates.pad();
    out.clear();
    for (std::size_t v = 0; v < voxels.size(); ++v)
      out.push_back(
          fit(voxels[v], candidates, facing.empty() ? Eigen::Vector3f::Zero() : facing[v], values != nullptr));
  }

  // The fit at x to the candidates within its support (fit_sums.hpp: the sums, in SIMD lanes).
  Value fit(const Eigen::Vector3d& x, const detail::FitCandidates& candidates, const Eigen::Vector3f& facing,
            bool with_values) const {
    detail::FitQuery query;
    const Eigen::Vector3f at = x.cast<float>();
    for (int a = 0; a < 3; ++a) {
      query.x[a] = at[a];
      query.facing[a] = facing[a];
    }
    query.support2 = static_cast<float>(support_ * support_);
    query.inv_two_sigma2 = static_cast<float>(inv_two_sigma2_);
    query.normal_gate = normal_gate_;
    query.with_values = with_values;
    const detail::FitSums r = detail::fit_sums(candidates, query);
    Value v;
    if (r.value_weight > 1e-9) v.value_mean = static_cast<float>(r.value_sum / r.value_weight);
    v.two_sided = r.two_sided;
    v.weight = r.weight;
    if (!(r.weight > 0)) return v;
    // Sums in coordinates relative to `at`: the fit's value there is u0.
    const Eigen::Vector3d m = Eigen::Vector3d(r.p[0], r.p[1], r.p[2]) / r.weight;
    const Eigen::Vector3d nbar = Eigen::Vector3d(r.n[0], r.n[1], r.n[2]) / r.weight;
    const double pp = r.pp / r.weight, pn = r.pn / r.weight;
    const double spread = pp - m.squaredNorm();
    double u4 = spread > 1e-12 ? 0.5 * (pn - m.dot(nbar)) / spread : 0;
    const double max_u4 = 0.5 / sigma_;  // a fitted radius below sigma is noise, not shape
    u4 = std::clamp(u4, -max_u4, max_u4);
    const Eigen::Vector3d u = nbar - 2 * u4 * m;
    const double u0 = -u.dot(m) - u4 * pp;
    // The algebraic sphere u0 + u.y + u4 |y|^2 (y from `at`) and its gradient at x itself.
    const Eigen::Vector3d delta = x - at.cast<double>();
    v.f = u0 + u.dot(delta) + u4 * delta.squaredNorm();
    v.normal = u + 2 * u4 * delta;
    return v;
  }

  // The nearest point's tangent-plane distance (for voxels out of the kernel's reach).
  double plane_distance(const Eigen::Vector3d& x, float gate) const {
    float d2 = 0;
    const std::int64_t i = tree_.nearest(x.cast<float>(), gate, d2);
    if (i < 0) return std::numeric_limits<double>::quiet_NaN();
    const auto k = static_cast<std::size_t>(i);
    return normals_[k].cast<double>().dot(x - points_[k].cast<double>());
  }

  const Tree& tree() const { return tree_; }
  double support() const { return support_; }

 private:
  // The points within a radius, in the tree's fixed traversal order, copied side by side.
  struct Gather {
    using DistanceType = float;
    using IndexType = std::uint32_t;
    Gather(const Implicit& implicit, detail::FitCandidates& out, float r2, const std::vector<float>* values)
        : self(implicit), found(out), radius2(r2), point_values(values) {}
    const Implicit& self;
    detail::FitCandidates& found;
    float radius2;
    const std::vector<float>* point_values;
    bool addPoint(float d2, std::uint32_t i) {
      if (d2 < radius2)
        found.push(self.points_[i].data(), self.normals_[i].data(), point_values != nullptr ? (*point_values)[i] : 0.0f,
                   i);
      return true;
    }
    float worstDist() const { return radius2; }
    bool full() const { return true; }
    std::size_t size() const { return found.size(); }
  };

  const std::vector<Eigen::Vector3f>& points_;
  const std::vector<Eigen::Vector3f>& normals_;
  const Tree& tree_;
  double sigma_, support_;
  double inv_two_sigma2_ = 1 / (2 * sigma_ * sigma_);
  float normal_gate_;  // cosine; -1 or below: every point
};

void check_cloud(const core::PointCloud& cloud) {
  if (cloud.points.empty()) throw std::invalid_argument("mesh: the point cloud is empty");
  if (cloud.normals.size() != cloud.points.size())
    throw std::invalid_argument("mesh: the point cloud has " + std::to_string(cloud.normals.size()) + " normals for " +
                                std::to_string(cloud.points.size()) + " points (one outward normal per point needed)");
  for (std::size_t i = 0; i < cloud.points.size(); ++i) {
    if (!cloud.points[i].allFinite())
      throw std::invalid_argument("mesh: point " + std::to_string(i) + " is not finite");
    const Eigen::Vector3f& n = cloud.normals[i];
    if (!n.allFinite() || !(n.squaredNorm() > 0.25f) || !(n.squaredNorm() < 4.f))
      throw std::invalid_argument("mesh: the normal of point " + std::to_string(i) +
                                  " is not a finite unit vector (run the normal estimation first)");
  }
  if (cloud.points.size() < 4)
    throw std::invalid_argument("mesh: " + std::to_string(cloud.points.size()) +
                                " point(s) do not define a surface (at least 4 needed)");
}

// Median nearest-neighbour distance over an evenly strided subset of at most 20000 points.
double median_spacing(const std::vector<Eigen::Vector3f>& points, const Tree& tree) {
  const std::size_t stride = std::max<std::size_t>(1, points.size() / 20000);
  std::vector<float> d;
  for (std::size_t i = 0; i < points.size(); i += stride) {
    Tree::TwoNearest result;
    tree.search(result, points[i]);
    if (result.d[1] < std::numeric_limits<float>::max() && result.d[1] > 0) d.push_back(std::sqrt(result.d[1]));
  }
  if (d.empty()) return 0;
  std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(d.size() / 2), d.end());
  return d[d.size() / 2];
}

// Trimming by triangles can leave a vertex whose triangles form two or more fans (a bow-tie):
// not a 2-manifold, and a border cycle through it cannot be filled (CGAL's hole filling needs
// a simple cycle: the small-rig ball bar's last open hole). At such a vertex the largest fan
// (ties: the one with the lowest triangle) is kept and the others dropped, until none is left.
// After the first pass only the vertices of dropped triangles are looked at again: any other
// vertex has the triangles it had, which formed one fan.
void remove_pinches(std::vector<std::array<std::uint32_t, 3>>& triangles, std::vector<std::uint8_t>& flags,
                    std::size_t vertex_count) {
  std::vector<std::uint8_t> look(vertex_count, 1);
  for (;;) {
    std::vector<std::uint32_t> start(vertex_count + 1, 0);
    for (const auto& t : triangles)
      for (const std::uint32_t v : t) ++start[v + 1];
    for (std::size_t v = 0; v < vertex_count; ++v) start[v + 1] += start[v];
    std::vector<std::uint32_t> incident(start.back()), fill(start.begin(), start.end() - 1);
    for (std::size_t i = 0; i < triangles.size(); ++i)
      for (const std::uint32_t v : triangles[i]) incident[fill[v]++] = static_cast<std::uint32_t>(i);
    std::vector<std::uint8_t> drop(triangles.size(), 0);
    bool dropped = false;
    std::vector<std::uint32_t> fan, size;
    for (std::size_t v = 0; v < vertex_count; ++v) {
      const std::uint32_t begin = start[v], end = start[v + 1];
      if (!look[v] || end - begin < 2) continue;
      // Fans: incident triangles joined when they share an edge through v (a second vertex).
      const std::size_t n = end - begin;
      fan.resize(n);
      std::iota(fan.begin(), fan.end(), 0u);
      auto root = [&](std::uint32_t a) {
        while (fan[a] != a) a = fan[a] = fan[fan[a]];
        return a;
      };
      for (std::size_t a = 0; a < n; ++a)
        for (std::size_t b = a + 1; b < n; ++b) {
          const auto& ta = triangles[incident[begin + a]];
          const auto& tb = triangles[incident[begin + b]];
          bool share = false;
          for (const std::uint32_t x : ta)
            if (x != v && (x == tb[0] || x == tb[1] || x == tb[2])) share = true;
          if (share) {
            const std::uint32_t ra = root(static_cast<std::uint32_t>(a)), rb = root(static_cast<std::uint32_t>(b));
            if (ra != rb) fan[std::max(ra, rb)] = std::min(ra, rb);
          }
        }
      size.assign(n, 0);
      for (std::size_t a = 0; a < n; ++a) ++size[root(static_cast<std::uint32_t>(a))];
      std::uint32_t best = 0;
      for (std::uint32_t a = 0; a < n; ++a)
        if (size[a] > size[best]) best = a;
      if (size[best] == n) continue;
      for (std::size_t a = 0; a < n; ++a)
        if (root(static_cast<std::uint32_t>(a)) != best) {
          drop[incident[begin + a]] = 1;
          dropped = true;
        }
    }
    if (!dropped) return;
    std::fill(look.begin(), look.end(), 0);
    std::size_t out = 0;
    for (std::size_t i = 0; i < triangles.size(); ++i)
      if (drop[i]) {
        for (const std::uint32_t v : triangles[i]) look[v] = 1;
      } else {
        if (!flags.empty()) flags[out] = flags[i];
        triangles[out++] = triangles[i];
      }
    triangles.resize(out);
    if (!flags.empty()) flags.resize(out);
  }
}

// The border cycles of at most `max_edges` edges whose box is at most `reach` across, each as
// its vertices in the direction the triangles traverse their border edges. Needs a mesh without
// bow-ties (remove_pinches): one border edge out of each border vertex.
std::vector<std::vector<std::uint32_t>> small_border_cycles(const std::vector<std::array<std::uint32_t, 3>>& triangles,
                                                            const std::vector<Eigen::Vector3f>& vertices,
                                                            std::size_t max_edges, float reach) {
  const std::size_t n = vertices.size();
  std::vector<std::uint32_t> first(n + 1, 0);
  for (const auto& t : triangles)
    for (const std::uint32_t v : t) ++first[v + 1];
  for (std::size_t v = 0; v < n; ++v) first[v + 1] += first[v];
  std::vector<std::uint32_t> out(first.back()), fill(first.begin(), first.end() - 1);
  for (const auto& t : triangles)
    for (std::size_t k = 0; k < 3; ++k) out[fill[t[k]]++] = t[(k + 1) % 3];
  const auto has_edge = [&](std::uint32_t a, std::uint32_t b) {
    return std::find(out.begin() + first[a], out.begin() + first[a + 1], b) != out.begin() + first[a + 1];
  };
  constexpr std::uint32_t none = UINT32_MAX, several = UINT32_MAX - 1;
  std::vector<std::uint32_t> next(n, none);
  for (std::size_t a = 0; a < n; ++a)
    for (std::uint32_t k = first[a]; k < first[a + 1]; ++k)
      if (!has_edge(out[k], static_cast<std::uint32_t>(a))) next[a] = next[a] == none ? out[k] : several;
  std::vector<std::uint8_t> seen(n, 0);
  std::vector<std::vector<std::uint32_t>> cycles;
  for (std::size_t start = 0; start < n; ++start) {
    if (next[start] >= several || seen[start]) continue;
    std::vector<std::uint32_t> cycle;
    Eigen::AlignedBox3f box;
    auto v = static_cast<std::uint32_t>(start);
    while (v < several && !seen[v] && cycle.size() <= max_edges) {
      seen[v] = 1;
      cycle.push_back(v);
      box.extend(vertices[v]);
      v = next[v];
    }
    if (v == start && cycle.size() >= 3 && cycle.size() <= max_edges && box.diagonal().norm() <= reach)
      cycles.push_back(std::move(cycle));
  }
  return cycles;
}

// A cell of a uniform grid as one key (coordinates within +-2^20 cells).
std::uint64_t cell_key(const Eigen::Vector3f& x, double cell) {
  std::uint64_t key = 0;
  for (int k = 0; k < 3; ++k)
    key = (key << 21) | static_cast<std::uint64_t>(static_cast<std::int64_t>(std::floor(x[k] / cell)) + (1 << 20));
  return key;
}

// Laps of the steps' wall time into MeshStats::step_ms.
class StepClock {
 public:
  explicit StepClock(core::MeshStats& stats) : stats_(stats), last_(std::chrono::steady_clock::now()) {}
  void lap(const char* step) {
    const auto now = std::chrono::steady_clock::now();
    stats_.add_step_ms(step, std::chrono::duration<double, std::milli>(now - last_).count());
    last_ = now;
  }

 private:
  core::MeshStats& stats_;
  std::chrono::steady_clock::time_point last_;
};

// The level set's cell, the scale of the data (max of cell and spacing), the kernel's sigma, and
// when the mesh began (for MeshStats::mesh_ms).
struct LevelSetScale {
  double cell = 0, scale = 0, sigma = 0;
  std::chrono::steady_clock::time_point start;
};

// Steps 2-7 (docs/mesh.md) on the points kept, the fit taking the points whose normal is within
// `side_gate` (a cosine; below -1: all) of the query's side.
core::MeshResult level_set_mesh(const std::vector<Eigen::Vector3f>& points, const std::vector<Eigen::Vector3f>& normals,
                                const Tree& tree, const std::vector<float>& intensity, const LevelSetScale& scales,
                                float side_gate, core::MeshResult result, const core::MeshOptions& options,
                                const core::InterruptionPoint& interrupt) {
  const double cell = scales.cell, scale = scales.scale, sigma = scales.sigma;
  const bool with_intensity = !intensity.empty();
  core::MeshStats& stats = result.stats;
  stats.sides_separated = side_gate >= -1;
  core::interruption_point(interrupt);
  StepClock clock(stats);
  const Implicit implicit(points, normals, tree, sigma, side_gate);
  core::interruption_point(interrupt);

  // 2. A sparse grid around the points: the fit evaluated in a narrow band (the voxels within 1
  // of a point's voxel), the other voxels of the band's leaves signed by OpenVDB's flood fill.
  // Cells with a corner out of the band (the level set leaving the band past the data's rim, or
  // reaching between sparse points: the pinholes closed below) are cut. A 2-voxel band kept
  // those cells, the least faithful ones (docs/mesh.md "Speed"), at 40 % more fitting time.
  openvdb::initialize();
  const float background = static_cast<float>(3 * cell);
  auto grid = openvdb::FloatGrid::create(background);
  grid->setTransform(openvdb::math::Transform::createLinearTransform(cell));
  grid->setGridClass(openvdb::GRID_LEVEL_SET);
  const openvdb::math::Transform& xform = grid->transform();
  {
    auto acc = grid->getAccessor();
    for (const auto& p : points)
      acc.setValueOn(xform.worldToIndexCellCentered(openvdb::Vec3d(p.x(), p.y(), p.z())), 0.f);
  }
  openvdb::tools::dilateActiveValues(grid->tree(), 1, openvdb::tools::NN_FACE_EDGE_VERTEX,
                                     openvdb::tools::IGNORE_TILES);
  clock.lap("band");
  const auto far_gate = static_cast<float>(16 * scale + 16 * cell * 8);
  {
    std::vector<openvdb::FloatTree::LeafNodeType*> leaves;
    grid->tree().getNodes(leaves);
    stats.leaves = leaves.size();
    stats.voxels = leaves.size() * openvdb::FloatTree::LeafNodeType::SIZE;
    // The fit in blocks of fit_block^3 voxels sharing one search (Implicit::at_block).
    const double block_half_diagonal = (0.5 * (fit_block - 1) * std::sqrt(3.0) + 1e-3) * cell;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size(), 4), [&](const auto& r) {
      core::interruption_point(interrupt);
      std::vector<openvdb::Index> offsets;
      std::vector<Eigen::Vector3d> centres;
      std::vector<Implicit::Value> values;
      for (std::size_t l = r.begin(); l < r.end(); ++l) {
        auto& leaf = *leaves[l];
        const openvdb::Coord origin = leaf.origin();
        for (int b = 0; b < blocks_per_leaf * blocks_per_leaf * blocks_per_leaf; ++b) {
          const openvdb::Coord corner =
              origin.offsetBy((b / (blocks_per_leaf * blocks_per_leaf)) * fit_block,
                              (b / blocks_per_leaf % blocks_per_leaf) * fit_block, (b % blocks_per_leaf) * fit_block);
          offsets.clear();
          centres.clear();
          for (int k = 0; k < fit_block * fit_block * fit_block; ++k) {
            const openvdb::Coord c =
                corner.offsetBy(k / (fit_block * fit_block), k / fit_block % fit_block, k % fit_block);
            const openvdb::Index offset = openvdb::FloatTree::LeafNodeType::coordToOffset(c);
            if (!leaf.isValueOn(offset)) continue;
            const openvdb::Vec3d w = xform.indexToWorld(c);
            offsets.push_back(offset);
            centres.emplace_back(w.x(), w.y(), w.z());
          }
          if (offsets.empty()) continue;
          const openvdb::Vec3d w = xform.indexToWorld(openvdb::Vec3d(corner.asVec3d() + 0.5 * (fit_block - 1)));
          implicit.at_block(Eigen::Vector3d(w.x(), w.y(), w.z()), block_half_diagonal, centres, values);
          for (std::size_t k = 0; k < offsets.size(); ++k) {
            double f = values[k].weight > 1e-6 ? values[k].f : implicit.plane_distance(centres[k], far_gate);
            if (!std::isfinite(f)) f = background;
            leaf.setValueOnly(offsets[k], static_cast<float>(std::clamp(f, -static_cast<double>(background),
                                                                        static_cast<double>(background))));
          }
        }
      }
    });
  }
  clock.lap("fit_voxels");
  core::interruption_point(interrupt);
  openvdb::tools::signedFloodFill(grid->tree());
  core::interruption_point(interrupt);
  clock.lap("flood_fill");

  // 3. The level set's zero surface.
  std::vector<openvdb::Vec3s> vdb_points;
  std::vector<openvdb::Vec3I> vdb_triangles;
  std::vector<openvdb::Vec4I> vdb_quads;
  openvdb::tools::volumeToMesh(*grid, vdb_points, vdb_triangles, vdb_quads, 0.0, options.adaptivity, true);
  clock.lap("volume_to_mesh");
  // A vertex lies in its cell (the voxels ijk .. ijk + 1): in the band when its 8 corners are.
  core::interruption_point(interrupt);
  std::vector<std::uint8_t> in_band(vdb_points.size(), 0);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, vdb_points.size(), 1024), [&](const auto& r) {
    core::interruption_point(interrupt);
    auto acc = grid->getConstAccessor();
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      const openvdb::Vec3d x = xform.worldToIndex(openvdb::Vec3d(vdb_points[i]));
      const openvdb::Coord c(static_cast<int>(std::floor(x.x())), static_cast<int>(std::floor(x.y())),
                             static_cast<int>(std::floor(x.z())));
      bool on = true;
      for (int k = 0; k < 8 && on; ++k) on = acc.isValueOn(c.offsetBy(k & 1, (k >> 1) & 1, (k >> 2) & 1));
      in_band[i] = on ? 1 : 0;
    }
  });
  grid.reset();
  std::vector<Eigen::Vector3f> vertices(vdb_points.size());
  for (std::size_t i = 0; i < vdb_points.size(); ++i)
    vertices[i] = Eigen::Vector3f(vdb_points[i].x(), vdb_points[i].y(), vdb_points[i].z());
  std::vector<std::array<std::uint32_t, 3>> triangles;
  triangles.reserve(vdb_triangles.size() + 2 * vdb_quads.size());
  // OpenVDB's polygons are clockwise seen from outside: reversed. Quads split along the
  // shorter diagonal.
  for (const auto& t : vdb_triangles) triangles.push_back({t[2], t[1], t[0]});
  for (const auto& q : vdb_quads) {
    const float d02 = (vertices[q[0]] - vertices[q[2]]).squaredNorm();
    const float d13 = (vertices[q[1]] - vertices[q[3]]).squaredNorm();
    if (d02 <= d13) {
      triangles.push_back({q[2], q[1], q[0]});
      triangles.push_back({q[3], q[2], q[0]});
    } else {
      triangles.push_back({q[3], q[1], q[0]});
      triangles.push_back({q[3], q[2], q[1]});
    }
  }

  clock.lap("polygons");
  // 4. Vertices onto f = 0: one Newton step along the fit's gradient (at most one cell); the
  // vertex normal is the gradient's direction there. The grid holds the fit's own values near the
  // surface, so volumeToMesh's vertex is already close (a second step and an evaluation at the
  // moved vertex left bench_mesh's figures unchanged and cost two thirds of this step's time).
  // Vertices out of the kernel's reach stay.
  std::vector<Eigen::Vector3f> vnormals(vertices.size(), Eigen::Vector3f::Zero());
  // The level set's own side at each vertex (area-weighted face normals): the fit there takes the
  // points of that side, so a vertex of one face of a thin edge is not pulled onto the other's.
  std::vector<Eigen::Vector3f> facing(vertices.size(), Eigen::Vector3f::Zero());
  for (const auto& t : triangles) {
    const Eigen::Vector3f face = (vertices[t[1]] - vertices[t[0]]).cross(vertices[t[2]] - vertices[t[0]]);
    for (const std::uint32_t v : t) facing[v] += face;
  }
  for (auto& n : facing)
    if (n.squaredNorm() > 0) n.normalize();
  // The normal of each vertex's nearest point (zero: no point within trim_gate).
  std::vector<Eigen::Vector3f> point_normal(vertices.size(), Eigen::Vector3f::Zero());
  std::vector<std::uint8_t> two_sided(vertices.size(), 0);
  // The albedo at each vertex (step 7), from the fit's own neighbours.
  std::vector<float> vintensity(with_intensity ? vertices.size() : 0);
  // Past the data's rim the level set is the fit's extrapolation, not surface: a vertex is kept
  // within trim_factor x scale of a point, and up to twice that in a gap between points (the
  // points around it on every side: their centroid within one scale of it along the surface),
  // but not beyond the rim (the points on one side: the centroid more than that away).
  const auto trim_gate = static_cast<float>(options.trim_factor * scale);
  const auto gap_gate = 2 * trim_gate;
  // The vertices in blocks of project_block cells, each block's fits over one tree search (as
  // the voxels'): with the fit's sums in SIMD lanes the search is the larger cost.
  std::vector<std::uint32_t> by_block(vertices.size());
  std::iota(by_block.begin(), by_block.end(), 0u);
  const double block_size = project_block * cell;
  std::vector<std::uint64_t> block_of(vertices.size());
  for (std::size_t i = 0; i < vertices.size(); ++i) block_of[i] = cell_key(vertices[i], block_size);
  std::stable_sort(by_block.begin(), by_block.end(),
                   [&](std::uint32_t a, std::uint32_t b) { return block_of[a] < block_of[b]; });
  std::vector<std::size_t> block_begin;
  for (std::size_t k = 0; k < by_block.size(); ++k)
    if (k == 0 || block_of[by_block[k]] != block_of[by_block[k - 1]]) block_begin.push_back(k);
  block_begin.push_back(by_block.size());
  const double block_half_diagonal = 0.5 * std::sqrt(3.0) * block_size;
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, block_begin.size() - 1, 16), [&](const auto& r) {
    core::interruption_point(interrupt);
    std::vector<Eigen::Vector3d> xs;
    std::vector<Eigen::Vector3f> sides;
    std::vector<Implicit::Value> fits;
    for (std::size_t b = r.begin(); b < r.end(); ++b) {
      xs.clear();
      sides.clear();
      Eigen::Vector3f lo = vertices[by_block[block_begin[b]]], hi = lo;
      for (std::size_t k = block_begin[b]; k < block_begin[b + 1]; ++k) {
        const std::uint32_t i = by_block[k];
        xs.push_back(vertices[i].cast<double>());
        sides.push_back(facing[i]);
        lo = lo.cwiseMin(vertices[i]);
        hi = hi.cwiseMax(vertices[i]);
      }
      const Eigen::Vector3d centre = 0.5 * (lo + hi).cast<double>();
      const double half_diagonal = std::min(block_half_diagonal, 0.5 * (hi - lo).cast<double>().norm() + 1e-6);
      implicit.at_block(centre, half_diagonal, xs, fits, sides, with_intensity ? &intensity : nullptr);
      for (std::size_t k = block_begin[b]; k < block_begin[b + 1]; ++k) {
        const std::uint32_t i = by_block[k];
        const Eigen::Vector3d x0 = xs[k - block_begin[b]];
        Eigen::Vector3d x = x0;
        Eigen::Vector3d n = Eigen::Vector3d::Zero();
        const Implicit::Value& v = fits[k - block_begin[b]];
        two_sided[i] = v.two_sided ? 1 : 0;
        if (with_intensity) vintensity[i] = v.value_mean;
        if (v.weight > 1e-6 && v.normal.norm() >= 1e-3) {
          n = v.normal.normalized();
          const Eigen::Vector3d moved = -v.f * v.normal / v.normal.squaredNorm();
          x = x0 + (moved.norm() > cell ? Eigen::Vector3d(moved * (cell / moved.norm())) : moved);
        }
        vertices[i] = x.cast<float>();
        vnormals[i] = n.cast<float>();
        float d2 = 0;
        const std::int64_t nearest = implicit.tree().nearest(vertices[i], gap_gate, d2);
        if (nearest < 0) continue;
        const Eigen::Vector3f& nearest_normal = normals[static_cast<std::size_t>(nearest)];
        if (d2 > trim_gate * trim_gate) {
          Tree::Centroid around(gap_gate * gap_gate);
          around.points = &points;
          implicit.tree().search(around, vertices[i]);
          const Eigen::Vector3f offset = around.sum / static_cast<float>(around.count) - vertices[i];
          if ((offset - nearest_normal * nearest_normal.dot(offset)).norm() > scale) continue;
        }
        point_normal[i] = nearest_normal;
      }
    }
  });

  clock.lap("project_vertices");
  // 5. Raw: triangles with a vertex away from every point are not surface, nor are triangles
  // facing away from the points at all three corners: past the rim of the data the fit, fed by
  // a few points on one side, curls back (a fold within the trim distance that crosses the
  // surface: the full-resolution sphere's 38 self-intersecting pairs). Watertight keeps the
  // cut and closes the holes it leaves (close_holes), with patches of its own.
  core::interruption_point(interrupt);
  const std::size_t level_set_triangles = triangles.size();
  std::vector<std::array<std::uint32_t, 3>> kept;
  kept.reserve(triangles.size());
  for (const auto& t : triangles) {
    if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) continue;
    const Eigen::Vector3f &n0 = point_normal[t[0]], &n1 = point_normal[t[1]], &n2 = point_normal[t[2]];
    if (n0.isZero() || n1.isZero() || n2.isZero()) continue;
    if (!in_band[t[0]] || !in_band[t[1]] || !in_band[t[2]]) continue;
    const Eigen::Vector3f face = (vertices[t[1]] - vertices[t[0]]).cross(vertices[t[2]] - vertices[t[0]]);
    if (face.dot(n0) < 0 && face.dot(n1) < 0 && face.dot(n2) < 0) continue;
    kept.push_back(t);
  }
  triangles.clear();
  triangles.shrink_to_fit();
  clock.lap("trim");
  {
    // Where a wall or an edge is thinner than about a cell (a blade's trailing edge) the two
    // sides' sheets of the level set can cross: such triangles are not the surface either. Only
    // triangles with a corner that has points of both sides within the kernel can cross (the
    // test on the whole mesh costs ~1.5 us a triangle).
    core::TriangleMesh suspects;
    suspects.vertices = vertices;
    std::vector<std::size_t> suspect_index;
    for (std::size_t i = 0; i < kept.size(); ++i)
      if (two_sided[kept[i][0]] || two_sided[kept[i][1]] || two_sided[kept[i][2]]) {
        suspects.triangles.push_back(kept[i]);
        suspect_index.push_back(i);
      }
    std::vector<std::uint8_t> crossing(kept.size(), 0);
    for (const std::size_t t : self_intersecting_triangles(suspects)) crossing[suspect_index[t]] = 1;
    std::size_t out = 0;
    for (std::size_t i = 0; i < kept.size(); ++i)
      if (!crossing[i]) kept[out++] = kept[i];
    stats.crossing_triangles = kept.size() - out;
    kept.resize(out);
  }
  clock.lap("crossings");
  std::vector<std::uint8_t> no_flags;
  remove_pinches(kept, no_flags, vertices.size());
  result.trimmed_triangles = level_set_triangles - kept.size();
  clock.lap("pinches");
  // Pinholes: where the points are sparse for the cell, a cell of the surface reaches out of the
  // band and is cut (step 3), leaving a hole a few cells across amid the points. Each is closed
  // by a fan around a vertex put on the fit's surface, flagged filled (in raw mode too); a fan
  // that crosses the surface (CGAL, against the faces near it) is taken out again.
  std::vector<std::uint8_t> kept_filled(kept.size(), 0);
  {
    struct Fan {
      std::size_t first = 0, count = 0;
      Eigen::AlignedBox3f box;
    };
    std::vector<Fan> fans;
    const std::size_t measured = kept.size();
    for (const auto& cycle :
         small_border_cycles(kept, vertices, pinhole_max_edges, static_cast<float>(pinhole_max_cells * cell))) {
      // Not at a thin edge: there a fan can cross the other face's sheet (watertight closes it).
      if (std::any_of(cycle.begin(), cycle.end(), [&](std::uint32_t v) { return two_sided[v] != 0; })) continue;
      Fan fan;
      fan.first = kept.size();
      Eigen::Vector3d centre = Eigen::Vector3d::Zero();
      Eigen::Vector3f side = Eigen::Vector3f::Zero();
      for (const std::uint32_t v : cycle) {
        centre += vertices[v].cast<double>();
        side += vnormals[v];
        fan.box.extend(vertices[v]);
      }
      centre /= static_cast<double>(cycle.size());
      if (side.squaredNorm() > 0) side.normalize();
      const auto fit = implicit.at(centre, side);
      Eigen::Vector3f normal = side;
      if (fit.weight > 1e-6 && fit.normal.norm() >= 1e-3) {
        const Eigen::Vector3d moved = -fit.f * fit.normal / fit.normal.squaredNorm();
        if (moved.norm() <= cell) centre += moved;
        normal = fit.normal.normalized().cast<float>();
      }
      const auto c = static_cast<std::uint32_t>(vertices.size());
      vertices.push_back(centre.cast<float>());
      vnormals.push_back(normal);
      if (with_intensity) vintensity.push_back(std::numeric_limits<float>::quiet_NaN());
      fan.box.extend(vertices.back());
      for (std::size_t k = 0; k < cycle.size(); ++k) {
        kept.push_back({cycle[(k + 1) % cycle.size()], cycle[k], c});
        kept_filled.push_back(1);
      }
      fan.count = cycle.size();
      fans.push_back(fan);
    }
    if (!fans.empty()) {
      std::unordered_set<std::uint64_t> near;
      std::vector<std::size_t> fan_of(kept.size() - measured);
      for (std::size_t f = 0; f < fans.size(); ++f) {
        for (std::size_t t = 0; t < fans[f].count; ++t) fan_of[fans[f].first - measured + t] = f;
        // The cells the fan's box touches, and one more around them.
        const Eigen::Vector3f lo = fans[f].box.min(), hi = fans[f].box.max();
        const auto steps = [&](int k) { return static_cast<int>(std::ceil((hi[k] - lo[k]) / cell)) + 1; };
        for (int i = -1; i <= steps(0); ++i)
          for (int j = -1; j <= steps(1); ++j)
            for (int k = -1; k <= steps(2); ++k)
              near.insert(cell_key(lo + Eigen::Vector3f(static_cast<float>(i * cell), static_cast<float>(j * cell),
                                                        static_cast<float>(k * cell)),
                                   cell));
      }
      core::TriangleMesh probe;
      probe.vertices = vertices;
      std::vector<std::size_t> probe_index;
      for (std::size_t i = 0; i < kept.size(); ++i) {
        const auto& t = kept[i];
        if (i < measured && !near.count(cell_key(vertices[t[0]], cell)) &&
            !near.count(cell_key(vertices[t[1]], cell)) && !near.count(cell_key(vertices[t[2]], cell)))
          continue;
        probe.triangles.push_back(t);
        probe_index.push_back(i);
      }
      std::vector<std::uint8_t> crossing_fan(fans.size(), 0);
      for (const std::size_t t : self_intersecting_triangles(probe))
        if (probe_index[t] >= measured) crossing_fan[fan_of[probe_index[t] - measured]] = 1;
      std::size_t out = measured;
      for (std::size_t i = measured; i < kept.size(); ++i)
        if (!crossing_fan[fan_of[i - measured]]) {
          kept[out] = kept[i];
          kept_filled[out++] = 1;
        }
      kept.resize(out);
      kept_filled.resize(out);
      for (const std::uint8_t crossed : crossing_fan)
        if (crossed) {
          ++stats.pinholes_crossing;
        } else {
          ++stats.pinholes_filled;
        }
    }
  }
  clock.lap("pinholes");

  // 6. Pieces (connected through shared vertices) smaller than min_piece_fraction of the largest.
  std::vector<std::uint32_t> parent(vertices.size());
  std::iota(parent.begin(), parent.end(), 0u);
  auto root = [&](std::uint32_t a) {
    while (parent[a] != a) a = parent[a] = parent[parent[a]];
    return a;
  };
  for (const auto& t : kept)
    for (int k = 1; k < 3; ++k) {
      const std::uint32_t a = root(t[0]), b = root(t[static_cast<std::size_t>(k)]);
      if (a != b) parent[std::max(a, b)] = std::min(a, b);
    }
  std::vector<std::size_t> piece_size(vertices.size(), 0);
  for (const auto& t : kept) ++piece_size[root(t[0])];
  const std::size_t largest = kept.empty() ? 0 : *std::max_element(piece_size.begin(), piece_size.end());
  const auto min_size = static_cast<std::size_t>(std::ceil(options.min_piece_fraction * static_cast<double>(largest)));
  std::vector<std::uint32_t> remap(vertices.size(), UINT32_MAX);
  core::TriangleMesh& mesh = result.mesh;
  for (const auto& t : kept) {
    if (piece_size[root(t[0])] < min_size) {
      ++stats.dropped_piece_triangles;
      continue;
    }
    for (const std::uint32_t v : t) remap[v] = 0;
  }
  for (std::size_t i = 0; i < vertices.size(); ++i)
    if (remap[i] == 0) {
      remap[i] = static_cast<std::uint32_t>(mesh.vertices.size());
      mesh.vertices.push_back(vertices[i]);
      mesh.normals.push_back(vnormals[i]);
      if (with_intensity) mesh.intensity.push_back(vintensity[i]);
    }
  for (std::size_t i = 0; i < kept.size(); ++i) {
    const auto& t = kept[i];
    if (piece_size[root(t[0])] < min_size) continue;
    mesh.triangles.push_back({remap[t[0]], remap[t[1]], remap[t[2]]});
    mesh.filled.push_back(kept_filled[i]);
  }
  stats.filled_triangles = static_cast<std::size_t>(std::count(mesh.filled.begin(), mesh.filled.end(), 1));

  clock.lap("pieces");
  core::interruption_point(interrupt);
  if (options.mode == core::MeshMode::watertight && !mesh.triangles.empty()) {
    // Where a patch crossed the measured surface and its hole stayed open (two sheets closer
    // than a patch's triangles are long: a thin edge), the crossed triangles go and the holes
    // left are closed again, the patches that held kept.
    std::size_t raw_holes = 0, faired = 0;
    for (int attempt = 0;; ++attempt) {
      std::vector<std::size_t> crossed;
      close_holes(mesh, options, stats, interrupt, &crossed);
      if (attempt == 0) raw_holes = stats.holes;
      faired += stats.holes_faired;
      if (stats.holes_left_open == 0 || crossed.empty() || attempt == max_reclosures) break;
      stats.crossed_faces_removed += crossed.size();
      std::vector<std::uint8_t> drop(mesh.triangles.size(), 0);
      for (const std::size_t t : crossed) drop[t] = 1;
      std::size_t out = 0;
      for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
        if (!drop[t]) {
          mesh.filled[out] = mesh.filled[t];
          mesh.triangles[out++] = mesh.triangles[t];
        }
      mesh.triangles.resize(out);
      mesh.filled.resize(out);
      remove_pinches(mesh.triangles, mesh.filled, mesh.vertices.size());
    }
    stats.holes = raw_holes;
    stats.holes_faired = faired;
    stats.holes_filled = raw_holes >= stats.holes_left_open ? raw_holes - stats.holes_left_open : 0;
    clock.lap("close_holes");
  }
  if (mesh.triangles.empty())
    throw std::invalid_argument("mesh: no surface left after trimming (" + std::to_string(points.size()) +
                                " points, cell " + std::to_string(cell) + " mm)");
  // 7. The albedo at each vertex: the points' Gaussian-weighted mean over the fit's kernel (for
  // the measured vertices summed in step 4, at the vertex before its Newton step, which moves it
  // microns where the kernel is 0.2-2 mm wide), the nearest point's where none is within its
  // support (deep in a filled patch). Each vertex is one serial sum in the tree's fixed order:
  // deterministic on any thread count.
  if (with_intensity) {
    mesh.intensity.resize(mesh.vertices.size(), std::numeric_limits<float>::quiet_NaN());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, mesh.vertices.size(), 1024), [&](const auto& r) {
      for (std::size_t i = r.begin(); i < r.end(); ++i) {
        if (!std::isnan(mesh.intensity[i])) continue;
        Tree::WeightedMean mean(intensity, sigma);
        implicit.tree().search(mean, mesh.vertices[i]);
        if (mean.weight > 1e-9) {
          mesh.intensity[i] = static_cast<float>(mean.sum / mean.weight);
        } else {
          float d2 = 0;
          const std::int64_t k = implicit.tree().nearest(mesh.vertices[i], 1e18f, d2);
          mesh.intensity[i] = k >= 0 ? intensity[static_cast<std::size_t>(k)] : 0.0f;
        }
      }
    });
  }
  clock.lap("intensity");
  stats.closed = core::mesh_topology(mesh).closed();
  clock.lap("topology");
  stats.mesh_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - scales.start).count();
  return result;
}

}  // namespace

core::MeshResult build_mesh(const core::PointCloud& cloud, const core::MeshOptions& options,
                            const core::InterruptionPoint& interrupt) {
  const auto start = std::chrono::steady_clock::now();
  options.check();
  check_cloud(cloud);
  core::MeshResult result;
  result.mode = options.mode;
  core::MeshStats& stats = result.stats;

  // 1. Spacing, cell, kernel; points without neighbours left out.
  auto all = std::make_unique<Tree>(cloud.points);
  const double spacing = median_spacing(cloud.points, *all);
  if (!(spacing > 0))
    throw std::invalid_argument("mesh: the points have no spacing (all " + std::to_string(cloud.size()) +
                                " at one position)");
  const double cell =
      options.cell_mm > 0 ? options.cell_mm : std::max(options.cell_spacing_factor * spacing, options.min_cell_mm);
  const double scale = std::max(cell, spacing);
  // The kernel follows the data, not the cell: half a cell at least, so that its support
  // (3 sigma) still covers the band of voxels evaluated around the points (1-2 cells).
  const double sigma = options.kernel_factor * std::max(spacing, cell / 2);
  std::vector<Eigen::Vector3f> points, normals;
  const bool with_intensity = cloud.intensity.size() == cloud.size();
  std::vector<float> intensity;  // of the points kept, when the cloud has it
  {
    const auto radius2 = static_cast<float>(9 * sigma * sigma);
    std::vector<std::uint8_t> keep(cloud.size(), 0);
    const auto need = static_cast<std::size_t>(options.min_neighbors) + 1;  // the point itself counts
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, cloud.size(), 1024), [&](const auto& r) {
      core::interruption_point(interrupt);
      for (std::size_t i = r.begin(); i < r.end(); ++i) {
        Tree::Count count(radius2, need);
        all->search(count, cloud.points[i]);
        keep[i] = count.count >= need ? 1 : 0;
      }
    });
    for (std::size_t i = 0; i < cloud.size(); ++i)
      if (keep[i]) {
        points.push_back(cloud.points[i]);
        normals.push_back(cloud.normals[i].normalized());
        if (with_intensity) intensity.push_back(cloud.intensity[i]);
      }
  }
  // The fit's tree: the one above when every point was kept (the same points in the same order).
  std::unique_ptr<Tree> kept_tree = points.size() == cloud.size() ? std::move(all) : std::make_unique<Tree>(points);
  all.reset();
  stats.add_step_ms("spacing",
                    std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
  stats.spacing_mm = spacing;
  stats.points_used = points.size();
  stats.isolated_points = cloud.size() - points.size();
  if (points.size() < 4)
    throw std::invalid_argument("mesh: only " + std::to_string(points.size()) + " of " + std::to_string(cloud.size()) +
                                " points have " + std::to_string(options.min_neighbors) + " neighbours within " +
                                std::to_string(3 * sigma) + " mm: no surface");
  core::interruption_point(interrupt);
  const LevelSetScale scales{cell, scale, sigma, start};
  if (!with_intensity) intensity.clear();
  result.cell_mm = cell;
  core::MeshResult separated =
      level_set_mesh(points, normals, *kept_tree, intensity, scales, side_agreement_cosine, result, options, interrupt);
  // 8. Fewer triangles, when asked for (simplify.cpp), on the mesh chosen.
  const auto simplified = [&](core::MeshResult chosen) {
    chosen.stats.triangles_before_simplify = chosen.mesh.triangles.size();
    if (options.max_triangles > 0 || options.simplify_tolerance_mm > 0) {
      const auto begin = std::chrono::steady_clock::now();
      simplify_mesh(chosen.mesh, options, chosen.stats, interrupt);
      if (chosen.stats.simplified) chosen.stats.closed = core::mesh_topology(chosen.mesh).closed();
      const auto end = std::chrono::steady_clock::now();
      chosen.stats.add_step_ms("simplify", std::chrono::duration<double, std::milli>(end - begin).count());
      chosen.stats.mesh_ms = std::chrono::duration<double, std::milli>(end - start).count();
    }
    return chosen;
  };
  if (options.mode != core::MeshMode::watertight || separated.stats.holes_left_open == 0)
    return simplified(std::move(separated));
  // A thin edge's patches crossed the surface and a hole stayed open: the surface of the fit
  // over both sides (closed where the separated one was not, less faithful at thin edges).
  core::MeshResult mixed =
      level_set_mesh(points, normals, *kept_tree, intensity, scales, -2.f, result, options, interrupt);
  core::MeshResult& chosen = mixed.stats.holes_left_open < separated.stats.holes_left_open ? mixed : separated;
  const core::MeshResult& other = &chosen == &mixed ? separated : mixed;
  for (std::size_t k = stats.step_ms.size(); k < other.stats.step_ms.size(); ++k)
    chosen.stats.add_step_ms(other.stats.step_ms[k].first, other.stats.step_ms[k].second);
  chosen.stats.mesh_ms = mixed.stats.mesh_ms;
  return simplified(std::move(chosen));
}

}  // namespace slscan::mesh
