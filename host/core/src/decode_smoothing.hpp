// The decoder's smoothing pass over rows of the unwrapped coordinate, compiled once per SIMD
// target and dispatched at run time by Google Highway (as decode_rows.hpp); every target gives
// the same bits (tests/host/test_simd_dispatch.cpp).
#pragma once

namespace slscan::core::detail {

struct SmoothRowsInput {
  const float* raw = nullptr;      // the coordinate before smoothing, width * height (NaN: masked)
  const float* quality = nullptr;  // the modulation, same size
  float* smoothed = nullptr;       // the result, same size
  int width = 0, height = 0;
  int radius = 0;            // DecodeOptions::smoothing_radius (1 or 2)
  int quadratic_radius = 0;  // DecodeOptions::quadratic_radius (0: off)
  float max_deviation = 0;   // px: the gate, from the view's noise
};

// Smooths rows [row_begin, row_end) with the best target the CPU runs.
void smooth_rows(const SmoothRowsInput& input, int row_begin, int row_end);

}  // namespace slscan::core::detail
