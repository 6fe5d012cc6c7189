// The nearest-within-a-gate tree against brute force, query by query: a scan-like surface with
// outliers, a flat sheet, a line, heaps of duplicates, tiny and empty clouds, queries on, near,
// between and far from the cloud, gates from tight to unbounded; and search(), the mesher's
// visitor over the points within a radius, against brute force too.
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <stdexcept>
#include <vector>

#include "slscan/core/detail/nearest_tree.hpp"

namespace {

using Points = std::vector<Eigen::Vector3f>;
using slscan::core::detail::NearestTree;

Points bumpy_sphere(std::size_t n, double radius, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g(0, 1);
  std::uniform_real_distribution<double> box(-1.3 * radius, 1.3 * radius);
  Points points;
  while (points.size() < n) {
    const Eigen::Vector3d d = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
    points.push_back((d * radius * (1 + 0.1 * d.x() * d.y()) + 0.01 * d * g(rng)).cast<float>());
  }
  for (std::size_t i = 0; i < n / 200; ++i)
    points[i * 197 % n] = Eigen::Vector3d(box(rng), box(rng), box(rng)).cast<float>();
  return points;
}

// Queries: cloud points themselves, points moved by up to `jitter`, and points anywhere in a
// box twice the cloud's size.
Points queries_for(const Points& points, float jitter, std::size_t n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  Eigen::Vector3f lo = points.empty() ? Eigen::Vector3f::Zero() : points[0], hi = lo;
  for (const auto& p : points) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  const Eigen::Vector3f centre = (lo + hi) / 2, half = (hi - lo).cwiseMax(Eigen::Vector3f::Constant(1));
  std::uniform_real_distribution<float> u(-1, 1);
  Points queries;
  for (std::size_t i = 0; i < n; ++i) {
    const Eigen::Vector3f r(u(rng), u(rng), u(rng));
    if (points.empty() || i % 3 == 2)
      queries.push_back(centre + r.cwiseProduct(half));
    else if (i % 3 == 0)
      queries.push_back(points[i * 7919 % points.size()]);
    else
      queries.push_back(points[i * 104729 % points.size()] + jitter * r);
  }
  return queries;
}

// The tree's answer to every query is brute force's: the same squared distance to the last bit,
// and the index it names lies at that distance (among equally near points any one will do).
void expect_brute_force_answers(const Points& points, const Points& queries, float gate) {
  const NearestTree tree(points);
  ASSERT_EQ(tree.size(), points.size());
  for (std::size_t q = 0; q < queries.size(); ++q) {
    const Eigen::Vector3f& x = queries[q];
    float best = gate * gate;
    std::int64_t best_index = -1;
    for (std::size_t i = 0; i < points.size(); ++i) {
      const float dx = points[i].x() - x.x(), dy = points[i].y() - x.y(), dz = points[i].z() - x.z();
      const float d = dx * dx + dy * dy + dz * dz;
      if (d < best) {
        best = d;
        best_index = static_cast<std::int64_t>(i);
      }
    }
    float d2 = -1;
    const std::int64_t found = tree.nearest_within(x, gate, d2);
    ASSERT_EQ(found < 0, best_index < 0) << "query " << q << " gate " << gate;
    if (found < 0) continue;
    ASSERT_EQ(d2, best) << "query " << q << " gate " << gate;
    const Eigen::Vector3f& p = points[static_cast<std::size_t>(found)];
    const float dx = p.x() - x.x(), dy = p.y() - x.y(), dz = p.z() - x.z();
    ASSERT_EQ(dx * dx + dy * dy + dz * dz, best) << "query " << q << ": index " << found << " is not at that distance";
  }
}

TEST(NearestTree, AScanLikeSurfaceWithOutliersAnswersAsBruteForce) {
  const Points points = bumpy_sphere(40000, 20, 1);
  const Points queries = queries_for(points, 0.5f, 3000, 2);
  for (float gate : {0.05f, 0.5f, 2.0f, std::numeric_limits<float>::infinity()})
    expect_brute_force_answers(points, queries, gate);
}

TEST(NearestTree, DegenerateCloudsAnswerAsBruteForce) {
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<float> u(0, 1);
  Points sheet, line, heaps;
  for (int i = 0; i < 5000; ++i) sheet.emplace_back(10 * u(rng), 10 * u(rng), 2.0f);
  for (int i = 0; i < 3000; ++i) line.emplace_back(0.5f, 50 * u(rng), -1.0f);
  // 40 points each at 60 places, and a run along one coordinate: every split lands on ties.
  for (int heap = 0; heap < 60; ++heap) {
    const int column = heap % 4, row = heap / 4;
    for (int i = 0; i < 40; ++i) heaps.emplace_back(static_cast<float>(column), static_cast<float>(row), 0.0f);
  }
  for (int i = 0; i < 500; ++i) heaps.emplace_back(1.0f, 1.0f, static_cast<float>(i % 3));
  for (const Points* cloud : {&sheet, &line, &heaps})
    for (float gate : {0.1f, 1.0f, 100.0f})
      expect_brute_force_answers(*cloud, queries_for(*cloud, 0.3f, 1500, 4), gate);
}

TEST(NearestTree, TinyAndEmptyCloudsAnswerAsBruteForce) {
  for (std::size_t n : {0, 1, 2, 11, 12, 13, 25, 100}) {
    const Points points = bumpy_sphere(n, 5, 5 + n);
    expect_brute_force_answers(points, queries_for(points, 1.0f, 300, 6), 3.0f);
  }
  const NearestTree empty(Points{});
  float d2 = 0;
  EXPECT_EQ(empty.nearest_within(Eigen::Vector3f::Zero(), 1.0f, d2), -1);
}

TEST(NearestTree, AQueryOutsideTheGateOrNotFiniteFindsNothing) {
  const Points points = bumpy_sphere(5000, 10, 7);
  const NearestTree tree(points);
  float d2 = 0;
  EXPECT_EQ(tree.nearest_within(Eigen::Vector3f(1000, 0, 0), 5.0f, d2), -1);
  EXPECT_EQ(tree.nearest_within(Eigen::Vector3f(std::nanf(""), 0, 0), 5.0f, d2), -1);
  EXPECT_EQ(tree.nearest_within(points[10], 0.0f, d2), -1);
  // A point of the cloud is its own nearest at distance 0.
  EXPECT_EQ(tree.nearest_within(points[10], 1.0f, d2), 10);
  EXPECT_EQ(d2, 0.0f);
}

TEST(NearestTree, ANonFinitePointIsRefusedByPosition) {
  Points points = bumpy_sphere(100, 10, 8);
  points[42].y() = std::numeric_limits<float>::infinity();
  try {
    const NearestTree tree(points);
    FAIL() << "accepted a cloud with an infinite point";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("point 42 of 100"), std::string::npos) << e.what();
  }
}

// The halves of a large node are built on two threads: the tree, and so every answer, must not
// depend on it.
TEST(NearestTree, AnswersAreTheSameOnOneAndTwoThreads) {
  Points points = bumpy_sphere(200000, 40, 9);
  // Duplicates: which of two equally near points is named depends on the tree's order.
  for (std::size_t i = 0; i < 20000; ++i) points[i + 100000] = points[i];
  const Points queries = queries_for(points, 0.2f, 20000, 10);
  auto answers = [&](int threads) {
    const tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
    const NearestTree tree(points);
    std::vector<std::int64_t> found;
    for (const auto& q : queries) {
      float d2 = 0;
      found.push_back(tree.nearest_within(q, 1.0f, d2));
    }
    return found;
  };
  const auto one = answers(1);
  EXPECT_EQ(one, answers(2));
  std::size_t hits = 0;
  for (auto f : one) hits += f >= 0 ? 1 : 0;
  EXPECT_GT(hits, queries.size() / 2);
}

// A result set as the mesher's: every point strictly within a fixed radius.
struct WithinRadius {
  float radius2;
  std::vector<std::pair<std::uint32_t, float>> found;
  bool addPoint(float d2, std::uint32_t i) {
    found.emplace_back(i, d2);
    return true;
  }
  float worstDist() const { return radius2; }
};

// search() gives each point strictly within the radius once, with its distance to the last bit.
TEST(NearestTreeSearch, GivesEveryPointWithinTheRadiusOnce) {
  Points points = bumpy_sphere(30000, 20, 11);
  for (std::size_t i = 0; i < 500; ++i) points[i + 20000] = points[i];  // duplicates
  const NearestTree tree(points);
  const Points queries = queries_for(points, 0.5f, 600, 12);
  std::size_t total = 0;
  for (float radius : {0.05f, 0.8f, 3.0f}) {
    for (std::size_t q = 0; q < queries.size(); ++q) {
      const Eigen::Vector3f& x = queries[q];
      std::vector<std::pair<std::uint32_t, float>> expected;
      for (std::size_t i = 0; i < points.size(); ++i) {
        const float dx = points[i].x() - x.x(), dy = points[i].y() - x.y(), dz = points[i].z() - x.z();
        const float d = dx * dx + dy * dy + dz * dz;
        if (d < radius * radius) expected.emplace_back(static_cast<std::uint32_t>(i), d);
      }
      WithinRadius result{radius * radius, {}};
      tree.search(result, x);
      std::sort(result.found.begin(), result.found.end());
      ASSERT_EQ(result.found, expected) << "query " << q << " radius " << radius;
      total += expected.size();
    }
  }
  EXPECT_GT(total, 10000u);  // the radii reach many points, not none
}

// A k-nearest search as the mesher's nearest-two: worstDist() shrinks as points are added, and
// no point nearer than the k-th nearest may be pruned on the way.
TEST(NearestTreeSearch, AShrinkingRadiusFindsTheKNearest) {
  struct KNearest {
    std::vector<float> sorted;  // the k smallest squared distances so far, ascending
    std::size_t k;
    bool addPoint(float dist, std::uint32_t) {
      sorted.insert(std::upper_bound(sorted.begin(), sorted.end(), dist), dist);
      if (sorted.size() > k) sorted.resize(k);
      return true;
    }
    float worstDist() const { return sorted.size() < k ? std::numeric_limits<float>::max() : sorted[k - 1]; }
  };
  const Points points = bumpy_sphere(20000, 15, 13);
  const NearestTree tree(points);
  for (const std::size_t k : {1, 2, 7}) {
    for (const auto& x : queries_for(points, 0.3f, 300, 14 + k)) {
      std::vector<float> all;
      for (const auto& p : points) {
        const float dx = p.x() - x.x(), dy = p.y() - x.y(), dz = p.z() - x.z();
        all.push_back(dx * dx + dy * dy + dz * dz);
      }
      std::sort(all.begin(), all.end());
      all.resize(k);
      KNearest result{{}, k};
      tree.search(result, x);
      ASSERT_EQ(result.sorted, all) << "k " << k;
    }
  }
}

// addPoint() returning false stops the search: a count that needs only k points sees exactly k.
TEST(NearestTreeSearch, StopsWhenTheResultSetIsFull) {
  struct FirstK {
    std::size_t k, seen = 0;
    bool addPoint(float, std::uint32_t) { return ++seen < k; }
    float worstDist() const { return 4.0f; }
  };
  const Points points = bumpy_sphere(20000, 10, 15);
  const NearestTree tree(points);
  FirstK first{5};
  tree.search(first, points[3]);
  EXPECT_EQ(first.seen, 5u);
  // Empty clouds and non-finite queries visit nothing.
  FirstK none{5};
  NearestTree(Points{}).search(none, Eigen::Vector3f::Zero());
  tree.search(none, Eigen::Vector3f(0, std::nanf(""), 0));
  EXPECT_EQ(none.seen, 0u);
}

}  // namespace
