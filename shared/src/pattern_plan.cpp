#include "slproto/pattern_plan.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>

namespace slproto {

const char* pattern_kind_name(PatternKind kind) noexcept {
  switch (kind) {
    case PatternKind::white:
      return "white";
    case PatternKind::black:
      return "black";
    case PatternKind::gray_bit:
      return "gray_bit";
    case PatternKind::complementary_bit:
      return "complementary_bit";
    case PatternKind::phase_step:
      return "phase_step";
    case PatternKind::gray_bit_inverse:
      return "gray_bit_inverse";
    case PatternKind::complementary_bit_inverse:
      return "complementary_bit_inverse";
  }
  return "unknown";
}

const char* gray_low_bits_name(GrayLowBits convention) noexcept {
  switch (convention) {
    case GrayLowBits::centre:
      return "centre";
    case GrayLowBits::slstudio_parity:
      return "slstudio_parity";
  }
  return "unknown";
}

const char* coding_axis_name(CodingAxis axis) noexcept { return axis == CodingAxis::columns ? "columns" : "rows"; }

int PatternPlanConfig::period_count() const { return period_px > 0 ? (coded_extent() + period_px - 1) / period_px : 0; }

int PatternPlanConfig::gray_bits() const {
  int bits = 0;
  while ((1 << bits) < period_count()) ++bits;
  return bits;
}

Status PatternPlanConfig::check() const {
  auto fail = [](std::string msg) { return make_error(Errc::invalid_argument, "pattern plan: " + msg); };
  if (projector_width < 2 || projector_width > 16384)
    return fail("projector_width " + std::to_string(projector_width) + " outside [2, 16384]");
  if (projector_height < 2 || projector_height > 16384)
    return fail("projector_height " + std::to_string(projector_height) + " outside [2, 16384]");
  if (axis != CodingAxis::columns && axis != CodingAxis::rows) return fail("axis is neither columns nor rows");
  if (period_px < 2 || period_px > coded_extent())
    return fail("period_px " + std::to_string(period_px) + " outside [2, coded extent " +
                std::to_string(coded_extent()) + "]");
  if (complementary_bit && period_px % 2 != 0)
    return fail("the complementary bit needs an even period_px, got " + std::to_string(period_px));
  if (phase_steps != 0 && (phase_steps < 3 || phase_steps > 64))
    return fail("phase_steps " + std::to_string(phase_steps) + " must be 0 (no phase shift) or in [3, 64]");
  if (!std::isfinite(phase_offset_rad) || std::abs(phase_offset_rad) > 2 * std::numbers::pi)
    return fail("phase_offset_rad " + std::to_string(phase_offset_rad) + " is not a finite angle within [-2 pi, 2 pi]");
  if (phase_steps == 0 && (phase_offset_rad != 0 || phase_offset_steps != 0))
    return fail("phase_offset_rad / phase_offset_steps need phase steps");
  if (phase_offset_steps < 0 || (phase_steps > 0 && phase_offset_steps >= phase_steps))
    return fail("phase_offset_steps " + std::to_string(phase_offset_steps) + " outside [0, phase_steps " +
                std::to_string(phase_steps) + ")");
  if (gray_low_bits != GrayLowBits::centre && gray_low_bits != GrayLowBits::slstudio_parity)
    return fail("gray_low_bits is neither centre nor slstudio_parity");
  if (gray_low_bits == GrayLowBits::slstudio_parity) {
    // The convention is about a Gray code's unshown low bits: with phase steps the phase gives
    // the position within a period, and a step of g pixels must be g = 2^s.
    if (phase_steps != 0)
      return fail("gray_low_bits slstudio_parity applies to a Gray code without phase steps, got phase_steps " +
                  std::to_string(phase_steps));
    const int step = complementary_bit ? period_px / 2 : period_px;
    if (step < 2 || (step & (step - 1)) != 0)
      return fail("gray_low_bits slstudio_parity needs a Gray step of 2^s pixels (the unshown low bits), got " +
                  std::to_string(step));
  }
  return Ok{};
}

double PatternPlanConfig::phase_shift_rad(int n) const {
  if (phase_steps <= 0) return 0.0;
  return phase_offset_rad + 2.0 * std::numbers::pi * (n - phase_offset_steps) / phase_steps;
}

Result<PatternPlan> PatternPlan::make(const PatternPlanConfig& config) {
  if (auto status = config.check(); !status) return status.error();
  return PatternPlan(config);
}

PatternPlan::PatternPlan(const PatternPlanConfig& config) : config_(config) {
  if (auto status = config.check(); !status) throw std::invalid_argument(status.error().message);
  const CodingAxis axis = config.axis;
  if (config.with_white_black) {
    patterns_.push_back({PatternKind::white, 0, axis});
    patterns_.push_back({PatternKind::black, 0, axis});
  }
  for (int bit = 0; bit < config.gray_bits(); ++bit) {
    patterns_.push_back({PatternKind::gray_bit, static_cast<std::uint16_t>(bit), axis});
    if (config.inverse_gray)
      patterns_.push_back({PatternKind::gray_bit_inverse, static_cast<std::uint16_t>(bit), axis});
  }
  if (config.complementary_bit) {
    patterns_.push_back({PatternKind::complementary_bit, 0, axis});
    if (config.inverse_gray) patterns_.push_back({PatternKind::complementary_bit_inverse, 0, axis});
  }
  for (int n = 0; n < config.phase_steps; ++n)
    patterns_.push_back({PatternKind::phase_step, static_cast<std::uint16_t>(n), axis});
}

int PatternPlan::index_of(PatternKind kind, int index) const {
  for (std::size_t i = 0; i < patterns_.size(); ++i)
    if (patterns_[i].kind == kind && patterns_[i].index == index) return static_cast<int>(i);
  return -1;
}

float PatternPlan::value(std::size_t i, double coord) const {
  const Pattern& pattern = patterns_.at(i);
  const double period = config_.period_px;
  switch (pattern.kind) {
    case PatternKind::white:
      return 1.0f;
    case PatternKind::black:
      return 0.0f;
    case PatternKind::gray_bit:
    case PatternKind::gray_bit_inverse: {
      // Gray bit `index` (0 = MSB of gray_bits()) of the fringe order k = floor(x / P).
      // Coordinates left of 0 or beyond the extent clamp to the first / last order.
      const auto k = static_cast<std::uint32_t>(
          std::clamp(std::floor(coord / period), 0.0, static_cast<double>(config_.period_count() - 1)));
      const int shift = config_.gray_bits() - 1 - pattern.index;
      const std::uint32_t bit = (binary_to_gray(k) >> shift) & 1u;
      return static_cast<float>(pattern.kind == PatternKind::gray_bit ? bit : 1u - bit);
    }
    case PatternKind::complementary_bit:
    case PatternKind::complementary_bit_inverse: {
      const auto h = static_cast<std::uint32_t>(
          std::clamp(std::floor(2.0 * coord / period), 0.0, static_cast<double>(2 * config_.period_count() - 1)));
      const std::uint32_t bit = binary_to_gray(h) & 1u;
      return static_cast<float>(pattern.kind == PatternKind::complementary_bit ? bit : 1u - bit);
    }
    case PatternKind::phase_step: {
      const double two_pi = 2.0 * std::numbers::pi;
      const double phase = two_pi * coord / period + config_.phase_shift_rad(pattern.index);
      return static_cast<float>(0.5 + 0.5 * std::cos(phase));
    }
  }
  return 0.0f;
}

std::vector<float> PatternPlan::profile(std::size_t i) const {
  std::vector<float> out(static_cast<std::size_t>(config_.coded_extent()));
  for (std::size_t x = 0; x < out.size(); ++x) out[x] = value(i, static_cast<double>(x));
  return out;
}

void PatternPlan::render(std::size_t i, std::span<std::uint8_t> image) const {
  const auto w = static_cast<std::size_t>(config_.projector_width);
  const auto h = static_cast<std::size_t>(config_.projector_height);
  if (image.size() < w * h) throw std::invalid_argument("pattern render: image buffer smaller than width x height");
  const std::vector<float> line = profile(i);
  std::vector<std::uint8_t> levels(line.size());
  for (std::size_t x = 0; x < line.size(); ++x) levels[x] = static_cast<std::uint8_t>(std::lround(255.0f * line[x]));
  for (std::size_t y = 0; y < h; ++y)
    for (std::size_t x = 0; x < w; ++x) image[y * w + x] = config_.axis == CodingAxis::columns ? levels[x] : levels[y];
}

}  // namespace slproto
