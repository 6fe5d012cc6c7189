// Final-cleanup and registration timings on synthetic scanner-like clouds: a lumpy closed
// surface sampled at ~0.1 mm spacing with 10 um noise (what a fused scan looks like), 1M and
// 3M points. The same operations and parameters as the PCL / Open3D figures in
// /work/shared/notes/performance.md (SOR k=20, radius removal, voxel 0.1 mm, normals k=20,
// point-to-plane ICP 100k -> 1M and 1M -> 1M).
#include <benchmark/benchmark.h>

#include <Eigen/Geometry>
#include <cmath>
#include <map>
#include <memory>
#include <nanoflann.hpp>
#include <random>

#include "cloud_filters_kdtree.hpp"
#include "slscan/core/cloud_filters.hpp"
#include "slscan/core/normals.hpp"
#include "slscan/core/point_index.hpp"
#include "slscan/core/registration.hpp"

namespace {

using slscan::core::PointCloud;

// Area grows with the count so the spacing stays ~0.1 mm, as in a real scan.
PointCloud make_surface(std::size_t n, std::uint64_t seed) {
  const double radius = std::sqrt(static_cast<double>(n) * 0.01 / (4 * M_PI));
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g(0, 1);
  PointCloud cloud;
  cloud.points.reserve(n);
  while (cloud.size() < n) {
    const Eigen::Vector3d d = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
    const double r = radius * (1 + 0.1 * d.x() * d.y() + 0.08 * std::sin(3 * d.z())) + 0.01 * g(rng);
    cloud.points.push_back((d * r + Eigen::Vector3d(0, 0, radius)).cast<float>());
  }
  // 0.5 % outliers, as left by fusion.
  std::uniform_real_distribution<double> box(-1.3 * radius, 1.3 * radius);
  for (std::size_t i = 0; i < n / 200; ++i)
    cloud.points[i * 197 % n] = Eigen::Vector3d(box(rng), box(rng), box(rng) + radius).cast<float>();
  cloud.confidence.assign(n, 1.0f);
  cloud.view_id.assign(n, 0);
  return cloud;
}

const PointCloud& surface(std::size_t n) {
  static std::map<std::size_t, PointCloud> cache;
  auto it = cache.find(n);
  if (it == cache.end()) it = cache.emplace(n, make_surface(n, n)).first;
  return it->second;
}

const PointCloud& surface_with_normals(std::size_t n) {
  static std::map<std::size_t, PointCloud> cache;
  auto it = cache.find(n);
  if (it == cache.end()) {
    PointCloud c = surface(n);
    c.normals = slscan::core::pca_normals(c, {});
    it = cache.emplace(n, std::move(c)).first;
  }
  return it->second;
}

// Google Benchmark's `for (auto _ : state)` leaves `_` unread by design.
// NOLINTBEGIN(clang-analyzer-deadcode.DeadStores)
void BM_StatisticalOutlierRemoval(benchmark::State& state) {
  const auto& cloud = surface(static_cast<std::size_t>(state.range(0)));
  std::size_t removed = 0;
  for (auto _ : state) removed = slscan::core::statistical_outlier_removal(cloud, {20, 1.0}).removed;
  state.counters["removed"] = static_cast<double>(removed);
}

void BM_RadiusOutlierRemoval(benchmark::State& state) {
  const auto& cloud = surface(static_cast<std::size_t>(state.range(0)));
  std::size_t removed = 0;
  for (auto _ : state) removed = slscan::core::radius_outlier_removal(cloud, {0.5, 5}).removed;
  state.counters["removed"] = static_cast<double>(removed);
}

void BM_VoxelDownsample(benchmark::State& state) {
  const auto& cloud = surface(static_cast<std::size_t>(state.range(0)));
  std::size_t kept = 0;
  for (auto _ : state) kept = slscan::core::voxel_downsample(cloud, 0.1).size();
  state.counters["kept"] = static_cast<double>(kept);
}

void BM_PcaNormals(benchmark::State& state) {
  const auto& cloud = surface(static_cast<std::size_t>(state.range(0)));
  for (auto _ : state) benchmark::DoNotOptimize(slscan::core::pca_normals(cloud, {}));
}

// The nearest point within a gate, as ICP asks it: our tree (PointIndex) against nanoflann's
// (slscan's own wrapper, as ICP used it before), built on the same 1M points, then 100k queries
// (every 10th point moved by 0.52 mm, 2 mm gate) on one thread. Ours builds on two threads;
// nanoflann 1.4 on one.
using slscan::core::detail::KdTree;

std::vector<Eigen::Vector3f> gated_queries(const std::vector<Eigen::Vector3f>& points) {
  std::vector<Eigen::Vector3f> queries;
  for (std::size_t i = 0; i < points.size(); i += 10) queries.push_back(points[i] + Eigen::Vector3f(0.3f, -0.3f, 0.3f));
  return queries;
}

void BM_NearestTreeBuild(benchmark::State& state) {
  const auto& points = surface(static_cast<std::size_t>(state.range(0))).points;
  for (auto _ : state) benchmark::DoNotOptimize(slscan::core::PointIndex(points).size());
}

void BM_NanoflannBuild(benchmark::State& state) {
  const auto& points = surface(static_cast<std::size_t>(state.range(0))).points;
  for (auto _ : state) benchmark::DoNotOptimize(KdTree(points).size());
}

// 100k gated queries against either index (both answer nearest_within).
template <class Index>
void time_gated_queries(benchmark::State& state, const Index& index, const std::vector<Eigen::Vector3f>& points) {
  const auto queries = gated_queries(points);
  std::size_t found = 0;
  for (auto _ : state) {
    found = 0;
    for (const auto& q : queries) {
      float d2 = 0;
      found += index.nearest_within(q, 2.0f, d2) >= 0 ? 1 : 0;
    }
  }
  state.counters["found"] = static_cast<double>(found);
}

void BM_NearestTreeQueries(benchmark::State& state) {
  const auto& points = surface(static_cast<std::size_t>(state.range(0))).points;
  time_gated_queries(state, slscan::core::PointIndex(points), points);
}

void BM_NanoflannQueries(benchmark::State& state) {
  const auto& points = surface(static_cast<std::size_t>(state.range(0))).points;
  time_gated_queries(state, KdTree(points), points);
}

// ICP: the target itself, the source a random subset moved by 0.5 deg / 0.5 mm.
void BM_IcpPointToPlane(benchmark::State& state) {
  const auto& target = surface_with_normals(1000000);
  const auto source_count = static_cast<std::size_t>(state.range(0));
  Eigen::Isometry3d motion = Eigen::Isometry3d::Identity();
  motion.linear() = Eigen::AngleAxisd(0.5 * M_PI / 180, Eigen::Vector3d(0.2, 1, 0.3).normalized()).toRotationMatrix();
  motion.translation() = Eigen::Vector3d(0.3, -0.3, 0.3);
  PointCloud source = slscan::core::transform_cloud(target, motion.inverse());
  slscan::core::IcpOptions options;
  options.source_points_per_view = source_count;
  double error_deg = 0, error_mm = 0;
  int iterations = 0;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& p : target.points) centroid += p.cast<double>() / static_cast<double>(target.size());
  for (auto _ : state) {
    const auto result = slscan::core::icp_point_to_plane(source, target, Eigen::Isometry3d::Identity(), options);
    // Residual motion after ICP: its angle, and how far it moves the cloud's centroid.
    const Eigen::Isometry3d err = result.target_from_source * motion.inverse();
    error_deg = slscan::core::rotation_angle_deg(err);
    error_mm = (err * centroid - centroid).norm();
    iterations = result.iterations;
  }
  state.counters["err_deg"] = error_deg;
  state.counters["err_mm"] = error_mm;
  state.counters["iterations"] = iterations;
}

// NOLINTEND(clang-analyzer-deadcode.DeadStores)

BENCHMARK(BM_StatisticalOutlierRemoval)->Arg(1000000)->Arg(3000000)->Unit(benchmark::kMillisecond)->Iterations(2);
BENCHMARK(BM_RadiusOutlierRemoval)->Arg(1000000)->Arg(3000000)->Unit(benchmark::kMillisecond)->Iterations(2);
BENCHMARK(BM_VoxelDownsample)->Arg(1000000)->Arg(3000000)->Unit(benchmark::kMillisecond)->Iterations(2);
BENCHMARK(BM_PcaNormals)->Arg(1000000)->Arg(3000000)->Unit(benchmark::kMillisecond)->Iterations(2);
BENCHMARK(BM_NearestTreeBuild)->Arg(1000000)->Unit(benchmark::kMillisecond)->Iterations(3);
BENCHMARK(BM_NanoflannBuild)->Arg(1000000)->Unit(benchmark::kMillisecond)->Iterations(3);
BENCHMARK(BM_NearestTreeQueries)->Arg(1000000)->Unit(benchmark::kMillisecond)->Iterations(3);
BENCHMARK(BM_NanoflannQueries)->Arg(1000000)->Unit(benchmark::kMillisecond)->Iterations(3);
BENCHMARK(BM_IcpPointToPlane)->Arg(100000)->Arg(1000000)->Unit(benchmark::kMillisecond)->Iterations(1);

}  // namespace

BENCHMARK_MAIN();
