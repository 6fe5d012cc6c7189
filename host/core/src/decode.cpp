#include "slscan/core/decode.hpp"

#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <string>

#include "decode_rows.hpp"
#include "decode_smoothing.hpp"
#include "slproto/number_text.hpp"
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
  // `out` may hold an earlier view: every field is set here or below, every pixel written.
  out.coordinate_noise_px = 0;
  out.smoothing_max_deviation_px = 0;
  out.coordinate.resize(n);
  out.quality.resize(n);
  out.intensity.resize(n);
  out.mask.resize(n);
  const auto& config = plan_.config();
  detail::DecodeRowsInput input;
  input.planes = store_.data();
  input.width = width_;
  input.height = height_;
  input.white = white_;
  input.black = black_;
  input.complementary = complementary_;
  input.complementary_inverse = complementary_inverse_;
  input.gray = gray_;
  input.gray_inverse = gray_inverse_;
  input.phase = phase_;
  input.code_frames = code_frames_;
  input.phase_sin = phase_sin_;
  input.phase_cos = phase_cos_;
  input.clip_level = static_cast<float>(options_.saturation_level());
  input.min_contrast = options_.min_contrast_dn;
  input.min_modulation = options_.min_modulation_dn;
  input.inverse_full_scale = 1.0f / static_cast<float>((1 << options_.bit_depth) - 1);
  input.period_px = static_cast<float>(config.period_px);
  input.coded_extent = static_cast<float>(config.coded_extent());
  input.slstudio_parity = config.gray_low_bits == slproto::GrayLowBits::slstudio_parity;
  const detail::DecodeRowsOutput output{out.coordinate.data(), out.quality.data(), out.intensity.data(),
                                        out.mask.data()};
  tbb::combinable<DecodeCounts> counts_by_thread;
  tbb::parallel_for(tbb::blocked_range<int>(0, height_, options_.rows_per_task), [&](const tbb::blocked_range<int>& r) {
    DecodeCounts& counts = counts_by_thread.local();
    if (bytes_per_pixel_ == 1)
      detail::decode_rows_8bit(input, r.begin(), r.end(), output, counts);
    else
      detail::decode_rows_16bit(input, r.begin(), r.end(), output, counts);
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

void ProjectorViewDecoder::smooth(DecodedView& out) {
  raw_coordinate_.swap(out.coordinate);
  out.coordinate.resize(raw_coordinate_.size());
  const int w = width_, h = height_;
  const NoiseEstimate noise =
      estimate_map_noise(raw_coordinate_, w, h, &out.quality,
                         plan_.config().phase_steps > 0 ? static_cast<float>(plan_.config().period_px) : 0.0f);
  out.coordinate_noise_px = static_cast<float>(noise.per_point);
  const float max_deviation =
      std::max(options_.smoothing_max_deviation_px, options_.noise_factor * static_cast<float>(noise.per_point));
  out.smoothing_max_deviation_px = max_deviation;
  const detail::SmoothRowsInput input{raw_coordinate_.data(),    out.quality.data(),        out.coordinate.data(), w, h,
                                      options_.smoothing_radius, options_.quadratic_radius, max_deviation};
  tbb::parallel_for(tbb::blocked_range<int>(0, h, options_.rows_per_task),
                    [&](const tbb::blocked_range<int>& rows) { detail::smooth_rows(input, rows.begin(), rows.end()); });
}

}  // namespace slscan::core
