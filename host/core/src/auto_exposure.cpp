#include "slscan/core/auto_exposure.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <map>
#include <stdexcept>
#include <tuple>
#include <utility>

#include "slproto/number_text.hpp"

namespace slscan::core {

namespace {

constexpr std::size_t kMaxRungs = 8;

using slproto::short_number;

// A lit pixel's state over the ladder: bit k of `usable` / `clipped` for rung k (ascending);
// `strong`: usable with at least full scale / max_ratio of contrast.
struct PixelClass {
  std::uint8_t usable = 0, clipped = 0, strong = 0;
  bool operator<(const PixelClass& other) const {
    return std::tie(usable, clipped, strong) < std::tie(other.usable, other.clipped, other.strong);
  }
};

struct Counts {
  std::size_t usable = 0, saturated = 0, dark = 0, unreachable = 0;
};

// Not usable at any chosen rung but at some other: clipped at the shortest chosen one (a
// shorter exposure would do) or else too faint (a longer one would). Usable at no rung of the
// ladder: unreachable, which no choice changes.
Counts count(const std::vector<std::pair<PixelClass, std::size_t>>& classes, unsigned chosen) {
  Counts out;
  const unsigned shortest = chosen & (~chosen + 1);
  for (const auto& [pixel, n] : classes) {
    if ((pixel.usable & chosen) != 0)
      out.usable += n;
    else if (pixel.usable == 0)
      out.unreachable += n;
    else if ((pixel.clipped & shortest) != 0)
      out.saturated += n;
    else
      out.dark += n;
  }
  return out;
}

}  // namespace

void AutoExposureOptions::check() const {
  auto fail = [](const std::string& what) { throw std::invalid_argument("auto-exposure: " + what); };
  if (!(max_saturated_share >= 0 && max_saturated_share < 1))
    fail("max_saturated_share " + short_number(max_saturated_share) + " outside [0, 1)");
  if (!(max_dark_share >= 0 && max_dark_share < 1))
    fail("max_dark_share " + short_number(max_dark_share) + " outside [0, 1)");
  if (!(min_contrast_dn > 0 && std::isfinite(min_contrast_dn)))
    fail("min_contrast_dn " + short_number(min_contrast_dn) + " is not a positive number");
  if (saturation_dn < 1 || saturation_dn > 65535)
    fail("saturation_dn " + std::to_string(saturation_dn) + " outside [1, 65535]");
  if (!(readout_allowance_us >= 0 && std::isfinite(readout_allowance_us)))
    fail("readout_allowance_us " + short_number(readout_allowance_us) + " is negative");
  if (!(min_period_us >= 0 && std::isfinite(min_period_us)))
    fail("min_period_us " + short_number(min_period_us) + " is negative");
  if (!(time_budget_s >= 0 && std::isfinite(time_budget_s)))
    fail("time_budget_s " + short_number(time_budget_s) + " is negative");
  if (!(max_ratio >= 2 && std::isfinite(max_ratio))) fail("max_ratio " + short_number(max_ratio) + " is below 2");
  if (!(min_weak_share >= 0 && min_weak_share < 1))
    fail("min_weak_share " + short_number(min_weak_share) + " outside [0, 1)");
  if (max_exposures < 1 || max_exposures > kMaxRungs)
    fail("max_exposures " + std::to_string(max_exposures) + " outside [1, 8]");
  if (!(reference_us >= 0 && std::isfinite(reference_us)))
    fail("reference_us " + short_number(reference_us) + " is negative");
}

std::vector<double> metering_ladder(double reference_us, double min_us, double max_us, int mains_hz) {
  if (mains_hz != 0 && mains_hz != 50 && mains_hz != 60)
    throw std::invalid_argument("auto-exposure: mains " + std::to_string(mains_hz) + " Hz is neither 50 nor 60");
  if (!(min_us > 0 && max_us >= min_us && std::isfinite(max_us)))
    throw std::invalid_argument("auto-exposure: exposure limits [" + short_number(min_us) + ", " +
                                short_number(max_us) + "] us are empty");
  if (!(reference_us > 0 && std::isfinite(reference_us)))
    throw std::invalid_argument("auto-exposure: reference exposure " + short_number(reference_us) +
                                " us is not positive");
  std::vector<double> rungs;
  auto add = [&](double exposure_us) {
    exposure_us = std::round(exposure_us);
    if (exposure_us >= min_us && exposure_us <= max_us &&
        (rungs.empty() || rungs.back() != exposure_us))  // NOLINT(clang-diagnostic-float-equal): rounded to whole us
      rungs.push_back(exposure_us);
  };
  if (mains_hz == 0) {
    for (int k = -3; k <= 4; ++k) add(std::ldexp(reference_us, k));
  } else {
    const double flicker_us = 1e6 / (2.0 * mains_hz);
    for (const int periods : {1, 2, 3, 4, 6, 8, 12, 16}) add(periods * flicker_us);
  }
  if (rungs.empty())
    throw std::invalid_argument("auto-exposure: no exposure of the metering ladder (" +
                                (mains_hz == 0 ? "the reference " + short_number(reference_us) + " us x 1/8 .. 16"
                                               : "1 .. 16 flicker periods of " + short_number(1e6 / (2.0 * mains_hz)) +
                                                     " us, --mains " + std::to_string(mains_hz)) +
                                ") lies within the exposures allowed, [" + short_number(min_us) + ", " +
                                short_number(max_us) + "] us");
  return rungs;
}

AutoExposureChoice choose_exposures(const std::vector<MeteringFrames>& frames, const AutoExposureOptions& options) {
  options.check();
  if (frames.empty()) throw std::invalid_argument("auto-exposure: no metering frames");
  std::vector<double> rungs;
  std::vector<int> projectors;
  for (const MeteringFrames& f : frames) {
    if (!(f.exposure_us > 0 && std::isfinite(f.exposure_us)))
      throw std::invalid_argument("auto-exposure: metering frames of exposure " + short_number(f.exposure_us) + " us");
    rungs.push_back(f.exposure_us);
    projectors.push_back(f.projector);
  }
  std::ranges::sort(rungs);
  rungs.erase(std::unique(rungs.begin(), rungs.end()), rungs.end());
  std::ranges::sort(projectors);
  projectors.erase(std::unique(projectors.begin(), projectors.end()), projectors.end());
  if (rungs.size() > kMaxRungs)
    throw std::invalid_argument("auto-exposure: " + std::to_string(rungs.size()) + " metered exposures (at most 8)");

  // frames_of[projector][rung]
  const std::size_t pixels = frames.front().white.size();
  std::vector<std::vector<const MeteringFrames*>> frames_of(projectors.size(),
                                                            std::vector<const MeteringFrames*>(rungs.size()));
  for (const MeteringFrames& f : frames) {
    if (pixels == 0 || f.white.size() != pixels || f.black.size() != pixels)
      throw std::invalid_argument("auto-exposure: the metering frames differ in size (or are empty)");
    const auto p = static_cast<std::size_t>(std::ranges::lower_bound(projectors, f.projector) - projectors.begin());
    const auto r = static_cast<std::size_t>(std::ranges::lower_bound(rungs, f.exposure_us) - rungs.begin());
    if (frames_of[p][r] != nullptr)
      throw std::invalid_argument("auto-exposure: projector " + std::to_string(f.projector) + " metered twice at " +
                                  short_number(f.exposure_us) + " us");
    frames_of[p][r] = &f;
  }
  for (std::size_t p = 0; p < projectors.size(); ++p)
    for (std::size_t r = 0; r < rungs.size(); ++r)
      if (frames_of[p][r] == nullptr)
        throw std::invalid_argument("auto-exposure: no metering frames of projector " + std::to_string(projectors[p]) +
                                    " at " + short_number(rungs[r]) + " us");

  // Classify every (projector, pixel); only the class counts matter from here on.
  const auto saturation = static_cast<std::uint16_t>(options.saturation_dn);
  const double faint = options.min_contrast_dn / 4;
  const double strong = options.saturation_dn / options.max_ratio;
  std::map<PixelClass, std::size_t> class_counts;
  std::vector<PixelClass> classes(pixels);
  for (std::size_t p = 0; p < projectors.size(); ++p) {
    std::ranges::fill(classes, PixelClass{});
    std::vector<std::uint8_t> shows_light(pixels, 0);
    for (std::size_t r = 0; r < rungs.size(); ++r) {
      const auto bit = static_cast<std::uint8_t>(1U << r);
      const std::uint16_t* white = frames_of[p][r]->white.data();
      const std::uint16_t* black = frames_of[p][r]->black.data();
      const bool longest = r + 1 == rungs.size();
      for (std::size_t i = 0; i < pixels; ++i) {
        const double contrast = static_cast<double>(white[i]) - static_cast<double>(black[i]);
        if (white[i] >= saturation) {
          // Clipped by the projector's light, not by an ambient lamp that clips the black too.
          if (black[i] < saturation) classes[i].clipped |= bit;
        } else if (contrast >= options.min_contrast_dn) {
          classes[i].usable |= bit;
          if (contrast >= strong) classes[i].strong |= bit;
        }
        if (longest && contrast >= faint) shows_light[i] = 1;
      }
    }
    for (std::size_t i = 0; i < pixels; ++i)
      if (classes[i].usable != 0 || classes[i].clipped != 0 || shows_light[i] != 0) ++class_counts[classes[i]];
  }
  const std::vector<std::pair<PixelClass, std::size_t>> lit(class_counts.begin(), class_counts.end());

  AutoExposureChoice out;
  for (const auto& entry : lit) out.lit_pixels += entry.second;
  if (out.lit_pixels == 0)
    throw std::runtime_error("auto-exposure: no pixel of the metering frames shows the projectors' light, even at " +
                             short_number(rungs.back()) +
                             " us (nothing in view, the projectors off, or the lens capped)");
  const auto lit_n = static_cast<double>(out.lit_pixels);
  for (std::size_t r = 0; r < rungs.size(); ++r) {
    std::size_t usable = 0, clipped = 0;
    for (const auto& [pixel, n] : lit) {
      if ((pixel.usable >> r & 1U) != 0) usable += n;
      if ((pixel.clipped >> r & 1U) != 0) clipped += n;
    }
    out.rungs.push_back({rungs[r], static_cast<double>(usable) / lit_n, static_cast<double>(clipped) / lit_n,
                         static_cast<double>(out.lit_pixels - usable - clipped) / lit_n});
  }

  auto cost_s = [&](unsigned chosen) {
    if (options.frames_per_exposure == 0) return 0.0;
    const int highest = std::bit_width(chosen) - 1;
    const double period_us =
        std::max(options.min_period_us, rungs[static_cast<std::size_t>(highest)] + options.readout_allowance_us);
    return static_cast<double>(options.frames_per_exposure) * std::popcount(chosen) * period_us * 1e-6;
  };
  auto affordable = [&](unsigned chosen) {
    return options.time_budget_s == 0 || cost_s(chosen) <= options.time_budget_s;
  };
  auto meets = [&](const Counts& c) {
    return static_cast<double>(c.saturated) <= options.max_saturated_share * lit_n &&
           static_cast<double>(c.dark) <= options.max_dark_share * lit_n;
  };
  // Nearer the reference (in ratio) first, then shorter.
  auto nearer = [&](std::size_t a, std::size_t b) {
    if (options.reference_us <= 0) return rungs[a] > rungs[b];
    const double da = std::abs(std::log(rungs[a] / options.reference_us));
    const double db = std::abs(std::log(rungs[b] / options.reference_us));
    return da != db ? da < db : rungs[a] < rungs[b];  // NOLINT(clang-diagnostic-float-equal): exact ties only
  };

  unsigned chosen = 0;
  // One exposure where one does.
  std::size_t single = rungs.size();
  for (std::size_t r = 0; r < rungs.size(); ++r)
    if (affordable(1U << r) && meets(count(lit, 1U << r)) && (single == rungs.size() || nearer(r, single))) single = r;
  if (single != rungs.size()) {
    chosen = 1U << single;
    out.reason = "one exposure leaves at most the allowed shares clipped and faint";
  } else {
    // Greedily: each step the affordable rung that makes the most lit pixels usable.
    for (;;) {
      const Counts now = count(lit, chosen);
      if (chosen != 0 && meets(now)) {
        out.reason = "the bracket leaves at most the allowed shares clipped and faint";
        break;
      }
      if (static_cast<std::size_t>(std::popcount(chosen)) == options.max_exposures) {
        out.reason = "the bracket is at its limit of " + std::to_string(options.max_exposures) + " exposures";
        break;
      }
      std::size_t best = rungs.size();
      std::size_t best_usable = 0;
      bool any_affordable = false;
      for (std::size_t r = 0; r < rungs.size(); ++r) {
        if ((chosen & (1U << r)) != 0 || !affordable(chosen | (1U << r))) continue;
        any_affordable = true;
        const std::size_t usable = count(lit, chosen | (1U << r)).usable;
        if (best == rungs.size() || usable > best_usable || (usable == best_usable && nearer(r, best))) {
          best = r;
          best_usable = usable;
        }
      }
      if (chosen == 0 && !any_affordable) {
        throw std::invalid_argument("auto-exposure: the time budget of " + short_number(options.time_budget_s) +
                                    " s is shorter than the scan at one exposure (" + short_number(cost_s(1U)) +
                                    " s at " + short_number(rungs[0]) +
                                    " us: " + std::to_string(options.frames_per_exposure) + " frames)");
      }
      if (best == rungs.size()) {
        out.reason = "the time budget of " + short_number(options.time_budget_s) + " s allows no further exposure";
        break;
      }
      if (chosen != 0 && best_usable == now.usable) {
        out.reason = "no further exposure makes more pixels usable";
        break;
      }
      chosen |= 1U << best;
    }
  }

  // The modulation: a pixel read only weakly (below full scale / max_ratio) at every chosen
  // exposure, where a rung within the bracket's span reads it strongly, gets that rung, while
  // enough lit pixels do. The span reaches up to the reference: what the board's own exposure
  // reads strongly auto-exposure does not leave weaker. On the rig's shiny blade, 1/8 and 1
  // alone (the fewest that read it) put the model's p99 at 96 um, with 1/4 added at 23 um
  // (docs/hdr.md). A matte part read at the reference alone has nothing to add: what is weak
  // there is weaker at every shorter rung.
  std::size_t span_top = static_cast<std::size_t>(std::bit_width(chosen) - 1);
  for (std::size_t r = span_top + 1; r < rungs.size() && rungs[r] <= options.reference_us; ++r) span_top = r;
  const unsigned span = (2U << span_top) - 1;
  const double weak_pixels = std::max(1.0, options.min_weak_share * lit_n);
  bool strengthened = false;
  while (static_cast<std::size_t>(std::popcount(chosen)) < options.max_exposures) {
    std::array<std::size_t, kMaxRungs> fixes{};
    std::size_t fixable = 0;
    for (const auto& [pixel, n] : lit) {
      if ((pixel.usable & chosen) == 0 || (pixel.strong & chosen) != 0) continue;
      const unsigned helps = pixel.strong & span & ~chosen;
      if (helps == 0) continue;
      fixable += n;
      for (std::size_t r = 0; r < rungs.size(); ++r)
        if ((helps >> r & 1U) != 0) fixes[r] += n;
    }
    if (static_cast<double>(fixable) < weak_pixels) break;
    std::size_t best = rungs.size();
    for (std::size_t r = 0; r < rungs.size(); ++r) {
      if (fixes[r] == 0 || !affordable(chosen | (1U << r))) continue;
      if (best == rungs.size() || fixes[r] > fixes[best] || (fixes[r] == fixes[best] && nearer(r, best))) best = r;
    }
    if (best == rungs.size()) {
      out.reason += "; the time budget of " + short_number(options.time_budget_s) + " s leaves " +
                    std::to_string(fixable) + " lit pixels read weakly that another exposure would read strongly";
      break;
    }
    chosen |= 1U << best;
    strengthened = true;
  }
  if (strengthened)
    out.reason += "; exposures added for pixels read below 1/" + short_number(options.max_ratio) + " of full scale";

  for (std::size_t r = 0; r < rungs.size(); ++r)
    if ((chosen & (1U << r)) != 0) out.exposures_us.push_back(rungs[r]);
  const Counts final_counts = count(lit, chosen);
  out.usable_share = static_cast<double>(final_counts.usable) / lit_n;
  out.saturated_share = static_cast<double>(final_counts.saturated) / lit_n;
  out.dark_share = static_cast<double>(final_counts.dark) / lit_n;
  out.unreachable_share = static_cast<double>(final_counts.unreachable) / lit_n;
  out.met = meets(final_counts);
  out.period_us = std::max(options.min_period_us, out.exposures_us.back() + options.readout_allowance_us);
  out.capture_s = cost_s(chosen);
  return out;
}

}  // namespace slscan::core
