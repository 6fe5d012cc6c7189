// Core's mesh helpers: the topology check and the mode names (the mesher is tested in
// test_mesher.cpp).
#include <gtest/gtest.h>

#include <string>

#include "slscan/core/mesh.hpp"

namespace {

TEST(MeshTopology, CountsOpenAndFlippedEdges) {
  slscan::core::TriangleMesh mesh;
  mesh.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}};
  mesh.triangles = {{0, 1, 2}, {1, 3, 2}};
  auto topo = slscan::core::mesh_topology(mesh);
  EXPECT_EQ(topo.edges, 5u);
  EXPECT_EQ(topo.boundary_edges, 4u);
  EXPECT_EQ(topo.inconsistent_edges, 0u);
  mesh.triangles[1] = {1, 2, 3};
  topo = slscan::core::mesh_topology(mesh);
  EXPECT_EQ(topo.inconsistent_edges, 1u);
  EXPECT_FALSE(topo.closed());
}

TEST(MeshTopology, ClosedTetrahedronAndAFinOnOneEdge) {
  slscan::core::TriangleMesh mesh;
  mesh.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 1, 1}};
  mesh.triangles = {{0, 2, 1}, {0, 1, 3}, {1, 2, 3}, {0, 3, 2}};
  auto topo = slscan::core::mesh_topology(mesh);
  EXPECT_EQ(topo.edges, 6u);
  EXPECT_EQ(topo.boundary_edges, 0u);
  EXPECT_EQ(topo.non_manifold_edges, 0u);
  EXPECT_EQ(topo.inconsistent_edges, 0u);
  EXPECT_TRUE(topo.closed());
  // A fin on edge 1-3: that edge has three triangles, the fin's other two edges are open.
  mesh.triangles.push_back({1, 4, 3});
  topo = slscan::core::mesh_topology(mesh);
  EXPECT_EQ(topo.edges, 8u);
  EXPECT_EQ(topo.non_manifold_edges, 1u);
  EXPECT_EQ(topo.boundary_edges, 2u);
  EXPECT_FALSE(topo.closed());
}

TEST(MeshMode, NamesRoundTripAndUnknownNamesAreRefused) {
  for (const auto mode : {slscan::core::MeshMode::raw, slscan::core::MeshMode::watertight}) {
    slscan::core::MeshMode parsed =
        mode == slscan::core::MeshMode::raw ? slscan::core::MeshMode::watertight : slscan::core::MeshMode::raw;
    ASSERT_TRUE(slscan::core::parse_mesh_mode(slscan::core::mesh_mode_name(mode), parsed));
    EXPECT_EQ(parsed, mode);
  }
  slscan::core::MeshMode mode = slscan::core::MeshMode::raw;
  EXPECT_FALSE(slscan::core::parse_mesh_mode("Watertight", mode));
  EXPECT_FALSE(slscan::core::parse_mesh_mode("", mode));
  EXPECT_EQ(mode, slscan::core::MeshMode::raw);
}

}  // namespace
