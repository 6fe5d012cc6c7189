// Auto-exposure (docs/hdr.md, "Auto-exposure"): from white and black frames captured at a
// ladder of exposures (the metering pass), the exposure or the bracket a scan should use.
//
// A pixel of a projector's light is *usable* at an exposure when its white frame is below the
// clip level and white - black reaches the contrast the decoder needs; it is
// *lit* when it is usable at some rung, clipped at some, or shows light (a quarter of that
// contrast) at the longest. Lit pixels usable at no rung of the ladder (a highlight that clips
// even at the shortest, a surface too dark even at the longest, a grazing edge) are
// *unreachable*: reported, but no choice changes them, so the limits are on the others. The
// choice is the fewest rungs that leave at most `max_saturated_share` of the lit pixels clipped
// at the shortest chosen exposure where a shorter rung would read them, and at most
// `max_dark_share` too faint where a longer one would, within the time budget: one exposure
// where one does (the one nearest the reference, the exposure the board's timing was made
// for), else greedily the rung that makes the most lit pixels usable; then rungs for pixels
// read only weakly where a rung within the bracket's span reads them well. The merge of a
// bracket (exposure_merge.hpp) then takes each pixel from its best exposure.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace slscan::core {

// One projector's white and black frame at one rung of the ladder, row-major, same size for all.
struct MeteringFrames {
  double exposure_us = 0;
  int projector = 0;
  std::vector<std::uint16_t> white, black;
};

struct AutoExposureOptions {
  double max_saturated_share = 0.01;  // of the lit pixels, left clipped where a shorter rung reads them
  double max_dark_share = 0.01;       // of the lit pixels, left faint where a longer rung reads them
  double min_contrast_dn = 12;        // white - black a usable pixel needs (DN of the frames)
  int saturation_dn = 255;            // the clip level: a white frame at or above it clipped
  // The scan's cost per rung: frames_per_exposure frames at a period of the longest chosen
  // exposure + readout_allowance_us, at least min_period_us. 0 seconds: no budget.
  std::size_t frames_per_exposure = 0;
  double readout_allowance_us = 0;
  double min_period_us = 0;
  double time_budget_s = 0;
  std::size_t max_exposures = 8;  // the protocol's bracket limit
  // The modulation: a pixel read below full scale / max_ratio at every chosen exposure where a
  // rung up to the longer of the chosen and the reference reads it above: that rung is added
  // while at least min_weak_share of the lit pixels are such.
  double max_ratio = 4;
  double min_weak_share = 0.001;
  double reference_us = 0;  // the board's exposure: preferred among single exposures that do
  // Throws std::invalid_argument naming the first impossible field.
  void check() const;
};

// What one rung saw, shares of the lit pixels (projectors together): usable, clipped, neither.
struct RungMeter {
  double exposure_us = 0;
  double usable_share = 0;
  double clipped_share = 0;
  double dark_share = 0;
};

struct AutoExposureChoice {
  std::vector<double> exposures_us;  // chosen, ascending; one for a single exposure
  std::size_t lit_pixels = 0;        // projectors together
  double usable_share = 0;           // of the lit pixels, usable at some chosen exposure
  double saturated_share = 0;        // not usable at a chosen exposure, clipped at the shortest
  double dark_share = 0;             // not usable at a chosen exposure, too faint at all
  double unreachable_share = 0;      // usable at no rung of the ladder (in neither share above)
  bool met = false;                  // both shares within their limits
  double period_us = 0;              // longest chosen + read-out allowance, >= min_period_us
  double capture_s = 0;              // frames_per_exposure x chosen x period (0 without a cost)
  std::vector<RungMeter> rungs;      // the ladder, as metered
  std::string reason;                // why the choice stopped where it did
};

// The ladder to meter: reference x 2^k (k = -3 .. 4, 8 rungs, the bracket limit) within
// [min_us, max_us]. With mains_hz (50 or 60) the ambient light flickers at twice that, and an
// exposure that is not a whole number of flicker periods catches a varying share of it: the
// rungs are then 1, 2, 3, 4, 6, 8, 12, 16 flicker periods (10 ms at 50 Hz) within the limits.
// Throws std::invalid_argument if no rung fits (naming the limits) or on a mains other than
// 0, 50, 60.
std::vector<double> metering_ladder(double reference_us, double min_us, double max_us, int mains_hz);

// Throws std::invalid_argument on no frames, frames of different sizes or of an exposure not
// in the ladder, more than 8 rungs, or a projector missing at some rung.
AutoExposureChoice choose_exposures(const std::vector<MeteringFrames>& frames, const AutoExposureOptions& options);

}  // namespace slscan::core
