#include "slscan/core/decode.hpp"

#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <string>

#include "slscan/core/decode_math.hpp"

namespace slscan::core {

using slproto::PatternKind;

void DecodeOptions::check() const {
  auto fail = [](const std::string& msg) { throw std::invalid_argument("decode options: " + msg); };
  if (bit_depth != 8 && bit_depth != 10 && bit_depth != 12 && bit_depth != 16)
    fail("bit_depth " + std::to_string(bit_depth) + " is not 8, 10, 12 or 16");
  if (!(min_contrast_dn >= 0) || !std::isfinite(min_contrast_dn))
    fail("min_contrast_dn must be a finite value >= 0, got " + std::to_string(min_contrast_dn));
  if (!(min_modulation_dn >= 0) || !std::isfinite(min_modulation_dn))
    fail("min_modulation_dn must be a finite value >= 0, got " + std::to_string(min_modulation_dn));
  if (saturation_dn < 0 || saturation_dn > (1 << bit_depth) - 1)
    fail("saturation_dn " + std::to_string(saturation_dn) + " outside [0 (auto), " +
         std::to_string((1 << bit_depth) - 1) + "]");
  if (smoothing_radius < 0 || smoothing_radius > 2)
    fail("smoothing_radius " + std::to_string(smoothing_radius) + " outside [0, 2]");
  if (!(smoothing_max_deviation_px > 0) || !std::isfinite(smoothing_max_deviation_px))
    fail("smoothing_max_deviation_px must be positive and finite");
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
  for (int bit = 0; bit < config.gray_bits(); ++bit) gray_.push_back(plan.index_of(PatternKind::gray_bit, bit));
  for (int n = 0; n < config.phase_steps; ++n) {
    phase_.push_back(plan.index_of(PatternKind::phase_step, n));
    const double d = 2.0 * std::numbers::pi * n / config.phase_steps;
    phase_cos_.push_back(static_cast<float>(std::cos(d)));
    phase_sin_.push_back(static_cast<float>(std::sin(d)));
  }
  if ((white_ < 0 || black_ < 0) && phase_.empty())
    throw std::invalid_argument(
        "decoder: the plan has neither white/black frames nor phase steps to threshold the Gray bits against");
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

// Row scratch of one worker: the per-pixel sums of one row, reused for every row it decodes.
struct RowScratch {
  std::vector<float> threshold2, contrast, sum_sin, sum_cos, sum;
  std::vector<std::uint32_t> code, max_value;
  void resize(int width) {
    const auto w = static_cast<std::size_t>(width);
    for (auto* v : {&threshold2, &contrast, &sum_sin, &sum_cos, &sum}) v->resize(w);
    code.resize(w);
    max_value.resize(w);
  }
};

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

}  // namespace

template <class Pixel>
void ProjectorViewDecoder::decode_rows(int row_begin, int row_end, DecodedView& out, DecodeCounts& counts) const {
  static tbb::enumerable_thread_specific<RowScratch> scratch_by_thread;
  RowScratch& s = scratch_by_thread.local();
  s.resize(width_);
  const int w = width_;
  const std::size_t plane = static_cast<std::size_t>(width_) * static_cast<std::size_t>(height_);
  const auto* planes = reinterpret_cast<const Pixel*>(store_.data());
  const auto& config = plan_.config();
  const bool with_white_black = white_ >= 0 && black_ >= 0;
  const bool with_phase = !phase_.empty();
  const bool with_complementary = complementary_ >= 0;
  const int steps = static_cast<int>(phase_.size());
  const float period = static_cast<float>(config.period_px);
  const float extent_max = static_cast<float>(config.coded_extent()) - 0.5f;
  const auto saturation = static_cast<std::uint32_t>(options_.saturation_level());
  const float min_contrast = options_.min_contrast_dn;
  const float min_modulation = options_.min_modulation_dn;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  constexpr float kTwoPi = 2.0f * std::numbers::pi_v<float>;
  constexpr float kHalfPi = 0.5f * std::numbers::pi_v<float>;
  constexpr float kThreeHalfPi = 1.5f * std::numbers::pi_v<float>;

  float* __restrict threshold2 = s.threshold2.data();
  float* __restrict contrast = s.contrast.data();
  float* __restrict sum_sin = s.sum_sin.data();
  float* __restrict sum_cos = s.sum_cos.data();
  float* __restrict sum = s.sum.data();
  std::uint32_t* __restrict code = s.code.data();
  std::uint32_t* __restrict max_value = s.max_value.data();

  for (int y = row_begin; y < row_end; ++y) {
    const std::size_t row_offset = static_cast<std::size_t>(y) * static_cast<std::size_t>(w);
    auto row_of = [&](int pattern) { return planes + static_cast<std::size_t>(pattern) * plane + row_offset; };

    // Plane by plane over the row: each loop is a contiguous, vectorisable pass.
    std::fill(max_value, max_value + w, 0u);
    for (std::size_t p = 0; p < plan_.size(); ++p) {
      const Pixel* __restrict in = row_of(static_cast<int>(p));
      for (int x = 0; x < w; ++x) max_value[x] = std::max(max_value[x], static_cast<std::uint32_t>(in[x]));
    }
    if (with_phase) {
      std::fill(sum_sin, sum_sin + w, 0.0f);
      std::fill(sum_cos, sum_cos + w, 0.0f);
      std::fill(sum, sum + w, 0.0f);
      for (int n = 0; n < steps; ++n) {
        const Pixel* __restrict in = row_of(phase_[static_cast<std::size_t>(n)]);
        const float ws = phase_sin_[static_cast<std::size_t>(n)], wc = phase_cos_[static_cast<std::size_t>(n)];
        for (int x = 0; x < w; ++x) {
          const float v = static_cast<float>(in[x]);
          sum_sin[x] += v * ws;
          sum_cos[x] += v * wc;
          sum[x] += v;
        }
      }
    }
    if (with_white_black) {
      const Pixel* __restrict white = row_of(white_);
      const Pixel* __restrict black = row_of(black_);
      for (int x = 0; x < w; ++x) {
        const float wv = static_cast<float>(white[x]), bv = static_cast<float>(black[x]);
        threshold2[x] = wv + bv;
        contrast[x] = wv - bv;
      }
    } else {
      // No white/black: the phase frames' mean is the threshold and their peak-to-peak the
      // contrast (2 B).
      const float two_over_n = 2.0f / static_cast<float>(steps);
      for (int x = 0; x < w; ++x) {
        threshold2[x] = sum[x] * two_over_n;
        contrast[x] = 2.0f * two_over_n * std::sqrt(sum_sin[x] * sum_sin[x] + sum_cos[x] * sum_cos[x]);
      }
    }
    // Gray word, most significant bit first, the complementary bit appended as the LSB.
    std::fill(code, code + w, 0u);
    auto add_bit = [&](int pattern) {
      const Pixel* __restrict in = row_of(pattern);
      for (int x = 0; x < w; ++x)
        code[x] = (code[x] << 1) | static_cast<std::uint32_t>(2.0f * static_cast<float>(in[x]) > threshold2[x]);
    };
    for (int pattern : gray_) add_bit(pattern);
    if (with_complementary) add_bit(complementary_);

    float* __restrict coordinate = out.coordinate.data() + row_offset;
    float* __restrict quality = out.quality.data() + row_offset;
    DecodeMask* __restrict mask = out.mask.data() + row_offset;
    const float modulation_scale = with_phase ? 2.0f / static_cast<float>(steps) : 0.0f;
    for (int x = 0; x < w; ++x) {
      const std::uint32_t h = slproto::gray_to_binary(code[x]);
      float coord;
      float q;
      if (with_phase) {
        const float phi = atan2_0_2pi(-sum_sin[x], sum_cos[x]);
        int order;
        if (with_complementary) {
          const int k = static_cast<int>(h >> 1), k2 = static_cast<int>((h + 1) >> 1);
          order = phi < kHalfPi ? k2 : (phi >= kThreeHalfPi ? k2 - 1 : k);
        } else {
          order = static_cast<int>(h);
        }
        coord = (phi / kTwoPi + static_cast<float>(order)) * period;
        q = modulation_scale * std::sqrt(sum_sin[x] * sum_sin[x] + sum_cos[x] * sum_cos[x]);
      } else if (with_complementary) {
        // Gray code alone: the centre of the half period h covers pixels [h P/2, (h+1) P/2 - 1].
        coord = static_cast<float>(h) * 0.5f * period + 0.25f * period - 0.5f;
        q = contrast[x];
      } else {
        coord = static_cast<float>(h) * period + 0.5f * period - 0.5f;
        q = contrast[x];
      }
      DecodeMask m = DecodeMask::valid;
      if (max_value[x] >= saturation) {
        m = DecodeMask::saturated;
      } else if (!(contrast[x] >= min_contrast)) {
        m = DecodeMask::low_contrast;
      } else if (with_phase && !(q >= min_modulation)) {
        m = DecodeMask::low_modulation;
      } else if (!(coord >= -0.5f && coord <= extent_max)) {
        m = DecodeMask::out_of_range;
      }
      mask[x] = m;
      const bool ok = m == DecodeMask::valid;
      coordinate[x] = ok ? coord : nan;
      quality[x] = ok ? q : 0.0f;
    }
    for (int x = 0; x < w; ++x) {
      switch (mask[x]) {
        case DecodeMask::valid:
          ++counts.valid;
          break;
        case DecodeMask::saturated:
          ++counts.saturated;
          break;
        case DecodeMask::low_contrast:
          ++counts.low_contrast;
          break;
        case DecodeMask::low_modulation:
          ++counts.low_modulation;
          break;
        case DecodeMask::out_of_range:
          ++counts.out_of_range;
          break;
      }
    }
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
    out.counts.valid += c.valid;
    out.counts.saturated += c.saturated;
    out.counts.low_contrast += c.low_contrast;
    out.counts.low_modulation += c.low_modulation;
    out.counts.out_of_range += c.out_of_range;
  });
  if (options_.smoothing_radius > 0) smooth(out);
  reset();
}

void ProjectorViewDecoder::smooth(DecodedView& out) {
  raw_coordinate_.swap(out.coordinate);
  out.coordinate.resize(raw_coordinate_.size());
  const int w = width_, h = height_;
  const int radius = options_.smoothing_radius;
  const float max_deviation = options_.smoothing_max_deviation_px;
  const float* raw = raw_coordinate_.data();
  // ~2 sigma of (5 x 5 mean - 3 x 3 mean): the phase noise of a pixel scales as 1 / B, and
  // is ~0.05 px at B = 30 DN on the rig (8-bit sensor, 1.5 DN read noise plus shot noise).
  constexpr float kCurvatureToleranceDnPx = 0.8f;
  const float* quality = out.quality.data();
  float* smoothed = out.coordinate.data();
  struct Sums {
    std::vector<float> wide, narrow, wide_count, narrow_count;  // counts as float: one vector type
  };
  static tbb::enumerable_thread_specific<Sums> sums_by_thread;
  tbb::parallel_for(tbb::blocked_range<int>(0, h, options_.rows_per_task), [&](const tbb::blocked_range<int>& rows) {
    Sums& sums = sums_by_thread.local();
    const auto uw = static_cast<std::size_t>(w);
    sums.wide.resize(uw);
    sums.narrow.resize(uw);
    sums.wide_count.resize(uw);
    sums.narrow_count.resize(uw);
    float* __restrict wide = sums.wide.data();
    float* __restrict narrow = sums.narrow.data();
    float* __restrict wide_count = sums.wide_count.data();
    float* __restrict narrow_count = sums.narrow_count.data();
    for (int y = rows.begin(); y < rows.end(); ++y) {
      const float* centre = raw + static_cast<std::size_t>(y) * uw;
      float* result = smoothed + static_cast<std::size_t>(y) * uw;
      std::copy(centre, centre + w, result);
      if (y < 1 || y >= h - 1 || w < 3) continue;
      const int r = (y >= radius && y < h - radius) ? radius : 1;
      std::fill(wide, wide + w, 0.0f);
      std::fill(narrow, narrow + w, 0.0f);
      std::fill(wide_count, wide_count + w, 0.0f);
      std::fill(narrow_count, narrow_count + w, 0.0f);
      // Sums of (neighbour - centre): small numbers, so float keeps ~1e-6 px. NaN (masked)
      // neighbours fail the self-comparison and are left out.
      for (int dv = -r; dv <= r; ++dv) {
        const float* row = raw + static_cast<std::size_t>(y + dv) * uw;
        for (int du = -r; du <= r; ++du) {
          const bool inner = du >= -1 && du <= 1 && dv >= -1 && dv <= 1;
          const float* shifted = row + du;
          if (inner) {
            for (int x = r; x < w - r; ++x) {
              const float value = shifted[x];
              const bool ok = value == value;
              const float delta = ok ? value - centre[x] : 0.0f;
              const float one = ok ? 1.0f : 0.0f;
              wide[x] += delta;
              wide_count[x] += one;
              narrow[x] += delta;
              narrow_count[x] += one;
            }
          } else {
            for (int x = r; x < w - r; ++x) {
              const float value = shifted[x];
              const bool ok = value == value;
              wide[x] += ok ? value - centre[x] : 0.0f;
              wide_count[x] += ok ? 1.0f : 0.0f;
            }
          }
        }
      }
      const auto full_wide = static_cast<float>((2 * r + 1) * (2 * r + 1));
      for (int x = r; x < w - r; ++x) {
        if (!(centre[x] == centre[x])) continue;
        const float mean_wide = wide[x] / full_wide;
        const float mean_narrow = narrow[x] / 9.0f;
        if (wide_count[x] == full_wide) {
          if (std::fabs(mean_wide) <= max_deviation) {
            // A window mean is biased by the coordinate's curvature, in proportion to the
            // window's second moment (4 for 5 x 5, 4/3 for 3 x 3). Where the two means differ
            // by more than noise (the limb of a sphere, a fillet), extrapolate the bias away
            // (Richardson: 1.5 m3 - 0.5 m5); elsewhere the 5 x 5 mean has the least noise.
            const float tolerance =
                kCurvatureToleranceDnPx /
                std::max(quality[static_cast<std::size_t>(y) * uw + static_cast<std::size_t>(x)], 1.0f);
            const bool curved = r == 2 && std::fabs(mean_wide - mean_narrow) > tolerance;
            result[x] = centre[x] + (curved ? 1.5f * mean_narrow - 0.5f * mean_wide : mean_wide);
          } else if (narrow_count[x] == 9.0f && std::fabs(mean_narrow) <= max_deviation) {
            result[x] = centre[x] + mean_narrow;
          }
        } else if (wide_count[x] >= 6.0f) {
          // Part of the window is masked (a shadow border, an edge): a one-sided mean would
          // be biased by the coordinate's slope, so fit a plane to the valid neighbours and
          // take its value at the centre. Only edge pixels get here.
          float value;
          if (plane_fit_at_centre(raw, uw, x, y, r, value) && std::fabs(value) <= max_deviation)
            result[x] = centre[x] + value;
        }
      }
    }
  });
}

}  // namespace slscan::core
