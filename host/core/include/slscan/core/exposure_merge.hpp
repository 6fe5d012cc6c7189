// HDR: one projector-view decoded at each exposure of a bracket, merged per pixel into one
// decoded view (docs/hdr.md). Each pixel keeps the exposure where it decoded with the highest
// modulation: clipped frames already masked it at the long exposures (DecodeMask::saturated),
// and among the ones left the longest gives the most signal over the shot noise. The rule is a
// total order on (decoded, modulation, -exposure index), so the result does not depend on the
// order the exposures arrive in: a live scan and its reprocessing merge alike.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "slscan/core/decode.hpp"

namespace slscan::core {

// What each exposure gave the merged view.
struct ExposureShare {
  double exposure_us = 0;
  std::size_t decoded = 0;  // pixels this exposure decoded on its own
  std::size_t chosen = 0;   // decoded pixels of the merged view taken from it
  std::size_t clipped = 0;  // pixels at the clip level in its white frame (or any frame without one)
};

class ExposureMerge {
 public:
  // `exposures_us` in bracket order (at least one, each > 0); intensities are scaled to
  // `reference_us`, so the albedo reads the same whichever exposure a pixel came from.
  ExposureMerge(std::vector<double> exposures_us, double reference_us);

  // The view decoded at bracket member `exposure_index`; any order, each once. Throws
  // std::invalid_argument on a repeated or unknown index or a view of another size.
  void add(std::size_t exposure_index, DecodedView&& view);
  std::size_t added() const { return added_count_; }
  bool has(std::size_t exposure_index) const { return exposure_index < added_.size() && added_[exposure_index] != 0; }
  bool complete() const { return added_count_ == exposures_us_.size(); }

  // The merged view (of the exposures added so far; at least one): counts recounted from the
  // merged mask, the noise figures and self-checks of the exposure that gave the most pixels
  // (the others' findings added, named by their exposure), clipped counts the least of the
  // exposures' (clipped whatever was chosen).
  DecodedView finish();
  // Per pixel, the bracket member it came from (valid after finish()).
  const std::vector<std::uint8_t>& chosen() const { return chosen_; }
  const std::vector<ExposureShare>& shares() const { return shares_; }

 private:
  std::vector<double> exposures_us_;
  double reference_us_ = 0;
  std::vector<std::uint8_t> added_;
  std::size_t added_count_ = 0;
  DecodedView merged_;
  std::vector<std::uint8_t> chosen_;
  std::vector<ExposureShare> shares_;
  // Per exposure, what finish() takes from the one that gave the most pixels.
  std::vector<DecodeChecks> checks_;
  std::vector<float> noise_px_, smoothing_px_;
  std::vector<DecodeCounts> counts_;
};

}  // namespace slscan::core
