// The triangulator's per-pixel solve over a tile of a row, compiled once per SIMD target and
// dispatched at run time by Google Highway (as decode_rows.hpp); every target gives the same
// bits (tests/host/test_simd_dispatch.cpp).
#pragma once

#include <Eigen/Core>
#include <cstdint>

#include "slscan/core/triangulate.hpp"

namespace slscan::core::detail {

// Pixels per tile: the tile's per-pixel doubles (12 arrays, 24 KB) stay in L1.
constexpr int kTilePixels = 256;

// n (<= kTilePixels) consecutive pixels: rays and decoded coordinates in, points, quality,
// validity and each pixel's outcome (for the counts) out.
struct TriangulateTileIo {
  int n = 0;
  const float* ray_x = nullptr;
  const float* ray_y = nullptr;
  const float* coord = nullptr;
  const float* quality_in = nullptr;
  Eigen::Vector3f* points = nullptr;
  float* quality_out = nullptr;
  std::uint8_t* valid = nullptr;
  TriangulateOutcome* outcome = nullptr;
};

// `columns`: the projector codes its columns (else its rows).
void solve_tile(const TriangulateTileParams& params, bool columns, const TriangulateTileIo& io);

}  // namespace slscan::core::detail
