#include "slscan/core/exposure_merge.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "slproto/number_text.hpp"

namespace slscan::core {

ExposureMerge::ExposureMerge(std::vector<double> exposures_us, double reference_us)
    : exposures_us_(std::move(exposures_us)), reference_us_(reference_us) {
  if (exposures_us_.empty() || exposures_us_.size() > 255)
    throw std::invalid_argument("exposure merge: " + std::to_string(exposures_us_.size()) +
                                " exposures (1 to 255 can be merged)");
  for (const double e : exposures_us_)
    if (!(e > 0 && std::isfinite(e)))
      throw std::invalid_argument("exposure merge: exposure " + std::to_string(e) + " us is not positive");
  if (!(reference_us_ > 0 && std::isfinite(reference_us_)))
    throw std::invalid_argument("exposure merge: reference exposure " + std::to_string(reference_us_) +
                                " us is not positive");
  const std::size_t n = exposures_us_.size();
  added_.assign(n, 0);
  shares_.resize(n);
  for (std::size_t i = 0; i < n; ++i) shares_[i].exposure_us = exposures_us_[i];
  checks_.resize(n);
  noise_px_.assign(n, 0);
  smoothing_px_.assign(n, 0);
  counts_.resize(n);
}

void ExposureMerge::add(std::size_t exposure_index, DecodedView&& view) {
  if (exposure_index >= exposures_us_.size())
    throw std::invalid_argument("exposure merge: exposure index " + std::to_string(exposure_index) +
                                " is beyond the bracket of " + std::to_string(exposures_us_.size()));
  if (added_[exposure_index] != 0)
    throw std::invalid_argument("exposure merge: exposure index " + std::to_string(exposure_index) + " added twice");
  const std::size_t pixels = static_cast<std::size_t>(view.width) * static_cast<std::size_t>(view.height);
  if (view.coordinate.size() != pixels || view.quality.size() != pixels || view.intensity.size() != pixels ||
      view.mask.size() != pixels)
    throw std::invalid_argument("exposure merge: a decoded view's planes do not match its size");
  if (added_count_ != 0 && (view.width != merged_.width || view.height != merged_.height))
    throw std::invalid_argument("exposure merge: the exposures' views differ in size");

  // The albedo as the reference exposure would have seen it.
  const auto scale = static_cast<float>(reference_us_ / exposures_us_[exposure_index]);
  for (float& v : view.intensity) v *= scale;

  ExposureShare& share = shares_[exposure_index];
  share.decoded = view.counts.valid;
  const SaturationCounts& clipped = view.counts.clipped;
  share.clipped = clipped.white != 0 ? clipped.white : std::max(clipped.gray, clipped.phase);
  checks_[exposure_index] = std::move(view.checks);
  noise_px_[exposure_index] = view.coordinate_noise_px;
  smoothing_px_[exposure_index] = view.smoothing_max_deviation_px;
  counts_[exposure_index] = view.counts;
  added_[exposure_index] = 1;
  const auto index = static_cast<std::uint8_t>(exposure_index);
  if (added_count_++ == 0) {
    merged_ = std::move(view);
    chosen_.assign(pixels, index);
    return;
  }
  // Decoded beats masked; then the higher modulation; then the earlier bracket member. Two
  // masked pixels keep the earlier member's reason.
  for (std::size_t i = 0; i < pixels; ++i) {
    const bool candidate_valid = view.mask[i] == DecodeMask::valid;
    const bool current_valid = merged_.mask[i] == DecodeMask::valid;
    bool better = false;
    if (candidate_valid != current_valid) {
      better = candidate_valid;
    } else if (candidate_valid && view.quality[i] != merged_.quality[i]) {
      better = view.quality[i] > merged_.quality[i];
    } else {
      better = index < chosen_[i];
    }
    if (!better) continue;
    merged_.coordinate[i] = view.coordinate[i];
    merged_.quality[i] = view.quality[i];
    merged_.intensity[i] = view.intensity[i];
    merged_.mask[i] = view.mask[i];
    chosen_[i] = index;
  }
}

DecodedView ExposureMerge::finish() {
  if (added_count_ == 0) throw std::logic_error("exposure merge: finish() before any exposure was added");
  DecodeCounts counts;
  for (ExposureShare& share : shares_) share.chosen = 0;
  for (std::size_t i = 0; i < merged_.mask.size(); ++i) {
    switch (merged_.mask[i]) {
      case DecodeMask::valid:
        ++counts.valid;
        ++shares_[chosen_[i]].chosen;
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
  std::size_t main = 0;
  bool first = true;
  for (std::size_t e = 0; e < exposures_us_.size(); ++e) {
    if (added_[e] == 0) continue;
    if (first) {
      counts.clipped = counts_[e].clipped;
      main = e;
      first = false;
      continue;
    }
    SaturationCounts& c = counts.clipped;
    const SaturationCounts& o = counts_[e].clipped;
    c = {std::min(c.white, o.white), std::min(c.black, o.black), std::min(c.gray, o.gray), std::min(c.phase, o.phase)};
    if (shares_[e].chosen > shares_[main].chosen) main = e;
  }
  merged_.counts = counts;
  merged_.coordinate_noise_px = noise_px_[main];
  merged_.smoothing_max_deviation_px = smoothing_px_[main];
  merged_.checks = std::move(checks_[main]);
  for (std::size_t e = 0; e < exposures_us_.size(); ++e) {
    if (added_[e] == 0 || e == main) continue;
    for (DecodeFinding& finding : checks_[e].findings) {
      finding.cause = "at exposure " + slproto::short_number(exposures_us_[e]) + " us, " + finding.cause;
      merged_.checks.findings.push_back(std::move(finding));
    }
  }
  return std::move(merged_);
}

}  // namespace slscan::core
