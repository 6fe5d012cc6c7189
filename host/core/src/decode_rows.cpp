// The decoder's per-pixel pass, once per SIMD target: Highway's foreach_target.h includes this
// file again for each target it compiles (HWY_TARGET_INCLUDE) inside that target's namespace
// and attributes; HWY_DYNAMIC_DISPATCH picks the CPU's best at the first call. The loops are
// the plain C++ the compiler vectorises for each target (see decode_rows.hpp).
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "decode_rows.cpp"
#include "decode_rows.hpp"

#include <hwy/foreach_target.h>  // IWYU pragma: keep
#include <hwy/highway.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <numbers>

#include "slproto/pattern_plan.hpp"
#include "slscan/core/decode_math.hpp"

HWY_BEFORE_NAMESPACE();
namespace slscan::core::detail {
namespace HWY_NAMESPACE {
namespace {

// Columns per tile: a tile's sums (a few floats per pixel) stay in L1 while the 19 planes'
// rows stream through once.
constexpr int kTileColumns = 512;

// The per-pixel arithmetic of one tile, after the plane passes have left the sums. Written
// as straight-line selects so the compiler vectorises it; kPhase / kComplementary select the
// plan's shape at compile time instead of testing it per pixel.
struct TileSums {
  alignas(64) float threshold2[kTileColumns];
  alignas(64) float contrast[kTileColumns];
  alignas(64) float sum_sin[kTileColumns];
  alignas(64) float sum_cos[kTileColumns];
  alignas(64) float sum[kTileColumns];
  alignas(64) std::uint32_t code[kTileColumns];
  alignas(64) float second_contrast[kTileColumns];  // with inverse Gray frames only
  alignas(64) float corrupt[kTileColumns];          // 1 where a clipped frame corrupts the pixel's code
  // The per-pixel results before masking; the reason is a DecodeMask as a float so that the
  // arithmetic loop has one element width (GCC 12 then vectorises it).
  alignas(64) float value[kTileColumns];
  alignas(64) float q[kTileColumns];
  alignas(64) float reason[kTileColumns];
};

struct TileConstants {
  float period, extent_max, min_contrast, min_modulation, modulation_scale;
  // Gray code alone: step h covers pixels [h step, (h + 1) step - 1] and decodes to
  // h step + low_offset + (h & 1) parity_offset (the centre, or SLStudio's pixel of the step).
  float step, low_offset, parity_offset;
  // Phase without the complementary bit: a phase at or above this (2 pi (1 - 0.5 / P)) belongs
  // to the previous Gray order.
  float late_phase;
};

template <bool kPhase, bool kComplementary>
void finish_tile(int n, TileSums& t, const TileConstants& k, float* __restrict coordinate, float* __restrict quality,
                 DecodeMask* __restrict mask) {
  constexpr float kTwoPi = 2.0f * std::numbers::pi_v<float>;
  constexpr float kHalfPi = 0.5f * std::numbers::pi_v<float>;
  constexpr float kThreeHalfPi = 1.5f * std::numbers::pi_v<float>;
  // Reasons as floats: GCC 12 if-converts selects whose condition and values have one width.
  constexpr auto kValid = static_cast<float>(DecodeMask::valid);
  constexpr auto kSaturated = static_cast<float>(DecodeMask::saturated);
  constexpr auto kLowContrast = static_cast<float>(DecodeMask::low_contrast);
  constexpr auto kLowModulation = static_cast<float>(DecodeMask::low_modulation);
  constexpr auto kOutOfRange = static_cast<float>(DecodeMask::out_of_range);
  float* __restrict reason = t.reason;
  float* __restrict value = t.value;
  float* __restrict q_out = t.q;
  const float* __restrict corrupt = t.corrupt;
  for (int x = 0; x < n; ++x) reason[x] = corrupt[x] != 0.0f ? kSaturated : kValid;
  for (int x = 0; x < n; ++x) {
    const std::uint32_t h = slproto::gray_to_binary(t.code[x]);
    const float contrast = t.contrast[x];
    float coord;
    float q;
    if constexpr (kPhase) {
      const float s = t.sum_sin[x], c = t.sum_cos[x];
      const float phi = atan2_0_2pi(-s, c);
      float order;
      if constexpr (kComplementary) {
        const auto k1 = static_cast<float>(static_cast<int>(h >> 1));
        const auto k2 = static_cast<float>(static_cast<int>((h + 1) >> 1));
        // K2 where phi < pi/2, K2 - 1 where phi >= 3 pi/2, else k (flat selects: GCC does
        // not if-convert nested ones). Exact in float: orders are far below 2^24.
        order = k1;
        order = phi >= kThreeHalfPi ? k2 - 1.0f : order;
        order = phi < kHalfPi ? k2 : order;
      } else {
        // Gray order h covers pixels [h P - 0.5, (h + 1) P - 0.5) but the phase wraps at h P:
        // over the half pixel before the wrap the phase is already near 2 pi, one order late.
        order = static_cast<float>(static_cast<int>(h));
        order = phi >= k.late_phase ? order - 1.0f : order;
      }
      coord = (phi / kTwoPi + order) * k.period;
      q = k.modulation_scale * std::sqrt(s * s + c * c);
    } else {
      // Gray code alone (h counts half periods with the complementary bit): one formula for
      // both conventions, so the convention costs no test per pixel.
      coord = static_cast<float>(h) * k.step + k.low_offset + static_cast<float>(h & 1u) * k.parity_offset;
      q = contrast;
    }
    // The first reason that applies: selects from the last reason to the first.
    const float saturated = reason[x];
    float m = ((coord >= -0.5f) & (coord <= k.extent_max)) ? kValid : kOutOfRange;
    if constexpr (kPhase) m = q >= k.min_modulation ? m : kLowModulation;
    m = contrast >= k.min_contrast ? m : kLowContrast;
    m = saturated != kValid ? kSaturated : m;
    reason[x] = m;
    value[x] = coord;
    q_out[x] = q;
  }
  // Masked pixels get NaN / 0 by masking the bits (the select form is not if-converted).
  const std::uint32_t nan_bits = 0x7fc00000u;
  for (int x = 0; x < n; ++x) {
    const std::uint32_t keep = 0u - static_cast<std::uint32_t>(reason[x] == kValid);
    std::uint32_t v, q;
    std::memcpy(&v, &value[x], sizeof v);
    std::memcpy(&q, &q_out[x], sizeof q);
    v = (v & keep) | (nan_bits & ~keep);
    q &= keep;
    std::memcpy(&coordinate[x], &v, sizeof v);
    std::memcpy(&quality[x], &q, sizeof q);
  }
  for (int x = 0; x < n; ++x) mask[x] = static_cast<DecodeMask>(static_cast<int>(reason[x]));
}

// Per-reason counts of a row of masks: one compare-and-add pass per reason (vectorised)
// rather than a switch per pixel.
void count_masks(const DecodeMask* __restrict mask, int n, DecodeCounts& counts) {
  auto count = [&](DecodeMask reason) {
    std::uint32_t c = 0;  // 32-bit: the compare-and-add vectorises without widening to 64
    for (int x = 0; x < n; ++x) c += mask[x] == reason ? 1 : 0;
    return c;
  };
  counts.valid += count(DecodeMask::valid);
  counts.saturated += count(DecodeMask::saturated);
  counts.low_contrast += count(DecodeMask::low_contrast);
  counts.low_modulation += count(DecodeMask::low_modulation);
  counts.out_of_range += count(DecodeMask::out_of_range);
}

template <class Pixel>
void decode_rows(const DecodeRowsInput& input, int row_begin, int row_end, const DecodeRowsOutput& out,
                 DecodeCounts& counts) {
  const int w = input.width;
  const std::size_t plane = static_cast<std::size_t>(input.width) * static_cast<std::size_t>(input.height);
  const auto* planes = static_cast<const Pixel*>(input.planes);
  const bool with_white_black = input.white >= 0 && input.black >= 0;
  const bool with_phase = !input.phase.empty();
  const bool with_complementary = input.complementary >= 0;
  const bool with_inverse = !input.gray_inverse.empty();
  const int steps = static_cast<int>(input.phase.size());
  const float clip_level = input.clip_level;
  const float gray_step = input.period_px * (with_complementary ? 0.5f : 1.0f);
  const bool slstudio = input.slstudio_parity;
  const TileConstants constants{input.period_px,
                                input.coded_extent - 0.5f,
                                input.min_contrast,
                                input.min_modulation,
                                with_phase ? 2.0f / static_cast<float>(steps) : 0.0f,
                                gray_step,
                                slstudio ? 0.0f : 0.5f * (gray_step - 1.0f),
                                slstudio ? gray_step - 1.0f : 0.0f,
                                2.0f * std::numbers::pi_v<float> * (1.0f - 0.5f / input.period_px)};
  const std::size_t code_bits = input.gray.size() + (with_complementary ? 1 : 0);
  const float inverse_full_scale = input.inverse_full_scale;

  TileSums t;
  alignas(64) Pixel max_value[kTileColumns];
  float* __restrict corrupt = t.corrupt;
  float* __restrict threshold2 = t.threshold2;
  float* __restrict contrast = t.contrast;
  float* __restrict sum_sin = t.sum_sin;
  float* __restrict sum_cos = t.sum_cos;
  float* __restrict sum = t.sum;
  std::uint32_t* __restrict code = t.code;
  float* __restrict second_contrast = t.second_contrast;

  for (int y = row_begin; y < row_end; ++y) {
    const std::size_t row_offset = static_cast<std::size_t>(y) * static_cast<std::size_t>(w);
    for (int x0 = 0; x0 < w; x0 += kTileColumns) {
      const int n = std::min(kTileColumns, w - x0);
      const std::size_t offset = row_offset + static_cast<std::size_t>(x0);
      auto tile_of = [&](int pattern) { return planes + static_cast<std::size_t>(pattern) * plane + offset; };

      // Plane by plane over the tile: each loop is a contiguous, vectorisable pass.
      if (with_phase) {
        // Step 0 has weights sin 0 = 0, cos 0 = 1: it initialises the sums.
        {
          const Pixel* __restrict in = tile_of(input.phase[0]);
          const float ws = input.phase_sin[0], wc = input.phase_cos[0];
          for (int x = 0; x < n; ++x) {
            const float v = static_cast<float>(in[x]);
            sum_sin[x] = v * ws;
            sum_cos[x] = v * wc;
            sum[x] = v;
          }
        }
        for (int s = 1; s < steps; ++s) {
          const Pixel* __restrict in = tile_of(input.phase[static_cast<std::size_t>(s)]);
          const float ws = input.phase_sin[static_cast<std::size_t>(s)],
                      wc = input.phase_cos[static_cast<std::size_t>(s)];
          for (int x = 0; x < n; ++x) {
            const float v = static_cast<float>(in[x]);
            sum_sin[x] += v * ws;
            sum_cos[x] += v * wc;
            sum[x] += v;
          }
        }
      }
      if (with_inverse) {
        // The contrast comes with the bits below.
      } else if (with_white_black) {
        const Pixel* __restrict white = tile_of(input.white);
        const Pixel* __restrict black = tile_of(input.black);
        for (int x = 0; x < n; ++x) {
          const float wv = static_cast<float>(white[x]), bv = static_cast<float>(black[x]);
          threshold2[x] = wv + bv;
          contrast[x] = wv - bv;
        }
      } else {
        // No white/black: the phase frames' mean is the threshold and their peak-to-peak the
        // contrast (2 B).
        const float two_over_n = 2.0f / static_cast<float>(steps);
        for (int x = 0; x < n; ++x) {
          threshold2[x] = sum[x] * two_over_n;
          contrast[x] = 2.0f * two_over_n * std::sqrt(sum_sin[x] * sum_sin[x] + sum_cos[x] * sum_cos[x]);
        }
      }
      // Gray word, most significant bit first, the complementary bit appended as the LSB.
      std::fill(code, code + n, 0u);
      auto add_bit = [&](int pattern) {
        const Pixel* __restrict in = tile_of(pattern);
        for (int x = 0; x < n; ++x)
          code[x] = (code[x] << 1) | (2.0f * static_cast<float>(in[x]) > threshold2[x] ? 1u : 0u);
      };
      if (with_inverse) {
        // A bit is 1 where the frame is brighter than its inverse. The pixel's contrast is the
        // second smallest |frame - inverse| over the code bits: at any coordinate at most one
        // bit of a Gray code (the complementary bit included) is near its edge, where a small
        // difference is expected and either reading gives a neighbouring step; every other bit
        // must be clear, which rejects shadows and bits blurred beyond reading alike.
        constexpr float kInfinity = std::numeric_limits<float>::infinity();
        std::fill(contrast, contrast + n, kInfinity);
        std::fill(second_contrast, second_contrast + n, kInfinity);
        auto add_inverse_bit = [&](int pattern, int inverse) {
          const Pixel* __restrict in = tile_of(pattern);
          const Pixel* __restrict inv = tile_of(inverse);
          for (int x = 0; x < n; ++x) code[x] = (code[x] << 1) | (in[x] > inv[x] ? 1u : 0u);
          for (int x = 0; x < n; ++x) {
            const float d = std::fabs(static_cast<float>(in[x]) - static_cast<float>(inv[x]));
            const float lowest = contrast[x];
            const float above = lowest > d ? lowest : d;
            second_contrast[x] = second_contrast[x] < above ? second_contrast[x] : above;
            contrast[x] = lowest < d ? lowest : d;
          }
        };
        for (std::size_t bit = 0; bit < input.gray.size(); ++bit)
          add_inverse_bit(input.gray[bit], input.gray_inverse[bit]);
        if (with_complementary) add_inverse_bit(input.complementary, input.complementary_inverse);
        if (code_bits >= 2) std::copy(second_contrast, second_contrast + n, contrast);
      } else {
        for (int pattern : input.gray) add_bit(pattern);
        if (with_complementary) add_bit(input.complementary);
      }

      // Saturation by frame kind: what each kind's clipped frames corrupt (decode.hpp).
      std::fill(corrupt, corrupt + n, 0.0f);
      auto max_of = [&](const int* patterns, std::size_t count) {
        const Pixel* __restrict first = tile_of(patterns[0]);
        std::copy(first, first + n, max_value);
        for (std::size_t i = 1; i < count; ++i) {
          const Pixel* __restrict in = tile_of(patterns[i]);
          for (int x = 0; x < n; ++x) max_value[x] = max_value[x] < in[x] ? in[x] : max_value[x];
        }
      };
      // Counts the clipped pixels of max_value and, when `corrupts`, marks them (`gate`: also
      // needs gate[x] != 0, or null).
      auto clipped = [&](std::size_t& count, bool corrupts, const float* __restrict gate) {
        std::uint32_t c = 0;
        for (int x = 0; x < n; ++x) {
          const bool clip = static_cast<float>(max_value[x]) >= clip_level;
          c += clip ? 1u : 0u;
          const bool bad = corrupts & clip & (gate == nullptr || gate[x] != 0.0f);
          corrupt[x] = bad ? 1.0f : corrupt[x];
        }
        count += c;
      };
      if (with_phase) {
        max_of(input.phase.data(), input.phase.size());
        clipped(counts.clipped.phase, true, nullptr);
      }
      if (with_white_black) {
        max_of(&input.white, 1);
        // The white frame sets the threshold; where the position comes from the Gray edges
        // (no phase, or phase without the complementary bit), a clipped white moves them.
        clipped(counts.clipped.white, !with_inverse && !(with_phase && with_complementary), nullptr);
        max_of(&input.black, 1);
        clipped(counts.clipped.black, !with_inverse, nullptr);
      }
      {
        float* __restrict unclear = t.q;  // scratch: finish_tile writes it later
        if (with_inverse) {
          // A bit is lost where its frame and its inverse both clip: max over bits of the pair's min.
          std::fill(unclear, unclear + n, 0.0f);
          auto both_clip = [&](int pattern, int inverse) {
            const Pixel* __restrict in = tile_of(pattern);
            const Pixel* __restrict inv = tile_of(inverse);
            for (int x = 0; x < n; ++x) {
              const Pixel lower = in[x] < inv[x] ? in[x] : inv[x];
              unclear[x] = static_cast<float>(lower) >= clip_level ? 1.0f : unclear[x];
            }
          };
          for (std::size_t bit = 0; bit < input.gray.size(); ++bit) both_clip(input.gray[bit], input.gray_inverse[bit]);
          if (with_complementary) both_clip(input.complementary, input.complementary_inverse);
        } else {
          // A clipped bright bit still reads 1 while the clip level is clear of the threshold.
          const float margin = input.min_contrast;
          for (int x = 0; x < n; ++x) unclear[x] = 2.0f * clip_level - threshold2[x] < margin ? 1.0f : 0.0f;
        }
        if (!input.code_frames.empty()) {
          max_of(input.code_frames.data(), input.code_frames.size());
          clipped(counts.clipped.gray, true, unclear);
        }
      }

      // The albedo channel (decode.hpp): ambient removed, as a fraction of the full scale.
      {
        float* __restrict intensity = out.intensity + offset;
        if (with_white_black) {
          const Pixel* __restrict white = tile_of(input.white);
          const Pixel* __restrict black = tile_of(input.black);
          for (int x = 0; x < n; ++x) {
            const float d = (static_cast<float>(white[x]) - static_cast<float>(black[x])) * inverse_full_scale;
            intensity[x] = d > 0.0f ? d : 0.0f;
          }
        } else if (with_phase) {
          const float peak_to_peak = 2.0f * 2.0f / static_cast<float>(steps) * inverse_full_scale;
          for (int x = 0; x < n; ++x)
            intensity[x] = peak_to_peak * std::sqrt(sum_sin[x] * sum_sin[x] + sum_cos[x] * sum_cos[x]);
        } else {
          std::fill(intensity, intensity + n, 0.0f);
          auto widest = [&](int pattern, int inverse) {
            const Pixel* __restrict in = tile_of(pattern);
            const Pixel* __restrict inv = tile_of(inverse);
            for (int x = 0; x < n; ++x) {
              const float d = std::fabs(static_cast<float>(in[x]) - static_cast<float>(inv[x]));
              intensity[x] = intensity[x] > d ? intensity[x] : d;
            }
          };
          for (std::size_t bit = 0; bit < input.gray.size(); ++bit) widest(input.gray[bit], input.gray_inverse[bit]);
          if (with_complementary) widest(input.complementary, input.complementary_inverse);
          for (int x = 0; x < n; ++x) intensity[x] *= inverse_full_scale;
        }
      }

      float* coordinate = out.coordinate + offset;
      float* quality = out.quality + offset;
      DecodeMask* mask = out.mask + offset;
      if (with_phase) {
        if (with_complementary)
          finish_tile<true, true>(n, t, constants, coordinate, quality, mask);
        else
          finish_tile<true, false>(n, t, constants, coordinate, quality, mask);
      } else {
        // Gray code alone: the constants carry the complementary bit's finer step.
        finish_tile<false, false>(n, t, constants, coordinate, quality, mask);
      }
    }
    count_masks(out.mask + row_offset, w, counts);
  }
}

}  // namespace

void DecodeRows8(const DecodeRowsInput& input, int row_begin, int row_end, const DecodeRowsOutput& out,
                 DecodeCounts& counts) {
  decode_rows<std::uint8_t>(input, row_begin, row_end, out, counts);
}

void DecodeRows16(const DecodeRowsInput& input, int row_begin, int row_end, const DecodeRowsOutput& out,
                  DecodeCounts& counts) {
  decode_rows<std::uint16_t>(input, row_begin, row_end, out, counts);
}

}  // namespace HWY_NAMESPACE
}  // namespace slscan::core::detail
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace slscan::core::detail {

HWY_EXPORT(DecodeRows8);
HWY_EXPORT(DecodeRows16);

void decode_rows_8bit(const DecodeRowsInput& input, int row_begin, int row_end, const DecodeRowsOutput& out,
                      DecodeCounts& counts) {
  HWY_DYNAMIC_DISPATCH(DecodeRows8)(input, row_begin, row_end, out, counts);
}

void decode_rows_16bit(const DecodeRowsInput& input, int row_begin, int row_end, const DecodeRowsOutput& out,
                       DecodeCounts& counts) {
  HWY_DYNAMIC_DISPATCH(DecodeRows16)(input, row_begin, row_end, out, counts);
}

}  // namespace slscan::core::detail
#endif  // HWY_ONCE
