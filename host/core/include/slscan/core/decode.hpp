// Stage 1: decode one projector-view (the frames of one slproto::PatternPlan seen by the
// camera) into the continuous projector coordinate along the plan's coding axis, per camera
// pixel, with the phase modulation as quality and a mask of what could not be decoded.
//
// Conventions (docs/conventions.md): the wrapped phase is
// phi = atan2(-sum I_n sin d_n, sum I_n cos d_n) in [0, 2 pi), d_n = 2 pi n / N; the order k
// comes from the Gray bits; with the complementary bit, K2 is used where phi is in [0, pi/2)
// and K2 - 1 where phi is in [3 pi/2, 2 pi); without it, k - 1 where phi is in
// [2 pi (1 - 0.5 / P), 2 pi) (the Gray edge lies half a pixel before the phase wrap, between
// projector pixels); x_p = (phi + 2 pi order) P / (2 pi), so a camera
// pixel that sees the centre of projector column 100 decodes to 100.0.
//
// The phase steps' shifts are the plan's (PatternPlanConfig::phase_shift_rad: another
// scanner's phase origin is removed, so the coordinate keeps our convention).
//
// Saturation by frame kind: a pixel at the clip level in a frame invalidates only what that
// frame corrupts: any phase frame, the phase; the black frame, the threshold; a Gray (or
// complementary) frame, nothing while the clip level stays clear of the bit's threshold
// (clipping keeps a bright bit bright); with inverse Gray frames, a bit whose frame and
// inverse both clip; the white frame, the threshold of a plan whose position comes from the
// Gray edges (no phase, or phase without the complementary bit's half-period margin).
//
// Self-checks (decode_checks.hpp): finish() measures, on a sample of rows, how consistent the
// redundant codes are, and names the likely cause where they contradict the plan.
//
// A Gray bit is 1 where its frame is brighter than half of white + black (or, without
// white/black frames, than the phase frames' mean); with inverse Gray frames, where it is
// brighter than its inverse. Without phase steps the coordinate is a Gray step's centre, or
// SLStudio's pixel of it (PatternPlanConfig::gray_low_bits).
//
// Frames are copied into a per-pattern store as they stream in (the camera's buffer goes back
// to the driver at once); finish() then decodes in tiles of rows over all planes at once,
// threaded over row blocks. See docs/pipeline.md for why this beats accumulating per frame.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "slproto/pattern_plan.hpp"
#include "slscan/core/decode_checks.hpp"

namespace slscan::core {

struct DecodeOptions {
  int bit_depth = 8;               // 8 (uint8 frames) or 10/12/16 (uint16 frames)
  float min_contrast_dn = 12.0f;   // white - black below this: too dark or too far to code
  float min_modulation_dn = 6.0f;  // phase modulation B below this: unreliable phase
  // A pixel at or above this level in a frame is clipped there (what that invalidates depends
  // on the frame's kind, above); 0 means the top code of bit_depth (255 for 8 bit); the full
  // scale 2^bit_depth (256 for 8 bit) means never.
  int saturation_dn = 0;
  int rows_per_task = 16;  // rows per TBB task: all planes of a block stay in cache
  // Noise reduction of the decoded coordinate over a (2 r + 1)^2 window centred on the pixel:
  // where the whole window decoded, its mean (a symmetric window keeps a linear ramp
  // unbiased); where part of it is masked, the value at the centre of a least-squares plane
  // through the valid pixels (a one-sided mean would be biased by the slope). Used only if it
  // stays within smoothing_max_deviation_px of the pixel's own value (no averaging across
  // depth edges; then the 3 x 3 mean, then the raw value). 0 turns it off. Sensor noise in the
  // phase is the largest per-pixel error on the rig; a 5 x 5 window divides it by ~5.
  int smoothing_radius = 2;
  // Where the whole (2 q + 1)^2 window around a pixel decoded, its value is instead the centre
  // of a least-squares quadratic surface through the window (a 2-D Savitzky-Golay kernel), if
  // that agrees with the 5 x 5 value within 1.6 / B px (and passes the same deviation gate). A
  // window mean is biased by the coordinate's curvature (its Laplacian times the window's
  // second moment): on the full rig's spheres the 5 x 5 mean puts every point ~4.5 um inside,
  // so each sphere measures ~12 um small (PS). The quadratic is unbiased there and, at q = 4
  // (9 x 9), as quiet as the 5 x 5 mean (variance 0.044 vs 0.040 of a pixel's). Off (0) by
  // default: with it the registered blade model reads worse (registration, not the views: see
  // docs/accuracy.md, "PS"). Otherwise 3 to 6, and only with smoothing on.
  int quadratic_radius = 0;
  float smoothing_max_deviation_px = 0.25f;
  // Noise-adaptive gate: the deviation limit is at least noise_factor x the view's own
  // coordinate noise (noise_estimate.hpp, from the unsmoothed coordinate of the better-lit
  // half of the view, differences modulo the period), so a noisy scanner's pixels are smoothed
  // rather than left raw; 0 keeps the fixed limit.
  float noise_factor = 3.0f;
  // Measure the codes' consistency after decoding (decode_checks.hpp); costs a sample of
  // ~64 k pixels whatever the image size.
  bool self_check = true;

  int saturation_level() const { return saturation_dn > 0 ? saturation_dn : (1 << bit_depth) - 1; }
  // Throws std::invalid_argument naming the first impossible field.
  void check() const;
};

// Why a pixel was masked (one reason per pixel, the first that applies in this order).
enum class DecodeMask : std::uint8_t {
  valid = 0,
  saturated = 1,  // at the top code in some frame: its intensities are clipped
  // white - black (or the phase peak-to-peak; or with inverse Gray frames, the second smallest
  // |bit - inverse| over the code bits) below min_contrast_dn
  low_contrast = 2,
  low_modulation = 3,  // phase modulation below min_modulation_dn
  out_of_range = 4,    // decoded coordinate outside the projector's coded extent
};

// Pixels at the clip level in at least one frame of each kind, whether or not that
// invalidated them (DecodeCounts::saturated counts those it did).
struct SaturationCounts {
  std::size_t white = 0, black = 0, gray = 0, phase = 0;  // gray: Gray and complementary frames, inverses too
  SaturationCounts& operator+=(const SaturationCounts& o) {
    white += o.white;
    black += o.black;
    gray += o.gray;
    phase += o.phase;
    return *this;
  }
};

struct DecodeCounts {
  std::size_t valid = 0, saturated = 0, low_contrast = 0, low_modulation = 0, out_of_range = 0;
  SaturationCounts clipped;  // by frame kind
  std::size_t total() const { return valid + saturated + low_contrast + low_modulation + out_of_range; }
};

// Per camera pixel (row-major, index = v * width + u).
struct DecodedView {
  int width = 0, height = 0;
  slproto::CodingAxis axis = slproto::CodingAxis::columns;
  std::vector<float> coordinate;  // projector coordinate along the axis (px); NaN where masked
  std::vector<float> quality;     // phase modulation B (DN), or Gray contrast without phase; 0 masked
  // The surface's albedo as the camera saw it, every pixel (masked ones too): white - black as a
  // fraction of the full scale 2^bit_depth - 1 (ambient removed), clamped to >= 0; without
  // white/black frames the phase peak-to-peak 2 B, without phase either the largest
  // |Gray frame - inverse| over the code bits (docs/pipeline.md).
  std::vector<float> intensity;
  std::vector<DecodeMask> mask;
  DecodeCounts counts;
  DecodeChecks checks;                   // with DecodeOptions::self_check
  float coordinate_noise_px = 0;         // the unsmoothed coordinate's per-pixel noise, estimated from the data
  float smoothing_max_deviation_px = 0;  // the deviation limit the smoothing used
};

// Decodes the frames of one projector-view. Reusable: after finish(), reset() (or
// finish() itself) readies it for the next view without reallocating.
class ProjectorViewDecoder {
 public:
  // Throws std::invalid_argument if the plan can't be decoded (neither white/black, inverse
  // Gray frames nor phase steps to threshold the Gray bits against), the size is impossible or options fail check().
  ProjectorViewDecoder(const slproto::PatternPlan& plan, int width, int height, const DecodeOptions& options = {});

  int width() const { return width_; }
  int height() const { return height_; }
  const slproto::PatternPlan& plan() const { return plan_; }
  const DecodeOptions& options() const { return options_; }

  // Pattern `pattern_index` of the plan seen by the camera; stride in elements (pixels) per
  // row, >= width. The 8-bit form needs bit_depth 8, the 16-bit form bit_depth > 8. Frames may
  // come in any order; a repeated index replaces the earlier frame. Throws on misuse.
  void add_frame(std::size_t pattern_index, const std::uint8_t* data, std::size_t stride);
  void add_frame(std::size_t pattern_index, const std::uint16_t* data, std::size_t stride);

  bool has_frame(std::size_t pattern_index) const { return present_.at(pattern_index) != 0; }
  bool complete() const;

  // Decodes; throws std::logic_error naming the missing pattern if a frame is missing.
  DecodedView finish();
  // Same, into an existing result whose buffers are reused.
  void finish(DecodedView& out);
  void reset();

 private:
  template <class Pixel>
  void store_frame(std::size_t pattern_index, const Pixel* data, std::size_t stride);
  void smooth(DecodedView& out);

  slproto::PatternPlan plan_;
  int width_ = 0, height_ = 0;
  DecodeOptions options_;
  std::size_t bytes_per_pixel_ = 1;
  std::vector<std::uint8_t> store_;  // one plane per pattern, width * height pixels each
  std::vector<std::uint8_t> present_;
  // Where each kind of pattern sits in the plan (-1 if absent), in decode order.
  int white_ = -1, black_ = -1, complementary_ = -1, complementary_inverse_ = -1;
  std::vector<int> gray_;          // gray_[bit] = pattern index, bit 0 = most significant
  std::vector<int> gray_inverse_;  // its inverse frame, when the plan has them
  std::vector<int> phase_;         // phase_[n] = pattern index of step n
  std::vector<int> code_frames_;   // every Gray and complementary frame and their inverses
  std::vector<float> phase_cos_, phase_sin_;
  std::vector<float> raw_coordinate_;  // before smoothing, reused
};

}  // namespace slscan::core
