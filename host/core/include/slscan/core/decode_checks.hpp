// Self-checks of a decoded projector-view: where the plan's codes are redundant, how well
// they agree with each other, measured from the frames themselves on a sample of rows, and
// what the disagreement most likely means. A capture whose description is wrong (phase frames
// rotated, reversed or one short, Gray bits reversed or shifted by a frame, a continuous
// phase-origin offset) decodes without any error but contradicts itself here; a right one
// does not (docs/pipeline.md, "Self-checks"; docs/real-data.md, "When the result looks wrong").
//
// What is measured (each only where the plan has what it needs; NaN otherwise):
//  * phase frames against each other: the shift of each listed frame, from the frames'
//    covariance over the sampled pixels (its two leading eigenvectors place the frames on a
//    circle), and the share of their variance a sinusoid explains: an N-step sequence steps by
//    360 / N degrees in the plan's order;
//  * the phase origin against the Gray code: with the complementary bit, the circular mean of
//    the wrapped phase minus the centre of its half period; without it, the circular mean of
//    the phase where the Gray order steps between neighbouring pixels. 0 when they agree;
//  * the phase direction against the Gray code: at neighbouring pixels whose Gray order (or
//    half period) differs by one, whether the phase advances the same way;
//  * the complementary bit against the phase: the share of pixels (a quarter period clear of
//    its edges) where the bit agrees with the half period the phase says;
//  * Gray code continuity: among neighbouring pixels whose orders differ, the share that
//    differ by one (a Gray code changes one bit per step); and each code frame's flip rate
//    between neighbours (bit i+1 flips twice as often as bit i);
//  * period jumps: neighbouring pixels whose coordinates differ by more than half a period.
//
// The checks read the decoder's stored planes and its output; they are independent of the
// decoder's inner loop (a scalar re-decode of the sampled pixels), so a faster inner loop keeps
// them as they are.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "slproto/pattern_plan.hpp"

namespace slscan::core {

struct DecodedView;
struct DecodeOptions;

// One contradiction found, in words a user can act on.
struct DecodeFinding {
  std::string check;  // "phase_order", "phase_direction", "phase_offset", "complementary", "gray_order", ...
  std::string cause;  // "the phase frames look rotated by 4 steps"
  std::string fix;    // "list them from frame 4, or set phase.offset_steps = 4"
  std::string message() const { return cause + ": " + fix; }
};

struct DecodeChecks {
  bool ran = false;
  int row_step = 0;                // rows sampled: pairs (v, v + 1) every row_step rows
  std::size_t sampled_pixels = 0;  // decoded (valid) pixels among them
  // Phase frames (NaN / empty without phase steps).
  std::vector<double> phase_shift_deg;  // per listed frame, relative to the first, in [0, 360)
  double sinusoid_share = 0;            // of the frames' variance, in [0, 1]
  double phase_offset_rad = 0;          // phase origin against the Gray code, (-pi, pi]
  double phase_offset_consistency = 0;  // 1: every pixel agrees on it; ~0: no common offset
  double phase_direction_agreement = 0;
  double complementary_agreement = 0;
  // Gray code.
  double gray_continuity = 0;
  std::vector<double> gray_flip_rate;  // per code frame: Gray bits MSB first, then the complementary bit
  double period_jump_rate = 0;         // of neighbouring decoded pairs
  // Which of the above were measured (enough pixels, and the plan has what they need).
  bool has_phase = false, has_offset = false, has_direction = false, has_complementary = false, has_gray = false;
  std::vector<DecodeFinding> findings;
  bool flagged() const { return !findings.empty(); }
};

// Thresholds below which a check is a finding. The defaults leave every capture of the
// virtual rig (all presets, both sizes) and the SLStudio skull unflagged, with margin.
struct DecodeCheckLimits {
  std::size_t min_pixels = 500;          // fewer sampled decoded pixels: nothing is judged
  double min_sinusoid_share = 0.75;      // the phase frames are one sinusoid sequence
  double max_step_error_deg = 12;        // each measured step within this of 360 / N
  double max_offset_rad = 0.2;           // 0.25 px at P = 8
  double min_offset_consistency = 0.5;   // below: the offset itself is not trusted
  double min_direction_agreement = 0.6;  // below 0.4 the phase runs backwards
  double min_complementary_agreement = 0.9;
  double min_gray_continuity = 0.8;
  double max_period_jump_rate = 0.1;  // a plan without the complementary bit has a few % under blur
};

// Raw frames as stored by the decoder: one plane per pattern, width * height pixels each,
// uint8 or uint16.
struct FramePlanes {
  const void* data = nullptr;
  bool sixteen_bit = false;
  int width = 0, height = 0;
};

// Runs the checks on `view` (its mask and counts as decoded) and the frames it came from;
// `unsmoothed` is the coordinate before the decoder's smoothing (same layout as
// view.coordinate). Deterministic: a fixed sample of rows, sums in a fixed order.
DecodeChecks check_decoded_view(const slproto::PatternPlan& plan, const FramePlanes& frames,
                                const std::vector<float>& unsmoothed, const DecodedView& view,
                                const DecodeOptions& options, const DecodeCheckLimits& limits = {});

}  // namespace slscan::core
