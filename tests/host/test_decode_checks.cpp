// Saturation by frame kind, the plan's phase origin, and the decoder's self-checks, on
// synthetic frames (each camera pixel sees a known projector coordinate; frames straight from
// slproto::PatternPlan::value with gamma, blur and noise). The wrong listings a user writes for
// another scanner's capture (phase frames rotated, reversed, one short, Gray bits reversed or
// shifted by a frame) are made by permuting the rendered frames, as a description would.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <random>
#include <vector>

#include "slscan/core/decode.hpp"

namespace {

using slproto::PatternKind;
using slproto::PatternPlan;
using slproto::PatternPlanConfig;
using slscan::core::DecodedView;
using slscan::core::DecodeMask;
using slscan::core::DecodeOptions;
using slscan::core::ProjectorViewDecoder;

using Frames = std::vector<std::vector<std::uint8_t>>;

struct Scene {
  int width = 320, height = 64;
  double gain = 150, black = 10, gamma = 2.2, blur_px = 1.2, noise_dn = 1.0;
  // A smooth ramp over most of the projector, ~1.3 projector px per camera px, with a slope
  // that visits every sub-pixel phase.
  double coordinate(int u, int v) const { return 40.3 + 1.3137 * u + 0.21 * v; }
};

Frames render(const PatternPlan& plan, const Scene& scene, std::uint32_t seed = 3) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 1.0);
  Frames frames(plan.size());
  for (std::size_t p = 0; p < plan.size(); ++p) {
    const bool smooth = plan[p].kind == PatternKind::phase_step;
    frames[p].resize(static_cast<std::size_t>(scene.width * scene.height));
    for (int v = 0; v < scene.height; ++v)
      for (int u = 0; u < scene.width; ++u) {
        const double x = scene.coordinate(u, v);
        double value = 0;
        constexpr int kSamples = 17;
        for (int s = 0; s < kSamples; ++s) {
          const double xs = x + scene.blur_px * ((s + 0.5) / kSamples - 0.5);
          value += std::pow(plan.value(p, smooth ? xs : std::floor(xs + 0.5)), scene.gamma);
        }
        const double dn = scene.black + scene.gain * value / kSamples + scene.noise_dn * noise(rng);
        frames[p][static_cast<std::size_t>(v * scene.width + u)] =
            static_cast<std::uint8_t>(std::clamp(std::round(dn), 0.0, 255.0));
      }
  }
  return frames;
}

DecodedView decode(const PatternPlan& plan, const Frames& frames, const Scene& scene, DecodeOptions options = {}) {
  ProjectorViewDecoder decoder(plan, scene.width, scene.height, options);
  for (std::size_t p = 0; p < frames.size(); ++p)
    decoder.add_frame(p, frames[p].data(), static_cast<std::size_t>(scene.width));
  return decoder.finish();
}

double median_error(const DecodedView& view, const Scene& scene) {
  std::vector<double> e;
  for (int v = 0; v < scene.height; ++v)
    for (int u = 0; u < scene.width; ++u) {
      const auto i = static_cast<std::size_t>(v * scene.width + u);
      if (view.mask[i] == DecodeMask::valid) e.push_back(std::abs(view.coordinate[i] - scene.coordinate(u, v)));
    }
  if (e.empty()) return 1e9;
  std::nth_element(e.begin(), e.begin() + static_cast<long>(e.size() / 2), e.end());
  return e[e.size() / 2];
}

std::string findings(const DecodedView& view) {
  std::string out;
  for (const auto& f : view.checks.findings) out += "[" + f.check + "] " + f.message() + "\n";
  return out;
}

// Frames of `plan` listed as a description would list them: new[i] = old[order[i]].
Frames reorder(const Frames& frames, const std::vector<int>& order) {
  Frames out;
  for (int i : order) out.push_back(frames[static_cast<std::size_t>(i)]);
  return out;
}

// The plan's pattern indices with the phase steps listed as `steps` (step numbers of `plan`).
std::vector<int> with_phase_order(const PatternPlan& plan, const std::vector<int>& steps) {
  std::vector<int> order;
  for (std::size_t p = 0; p < plan.size(); ++p)
    if (plan[p].kind != PatternKind::phase_step) order.push_back(static_cast<int>(p));
  for (int s : steps) order.push_back(plan.index_of(PatternKind::phase_step, s));
  return order;
}

TEST(SaturationByKind, ClippedGrayFramesCostNothingClippedPhaseFramesMaskThePhase) {
  const PatternPlan plan;
  Scene scene;
  Frames frames = render(plan, scene);
  // Columns 100-159: the binary frames clip (a brighter exposure for them); 200-239: a phase
  // frame clips; 260-299: the white frame clips.
  for (std::size_t p = 0; p < plan.size(); ++p) {
    const auto kind = plan[p].kind;
    for (int v = 0; v < scene.height; ++v)
      for (int u = 0; u < scene.width; ++u) {
        auto& value = frames[p][static_cast<std::size_t>(v * scene.width + u)];
        const bool gray = kind == PatternKind::gray_bit || kind == PatternKind::complementary_bit;
        if (u >= 100 && u < 160 && gray && value > 90) value = 255;
        if (u >= 200 && u < 240 && kind == PatternKind::phase_step && plan[p].index == 2 && value > 100) value = 255;
        if (u >= 260 && u < 300 && kind == PatternKind::white) value = 255;
      }
  }
  const DecodedView view = decode(plan, frames, scene);
  std::size_t phase_clipped = 0;
  for (int v = 0; v < scene.height; ++v)
    for (int u = 0; u < scene.width; ++u) {
      const auto i = static_cast<std::size_t>(v * scene.width + u);
      if (u >= 200 && u < 240) {
        phase_clipped += frames[static_cast<std::size_t>(plan.index_of(PatternKind::phase_step, 2))][i] == 255;
        if (frames[static_cast<std::size_t>(plan.index_of(PatternKind::phase_step, 2))][i] == 255) {
          EXPECT_EQ(view.mask[i], DecodeMask::saturated) << u << ", " << v;
        }
      } else {
        EXPECT_EQ(view.mask[i], DecodeMask::valid) << u << ", " << v;
      }
    }
  EXPECT_LT(median_error(view, scene), 0.03) << "clipped Gray and white frames leave the coordinate as it was";
  EXPECT_EQ(view.counts.saturated, phase_clipped);
  EXPECT_EQ(view.counts.clipped.phase, phase_clipped);
  EXPECT_EQ(view.counts.clipped.white, static_cast<std::size_t>(40 * scene.height));
  EXPECT_EQ(view.counts.clipped.black, 0u);
  EXPECT_EQ(view.counts.clipped.gray, static_cast<std::size_t>(60 * scene.height));

  // Gray code alone: the white frame sets the edges, so a clipped white masks; clipped Gray
  // frames still do not.
  PatternPlanConfig gray_only;
  gray_only.phase_steps = 0;
  gray_only.complementary_bit = false;
  gray_only.period_px = 2;
  const PatternPlan plain(gray_only);
  Frames g = render(plain, scene);
  for (std::size_t p = 0; p < plain.size(); ++p)
    for (int v = 0; v < scene.height; ++v)
      for (int u = 0; u < scene.width; ++u) {
        auto& value = g[p][static_cast<std::size_t>(v * scene.width + u)];
        if (u >= 100 && u < 160 && plain[p].kind == PatternKind::gray_bit && value > 90) value = 255;
        if (u >= 260 && u < 300 && plain[p].kind == PatternKind::white) value = 255;
      }
  DecodeOptions no_smoothing;
  no_smoothing.smoothing_radius = 0;
  const DecodedView gv = decode(plain, g, scene, no_smoothing);
  EXPECT_EQ(gv.counts.saturated, static_cast<std::size_t>(40 * scene.height));
  EXPECT_EQ(gv.counts.clipped.gray, static_cast<std::size_t>(60 * scene.height));
  for (int v = 0; v < scene.height; ++v)
    for (int u = 100; u < 160; ++u)
      EXPECT_EQ(gv.mask[static_cast<std::size_t>(v * scene.width + u)], DecodeMask::valid);
}

TEST(SaturationByKind, BothInverseFramesClippedLoseTheBitAndFullScaleTurnsItOff) {
  PatternPlanConfig config;
  config.inverse_gray = true;
  config.with_white_black = false;
  const PatternPlan plan(config);
  Scene scene;
  Frames frames = render(plan, scene);
  const int bit2 = plan.index_of(PatternKind::gray_bit, 2), inverse2 = plan.index_of(PatternKind::gray_bit_inverse, 2);
  for (int v = 0; v < scene.height; ++v)
    for (int u = 0; u < 80; ++u) {
      frames[static_cast<std::size_t>(bit2)][static_cast<std::size_t>(v * scene.width + u)] = 255;
      if (u < 40) frames[static_cast<std::size_t>(inverse2)][static_cast<std::size_t>(v * scene.width + u)] = 255;
    }
  const DecodedView view = decode(plan, frames, scene);
  EXPECT_EQ(view.counts.saturated, static_cast<std::size_t>(40 * scene.height)) << "both clipped: the bit is lost";
  EXPECT_EQ(view.counts.clipped.gray, static_cast<std::size_t>(80 * scene.height));

  DecodeOptions never;
  never.saturation_dn = 256;  // the full scale of 8 bit: nothing counts as clipped
  EXPECT_NO_THROW(never.check());
  const DecodedView all = decode(plan, frames, scene, never);
  EXPECT_EQ(all.counts.saturated, 0u);
  EXPECT_EQ(all.counts.clipped.gray, 0u);
  never.saturation_dn = 257;
  EXPECT_THROW(never.check(), std::invalid_argument);
}

TEST(PhaseOrigin, APlanWithAnOffsetOriginDecodesToOurCoordinate) {
  Scene scene;
  scene.noise_dn = 0;
  const PatternPlan reference;
  const double base = median_error(decode(reference, render(reference, scene), scene), scene);
  PatternPlanConfig shifted;
  shifted.phase_offset_rad = 0.37;
  shifted.phase_offset_steps = 3;
  const PatternPlan plan(shifted);
  const DecodedView view = decode(plan, render(plan, scene), scene);
  EXPECT_EQ(view.counts.valid, static_cast<std::size_t>(scene.width * scene.height));
  EXPECT_LT(median_error(view, scene), base + 0.002);
  EXPECT_FALSE(view.checks.flagged()) << findings(view);
  EXPECT_NEAR(view.checks.phase_offset_rad, 0.0, 0.05);

  // The same frames described without the offset: the check measures it and says what to set.
  const DecodedView described_wrong = decode(reference, render(plan, scene), scene);
  ASSERT_TRUE(described_wrong.checks.flagged());
  const auto& finding = described_wrong.checks.findings.front();
  EXPECT_EQ(finding.check, "phase_offset") << findings(described_wrong);
  EXPECT_NEAR(described_wrong.checks.phase_offset_rad, 0.37 - 2 * std::numbers::pi * 3 / 8, 0.05);
  EXPECT_NE(finding.fix.find("phase.offset_rad = -1.98"), std::string::npos) << finding.fix;
  PatternPlanConfig bad = shifted;
  bad.phase_offset_steps = 8;
  EXPECT_FALSE(bad.check());
  bad = shifted;
  bad.phase_offset_rad = std::nan("");
  EXPECT_FALSE(bad.check());
}

// The checks on a right listing: nothing flagged, and the measurements where they should be.
TEST(DecodeChecks, RightListingsAreNotFlagged) {
  Scene scene;
  for (const bool complementary : {true, false})
    for (const bool white_black : {true, false}) {
      PatternPlanConfig config;
      config.complementary_bit = complementary;
      config.with_white_black = white_black;
      const PatternPlan plan(config);
      const DecodedView view = decode(plan, render(plan, scene), scene);
      SCOPED_TRACE(std::string(complementary ? "complementary" : "no complementary") +
                   (white_black ? ", white/black" : ", no white/black"));
      EXPECT_FALSE(view.checks.flagged()) << findings(view);
      EXPECT_TRUE(view.checks.has_phase);
      EXPECT_GT(view.checks.sinusoid_share, 0.9) << "gamma 2.2 leaves harmonics";
      ASSERT_EQ(view.checks.phase_shift_deg.size(), 8u);
      for (std::size_t n = 0; n < 8; ++n) EXPECT_NEAR(view.checks.phase_shift_deg[n], 45.0 * n, 3.0) << n;
      EXPECT_NEAR(view.checks.phase_offset_rad, 0.0, 0.1);
      EXPECT_GT(view.checks.phase_direction_agreement, 0.9);
      EXPECT_GT(view.checks.gray_continuity, 0.95);
      if (complementary) {
        EXPECT_GT(view.checks.complementary_agreement, 0.99);
      }
      EXPECT_LT(view.checks.period_jump_rate, complementary ? 0.01 : 0.06);
    }
}

// The check's figures from the frames written plainly, over the rows it samples.
TEST(DecodeChecks, MatchesAPlainComputationOverTheSampledRows) {
  Scene scene;
  const PatternPlan plan;
  const Frames frames = render(plan, scene);
  const DecodedView view = decode(plan, frames, scene);
  const int step = view.checks.row_step;
  ASSERT_GE(step, 2);
  auto at = [&](int pattern, int u, int v) {
    return static_cast<double>(
        frames[static_cast<std::size_t>(pattern)][static_cast<std::size_t>(v * scene.width + u)]);
  };
  std::size_t sampled = 0, comp = 0, comp_agree = 0, changes = 0, by_one = 0;
  auto code_of = [&](int u, int v, double& phi) {
    const double t = at(0, u, v) + at(1, u, v);
    std::uint32_t word = 0;
    for (int b = 0; b < 8; ++b) word = (word << 1) | (2 * at(plan.index_of(PatternKind::gray_bit, b), u, v) > t);
    word = (word << 1) | (2 * at(plan.index_of(PatternKind::complementary_bit), u, v) > t);
    double s = 0, c = 0;
    for (int n = 0; n < 8; ++n) {
      const double value = at(plan.index_of(PatternKind::phase_step, n), u, v);
      s += value * std::sin(2 * std::numbers::pi * n / 8);
      c += value * std::cos(2 * std::numbers::pi * n / 8);
    }
    phi = std::atan2(-s, c);
    if (phi < 0) phi += 2 * std::numbers::pi;
    return slproto::gray_to_binary(word);
  };
  auto valid = [&](int u, int v) {
    return view.mask[static_cast<std::size_t>(v * scene.width + u)] == DecodeMask::valid;
  };
  auto coded = [&](int u, int v) {
    const DecodeMask m = view.mask[static_cast<std::size_t>(v * scene.width + u)];
    return m == DecodeMask::valid || m == DecodeMask::out_of_range || m == DecodeMask::low_modulation;
  };
  for (int v = step / 2; v + 1 < scene.height; v += step) {
    for (int r = 0; r < 2; ++r)
      for (int u = 0; u < scene.width; ++u) {
        if (!valid(u, v + r)) continue;
        ++sampled;
        double phi;
        const std::uint32_t h = code_of(u, v + r, phi);
        const double psi = std::fmod(phi + std::numbers::pi / 8, 2 * std::numbers::pi);
        if (std::min({psi, std::abs(psi - std::numbers::pi), 2 * std::numbers::pi - psi}) >= std::numbers::pi / 4) {
          ++comp;
          comp_agree += ((h & 1u) != 0) == (psi >= std::numbers::pi);
        }
      }
    auto pair = [&](int ua, int va, int ub, int vb) {
      if (!coded(ua, va) || !coded(ub, vb)) return;
      double phi;
      const std::uint32_t a = code_of(ua, va, phi), b = code_of(ub, vb, phi);
      if (a == b) return;
      ++changes;
      by_one += a + 1 == b || b + 1 == a;
    };
    for (int r = 0; r < 2; ++r)
      for (int u = 0; u + 1 < scene.width; ++u) pair(u, v + r, u + 1, v + r);
    for (int u = 0; u < scene.width; ++u) pair(u, v, u, v + 1);
  }
  EXPECT_EQ(view.checks.sampled_pixels, sampled);
  EXPECT_DOUBLE_EQ(view.checks.complementary_agreement, static_cast<double>(comp_agree) / static_cast<double>(comp));
  EXPECT_DOUBLE_EQ(view.checks.gray_continuity, static_cast<double>(by_one) / static_cast<double>(changes));
}

struct Wrong {
  const char* name;
  std::vector<int> order;  // frames of the default plan as the wrong description lists them
  PatternPlanConfig described;
  const char* check;  // the finding expected first
  const char* words;  // in its message
};

TEST(DecodeChecks, EachWrongListingIsNamed) {
  Scene scene;
  const PatternPlan plan;
  const Frames frames = render(plan, scene);
  PatternPlanConfig seven;
  seven.phase_steps = 7;
  std::vector<int> gray_reversed;
  gray_reversed.push_back(0);
  gray_reversed.push_back(1);
  for (int b = 7; b >= 0; --b) gray_reversed.push_back(plan.index_of(PatternKind::gray_bit, b));
  for (std::size_t p = 10; p < plan.size(); ++p) gray_reversed.push_back(static_cast<int>(p));
  // Gray files one late: white, black, then bits 1..7 and the complementary frame as bits 0..7,
  // and the first phase frame as the complementary one.
  std::vector<int> gray_late = {0, 1, 3, 4, 5, 6, 7, 8, 9, 10, 11};
  for (int n = 0; n < 8; ++n) gray_late.push_back(11 + n);
  std::vector<int> gray_early = {0, 1, 1, 2, 3, 4, 5, 6, 7, 8, 10};
  for (int n = 0; n < 8; ++n) gray_early.push_back(11 + n);
  const std::vector<Wrong> cases = {
      {"phase frames rotated by 4",
       with_phase_order(plan, {4, 5, 6, 7, 0, 1, 2, 3}),
       {},
       "phase_offset",
       "list them from frame 4, or set phase.offset_steps = 4"},
      {"phase frames rotated by 6",
       with_phase_order(plan, {2, 3, 4, 5, 6, 7, 0, 1}),
       {},
       "phase_offset",
       "rotated by 6 steps (their phase origin is 1.57 rad"},
      {"phase frames reversed",
       with_phase_order(plan, {0, 7, 6, 5, 4, 3, 2, 1}),
       {},
       "phase_direction",
       "list them as 0, 7, 6, ..., 1"},
      {"a phase frame missing", with_phase_order(plan, {0, 1, 2, 3, 4, 5, 6}), seven, "phase_frames",
       "an 8-step sequence with 1 frame missing"},
      {"phase frames out of order",
       with_phase_order(plan, {0, 2, 1, 3, 4, 5, 6, 7}),
       {},
       "phase_frames",
       "out of order"},
      {"Gray bits LSB first", gray_reversed, {}, "gray_order", "least significant bit first"},
      {"Gray files one late", gray_late, {}, "gray_order", "starts one frame late"},
      {"Gray files one early", gray_early, {}, "gray_order", "starts one frame early"},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.name);
    const PatternPlan described(c.described);
    const Frames listed = reorder(frames, c.order);
    ASSERT_EQ(listed.size(), described.size());
    const DecodedView view = decode(described, listed, scene);
    ASSERT_TRUE(view.checks.flagged());
    EXPECT_EQ(view.checks.findings.front().check, c.check) << findings(view);
    EXPECT_NE(view.checks.findings.front().message().find(c.words), std::string::npos) << findings(view);
  }
}

}  // namespace
