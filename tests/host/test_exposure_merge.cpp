// HDR merge of one projector-view decoded at several exposures (exposure_merge.hpp), on frames
// the virtual rig renders of its shiny blade: what clips at the long exposure decodes at a short
// one, the merged coordinates are as right as each exposure's own (against the rig's truth),
// intensities come back to the reference scale, and the order the exposures arrive in changes
// no bit.
#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <vector>

#include "slrig/rig.hpp"
#include "slscan/core/decode.hpp"
#include "slscan/core/exposure_merge.hpp"

namespace {

using slscan::core::DecodedView;
using slscan::core::DecodeMask;
using slscan::core::ExposureMerge;
using slscan::core::ProjectorViewDecoder;

struct Rendered {
  slrig::Scene scene;
  slrig::ViewRenderer renderer;
  slproto::PatternPlan plan;
};

Rendered shiny_blade_view() {
  slrig::Scene scene = slrig::scene_preset("shiny_blade", slrig::RigSize::small).value();
  slrig::ViewRenderer renderer(scene, scene.view_angles_deg.at(0), 0);
  slproto::PatternPlan plan(scene.pattern_plan);
  return {std::move(scene), std::move(renderer), std::move(plan)};
}

// The left projector's view at `fraction` of the reference exposure, decoded.
DecodedView decode_at(const Rendered& r, double fraction) {
  ProjectorViewDecoder decoder(r.plan, r.renderer.width(), r.renderer.height());
  std::vector<std::uint8_t> frame(r.renderer.frame_bytes());
  const slrig::Exposure exposure{.exposure_us = r.scene.sensor.exposure_us * fraction};
  for (std::size_t k = 0; k < r.plan.size(); ++k) {
    r.renderer.render(slproto::ProjectorSide::left, r.plan, k, frame, exposure);
    decoder.add_frame(k, frame.data(), static_cast<std::size_t>(r.renderer.width()));
  }
  return decoder.finish();
}

bool same_bits(const std::vector<float>& a, const std::vector<float>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

// RMS of decoded - true projector coordinate over the pixels `take` selects.
template <class Take>
double coordinate_rms(const DecodedView& view, const std::vector<float>& truth, Take take) {
  double sum = 0;
  std::size_t n = 0;
  for (std::size_t i = 0; i < truth.size(); ++i) {
    if (view.mask[i] != DecodeMask::valid || !std::isfinite(truth[i]) || !take(i)) continue;
    const double d = view.coordinate[i] - truth[i];
    sum += d * d;
    ++n;
  }
  EXPECT_GT(n, 200u);
  return std::sqrt(sum / static_cast<double>(std::max<std::size_t>(n, 1)));
}

class ExposureMergeOnTheShinyBlade : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    rendered_ = new Rendered(shiny_blade_view());
    for (const double f : kFractions) views_.push_back(decode_at(*rendered_, f));
  }
  static void TearDownTestSuite() {
    delete rendered_;
    views_.clear();
  }
  static ExposureMerge merged_in(const std::vector<std::size_t>& order) {
    ExposureMerge merge({8333, 2083.25, 1041.625}, 8333);
    for (const std::size_t e : order) merge.add(e, DecodedView(views_[e]));
    return merge;
  }
  static constexpr double kFractions[3] = {1.0, 0.25, 0.125};
  static Rendered* rendered_;
  static std::vector<DecodedView> views_;
};
Rendered* ExposureMergeOnTheShinyBlade::rendered_ = nullptr;
std::vector<DecodedView> ExposureMergeOnTheShinyBlade::views_;

TEST_F(ExposureMergeOnTheShinyBlade, DecodesWhatClipsAtTheReferenceAndKeepsTheRest) {
  const DecodedView& reference = views_[0];
  ASSERT_GT(reference.counts.saturated, 2000u) << "the lobe must clip at the reference exposure";
  ExposureMerge merge = merged_in({0, 1, 2});
  const DecodedView merged = merge.finish();
  std::size_t recovered = 0, kept = 0;
  for (std::size_t i = 0; i < merged.mask.size(); ++i) {
    if (reference.mask[i] == DecodeMask::valid) {
      // A pixel the reference decoded keeps the reference's decode: the shorter ones have less
      // modulation wherever the reference did not clip.
      kept +=
          merged.mask[i] == DecodeMask::valid && merge.chosen()[i] == 0 &&
          std::bit_cast<std::uint32_t>(merged.coordinate[i]) == std::bit_cast<std::uint32_t>(reference.coordinate[i]);
    } else if (reference.mask[i] == DecodeMask::saturated) {
      recovered += merged.mask[i] == DecodeMask::valid;
    }
  }
  EXPECT_EQ(kept, reference.counts.valid);
  EXPECT_GT(static_cast<double>(recovered), 0.95 * static_cast<double>(reference.counts.saturated));
  EXPECT_EQ(merged.counts.valid, reference.counts.valid + recovered);
  EXPECT_EQ(merged.counts.total(), merged.mask.size());
  // The shares add up to the merged count; each exposure's own count is reported.
  std::size_t chosen = 0;
  for (std::size_t e = 0; e < 3; ++e) {
    chosen += merge.shares()[e].chosen;
    EXPECT_EQ(merge.shares()[e].decoded, views_[e].counts.valid);
  }
  EXPECT_EQ(chosen, merged.counts.valid);
  EXPECT_GT(merge.shares()[0].clipped, merge.shares()[2].clipped);
}

TEST_F(ExposureMergeOnTheShinyBlade, RecoveredPixelsAreAsRightAsTheShortExposuresOwn) {
  const std::vector<float>& truth = rendered_->renderer.ground_truth().projector_coord[0];
  ExposureMerge merge = merged_in({2, 1, 0});
  const DecodedView merged = merge.finish();
  const auto& chosen = merge.chosen();
  for (const std::uint8_t e : {1, 2}) {
    auto from_e = [&](std::size_t i) { return chosen[i] == e && views_[0].mask[i] == DecodeMask::saturated; };
    const double in_merge = coordinate_rms(merged, truth, from_e);
    const double own = coordinate_rms(views_[e], truth, from_e);
    EXPECT_EQ(in_merge, own) << "exposure " << int(e) << ": the merge copies the exposure's decode";
    EXPECT_LT(in_merge, 0.5) << "exposure " << int(e) << ": projector px";
  }
}

TEST_F(ExposureMergeOnTheShinyBlade, IntensityIsScaledToTheReference) {
  ExposureMerge merge = merged_in({0, 2, 1});
  const DecodedView merged = merge.finish();
  // Where the reference and the 1/4 exposure both decoded (neither clipped), the 1/4 exposure's
  // intensity scaled by 4 reads as the reference's (within its quantisation and noise).
  std::vector<double> ratios;
  for (std::size_t i = 0; i < merged.mask.size(); ++i)
    if (views_[0].mask[i] == DecodeMask::valid && views_[1].mask[i] == DecodeMask::valid &&
        views_[0].intensity[i] > 0.2f)
      ratios.push_back(4.0 * views_[1].intensity[i] / views_[0].intensity[i]);
  ASSERT_GT(ratios.size(), 500u);
  std::nth_element(ratios.begin(), ratios.begin() + static_cast<std::ptrdiff_t>(ratios.size() / 2), ratios.end());
  EXPECT_NEAR(ratios[ratios.size() / 2], 1.0, 0.03);
  // In the merge each pixel's intensity is its exposure's, times reference / exposure.
  const double scales[3] = {1.0, 4.0, 8.0};
  for (std::size_t i = 0; i < merged.mask.size(); i += 37) {
    const std::uint8_t e = merge.chosen()[i];
    EXPECT_FLOAT_EQ(merged.intensity[i], static_cast<float>(views_[e].intensity[i] * scales[e])) << i;
  }
}

TEST_F(ExposureMergeOnTheShinyBlade, TheOrderOfArrivalChangesNoBit) {
  ExposureMerge a = merged_in({0, 1, 2}), b = merged_in({2, 0, 1}), c = merged_in({1, 2, 0});
  const DecodedView va = a.finish(), vb = b.finish(), vc = c.finish();
  for (const DecodedView* v : {&vb, &vc}) {
    EXPECT_TRUE(same_bits(va.coordinate, v->coordinate));
    EXPECT_TRUE(same_bits(va.quality, v->quality));
    EXPECT_TRUE(same_bits(va.intensity, v->intensity));
    EXPECT_TRUE(va.mask == v->mask);
    EXPECT_EQ(va.coordinate_noise_px, v->coordinate_noise_px);
    EXPECT_EQ(va.counts.valid, v->counts.valid);
  }
  EXPECT_EQ(a.chosen(), b.chosen());
  EXPECT_EQ(a.chosen(), c.chosen());
}

TEST_F(ExposureMergeOnTheShinyBlade, APartialBracketMergesWhatCame) {
  ExposureMerge merge({8333, 2083.25, 1041.625}, 8333);
  merge.add(2, DecodedView(views_[2]));
  EXPECT_FALSE(merge.complete());
  EXPECT_TRUE(merge.has(2));
  EXPECT_FALSE(merge.has(0));
  const DecodedView only = merge.finish();
  EXPECT_EQ(only.counts.valid, views_[2].counts.valid);
  EXPECT_TRUE(only.mask == views_[2].mask);
}

TEST(ExposureMerge, RefusesWhatCannotBeMerged) {
  EXPECT_THROW(ExposureMerge({}, 1000), std::invalid_argument);
  EXPECT_THROW(ExposureMerge({1000, 0}, 1000), std::invalid_argument);
  EXPECT_THROW(ExposureMerge({1000, NAN}, 1000), std::invalid_argument);
  EXPECT_THROW(ExposureMerge({1000}, -1), std::invalid_argument);
  ExposureMerge merge({1000, 500}, 1000);
  EXPECT_THROW(merge.finish(), std::logic_error);
  DecodedView view;
  view.width = 2;
  view.height = 1;
  view.coordinate = {1, 2};
  view.quality = {3, 4};
  view.intensity = {0.5f, 0.5f};
  view.mask = {DecodeMask::valid, DecodeMask::valid};
  EXPECT_THROW(merge.add(2, DecodedView(view)), std::invalid_argument);
  merge.add(1, DecodedView(view));
  try {
    merge.add(1, DecodedView(view));
    FAIL() << "a repeated exposure must be refused";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("index 1 added twice"), std::string::npos) << e.what();
  }
  DecodedView other = view;
  other.width = 1;
  other.height = 2;
  EXPECT_THROW(merge.add(0, std::move(other)), std::invalid_argument);
  DecodedView short_planes = view;
  short_planes.quality.pop_back();
  EXPECT_THROW(merge.add(0, std::move(short_planes)), std::invalid_argument);
}

}  // namespace
