// Auto-exposure's choice (auto_exposure.hpp): on frames of known radiance, what a single
// exposure serves and what needs a bracket, the time budget, the unreachable pixels, the
// ladder and its mains rounding, bad metering input; then on the virtual rig's own frames:
// the shiny blade gets a bracket whose merge decodes what the reference exposure clipped, a
// matte part one exposure.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

#include "slrig/rig.hpp"
#include "slscan/core/auto_exposure.hpp"
#include "slscan/core/decode.hpp"

namespace {

using slscan::core::AutoExposureChoice;
using slscan::core::AutoExposureOptions;
using slscan::core::choose_exposures;
using slscan::core::metering_ladder;
using slscan::core::MeteringFrames;

constexpr double kReference = 2000;
constexpr int kClip = 255;

// Pixels of given radiance (DN per us of exposure) over a black level of 4 DN, clipped at 255.
std::vector<MeteringFrames> meter(const std::vector<double>& radiance, const std::vector<double>& ladder,
                                  int projectors = 1) {
  std::vector<MeteringFrames> out;
  for (int p = 0; p < projectors; ++p)
    for (const double e : ladder) {
      MeteringFrames f;
      f.exposure_us = e;
      f.projector = p;
      for (const double r : radiance) {
        f.white.push_back(static_cast<std::uint16_t>(std::min<double>(kClip, std::round(4 + r * e))));
        f.black.push_back(4);
      }
      out.push_back(std::move(f));
    }
  return out;
}

// n pixels of radiance r appended.
void add(std::vector<double>& radiance, std::size_t n, double r) { radiance.insert(radiance.end(), n, r); }

AutoExposureOptions options() {
  AutoExposureOptions o;
  o.saturation_dn = kClip;
  o.min_contrast_dn = 24;
  o.reference_us = kReference;
  return o;
}

TEST(MeteringLadder, OctavesAroundTheReferenceWithinTheLimits) {
  EXPECT_EQ(metering_ladder(2000, 235, 1e6, 0), (std::vector<double>{250, 500, 1000, 2000, 4000, 8000, 16000, 32000}));
  EXPECT_EQ(metering_ladder(2000, 235, 5000, 0), (std::vector<double>{250, 500, 1000, 2000, 4000}));
  EXPECT_EQ(metering_ladder(1000, 235, 1e6, 0).front(), 250);  // 125 is below the DLP's minimum
}

TEST(MeteringLadder, WholeFlickerPeriodsWithMains) {
  EXPECT_EQ(metering_ladder(2000, 235, 1e6, 50),
            (std::vector<double>{10000, 20000, 30000, 40000, 60000, 80000, 120000, 160000}));
  const std::vector<double> sixty = metering_ladder(8333, 235, 40000, 60);
  ASSERT_EQ(sixty.size(), 4u);
  EXPECT_EQ(sixty.front(), 8333);  // 1e6 / 120, rounded to whole us
  EXPECT_EQ(sixty.back(), 33333);
}

TEST(MeteringLadder, RefusesWhatCannotBeMet) {
  EXPECT_THROW(metering_ladder(2000, 235, 1e6, 55), std::invalid_argument);
  try {
    (void)metering_ladder(2000, 235, 9000, 50);  // the budget's longest exposure is below one 10 ms period
    FAIL() << "no rung fits";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("10000 us, --mains 50"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("[235, 9000] us"), std::string::npos) << e.what();
  }
  EXPECT_THROW(metering_ladder(0, 235, 1e6, 0), std::invalid_argument);
}

TEST(AutoExposure, AMatteSceneGetsOneExposureTheReference) {
  // Radiances a factor of 3 apart: 2000 us reads them all (30 .. 90 DN over black, unclipped).
  std::vector<double> radiance;
  add(radiance, 4000, 0.015);
  add(radiance, 4000, 0.045);
  add(radiance, 2000, 0);  // shadow: not lit, not counted
  const std::vector<double> ladder = metering_ladder(kReference, 235, 1e6, 0);
  const AutoExposureChoice choice = choose_exposures(meter(radiance, ladder, 2), options());
  EXPECT_EQ(choice.exposures_us, std::vector<double>{kReference});
  EXPECT_EQ(choice.lit_pixels, 16000u);  // two projectors
  EXPECT_DOUBLE_EQ(choice.usable_share, 1.0);
  EXPECT_TRUE(choice.met);
  ASSERT_EQ(choice.rungs.size(), ladder.size());
  // 4000 us reads them all too, 8000 clips the bright half.
  EXPECT_DOUBLE_EQ(choice.rungs[4].usable_share, 1.0);
  EXPECT_DOUBLE_EQ(choice.rungs[5].clipped_share, 0.5);
}

TEST(AutoExposure, HighlightsAndDarkPartsGetABracketThatReadsEveryRegion) {
  std::vector<double> radiance;
  add(radiance, 5000, 0.04);   // matte: 2000 us -> 84 DN
  add(radiance, 1000, 0.6);    // highlight: clips from 500 us on, reads at 250 us (154 DN)
  add(radiance, 1000, 0.001);  // dark: 2 DN at 2000 us, reads from 24 000 us (32 000 -> 36 DN)
  const std::vector<double> ladder = metering_ladder(kReference, 235, 1e6, 0);
  const AutoExposureChoice choice = choose_exposures(meter(radiance, ladder), options());
  ASSERT_GE(choice.exposures_us.size(), 2u);
  EXPECT_TRUE(std::ranges::is_sorted(choice.exposures_us));
  EXPECT_LE(choice.exposures_us.front(), 250);
  EXPECT_GE(choice.exposures_us.back(), 32000);
  EXPECT_DOUBLE_EQ(choice.usable_share, 1.0);
  EXPECT_TRUE(choice.met) << choice.reason;
  EXPECT_EQ(choice.exposures_us.size(), 3u);  // each region needs its own rung: no fewer, no more
}

TEST(AutoExposure, PixelsReadWeaklyGetAnExposureThatReadsThemWell) {
  std::vector<double> radiance;
  add(radiance, 5000, 0.04);  // matte: 2000 us -> 80 DN over black, 1000 us -> 40: usable, weak
  add(radiance, 1000, 0.6);   // highlight: only 250 us reads it (150 DN)
  add(radiance, 1000, 0.15);  // sheen: clips at 2000 us, 150 DN at 1000 us
  const std::vector<double> ladder = metering_ladder(kReference, 235, 1e6, 0);
  AutoExposureOptions o = options();
  o.max_exposures = 2;
  // 1000 and 250 us read every pixel: the fewest.
  AutoExposureChoice choice = choose_exposures(meter(radiance, ladder), o);
  EXPECT_EQ(choice.exposures_us, (std::vector<double>{250, 1000})) << choice.reason;
  EXPECT_TRUE(choice.met);
  // The matte part, half of the lit pixels, reads below 255 / 4 there and strongly at the
  // reference: it is added.
  choice = choose_exposures(meter(radiance, ladder), options());
  EXPECT_EQ(choice.exposures_us, (std::vector<double>{250, 1000, 2000})) << choice.reason;
  EXPECT_NE(choice.reason.find("exposures added for pixels read below 1/4 of full scale"), std::string::npos)
      << choice.reason;
}

TEST(AutoExposure, TheTimeBudgetCapsTheBracketAndSaysSo) {
  std::vector<double> radiance;
  add(radiance, 5000, 0.04);
  add(radiance, 1000, 0.6);
  add(radiance, 1000, 0.001);
  AutoExposureOptions o = options();
  o.frames_per_exposure = 100;
  o.readout_allowance_us = 3000;
  o.min_period_us = 5000;
  // One pass at 2000 us: 100 x 5 ms = 0.5 s; a second at a longer period does not fit 0.6 s.
  o.time_budget_s = 0.6;
  const std::vector<double> ladder = metering_ladder(kReference, 235, 1e6, 0);
  AutoExposureChoice choice = choose_exposures(meter(radiance, ladder), o);
  EXPECT_EQ(choice.exposures_us.size(), 1u);
  EXPECT_FALSE(choice.met);
  EXPECT_NE(choice.reason.find("time budget of 0.6 s"), std::string::npos) << choice.reason;
  EXPECT_LE(choice.capture_s, 0.6);
  // Enough for the bracket: 3 passes at 35 ms.
  o.time_budget_s = 11;
  choice = choose_exposures(meter(radiance, ladder), o);
  EXPECT_TRUE(choice.met);
  EXPECT_DOUBLE_EQ(choice.period_us, 35000);
  EXPECT_NEAR(choice.capture_s, 100 * 3 * 0.035, 1e-9);
  // Shorter than any one pass.
  o.time_budget_s = 0.1;
  try {
    (void)choose_exposures(meter(radiance, ladder), o);
    FAIL() << "no exposure fits 0.1 s";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("time budget of 0.1 s is shorter"), std::string::npos) << e.what();
  }
}

TEST(AutoExposure, PixelsNoRungReadsAreReportedNotChased) {
  std::vector<double> radiance;
  add(radiance, 9000, 0.04);
  add(radiance, 1000, 50);  // clips even at 250 us: a specular glint
  const std::vector<double> ladder = metering_ladder(kReference, 235, 1e6, 0);
  const AutoExposureChoice choice = choose_exposures(meter(radiance, ladder), options());
  EXPECT_EQ(choice.exposures_us, std::vector<double>{kReference});
  EXPECT_DOUBLE_EQ(choice.unreachable_share, 0.1);
  EXPECT_DOUBLE_EQ(choice.saturated_share, 0.0);
  EXPECT_TRUE(choice.met);
}

TEST(AutoExposure, TheOrderOfTheFramesChangesNothing) {
  std::vector<double> radiance;
  std::mt19937 random(7);
  std::uniform_real_distribution<double> log_radiance(-7, 0);
  radiance.reserve(20000);
  for (int i = 0; i < 20000; ++i) radiance.push_back(std::exp(log_radiance(random)));
  const std::vector<double> ladder = metering_ladder(kReference, 235, 1e6, 0);
  std::vector<MeteringFrames> frames = meter(radiance, ladder, 2);
  const AutoExposureChoice first = choose_exposures(frames, options());
  std::shuffle(frames.begin(), frames.end(), random);
  const AutoExposureChoice second = choose_exposures(frames, options());
  EXPECT_EQ(first.exposures_us, second.exposures_us);
  EXPECT_EQ(first.usable_share, second.usable_share);
  EXPECT_GT(first.exposures_us.size(), 1u);
}

TEST(AutoExposure, BadMeteringInputIsNamed) {
  const std::vector<double> ladder{1000, 2000};
  std::vector<MeteringFrames> frames = meter({0.04, 0.04}, ladder, 2);
  frames.pop_back();  // projector 1 at 2000 us
  try {
    (void)choose_exposures(frames, options());
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("no metering frames of projector 1 at 2000 us"), std::string::npos)
        << e.what();
  }
  frames = meter({0.04, 0.04}, ladder);
  frames[1].white.pop_back();
  EXPECT_THROW((void)choose_exposures(frames, options()), std::invalid_argument);
  EXPECT_THROW((void)choose_exposures({}, options()), std::invalid_argument);
  // Nothing lit: a capped lens.
  EXPECT_THROW((void)choose_exposures(meter({0, 0}, ladder), options()), std::runtime_error);
  AutoExposureOptions o = options();
  o.max_dark_share = 1.5;
  try {
    (void)choose_exposures(meter({0.04}, ladder), o);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("max_dark_share 1.5"), std::string::npos) << e.what();
  }
}

// The rig's frames: white and black of the left projector at each rung (fractions of the
// scene's reference exposure).
std::vector<MeteringFrames> rig_metering(const std::string& preset, std::span<const double> fractions) {
  const slrig::Scene scene = slrig::scene_preset(preset, slrig::RigSize::small).value();
  const slrig::ViewRenderer renderer(scene, scene.view_angles_deg.at(0), 0);
  const slproto::PatternPlan plan(scene.pattern_plan);
  std::vector<std::uint8_t> frame(renderer.frame_bytes());
  std::vector<MeteringFrames> out;
  for (const double f : fractions) {
    MeteringFrames m;
    m.exposure_us = kReference * f;
    const slrig::Exposure exposure{.exposure_us = scene.sensor.exposure_us * f};
    for (const auto kind : {slproto::PatternKind::white, slproto::PatternKind::black}) {
      renderer.render(slproto::ProjectorSide::left, plan, static_cast<std::size_t>(plan.index_of(kind)), frame,
                      exposure);
      auto& image = kind == slproto::PatternKind::white ? m.white : m.black;
      image.assign(frame.begin(), frame.end());
    }
    out.push_back(std::move(m));
  }
  return out;
}

constexpr std::array<double, 8> kRigFractions{0.125, 0.25, 0.5, 1, 2, 4, 8, 16};

// As slscan meters: the decoder's own floors (8-bit frames).
AutoExposureOptions rig_options() {
  const slscan::core::DecodeOptions decode;
  AutoExposureOptions o = options();
  o.min_contrast_dn = std::max<double>(decode.min_contrast_dn, 2.0 * decode.min_modulation_dn);
  o.saturation_dn = decode.saturation_level();
  return o;
}

TEST(AutoExposureOnTheRig, TheShinyBladeGetsAShortExposureForItsHighlights) {
  const std::vector<MeteringFrames> frames = rig_metering("shiny_blade", kRigFractions);
  const AutoExposureChoice choice = choose_exposures(frames, rig_options());
  ASSERT_GE(choice.exposures_us.size(), 2u) << choice.reason;
  // The reference clips a share of the lit blade that a shorter rung reads.
  const auto reference = std::ranges::find(kRigFractions, 1.0) - kRigFractions.begin();
  EXPECT_GT(choice.rungs[static_cast<std::size_t>(reference)].clipped_share, 0.02);
  EXPECT_LT(choice.exposures_us.front(), kReference);
  EXPECT_LE(choice.saturated_share, 0.01);
  EXPECT_TRUE(choice.met) << choice.reason;
}

TEST(AutoExposureOnTheRig, MattePartsGetTheReferenceAlone) {
  for (const char* preset : {"sphere", "ballbar", "teacup"}) {
    const AutoExposureChoice choice = choose_exposures(rig_metering(preset, kRigFractions), rig_options());
    EXPECT_EQ(choice.exposures_us, std::vector<double>{kReference}) << preset << ": " << choice.reason;
    EXPECT_TRUE(choice.met) << preset << ": " << choice.reason;
  }
}

TEST(AutoExposureOnTheRig, TheDarkBladeGetsALongerExposure) {
  const AutoExposureChoice choice = choose_exposures(rig_metering("dark_blade", kRigFractions), rig_options());
  EXPECT_GT(choice.exposures_us.back(), kReference) << choice.reason;
  EXPECT_TRUE(choice.met) << choice.reason;
  EXPECT_LE(choice.dark_share, 0.01);
}

}  // namespace
