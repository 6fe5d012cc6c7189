// The decoder's per-pixel pass over rows of stored frames, compiled once per SIMD target
// (SSE2 ... AVX-512 on x86, NEON / SVE on Arm) and dispatched at run time by Google Highway:
// a generic build (a Debian package) runs the widest vectors the CPU has. Every target gives
// the same bits (no contraction into FMA in these files: CMakeLists.txt); tested in
// tests/host/test_simd_dispatch.cpp.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>

#include "slscan/core/decode.hpp"

namespace slscan::core::detail {

// What the pass reads, from a ProjectorViewDecoder; pattern indices into the plan, -1 absent.
struct DecodeRowsInput {
  const void* planes = nullptr;  // one plane per pattern, width * height pixels of 1 or 2 bytes
  int width = 0, height = 0;
  int white = -1, black = -1, complementary = -1, complementary_inverse = -1;
  std::span<const int> gray, gray_inverse, phase, code_frames;
  std::span<const float> phase_sin, phase_cos;
  float clip_level = 0;  // a float: the full scale (2^bit_depth, "never") does not fit a pixel
  float min_contrast = 0, min_modulation = 0;
  float inverse_full_scale = 0;
  // From the plan's configuration.
  float period_px = 0, coded_extent = 0;
  bool slstudio_parity = false;
};

// Where it writes: whole-view buffers, width * height each.
struct DecodeRowsOutput {
  float* coordinate = nullptr;
  float* quality = nullptr;
  float* intensity = nullptr;
  DecodeMask* mask = nullptr;
};

// Decodes rows [row_begin, row_end) with the best target the CPU runs, adding to `counts`
// (valid, masks by reason, clipped by frame kind).
void decode_rows_8bit(const DecodeRowsInput& in, int row_begin, int row_end, const DecodeRowsOutput& out,
                      DecodeCounts& counts);
void decode_rows_16bit(const DecodeRowsInput& in, int row_begin, int row_end, const DecodeRowsOutput& out,
                       DecodeCounts& counts);

}  // namespace slscan::core::detail
