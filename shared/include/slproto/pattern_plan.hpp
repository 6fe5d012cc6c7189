// The pattern plan: the one definition of what the projectors show, used by the firmware,
// the virtual rig and the host decoder alike.
//
// Conventions (docs/conventions.md):
//  * Projector pixel centres are at integer coordinates; column x covers [x - 0.5, x + 0.5].
//  * Phase: phi(x) = 2 pi x / P. Phase frame n (0-based) shows
//        I_n(x) = 0.5 + 0.5 cos(phi(x) + o + 2 pi (n - s) / N),
//    o = phase_offset_rad, s = phase_offset_steps (both 0 in our own plans): another scanner's
//    phase origin. s says which frame shows our step 0 (the list rotated by s frames); o is a
//    continuous offset of the origin (the phase the frames show at coordinate 0).
//  * Gray order k = floor(x / P). The m Gray frames show the reflected binary Gray code of k,
//    most significant bit first. With the complementary bit, one more frame shows the least
//    significant bit of the Gray code of the half-period index h = floor(2 x / P); the top m
//    bits of gray(h) equal gray(k), so the m + 1 frames together give h, and the
//    complementary order K2 = floor((h + 1) / 2) = floor((x + P / 2) / P) is shifted by half a
//    period against k. The decoder uses K2 where the wrapped phase is near a period edge.
//  * Inverse Gray frames (inverse_gray): each Gray bit, and the complementary bit, is
//    followed by its inverse (1 - value). The decoder then reads a bit as 1 where the frame is
//    brighter than its inverse, a threshold that needs no white/black frames.
//  * Pattern images are rendered at pixel centres (x = column index); a bright pixel is 1.0.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "slproto/result.hpp"

namespace slproto {

enum class CodingAxis : std::uint8_t { columns = 0, rows = 1 };

enum class PatternKind : std::uint8_t {
  white = 0,
  black = 1,
  gray_bit = 2,           // index = bit number, 0 = most significant
  complementary_bit = 3,  // the half-period Gray bit (index 0)
  phase_step = 4,         // index = step n in 0..N-1
  gray_bit_inverse = 5,   // the inverse of gray_bit `index`, shown right after it
  complementary_bit_inverse = 6,
};

// Which projector coordinate a Gray code without phase steps decodes to. A decoded step c
// numbers the g = period_px (or period_px / 2 with the complementary bit) pixels
// c g ... c g + g - 1 of the coding axis.
enum class GrayLowBits : std::uint8_t {
  // Their centre, c g + (g - 1) / 2: the estimate with the smallest error for a pixel that
  // may see any of them.
  centre = 0,
  // SLStudio's DecoderGrayCode (jakobwilm/slstudio), which reads the unshown low bits of the
  // code as 0 and converts that word to binary: its low bits all equal c's parity, so it
  // returns c g + (c & 1) (g - 1), the first pixel of the step for even c and the last for odd
  // c. Needs a power-of-two g (the unshown bits of a binary code). For reprocessing captures
  // whose calibration and reference were made with that decoder (docs/real-data.md).
  slstudio_parity = 1,
};

const char* pattern_kind_name(PatternKind kind) noexcept;
const char* coding_axis_name(CodingAxis axis) noexcept;
const char* gray_low_bits_name(GrayLowBits convention) noexcept;  // "centre", "slstudio_parity"

struct Pattern {
  PatternKind kind = PatternKind::white;
  std::uint16_t index = 0;
  CodingAxis axis = CodingAxis::columns;
  bool operator==(const Pattern&) const = default;
};

struct PatternPlanConfig {
  int projector_width = 1140;  // DLP4500 coding axis (columns)
  int projector_height = 912;
  CodingAxis axis = CodingAxis::columns;
  int period_px = 8;    // fringe period P in projector pixels
  int phase_steps = 8;  // N
  bool complementary_bit = true;
  bool with_white_black = true;
  bool inverse_gray = false;                        // each Gray (and complementary) bit followed by its inverse frame
  GrayLowBits gray_low_bits = GrayLowBits::centre;  // only for plans without phase steps
  // Another scanner's phase origin (see above); only with phase steps. The decoder removes it,
  // so the decoded coordinate keeps our convention.
  double phase_offset_rad = 0;  // finite, within [-2 pi, 2 pi]
  int phase_offset_steps = 0;   // in [0, phase_steps)
  // The phase step n's total shift o + 2 pi (n - s) / N (radians).
  double phase_shift_rad(int n) const;
  bool operator==(const PatternPlanConfig&) const = default;

  // Coded extent along the axis (width for columns, height for rows).
  int coded_extent() const { return axis == CodingAxis::columns ? projector_width : projector_height; }
  // Number of fringe periods and of Gray bits needed to number them.
  int period_count() const;
  int gray_bits() const;
  // Frames of the code bits: Gray bits and the complementary bit, with their inverses.
  int code_frames() const { return (gray_bits() + (complementary_bit ? 1 : 0)) * (inverse_gray ? 2 : 1); }
  Status check() const;  // names the first impossible field
};

class PatternPlan {
 public:
  // The paper's plan: white, black, 8 Gray bits + complementary bit, 8 phase steps, P = 8.
  PatternPlan() : PatternPlan(PatternPlanConfig{}) {}
  // Builds the ordered list; config must pass check() (throws std::invalid_argument if not:
  // use make() on outside input).
  explicit PatternPlan(const PatternPlanConfig& config);
  static Result<PatternPlan> make(const PatternPlanConfig& config);

  const PatternPlanConfig& config() const { return config_; }
  const std::vector<Pattern>& patterns() const { return patterns_; }
  std::size_t size() const { return patterns_.size(); }
  const Pattern& operator[](std::size_t i) const { return patterns_[i]; }

  // Index of the first pattern of each kind in the sequence, or -1.
  int index_of(PatternKind kind, int index = 0) const;

  // Value in [0, 1] of pattern i at projector coordinate `coord` along the coding axis,
  // for continuous coord (sampled at the pixel centre when coord is an integer).
  float value(std::size_t i, double coord) const;

  // The 1D profile of pattern i along the coding axis: one value per projector pixel.
  std::vector<float> profile(std::size_t i) const;

  // Renders pattern i as an 8-bit image (projector_width x projector_height, stride = width).
  void render(std::size_t i, std::span<std::uint8_t> image) const;

 private:
  PatternPlanConfig config_;
  std::vector<Pattern> patterns_;
};

// Reflected binary Gray code and its inverse.
constexpr std::uint32_t binary_to_gray(std::uint32_t n) { return n ^ (n >> 1); }
constexpr std::uint32_t gray_to_binary(std::uint32_t g) {
  g ^= g >> 16;
  g ^= g >> 8;
  g ^= g >> 4;
  g ^= g >> 2;
  g ^= g >> 1;
  return g;
}

}  // namespace slproto
