#include "slscan/core/decode.hpp"

#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <string>

#include "slproto/number_text.hpp"
#include "slscan/core/decode_math.hpp"
#include "slscan/core/noise_estimate.hpp"

namespace slscan::core {

using slproto::PatternKind;

void DecodeOptions::check() const {
  auto fail = [](const std::string& msg) { throw std::invalid_argument("decode options: " + msg); };
  if (bit_depth != 8 && bit_depth != 10 && bit_depth != 12 && bit_depth != 16)
    fail("bit_depth " + std::to_string(bit_depth) + " is not 8, 10, 12 or 16");
  if (!(min_contrast_dn >= 0) || !std::isfinite(min_contrast_dn))
    fail("min_contrast_dn must be a finite value >= 0, got " + slproto::short_number(min_contrast_dn));
  if (!(min_modulation_dn >= 0) || !std::isfinite(min_modulation_dn))
    fail("min_modulation_dn must be a finite value >= 0, got " + slproto::short_number(min_modulation_dn));
  if (saturation_dn < 0 || saturation_dn > (1 << bit_depth))
    fail("saturation_dn " + std::to_string(saturation_dn) + " outside [0 (the top code), " +
         std::to_string(1 << bit_depth) + " (full scale: never clipped)]");
  if (smoothing_radius < 0 || smoothing_radius > 2)
    fail("smoothing_radius " + std::to_string(smoothing_radius) + " outside [0, 2]");
  if (quadratic_radius != 0 && (quadratic_radius < 3 || quadratic_radius > 6))
    fail("quadratic_radius " + std::to_string(quadratic_radius) + " is not 0 (off) or in [3, 6]");
  if (!(smoothing_max_deviation_px > 0) || !std::isfinite(smoothing_max_deviation_px))
    fail("smoothing_max_deviation_px must be positive and finite");
  if (!(noise_factor >= 0) || !std::isfinite(noise_factor))
    fail("noise_factor must be a finite value >= 0 (0: the fixed smoothing_max_deviation_px)");
  if (rows_per_task < 1 || rows_per_task > 4096)
    fail("rows_per_task " + std::to_string(rows_per_task) + " outside [1, 4096]");
}

ProjectorViewDecoder::ProjectorViewDecoder(const slproto::PatternPlan& plan, int width, int height,
                                           const DecodeOptions& options)
    : plan_(plan), width_(width), height_(height), options_(options) {
  options_.check();
  if (width < 1 || height < 1 || width > 65536 || height > 65536)
    throw std::invalid_argument("decoder: image size " + std::to_string(width) + " x " + std::to_string(height) +
                                " is impossible");
  const auto& config = plan.config();
  if (config.gray_bits() + (config.complementary_bit ? 1 : 0) > 30)
    throw std::invalid_argument("decoder: plan needs more than 30 code bits");
  white_ = plan.index_of(PatternKind::white);
  black_ = plan.index_of(PatternKind::black);
  complementary_ = plan.index_of(PatternKind::complementary_bit);
  complementary_inverse_ = plan.index_of(PatternKind::complementary_bit_inverse);
  for (int bit = 0; bit < config.gray_bits(); ++bit) {
    gray_.push_back(plan.index_of(PatternKind::gray_bit, bit));
    if (config.inverse_gray) gray_inverse_.push_back(plan.index_of(PatternKind::gray_bit_inverse, bit));
  }
  for (int n = 0; n < config.phase_steps; ++n) {
    phase_.push_back(plan.index_of(PatternKind::phase_step, n));
    const double d = config.phase_shift_rad(n);  // 2 pi n / N in our own plans
    phase_cos_.push_back(static_cast<float>(std::cos(d)));
    phase_sin_.push_back(static_cast<float>(std::sin(d)));
  }
  if ((white_ < 0 || black_ < 0) && phase_.empty() && gray_inverse_.empty())
    throw std::invalid_argument(
        "decoder: the plan has neither white/black frames, inverse Gray frames nor phase steps to threshold the Gray "
        "bits against");
  code_frames_ = gray_;
  if (complementary_ >= 0) code_frames_.push_back(complementary_);
  code_frames_.insert(code_frames_.end(), gray_inverse_.begin(), gray_inverse_.end());
  if (complementary_inverse_ >= 0) code_frames_.push_back(complementary_inverse_);
  bytes_per_pixel_ = options_.bit_depth > 8 ? 2 : 1;
  store_.resize(plan.size() * static_cast<std::size_t>(width) * static_cast<std::size_t>(height) * bytes_per_pixel_);
  present_.assign(plan.size(), 0);
}

template <class Pixel>
void ProjectorViewDecoder::store_frame(std::size_t pattern_index, const Pixel* data, std::size_t stride) {
  if (pattern_index >= plan_.size())
    throw std::out_of_range("decoder: pattern index " + std::to_string(pattern_index) + " beyond the plan's " +
                            std::to_string(plan_.size()) + " patterns");
  if (data == nullptr) throw std::invalid_argument("decoder: frame data is null");
  if (stride < static_cast<std::size_t>(width_))
    throw std::invalid_argument("decoder: stride " + std::to_string(stride) + " smaller than the width " +
                                std::to_string(width_));
  if (sizeof(Pixel) != bytes_per_pixel_)
    throw std::invalid_argument("decoder: " + std::to_string(8 * sizeof(Pixel)) + "-bit frame for a " +
                                std::to_string(options_.bit_depth) + "-bit decoder");
  const std::size_t plane = static_cast<std::size_t>(width_) * static_cast<std::size_t>(height_);
  auto* dst = reinterpret_cast<Pixel*>(store_.data()) + pattern_index * plane;
  const auto row_bytes = static_cast<std::size_t>(width_) * sizeof(Pixel);
  tbb::parallel_for(tbb::blocked_range<int>(0, height_, 64), [&](const tbb::blocked_range<int>& rows) {
    for (int y = rows.begin(); y < rows.end(); ++y)
      std::memcpy(dst + static_cast<std::size_t>(y) * static_cast<std::size_t>(width_),
                  data + static_cast<std::size_t>(y) * stride, row_bytes);
  });
  present_[pattern_index] = 1;
}

void ProjectorViewDecoder::add_frame(std::size_t pattern_index, const std::uint8_t* data, std::size_t stride) {
  store_frame(pattern_index, data, stride);
}

void ProjectorViewDecoder::add_frame(std::size_t pattern_index, const std::uint16_t* data, std::size_t stride) {
  store_frame(pattern_index, data, stride);
}

bool ProjectorViewDecoder::complete() const {
  return std::all_of(present_.begin(), present_.end(), [](std::uint8_t p) { return p != 0; });
}

void ProjectorViewDecoder::reset() { std::fill(present_.begin(), present_.end(), std::uint8_t{0}); }

DecodedView ProjectorViewDecoder::finish() {
  DecodedView out;
  finish(out);
  return out;
}

namespace {

// Columns per tile: a tile's sums (a few floats per pixel) stay in L1 while the 19 planes'
// rows stream through once.
constexpr int kTileColumns = 512;

// Least-squares plane c = a + gx du + gy dv over the valid pixels of the (2 r + 1)^2 window
// around (x, y), in differences from the centre value; `value` = a (the plane at the centre).
// False when the valid pixels don't pin a plane down (collinear or too few).
bool plane_fit_at_centre(const float* raw, std::size_t stride, int x, int y, int r, float& value) {
  const float c0 = raw[static_cast<std::size_t>(y) * stride + static_cast<std::size_t>(x)];
  double n = 0, su = 0, sv = 0, suu = 0, svv = 0, suv = 0, sc = 0, scu = 0, scv = 0;
  for (int dv = -r; dv <= r; ++dv) {
    const float* row = raw + static_cast<std::size_t>(y + dv) * stride;
    for (int du = -r; du <= r; ++du) {
      const float v = row[x + du];
      if (!(v == v)) continue;
      const double c = v - c0;
      n += 1;
      su += du;
      sv += dv;
      suu += du * du;
      svv += dv * dv;
      suv += du * dv;
      sc += c;
      scu += c * du;
      scv += c * dv;
    }
  }
  // Solve [n su sv; su suu suv; sv suv svv] [a gx gy]^T = [sc scu scv]^T by Cramer's rule.
  const double det = n * (suu * svv - suv * suv) - su * (su * svv - suv * sv) + sv * (su * suv - suu * sv);
  if (!(std::abs(det) > 1e-6 * n * n * n)) return false;
  const double det_a = sc * (suu * svv - suv * suv) - su * (scu * svv - suv * scv) + sv * (scu * suv - suu * scv);
  value = static_cast<float>(det_a / det);
  return std::isfinite(value);
}

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

}  // namespace

template <class Pixel>
void ProjectorViewDecoder::decode_rows(int row_begin, int row_end, DecodedView& out, DecodeCounts& counts) const {
  const int w = width_;
  const std::size_t plane = static_cast<std::size_t>(width_) * static_cast<std::size_t>(height_);
  const auto* planes = reinterpret_cast<const Pixel*>(store_.data());
  const auto& config = plan_.config();
  const bool with_white_black = white_ >= 0 && black_ >= 0;
  const bool with_phase = !phase_.empty();
  const bool with_complementary = complementary_ >= 0;
  const bool with_inverse = !gray_inverse_.empty();
  const int steps = static_cast<int>(phase_.size());
  // As a float: the full scale (2^bit_depth, "never") does not fit a Pixel.
  const auto clip_level = static_cast<float>(options_.saturation_level());
  const float gray_step = static_cast<float>(config.period_px) * (with_complementary ? 0.5f : 1.0f);
  const bool slstudio = config.gray_low_bits == slproto::GrayLowBits::slstudio_parity;
  const TileConstants constants{
      static_cast<float>(config.period_px),
      static_cast<float>(config.coded_extent()) - 0.5f,
      options_.min_contrast_dn,
      options_.min_modulation_dn,
      with_phase ? 2.0f / static_cast<float>(steps) : 0.0f,
      gray_step,
      slstudio ? 0.0f : 0.5f * (gray_step - 1.0f),
      slstudio ? gray_step - 1.0f : 0.0f,
      2.0f * std::numbers::pi_v<float> * (1.0f - 0.5f / static_cast<float>(config.period_px))};
  const std::size_t code_bits = gray_.size() + (with_complementary ? 1 : 0);
  const float inverse_full_scale = 1.0f / static_cast<float>((1 << options_.bit_depth) - 1);

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
          const Pixel* __restrict in = tile_of(phase_[0]);
          const float ws = phase_sin_[0], wc = phase_cos_[0];
          for (int x = 0; x < n; ++x) {
            const float v = static_cast<float>(in[x]);
            sum_sin[x] = v * ws;
            sum_cos[x] = v * wc;
            sum[x] = v;
          }
        }
        for (int s = 1; s < steps; ++s) {
          const Pixel* __restrict in = tile_of(phase_[static_cast<std::size_t>(s)]);
          const float ws = phase_sin_[static_cast<std::size_t>(s)], wc = phase_cos_[static_cast<std::size_t>(s)];
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
        const Pixel* __restrict white = tile_of(white_);
        const Pixel* __restrict black = tile_of(black_);
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
        for (std::size_t bit = 0; bit < gray_.size(); ++bit) add_inverse_bit(gray_[bit], gray_inverse_[bit]);
        if (with_complementary) add_inverse_bit(complementary_, complementary_inverse_);
        if (code_bits >= 2) std::copy(second_contrast, second_contrast + n, contrast);
      } else {
        for (int pattern : gray_) add_bit(pattern);
        if (with_complementary) add_bit(complementary_);
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
        max_of(phase_.data(), phase_.size());
        clipped(counts.clipped.phase, true, nullptr);
      }
      if (with_white_black) {
        max_of(&white_, 1);
        // The white frame sets the threshold; where the position comes from the Gray edges
        // (no phase, or phase without the complementary bit), a clipped white moves them.
        clipped(counts.clipped.white, !with_inverse && !(with_phase && with_complementary), nullptr);
        max_of(&black_, 1);
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
          for (std::size_t bit = 0; bit < gray_.size(); ++bit) both_clip(gray_[bit], gray_inverse_[bit]);
          if (with_complementary) both_clip(complementary_, complementary_inverse_);
        } else {
          // A clipped bright bit still reads 1 while the clip level is clear of the threshold.
          const float margin = options_.min_contrast_dn;
          for (int x = 0; x < n; ++x) unclear[x] = 2.0f * clip_level - threshold2[x] < margin ? 1.0f : 0.0f;
        }
        if (!code_frames_.empty()) {
          max_of(code_frames_.data(), code_frames_.size());
          clipped(counts.clipped.gray, true, unclear);
        }
      }

      // The albedo channel (decode.hpp): ambient removed, as a fraction of the full scale.
      {
        float* __restrict intensity = out.intensity.data() + offset;
        if (with_white_black) {
          const Pixel* __restrict white = tile_of(white_);
          const Pixel* __restrict black = tile_of(black_);
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
          for (std::size_t bit = 0; bit < gray_.size(); ++bit) widest(gray_[bit], gray_inverse_[bit]);
          if (with_complementary) widest(complementary_, complementary_inverse_);
          for (int x = 0; x < n; ++x) intensity[x] *= inverse_full_scale;
        }
      }

      float* coordinate = out.coordinate.data() + offset;
      float* quality = out.quality.data() + offset;
      DecodeMask* mask = out.mask.data() + offset;
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
    count_masks(out.mask.data() + row_offset, w, counts);
  }
}

void ProjectorViewDecoder::finish(DecodedView& out) {
  for (std::size_t i = 0; i < present_.size(); ++i)
    if (!present_[i]) {
      const auto& pattern = plan_[i];
      throw std::logic_error("decoder: frame " + std::to_string(i) + " (" + slproto::pattern_kind_name(pattern.kind) +
                             " " + std::to_string(pattern.index) + ") was never added");
    }
  const std::size_t n = static_cast<std::size_t>(width_) * static_cast<std::size_t>(height_);
  out.width = width_;
  out.height = height_;
  out.axis = plan_.config().axis;
  out.coordinate.resize(n);
  out.quality.resize(n);
  out.intensity.resize(n);
  out.mask.resize(n);
  tbb::combinable<DecodeCounts> counts_by_thread;
  tbb::parallel_for(tbb::blocked_range<int>(0, height_, options_.rows_per_task), [&](const tbb::blocked_range<int>& r) {
    DecodeCounts& counts = counts_by_thread.local();
    if (bytes_per_pixel_ == 1) {
      decode_rows<std::uint8_t>(r.begin(), r.end(), out, counts);
    } else {
      decode_rows<std::uint16_t>(r.begin(), r.end(), out, counts);
    }
  });
  out.counts = {};
  counts_by_thread.combine_each([&](const DecodeCounts& c) {
    out.counts.clipped += c.clipped;
    out.counts.valid += c.valid;
    out.counts.saturated += c.saturated;
    out.counts.low_contrast += c.low_contrast;
    out.counts.low_modulation += c.low_modulation;
    out.counts.out_of_range += c.out_of_range;
  });
  if (options_.smoothing_radius > 0) smooth(out);
  // The self-check hook: reads the stored frames and the output, never the inner loop's state.
  if (options_.self_check) {
    const FramePlanes frames{store_.data(), bytes_per_pixel_ == 2, width_, height_};
    out.checks = check_decoded_view(plan_, frames, options_.smoothing_radius > 0 ? raw_coordinate_ : out.coordinate,
                                    out, options_);
  } else {
    out.checks = {};
  }
  reset();
}

namespace {

// v, or +0 where v is NaN (masked), by masking the bits: a select followed by the widening to
// double is not if-converted by GCC 12, this is.
inline float zero_if_nan(float v) {
  std::uint32_t bits;
  std::memcpy(&bits, &v, sizeof bits);
  bits &= 0u - static_cast<std::uint32_t>(v == v);
  float out;
  std::memcpy(&out, &bits, sizeof out);
  return out;
}

}  // namespace

// Per pixel of a row, from its window means (differences to the centre) and counts: the
// smoothed value, and a flag where the plane fit must decide instead. A free function with
// restrict pointers and scalars by value: as a lambda over captured references GCC 12 leaves
// it scalar.
template <int R>
void choose_smoothed(int w, const float* __restrict centre, const float* __restrict means_wide,
                     const float* __restrict means_narrow, const float* __restrict counts_wide,
                     const float* __restrict counts_narrow, const float* __restrict modulation, float full_count,
                     float deviation, float* __restrict result, float* __restrict needs_fit) {
  // ~2 sigma of (5 x 5 mean - 3 x 3 mean): the phase noise of a pixel scales as 1 / B, and
  // is ~0.05 px at B = 30 DN on the rig (8-bit sensor, 1.5 DN read noise plus shot noise).
  constexpr float kCurvatureToleranceDnPx = 0.8f;
  for (int x = R; x < w - R; ++x) {
    const float c = centre[x];
    const float mean_wide = means_wide[x], mean_narrow = means_narrow[x];
    const float n5 = counts_wide[x], n3 = counts_narrow[x];
    // A window mean is biased by the coordinate's curvature, in proportion to the window's
    // second moment (4 for 5 x 5, 4/3 for 3 x 3). Where the two means differ by more than
    // noise (the limb of a sphere, a fillet), extrapolate the bias away (Richardson:
    // 1.5 m3 - 0.5 m5); elsewhere the 5 x 5 mean has the least noise.
    const float b = modulation[x];
    const float tolerance = kCurvatureToleranceDnPx / (b > 1.0f ? b : 1.0f);
    const bool curved = R == 2 && std::fabs(mean_wide - mean_narrow) > tolerance;
    const float wide_value = c + (curved ? 1.5f * mean_narrow - 0.5f * mean_wide : mean_wide);
    const float narrow_value = ((n3 == 9.0f) & (std::fabs(mean_narrow) <= deviation)) ? c + mean_narrow : c;
    const float full_value = std::fabs(mean_wide) <= deviation ? wide_value : narrow_value;
    // A NaN centre leaves the window short of full, so it stays NaN here.
    const bool full = n5 == full_count;
    result[x] = full ? full_value : c;
    needs_fit[x] = (!full & (n5 >= 6.0f) & (c == c)) ? 1.0f : 0.0f;
  }
}

namespace {

// One row's working buffers for quadratic_where_whole (reused across rows by each thread).
struct QuadraticRows {
  std::vector<double> sum, weighted;  // per column, over the window's rows
  std::vector<float> count, value, whole;
};

// Row y's pixels whose (2 q + 1)^2 window decoded whole get the window's quadratic value, if it
// stays within max_deviation of their own and near the value the smaller window chose
// (`result` on entry): they differ by the curvature bias the quadratic removes (below the
// Richardson threshold, 1.2 / B px, where the 5 x 5 mean was kept) plus noise, but by far more
// where the wider window reaches over a depth step the smaller one does not see (a step of D
// px in its outer column moves the quadratic by ~0.09 D).
template <int Q>
void quadratic_where_whole(const float* raw, const float* modulation, std::size_t uw, int y, float max_deviation,
                           QuadraticRows& rows, float* __restrict result) {
  constexpr int n = 2 * Q + 1;
  // 1-D: a (2 Q + 1)-point quadratic's value at its centre is sum_i w_i z_i (Savitzky-Golay).
  // 2-D, on {1, u, v, u^2, uv, v^2}: sum_ij ((w_i + w_j) / n - 1 / n^2) z_ij, which is
  // sum_i (w_i / n - 1 / n^2) S_i + sum_i T_i / n over the columns' plain sums S and
  // w-weighted sums T.
  std::array<double, n> w_rows{}, k_across{};
  for (int i = -Q; i <= Q; ++i) {
    const double wi = (3.0 * (3 * Q * Q + 3 * Q - 1) - 15.0 * i * i) / ((2 * Q + 3) * (2 * Q + 1) * (2 * Q - 1));
    w_rows[static_cast<std::size_t>(i + Q)] = wi;
    k_across[static_cast<std::size_t>(i + Q)] = wi / n - 1.0 / (n * n);
  }
  constexpr double inv_n = 1.0 / n;
  constexpr auto full = static_cast<float>(n * n);
  constexpr float kAgreementDnPx = 1.6f;  // 2 x choose_smoothed's curvature tolerance (DN px)
  const int w = static_cast<int>(uw);
  rows.sum.assign(uw, 0.0);
  rows.weighted.assign(uw, 0.0);
  rows.count.assign(uw, 0.0f);
  rows.value.resize(uw);
  rows.whole.resize(uw);
  double* __restrict sum = rows.sum.data();
  double* __restrict weighted = rows.weighted.data();
  float* __restrict count = rows.count.data();
  for (int dy = -Q; dy <= Q; ++dy) {
    const float* __restrict row = raw + static_cast<std::size_t>(y + dy) * uw;
    const double weight = w_rows[static_cast<std::size_t>(dy + Q)];
    for (int x = 0; x < w; ++x) {
      const auto v = static_cast<double>(zero_if_nan(row[x]));
      sum[x] += v;
      weighted[x] += weight * v;
      count[x] += row[x] == row[x] ? 1.0f : 0.0f;
    }
  }
  float* __restrict value = rows.value.data();
  float* __restrict whole = rows.whole.data();
  for (int x = Q; x < w - Q; ++x) {
    double fitted = 0;
    float valid = 0;
    for (int i = 0; i < n; ++i) {
      fitted += k_across[static_cast<std::size_t>(i)] * sum[x - Q + i] + inv_n * weighted[x - Q + i];
      valid += count[x - Q + i];
    }
    value[x] = static_cast<float>(fitted);
    whole[x] = valid == full ? 1.0f : 0.0f;
  }
  const float* __restrict centre = raw + static_cast<std::size_t>(y) * uw;
  const float* __restrict row_modulation = modulation + static_cast<std::size_t>(y) * uw;
  for (int x = Q; x < w - Q; ++x) {
    const float b = row_modulation[x];
    const float agreement = kAgreementDnPx / (b > 1.0f ? b : 1.0f);
    const float v = value[x];
    const bool take =
        (whole[x] == 1.0f) & (std::fabs(v - centre[x]) <= max_deviation) & (std::fabs(v - result[x]) <= agreement);
    result[x] = take ? v : result[x];
  }
}

void quadratic_where_whole(int q, const float* raw, const float* modulation, std::size_t uw, int y, float max_deviation,
                           QuadraticRows& rows, float* result) {
  switch (q) {
    case 3:
      return quadratic_where_whole<3>(raw, modulation, uw, y, max_deviation, rows, result);
    case 4:
      return quadratic_where_whole<4>(raw, modulation, uw, y, max_deviation, rows, result);
    case 5:
      return quadratic_where_whole<5>(raw, modulation, uw, y, max_deviation, rows, result);
    case 6:
      return quadratic_where_whole<6>(raw, modulation, uw, y, max_deviation, rows, result);
    default:
      throw std::logic_error("quadratic_radius outside [3, 6] past DecodeOptions::check()");
  }
}

}  // namespace

void ProjectorViewDecoder::smooth(DecodedView& out) {
  raw_coordinate_.swap(out.coordinate);
  out.coordinate.resize(raw_coordinate_.size());
  const int w = width_, h = height_;
  const int radius = options_.smoothing_radius;
  const NoiseEstimate noise =
      estimate_map_noise(raw_coordinate_, w, h, &out.quality,
                         plan_.config().phase_steps > 0 ? static_cast<float>(plan_.config().period_px) : 0.0f);
  out.coordinate_noise_px = static_cast<float>(noise.per_point);
  const float max_deviation =
      std::max(options_.smoothing_max_deviation_px, options_.noise_factor * static_cast<float>(noise.per_point));
  out.smoothing_max_deviation_px = max_deviation;
  const float* raw = raw_coordinate_.data();
  const float* quality = out.quality.data();
  float* smoothed = out.coordinate.data();
  // Separable window sums: per row, the column sums over the window's rows (3 and 5), then
  // per pixel the sum of 3 or 5 column sums. Double keeps the sums of the coordinates
  // themselves (up to ~1e3 px) exact to well below 1e-9 px, so no per-window differences to
  // the centre are needed. Counts of valid pixels ride along the same way; masked (NaN)
  // pixels count as 0. Each row's sums are computed from its own window only (no running
  // sums across rows), so the result does not depend on how TBB splits the rows.
  const int q = options_.quadratic_radius;
  struct Columns {
    std::vector<double> narrow, wide;
    QuadraticRows quadratic;
    std::vector<float> narrow_count, wide_count;
    std::vector<float> mean_wide, mean_narrow, window_count_wide, window_count_narrow;
    std::vector<float> needs_fit;  // 1 where the plane fit decides (float: one element width)
  };
  static tbb::enumerable_thread_specific<Columns> columns_by_thread;
  tbb::parallel_for(tbb::blocked_range<int>(0, h, options_.rows_per_task), [&](const tbb::blocked_range<int>& rows) {
    Columns& columns = columns_by_thread.local();
    const auto uw = static_cast<std::size_t>(w);
    columns.narrow.resize(uw);
    columns.wide.resize(uw);
    columns.narrow_count.resize(uw);
    columns.wide_count.resize(uw);
    columns.needs_fit.resize(uw);
    columns.mean_wide.resize(uw);
    columns.mean_narrow.resize(uw);
    columns.window_count_wide.resize(uw);
    columns.window_count_narrow.resize(uw);
    double* __restrict col_narrow = columns.narrow.data();
    double* __restrict col_wide = columns.wide.data();
    float* __restrict count_narrow = columns.narrow_count.data();
    float* __restrict count_wide = columns.wide_count.data();
    float* __restrict needs_fit = columns.needs_fit.data();
    for (int y = rows.begin(); y < rows.end(); ++y) {
      const float* __restrict centre = raw + static_cast<std::size_t>(y) * uw;
      float* __restrict result = smoothed + static_cast<std::size_t>(y) * uw;
      std::copy(centre, centre + w, result);
      if (y < 1 || y >= h - 1 || w < 3) continue;
      const int r = (y >= radius && y < h - radius) ? radius : 1;
      {
        const float* __restrict above = centre - uw;
        const float* __restrict below = centre + uw;
        for (int x = 0; x < w; ++x) {
          const float a = above[x], c = centre[x], b = below[x];
          col_narrow[x] = static_cast<double>(zero_if_nan(a)) + static_cast<double>(zero_if_nan(c)) +
                          static_cast<double>(zero_if_nan(b));
          count_narrow[x] = (a == a ? 1.0f : 0.0f) + (c == c ? 1.0f : 0.0f) + (b == b ? 1.0f : 0.0f);
        }
      }
      const double* __restrict sum_wide = col_narrow;
      const float* __restrict n_wide = count_narrow;
      if (r == 2) {
        const float* __restrict above = centre - 2 * uw;
        const float* __restrict below = centre + 2 * uw;
        for (int x = 0; x < w; ++x) {
          const float a = above[x], b = below[x];
          col_wide[x] = col_narrow[x] + (static_cast<double>(zero_if_nan(a)) + static_cast<double>(zero_if_nan(b)));
          count_wide[x] = count_narrow[x] + ((a == a ? 1.0f : 0.0f) + (b == b ? 1.0f : 0.0f));
        }
        sum_wide = col_wide;
        n_wide = count_wide;
      }
      const auto full_wide = static_cast<float>((2 * r + 1) * (2 * r + 1));
      const double inv_full_wide = 1.0 / static_cast<double>(full_wide);
      const float* __restrict row_quality = quality + static_cast<std::size_t>(y) * uw;
      // Two passes: the window means from the double sums (no selects), then the choice among
      // them in float only (GCC 12 if-converts selects of one element width).
      float* __restrict means_wide = columns.mean_wide.data();
      float* __restrict means_narrow = columns.mean_narrow.data();
      float* __restrict counts_wide = columns.window_count_wide.data();
      float* __restrict counts_narrow = columns.window_count_narrow.data();
      auto window_means = [&]<int R>() {
        for (int x = R; x < w - R; ++x) {
          const double s3 = col_narrow[x - 1] + col_narrow[x] + col_narrow[x + 1];
          double s5 = s3;
          if constexpr (R == 2)
            s5 = sum_wide[x - 2] + sum_wide[x - 1] + sum_wide[x] + sum_wide[x + 1] + sum_wide[x + 2];
          const auto c = static_cast<double>(centre[x]);
          means_wide[x] = static_cast<float>(s5 * inv_full_wide - c);
          means_narrow[x] = static_cast<float>(s3 * (1.0 / 9.0) - c);
        }
        for (int x = R; x < w - R; ++x) {
          const float n3 = count_narrow[x - 1] + count_narrow[x] + count_narrow[x + 1];
          float n5 = n3;
          if constexpr (R == 2) n5 = n_wide[x - 2] + n_wide[x - 1] + n_wide[x] + n_wide[x + 1] + n_wide[x + 2];
          counts_wide[x] = n5;
          counts_narrow[x] = n3;
        }
      };
      if (r == 2) {
        window_means.template operator()<2>();
        choose_smoothed<2>(w, centre, means_wide, means_narrow, counts_wide, counts_narrow, row_quality, full_wide,
                           max_deviation, result, needs_fit);
      } else {
        window_means.template operator()<1>();
        choose_smoothed<1>(w, centre, means_wide, means_narrow, counts_wide, counts_narrow, row_quality, full_wide,
                           max_deviation, result, needs_fit);
      }
      // Part of the window is masked (a shadow border, an edge): a one-sided mean would be
      // biased by the coordinate's slope, so fit a plane to the valid neighbours and take its
      // value at the centre. Only edge pixels get here.
      for (int x = r; x < w - r; ++x) {
        if (needs_fit[x] == 0.0f) continue;
        float value;
        if (plane_fit_at_centre(raw, uw, x, y, r, value) && std::fabs(value) <= max_deviation)
          result[x] = centre[x] + value;
      }
      if (q > 0 && y >= q && y < h - q && w > 2 * q)
        quadratic_where_whole(q, raw, quality, uw, y, max_deviation, columns.quadratic, result);
    }
  });
}

}  // namespace slscan::core
