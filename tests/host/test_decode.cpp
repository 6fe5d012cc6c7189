// Decoder tests on synthetic frames: each camera pixel sees a known projector coordinate, and
// its frames are generated straight from slproto::PatternPlan::value (with projector gamma,
// blur at the Gray edges, sensor noise and 8/16-bit quantisation). No rig needed.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <functional>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "slscan/core/decode.hpp"

namespace {

using slproto::CodingAxis;
using slproto::PatternPlan;
using slproto::PatternPlanConfig;
using slscan::core::DecodedView;
using slscan::core::DecodeMask;
using slscan::core::DecodeOptions;
using slscan::core::ProjectorViewDecoder;

struct SceneModel {
  int width = 320, height = 40;
  std::function<double(int, int)> coordinate;                             // true projector coordinate of pixel (u, v)
  std::function<double(int, int)> gain = [](int, int) { return 180.0; };  // DN for a full-white pattern
  double black_dn = 8.0;                                                  // ambient + dark level
  double gamma = 1.0;                                                     // projector response: radiance = value^gamma
  double blur_px = 0.0;  // box blur of the pattern (projector px), sampled at 33 points
  double noise_dn = 0.0;
  int bit_depth = 8;
  std::uint32_t seed = 7;
};

// The row-major index of pixel (u, v).
std::size_t pixel(int u, int v, int width) {
  return static_cast<std::size_t>(v) * static_cast<std::size_t>(width) + static_cast<std::size_t>(u);
}

// What the DMD shows at continuous coordinate x: binary patterns are constant over each
// projector pixel [c - 0.5, c + 0.5) (so their edges fall between pixel centres); the sine is
// smooth (defocus removes the pixel steps, leaving its phase).
double pattern_at(const PatternPlan& plan, std::size_t p, double x) {
  const auto kind = plan[p].kind;
  const bool binary = kind != slproto::PatternKind::phase_step && kind != slproto::PatternKind::white &&
                      kind != slproto::PatternKind::black;
  return plan.value(p, binary ? std::floor(x + 0.5) : x);
}

// Frames of a plan for the scene, as 16-bit samples (narrowed to 8 bit by the caller).
std::vector<std::vector<std::uint16_t>> render(const PatternPlan& plan, const SceneModel& scene) {
  std::mt19937 rng(scene.seed);
  std::normal_distribution<double> noise(0.0, 1.0);
  const double top = std::pow(2.0, scene.bit_depth) - 1.0;
  const double scale = top / 255.0;
  std::vector<std::vector<std::uint16_t>> frames(plan.size());
  for (std::size_t p = 0; p < plan.size(); ++p) {
    auto& frame = frames[p];
    frame.resize(static_cast<std::size_t>(scene.width) * static_cast<std::size_t>(scene.height));
    for (int v = 0; v < scene.height; ++v)
      for (int u = 0; u < scene.width; ++u) {
        const double x = scene.coordinate(u, v);
        double value = 0;
        if (scene.blur_px > 0) {
          constexpr int kSamples = 33;
          for (int s = 0; s < kSamples; ++s) {
            const double offset = scene.blur_px * ((s + 0.5) / kSamples - 0.5);
            value += std::pow(pattern_at(plan, p, x + offset), scene.gamma);
          }
          value /= kSamples;
        } else {
          value = std::pow(pattern_at(plan, p, x), scene.gamma);
        }
        double dn = scale * (scene.black_dn + scene.gain(u, v) * value) + scale * scene.noise_dn * noise(rng);
        frame[pixel(u, v, scene.width)] = static_cast<std::uint16_t>(std::clamp(std::round(dn), 0.0, top));
      }
  }
  return frames;
}

DecodedView decode(const PatternPlan& plan, const SceneModel& scene, DecodeOptions options = {}) {
  options.bit_depth = scene.bit_depth;
  ProjectorViewDecoder decoder(plan, scene.width, scene.height, options);
  const auto frames = render(plan, scene);
  for (std::size_t p = 0; p < frames.size(); ++p) {
    if (scene.bit_depth == 8) {
      std::vector<std::uint8_t> narrow(frames[p].begin(), frames[p].end());
      decoder.add_frame(p, narrow.data(), static_cast<std::size_t>(scene.width));
    } else {
      decoder.add_frame(p, frames[p].data(), static_cast<std::size_t>(scene.width));
    }
  }
  return decoder.finish();
}

struct Errors {
  double max_abs = 0, median_abs = 0;
  std::size_t jumps = 0;  // errors of half a period or more: a wrong fringe order
  std::size_t compared = 0;
};

Errors errors(const DecodedView& view, const SceneModel& scene, double period) {
  Errors e;
  std::vector<double> abs_errors;
  for (int v = 0; v < scene.height; ++v)
    for (int u = 0; u < scene.width; ++u) {
      const auto i = pixel(u, v, scene.width);
      if (view.mask[i] != DecodeMask::valid) continue;
      const double err = std::abs(view.coordinate[i] - scene.coordinate(u, v));
      if (err >= 0.5 * period) ++e.jumps;
      abs_errors.push_back(err);
    }
  e.compared = abs_errors.size();
  if (!abs_errors.empty()) {
    e.max_abs = *std::max_element(abs_errors.begin(), abs_errors.end());
    std::nth_element(abs_errors.begin(), abs_errors.begin() + static_cast<long>(abs_errors.size() / 2),
                     abs_errors.end());
    e.median_abs = abs_errors[abs_errors.size() / 2];
  }
  return e;
}

// A smooth coordinate map over most of the 1140-px coded extent, with a slope that is not a
// rational multiple of the period so every sub-pixel phase is visited.
double ramp(int u, int v) { return 2.37 + 3.4713 * u + 0.0917 * v; }

TEST(Decode, RecoversExactCoordinateNoiseFree16Bit) {
  const PatternPlan plan;  // the paper's 19 frames
  SceneModel scene;
  scene.coordinate = ramp;
  scene.bit_depth = 16;
  const DecodedView view = decode(plan, scene);
  EXPECT_EQ(view.counts.valid, static_cast<std::size_t>(scene.width) * static_cast<std::size_t>(scene.height));
  const Errors e = errors(view, scene, 8);
  EXPECT_EQ(e.compared, static_cast<std::size_t>(scene.width) * static_cast<std::size_t>(scene.height));
  EXPECT_EQ(e.jumps, 0u);
  // 16-bit quantisation of a 180 x 257 DN sine: ~1e-5 rad of phase; the fast atan2 adds ~2e-7.
  EXPECT_LT(e.max_abs, 1e-3);
}

TEST(Decode, PixelCentreConvention) {
  // A pixel that sees the centre of projector column 100 decodes to 100.0, not 100.5; and the
  // centres either side of a Gray edge (x = 8k - 0.5) decode to their own column.
  const PatternPlan plan;
  const std::vector<double> truth = {100.0, 0.0, 7.0, 8.0, 15.0, 16.0, 1139.0, 571.25, 799.75, 4.0, 3.999, 4.001};
  SceneModel scene;
  scene.width = static_cast<int>(truth.size());
  scene.height = 1;
  scene.bit_depth = 16;
  scene.coordinate = [&](int u, int) { return truth[static_cast<std::size_t>(u)]; };
  const DecodedView view = decode(plan, scene);
  for (std::size_t i = 0; i < truth.size(); ++i) {
    ASSERT_EQ(view.mask[i], DecodeMask::valid) << "column " << truth[i];
    EXPECT_NEAR(view.coordinate[i], truth[i], 1e-3) << "column " << truth[i];
  }
}

TEST(Decode, GammaAndNoiseStayAccurate) {
  const PatternPlan plan;
  SceneModel scene;
  scene.coordinate = ramp;
  scene.gamma = 2.2;
  scene.noise_dn = 1.5;
  scene.blur_px = 1.4;
  const DecodedView view = decode(plan, scene);
  const Errors e = errors(view, scene, 8);
  EXPECT_GT(e.compared, static_cast<std::size_t>(0.99 * scene.width * scene.height));
  EXPECT_EQ(e.jumps, 0u);
  // Gamma 2.2 puts harmonics into the sine; an 8-step shift cancels all up to the 6th, so
  // what is left is noise: sigma_phi ~ sigma / (B sqrt(N / 2)) ~ 1.5 / (90 * 2) rad ~ 0.01 px.
  EXPECT_LT(e.median_abs, 0.02);
  EXPECT_LT(e.max_abs, 0.12);
}

TEST(Decode, ComplementaryBitRemovesJumpsAtPeriodEdges) {
  // Blur and noise make the Gray bits unreliable within ~1 px of their edges. Without the
  // complementary bit, those pixels get the neighbouring fringe order: 2 pi jumps (errors of a
  // whole period). With it, the order is taken from K2 near the period edges: no jumps.
  SceneModel scene;
  scene.coordinate = ramp;
  scene.blur_px = 2.0;
  scene.noise_dn = 3.0;
  scene.gamma = 2.2;
  PatternPlanConfig with;
  PatternPlanConfig without = with;
  without.complementary_bit = false;
  const DecodedView plain = decode(PatternPlan(without), scene);
  const DecodedView corrected = decode(PatternPlan(with), scene);
  const Errors e_plain = errors(plain, scene, 8);
  const Errors e_corrected = errors(corrected, scene, 8);
  EXPECT_GT(e_plain.jumps, 50u) << "the blur should have made plain Gray decoding jump";
  EXPECT_EQ(e_corrected.jumps, 0u);
  EXPECT_LT(e_corrected.max_abs, 0.3);
  EXPECT_GT(e_corrected.compared, static_cast<std::size_t>(0.99 * scene.width * scene.height));
}

TEST(Decode, MasksLowContrastLowModulationAndSaturation) {
  const PatternPlan plan;
  SceneModel scene;
  scene.coordinate = ramp;
  scene.noise_dn = 0.5;
  // Column bands: dark (contrast 5 DN), overexposed (clips at 255), normal.
  scene.gain = [](int u, int) { return u < 100 ? 5.0 : (u < 200 ? 400.0 : 150.0); };
  const DecodedView view = decode(plan, scene);
  std::size_t checked = 0;
  for (int v = 0; v < scene.height; ++v)
    for (int u = 0; u < scene.width; ++u) {
      const auto i = pixel(u, v, scene.width);
      const DecodeMask expected =
          u < 100 ? DecodeMask::low_contrast : (u < 200 ? DecodeMask::saturated : DecodeMask::valid);
      ASSERT_EQ(view.mask[i], expected) << "pixel " << u << ", " << v;
      if (expected != DecodeMask::valid) {
        EXPECT_TRUE(std::isnan(view.coordinate[i]));
        EXPECT_EQ(view.quality[i], 0.0f);
      }
      ++checked;
    }
  EXPECT_EQ(checked, static_cast<std::size_t>(scene.width) * static_cast<std::size_t>(scene.height));
  EXPECT_EQ(view.counts.low_contrast, static_cast<std::size_t>(100 * scene.height));
  EXPECT_EQ(view.counts.saturated, static_cast<std::size_t>(100 * scene.height));
  EXPECT_EQ(view.counts.valid, static_cast<std::size_t>(120 * scene.height));
  EXPECT_EQ(view.counts.total(), static_cast<std::size_t>(scene.width) * static_cast<std::size_t>(scene.height));

  // Low modulation: white/black are fine but the fringes are washed out (a blur of exactly one
  // period cancels the sine), as on a surface far out of the projector's focus.
  SceneModel washed = scene;
  washed.gain = [](int, int) { return 150.0; };
  washed.blur_px = 8.0;
  const DecodedView blurred = decode(plan, washed);
  EXPECT_EQ(blurred.counts.low_modulation, static_cast<std::size_t>(washed.width * washed.height));
  EXPECT_EQ(blurred.counts.valid, 0u);
}

TEST(Decode, RowsAxisWithOddStepsAndPeriod) {
  PatternPlanConfig config;
  config.axis = CodingAxis::rows;
  config.period_px = 12;
  config.phase_steps = 5;
  const PatternPlan plan(config);
  SceneModel scene;
  scene.coordinate = [](int u, int v) { return 1.7 + 2.7913 * u + 0.31 * v; };  // up to ~906 of 912 rows
  scene.gamma = 2.2;
  scene.noise_dn = 1.0;
  scene.blur_px = 1.0;
  const DecodedView view = decode(plan, scene);
  EXPECT_EQ(view.axis, CodingAxis::rows);
  const Errors e = errors(view, scene, 12);
  EXPECT_GT(e.compared, static_cast<std::size_t>(0.99 * scene.width * scene.height));
  EXPECT_EQ(e.jumps, 0u);
  // A 5-step shift leaves gamma's 4th and 6th harmonics aliased onto the fundamental: a few
  // hundredths of a pixel at P = 12.
  EXPECT_LT(e.median_abs, 0.08);
}

TEST(Decode, PlanWithoutWhiteBlackThresholdsAgainstThePhaseMean) {
  PatternPlanConfig config;
  config.with_white_black = false;
  const PatternPlan plan(config);
  SceneModel scene;
  scene.coordinate = ramp;
  scene.noise_dn = 1.0;
  const DecodedView view = decode(plan, scene);
  const Errors e = errors(view, scene, 8);
  EXPECT_GT(e.compared, static_cast<std::size_t>(0.99 * scene.width * scene.height));
  EXPECT_EQ(e.jumps, 0u);
  EXPECT_LT(e.median_abs, 0.02);
}

TEST(Decode, GrayCodeOnlyPlanGivesHalfPeriodCentres) {
  PatternPlanConfig config;
  config.phase_steps = 0;
  const PatternPlan plan(config);
  SceneModel scene;
  scene.coordinate = ramp;
  const DecodedView view = decode(plan, scene);
  EXPECT_EQ(view.counts.valid, static_cast<std::size_t>(scene.width) * static_cast<std::size_t>(scene.height));
  const Errors e = errors(view, scene, 8);
  // Half-period resolution: the centre of a 4-px cell is within 2 px of any point in it.
  EXPECT_LE(e.max_abs, 2.0 + 1e-6);
}

// Pixel u sees the centre of projector pixel x = 3 u + 1 (a ramp over 960 of the 1140 columns).
double integer_columns(int u, int) { return 3.0 * u + 1.0; }

TEST(Decode, InverseGrayFramesGiveExactStepsWithoutWhiteBlack) {
  for (bool complementary : {false, true}) {
    SCOPED_TRACE(complementary ? "with the complementary bit" : "Gray bits only");
    PatternPlanConfig config;
    config.phase_steps = 0;
    config.with_white_black = false;
    config.inverse_gray = true;
    config.complementary_bit = complementary;
    const PatternPlan plan(config);
    ASSERT_EQ(plan.size(), static_cast<std::size_t>(2 * (config.gray_bits() + (complementary ? 1 : 0))));
    SceneModel scene;
    scene.coordinate = integer_columns;
    scene.gamma = 2.2;
    scene.noise_dn = 1.0;
    // A dim band (left) and a band whose frames differ from their inverses by 10 DN (right of
    // 300): both below min_contrast_dn 12 in every bit. The middle has 200 DN of contrast.
    scene.gain = [](int u, int) { return u < 40 ? 4.0 : (u >= 300 ? 10.0 : 200.0); };
    scene.black_dn = 8.0;
    DecodeOptions options;
    options.smoothing_radius = 0;  // steps, not a phase: nothing to smooth
    const DecodedView view = decode(plan, scene, options);
    const double step = complementary ? 4.0 : 8.0;
    for (int v = 0; v < scene.height; ++v)
      for (int u = 0; u < scene.width; ++u) {
        const auto i = pixel(u, v, scene.width);
        if (u < 40 || u >= 300) {
          ASSERT_EQ(view.mask[i], DecodeMask::low_contrast) << "u " << u;
          ASSERT_TRUE(std::isnan(view.coordinate[i]));
          continue;
        }
        ASSERT_EQ(view.mask[i], DecodeMask::valid) << "u " << u;
        const double h = std::floor(integer_columns(u, v) / step);
        ASSERT_EQ(view.coordinate[i], static_cast<float>(h * step + 0.5 * (step - 1))) << "u " << u;
        EXPECT_GT(view.quality[i], 150.0f) << "the contrast of a clear pixel is its frame - inverse difference";
      }
  }
}

TEST(Decode, InverseGrayContrastToleratesOneBitAtItsEdgeButNotTwo) {
  PatternPlanConfig config;
  config.phase_steps = 0;
  config.with_white_black = false;
  config.inverse_gray = true;
  config.complementary_bit = false;
  const PatternPlan plan(config);
  SceneModel scene;
  scene.coordinate = integer_columns;
  auto frames = render(plan, scene);
  const int bit3 = plan.index_of(slproto::PatternKind::gray_bit, 3);
  const int bit3_inverse = plan.index_of(slproto::PatternKind::gray_bit_inverse, 3);
  const int bit6 = plan.index_of(slproto::PatternKind::gray_bit, 6);
  const int bit6_inverse = plan.index_of(slproto::PatternKind::gray_bit_inverse, 6);
  ASSERT_EQ(bit3_inverse, bit3 + 1) << "each inverse follows its bit";
  // Columns 100..149: bit 3 unreadable (frame and inverse 2 DN apart), as at a stripe edge.
  // Columns 200..249: bits 3 and 6 unreadable: not a Gray edge but a blurred or broken code.
  auto blur = [&](int bit, int inverse, int u0, int u1) {
    for (int v = 0; v < scene.height; ++v)
      for (int u = u0; u < u1; ++u) {
        const auto i = pixel(u, v, scene.width);
        frames[static_cast<std::size_t>(bit)][i] = 100;
        frames[static_cast<std::size_t>(inverse)][i] = 98;
      }
  };
  blur(bit3, bit3_inverse, 100, 150);
  blur(bit3, bit3_inverse, 200, 250);
  blur(bit6, bit6_inverse, 200, 250);
  DecodeOptions options;
  options.smoothing_radius = 0;
  ProjectorViewDecoder decoder(plan, scene.width, scene.height, options);
  for (std::size_t p = 0; p < frames.size(); ++p) {
    std::vector<std::uint8_t> narrow(frames[p].begin(), frames[p].end());
    decoder.add_frame(p, narrow.data(), static_cast<std::size_t>(scene.width));
  }
  const DecodedView view = decoder.finish();
  for (int u = 0; u < scene.width; ++u) {
    const auto i = static_cast<std::size_t>(u);
    const bool broken = u >= 200 && u < 250;
    EXPECT_EQ(view.mask[i], broken ? DecodeMask::low_contrast : DecodeMask::valid) << "u " << u;
    if (!broken && (u < 100 || u >= 150)) {
      EXPECT_EQ(view.coordinate[i], static_cast<float>(std::floor(integer_columns(u, 0) / 8) * 8 + 3.5)) << u;
    }
  }
  EXPECT_EQ(view.counts.low_contrast, static_cast<std::size_t>(50 * scene.height));
}

TEST(Decode, InverseGrayFramesWithPhaseAndWhiteBlack) {
  // Inverse frames threshold the Gray bits; phase (with and without the complementary bit, with
  // and without white/black frames) gives the position within the period as usual.
  for (bool white_black : {false, true})
    for (bool complementary : {false, true}) {
      SCOPED_TRACE(std::string(white_black ? "white/black" : "no white/black") +
                   (complementary ? ", complementary" : ", no complementary"));
      PatternPlanConfig config;
      config.inverse_gray = true;
      config.with_white_black = white_black;
      config.complementary_bit = complementary;
      const PatternPlan plan(config);
      SceneModel scene;
      scene.coordinate = ramp;
      scene.gamma = 2.2;
      scene.noise_dn = 1.0;
      scene.blur_px = complementary ? 2.0 : 0.0;  // without the complementary bit, edges must be sharp
      const DecodedView view = decode(plan, scene);
      const Errors e = errors(view, scene, 8);
      EXPECT_GT(e.compared, static_cast<std::size_t>(0.99 * scene.width * scene.height));
      // Without the complementary bit a pixel within the noise of a period edge can still take
      // the neighbouring order (measured: 6 and 12 of 12,800; 800, i.e. the half pixel before
      // every phase wrap, before the decoder took the Gray edge's offset into account).
      EXPECT_LE(e.jumps, complementary ? 0u : e.compared / 500);
      EXPECT_LT(e.median_abs, 0.02);
    }
}

// SLStudio's DecoderGrayCode, bit for bit (jakobwilm/slstudio, read for its convention): the
// shown Gray bits with the unshown ones read as 0, then Gray -> binary by prefix XOR.
int slstudio_decode(int column, int bits_not_projected) {
  int word = ((column >> 1) ^ column) & ~((1 << bits_not_projected) - 1);
  for (int shift = 1; shift < 16; shift <<= 1) word ^= word >> shift;
  return word;
}

TEST(Decode, SlstudioParityConventionMatchesSlstudiosDecoderForEveryColumn) {
  for (int s = 1; s <= 3; ++s) {
    SCOPED_TRACE(std::to_string(s) + " bits not projected");
    PatternPlanConfig config;
    config.projector_width = 1824;
    config.projector_height = 1140;
    config.phase_steps = 0;
    config.complementary_bit = false;
    config.period_px = 1 << s;
    config.gray_low_bits = slproto::GrayLowBits::slstudio_parity;
    SceneModel scene;
    scene.width = 1824;
    scene.height = 2;
    scene.coordinate = [](int u, int) { return static_cast<double>(u); };
    DecodeOptions options;
    options.smoothing_radius = 0;
    const DecodedView view = decode(PatternPlan(config), scene, options);
    config.gray_low_bits = slproto::GrayLowBits::centre;
    const DecodedView centre = decode(PatternPlan(config), scene, options);
    for (int x = 0; x < 1824; ++x) {
      ASSERT_EQ(view.mask[static_cast<std::size_t>(x)], DecodeMask::valid);
      ASSERT_EQ(view.coordinate[static_cast<std::size_t>(x)], static_cast<float>(slstudio_decode(x, s))) << "x " << x;
      // Half a step left of the centre for even steps, right for odd ones.
      const int c = x >> s;
      ASSERT_EQ(view.coordinate[static_cast<std::size_t>(x)] - centre.coordinate[static_cast<std::size_t>(x)],
                (c & 1 ? 0.5f : -0.5f) * static_cast<float>((1 << s) - 1));
    }
  }
  // The same convention through the complementary bit (a Gray step of P / 2 = 2 pixels) and
  // inverse frames: step c covers 2c, 2c + 1.
  PatternPlanConfig config;
  config.phase_steps = 0;
  config.period_px = 4;
  config.inverse_gray = true;
  config.with_white_black = false;
  config.gray_low_bits = slproto::GrayLowBits::slstudio_parity;
  SceneModel scene;
  scene.width = 1140;
  scene.height = 2;
  scene.coordinate = [](int u, int) { return static_cast<double>(u); };
  DecodeOptions options;
  options.smoothing_radius = 0;
  const DecodedView view = decode(PatternPlan(config), scene, options);
  for (int x = 0; x < 1140; ++x)
    ASSERT_EQ(view.coordinate[static_cast<std::size_t>(x)], static_cast<float>(slstudio_decode(x, 1))) << "x " << x;
}

TEST(Decode, FramesInAnyOrderAndWithStride) {
  const PatternPlan plan;
  SceneModel scene;
  scene.coordinate = ramp;
  scene.noise_dn = 1.0;
  const auto frames = render(plan, scene);
  const DecodedView reference = decode(plan, scene);

  // Reverse order, padded rows, and one frame first sent wrong then replaced.
  const std::size_t stride = static_cast<std::size_t>(scene.width) + 13;
  ProjectorViewDecoder decoder(plan, scene.width, scene.height);
  std::vector<std::uint8_t> padded(stride * static_cast<std::size_t>(scene.height), 0);
  std::vector<std::uint8_t> junk(padded.size(), 77);
  decoder.add_frame(4, junk.data(), stride);
  for (std::size_t p = plan.size(); p-- > 0;) {
    for (int v = 0; v < scene.height; ++v)
      for (int u = 0; u < scene.width; ++u)
        padded[static_cast<std::size_t>(v) * stride + static_cast<std::size_t>(u)] =
            static_cast<std::uint8_t>(frames[p][pixel(u, v, scene.width)]);
    decoder.add_frame(p, padded.data(), stride);
  }
  const DecodedView view = decoder.finish();
  ASSERT_EQ(view.coordinate.size(), reference.coordinate.size());
  for (std::size_t i = 0; i < view.coordinate.size(); ++i) {
    ASSERT_EQ(view.mask[i], reference.mask[i]);
    if (view.mask[i] == DecodeMask::valid) {
      ASSERT_EQ(view.coordinate[i], reference.coordinate[i]);
    }
  }
  // finish() readies the decoder for the next view: nothing is present any more.
  EXPECT_FALSE(decoder.complete());
}

// The scan pipeline decodes each projector-view into a result that held an earlier one (its
// buffers reused): the result must be exactly a fresh decode's, whatever the earlier view held.
TEST(Decode, FinishIntoAReusedResultEqualsAFreshOne) {
  const PatternPlan plan;
  auto feed = [&](ProjectorViewDecoder& decoder, const SceneModel& scene) {
    const auto frames = render(plan, scene);
    for (std::size_t p = 0; p < frames.size(); ++p) {
      const std::vector<std::uint8_t> narrow(frames[p].begin(), frames[p].end());
      decoder.add_frame(p, narrow.data(), static_cast<std::size_t>(scene.width));
    }
  };
  SceneModel earlier;  // smoothed, every pixel lit
  earlier.coordinate = ramp;
  earlier.noise_dn = 1.5;
  SceneModel next;  // not smoothed, a dark band masked, another slope
  next.coordinate = [](int u, int v) { return 11.0 + 2.9 * u - 0.2 * v; };
  next.gain = [](int u, int) { return u < 60 ? 2.0 : 170.0; };
  next.noise_dn = 0.8;
  next.seed = 99;
  DecodeOptions smoothed, plain;
  smoothed.smoothing_radius = 2;
  plain.smoothing_radius = 0;
  plain.self_check = true;

  ProjectorViewDecoder first(plan, earlier.width, earlier.height, smoothed);
  feed(first, earlier);
  DecodedView reused;
  first.finish(reused);
  ASSERT_GT(reused.coordinate_noise_px, 0.0f);
  ProjectorViewDecoder second(plan, next.width, next.height, plain);
  feed(second, next);
  second.finish(reused);
  ProjectorViewDecoder fresh_decoder(plan, next.width, next.height, plain);
  feed(fresh_decoder, next);
  const DecodedView fresh = fresh_decoder.finish();

  auto same_bits = [](const auto& a, const auto& b) {
    return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(a[0])) == 0;
  };
  EXPECT_TRUE(same_bits(reused.coordinate, fresh.coordinate));
  EXPECT_TRUE(same_bits(reused.quality, fresh.quality));
  EXPECT_TRUE(same_bits(reused.intensity, fresh.intensity));
  EXPECT_TRUE(same_bits(reused.mask, fresh.mask));
  EXPECT_EQ(reused.counts.valid, fresh.counts.valid);
  EXPECT_EQ(reused.counts.low_contrast + reused.counts.low_modulation,
            fresh.counts.low_contrast + fresh.counts.low_modulation);
  EXPECT_GT(fresh.counts.low_contrast + fresh.counts.low_modulation, 0u);  // the dark band is masked
  EXPECT_EQ(reused.coordinate_noise_px, fresh.coordinate_noise_px);
  EXPECT_EQ(reused.smoothing_max_deviation_px, fresh.smoothing_max_deviation_px);
  EXPECT_EQ(reused.checks.ran, fresh.checks.ran);
  EXPECT_EQ(reused.checks.sampled_pixels, fresh.checks.sampled_pixels);
}

TEST(Decode, RejectsMisuseWithClearErrors) {
  const PatternPlan plan;
  std::vector<std::uint8_t> frame8(64 * 8);
  std::vector<std::uint16_t> frame16(64 * 8);
  ProjectorViewDecoder decoder(plan, 64, 8);
  EXPECT_THROW(decoder.add_frame(19, frame8.data(), 64), std::out_of_range);
  EXPECT_THROW(decoder.add_frame(0, frame8.data(), 63), std::invalid_argument);
  EXPECT_THROW(decoder.add_frame(0, static_cast<const std::uint8_t*>(nullptr), 64), std::invalid_argument);
  EXPECT_THROW(decoder.add_frame(0, frame16.data(), 64), std::invalid_argument);  // 16-bit into 8-bit
  for (std::size_t p = 0; p < plan.size(); ++p)
    if (p != 7) decoder.add_frame(p, frame8.data(), 64);
  try {
    (void)decoder.finish();
    ADD_FAILURE() << "finish() with a missing frame must throw";
  } catch (const std::logic_error& e) {
    EXPECT_NE(std::string(e.what()).find("frame 7 (gray_bit 5)"), std::string::npos) << e.what();
  }
  DecodeOptions bad;
  bad.bit_depth = 9;
  EXPECT_THROW(bad.check(), std::invalid_argument);
  bad = {};
  bad.min_modulation_dn = -1;
  EXPECT_THROW(bad.check(), std::invalid_argument);
  bad = {};
  bad.saturation_dn = 300;
  EXPECT_THROW(bad.check(), std::invalid_argument);
  EXPECT_THROW(ProjectorViewDecoder(plan, 0, 8), std::invalid_argument);
  PatternPlanConfig unusable;
  unusable.with_white_black = false;
  unusable.phase_steps = 0;
  EXPECT_THROW(ProjectorViewDecoder(PatternPlan(unusable), 8, 8), std::invalid_argument);
  unusable.inverse_gray = true;  // the inverse frames are a threshold of their own
  EXPECT_NO_THROW(ProjectorViewDecoder(PatternPlan(unusable), 8, 8));
}

TEST(Decode, TwelveBitFrames) {
  const PatternPlan plan;
  SceneModel scene;
  scene.coordinate = ramp;
  scene.bit_depth = 12;
  scene.noise_dn = 1.0;  // in 8-bit DN units, scaled to 12 bit by the renderer
  scene.gamma = 2.2;
  DecodeOptions options;
  options.min_contrast_dn = 12.0f * 16;
  options.min_modulation_dn = 6.0f * 16;
  const DecodedView view = decode(plan, scene, options);
  const Errors e = errors(view, scene, 8);
  EXPECT_EQ(e.compared, static_cast<std::size_t>(scene.width) * static_cast<std::size_t>(scene.height));
  EXPECT_EQ(e.jumps, 0u);
  EXPECT_LT(e.median_abs, 0.02);
}

}  // namespace

namespace {

// The value at the centre of the least-squares quadratic surface (1, du, dv, du^2, du dv, dv^2)
// through a whole (2 q + 1)^2 window, solved from the normal equations; NaN if any is masked.
double quadratic_fit_at_centre(const DecodedView& raw, int u, int v, int q) {
  using Vector6d = Eigen::Matrix<double, 6, 1>;
  Eigen::Matrix<double, 6, 6> normal = Eigen::Matrix<double, 6, 6>::Zero();
  Vector6d rhs = Vector6d::Zero();
  for (int dv = -q; dv <= q; ++dv)
    for (int du = -q; du <= q; ++du) {
      const double value = raw.coordinate[pixel(u + du, v + dv, raw.width)];
      if (std::isnan(value)) return std::numeric_limits<double>::quiet_NaN();
      Vector6d basis;
      basis << 1.0, du, dv, double(du) * du, double(du) * dv, double(dv) * dv;
      normal += basis * basis.transpose();
      rhs += basis * value;
    }
  return normal.ldlt().solve(rhs)(0);
}

// The smoothing as docs/pipeline.md states it, written plainly per window in double: the
// decoder's separable sums must give the same values.
std::vector<float> reference_smoothing(const DecodedView& raw, float max_deviation, int quadratic_radius) {
  const int w = raw.width, h = raw.height;
  std::vector<float> out = raw.coordinate;
  auto at = [&](int u, int v) { return raw.coordinate[pixel(u, v, w)]; };
  for (int v = 1; v < h - 1; ++v) {
    const int r = (v >= 2 && v < h - 2) ? 2 : 1;
    for (int u = r; u < w - r; ++u) {
      const double c = at(u, v);
      if (std::isnan(c)) continue;
      double s5 = 0, s3 = 0;
      int n5 = 0, n3 = 0;
      Eigen::Matrix3d normal = Eigen::Matrix3d::Zero();
      Eigen::Vector3d rhs = Eigen::Vector3d::Zero();
      for (int dv = -r; dv <= r; ++dv)
        for (int du = -r; du <= r; ++du) {
          const double value = at(u + du, v + dv);
          if (std::isnan(value)) continue;
          ++n5;
          s5 += value;
          if (std::abs(du) <= 1 && std::abs(dv) <= 1) {
            ++n3;
            s3 += value;
          }
          const Eigen::Vector3d basis(1.0, du, dv);
          normal += basis * basis.transpose();
          rhs += basis * (value - c);
        }
      const int full = (2 * r + 1) * (2 * r + 1);
      auto& result = out[pixel(u, v, w)];
      if (n5 == full) {
        const double m5 = s5 / full - c, m3 = s3 / 9 - c;
        const double tolerance = 0.8 / std::max<double>(raw.quality[pixel(u, v, w)], 1.0);
        if (std::abs(m5) <= max_deviation) {
          const bool curved = r == 2 && std::abs(m5 - m3) > tolerance;
          result = static_cast<float>(c + (curved ? 1.5 * m3 - 0.5 * m5 : m5));
        } else if (n3 == 9 && std::abs(m3) <= max_deviation) {
          result = static_cast<float>(c + m3);
        }
      } else if (n5 >= 6) {
        const Eigen::FullPivLU<Eigen::Matrix3d> lu(normal);
        if (lu.rank() == 3) {
          const double a = lu.solve(rhs)(0);
          if (std::abs(a) <= max_deviation) result = static_cast<float>(c + a);
        }
      }
      const int q = quadratic_radius;
      if (q > 0 && u >= q && u < w - q && v >= q && v < h - q) {
        const double value = quadratic_fit_at_centre(raw, u, v, q);
        const double agreement = 1.6 / std::max<double>(raw.quality[pixel(u, v, w)], 1.0);
        if (!std::isnan(value) && std::abs(value - c) <= max_deviation && std::abs(value - result) <= agreement)
          result = static_cast<float>(value);
      }
    }
  }
  return out;
}

void expect_smoothing_matches_the_definition(const DecodedView& raw, const DecodedView& smoothed,
                                             const std::vector<float>& expected) {
  ASSERT_EQ(raw.mask, smoothed.mask);
  std::size_t compared = 0, changed = 0, off = 0;
  double worst = 0;
  for (std::size_t i = 0; i < expected.size(); ++i) {
    if (std::isnan(expected[i])) {
      EXPECT_TRUE(std::isnan(smoothed.coordinate[i])) << "pixel " << i;
      continue;
    }
    ++compared;
    if (expected[i] != raw.coordinate[i]) ++changed;
    const double diff = std::abs(static_cast<double>(smoothed.coordinate[i]) - expected[i]);
    worst = std::max(worst, diff);
    if (diff > 1e-4) ++off;  // a decision at its threshold may flip on round-off
  }
  EXPECT_GT(changed, compared * 9 / 10) << "most pixels should be smoothed";
  EXPECT_LE(off, compared / 1000) << "worst " << worst;
  EXPECT_LT(worst, 0.05);
}

TEST(Decode, SmoothingMatchesTheWindowDefinition) {
  const PatternPlan plan;
  SceneModel scene;
  scene.width = 200;
  scene.height = 48;
  // Curved (so the Richardson branch runs), with a depth step (the deviation gate), a masked
  // band and a masked hole (the plane fit), under noise.
  scene.coordinate = [](int u, int v) {
    return 2.37 + 3.4713 * u + 0.0917 * v + 0.0011 * (u - 100) * (u - 100) + (u >= 150 ? 0.8 : 0.0);
  };
  scene.noise_dn = 2.0;
  scene.gain = [](int u, int v) {
    if (u < 30) return 0.0;
    if (u >= 90 && u < 96 && v >= 20 && v < 25) return 0.0;
    return 60.0 + 0.5 * u;
  };
  DecodeOptions raw_options;
  raw_options.smoothing_radius = 0;
  const DecodedView raw = decode(plan, scene, raw_options);
  std::vector<std::vector<float>> expected;
  for (int quadratic_radius : {0, 4}) {
    SCOPED_TRACE("quadratic_radius " + std::to_string(quadratic_radius));
    DecodeOptions options;
    options.quadratic_radius = quadratic_radius;
    const DecodedView smoothed = decode(plan, scene, options);
    expected.push_back(reference_smoothing(raw, options.smoothing_max_deviation_px, quadratic_radius));
    expect_smoothing_matches_the_definition(raw, smoothed, expected.back());
  }
  std::size_t quadratic = 0;
  for (std::size_t i = 0; i < expected[0].size(); ++i) quadratic += expected[0][i] != expected[1][i];
  EXPECT_GT(quadratic, expected[0].size() / 2) << "the 9 x 9 quadratic should decide most pixels";
}

// A gently curved coordinate (a sphere seen face on) under noise: a window mean is off by the
// Laplacian times the window's second moment per axis (2 x 0.002 px x 2 for 5 x 5: 0.008 px,
// a few um of depth on the full rig; too little per pixel for the Richardson branch, which
// waits for curvature above the noise), where the quadratic window is unbiased at the same
// noise. The mean of the signed error over the interior shows it.
TEST(Decode, SmoothingIsUnbiasedOnACurvedSurface) {
  const PatternPlan plan;
  SceneModel scene;
  scene.width = 240;
  scene.height = 120;
  scene.coordinate = [](int u, int v) {
    return 40.0 + 3.3 * u + 0.2 * v + 0.002 * ((u - 120) * (u - 120) + (v - 60) * (v - 60));
  };
  scene.noise_dn = 2.0;
  DecodeOptions box_only;
  box_only.quadratic_radius = 0;
  DecodeOptions with_quadratic;
  with_quadratic.quadratic_radius = 4;
  DecodeOptions raw_options;
  raw_options.smoothing_radius = 0;
  const DecodedView raw = decode(plan, scene, raw_options);
  const DecodedView box = decode(plan, scene, box_only);
  const DecodedView quadratic = decode(plan, scene, with_quadratic);
  auto signed_mean = [&](const DecodedView& view) {
    double sum = 0;
    int n = 0;
    for (int v = 8; v < scene.height - 8; ++v)
      for (int u = 8; u < scene.width - 8; ++u) {
        const auto i = pixel(u, v, scene.width);
        if (view.mask[i] != DecodeMask::valid) continue;
        sum += view.coordinate[i] - scene.coordinate(u, v);
        ++n;
      }
    EXPECT_GT(n, (scene.width - 16) * (scene.height - 16) * 9 / 10);
    return sum / n;
  };
  const double raw_bias = signed_mean(raw), box_bias = signed_mean(box), quadratic_bias = signed_mean(quadratic);
  std::printf("mean signed error (px): raw %.5f, 5 x 5 mean %.5f, quadratic %.5f\n", raw_bias, box_bias,
              quadratic_bias);
  EXPECT_NEAR(raw_bias, 0.0, 0.0015);
  EXPECT_GT(box_bias, 0.005) << "the 5 x 5 mean's bias (what the quadratic removes)";
  EXPECT_LT(box_bias, 0.009);
  EXPECT_NEAR(quadratic_bias, 0.0, 0.0015);
  const Errors e_raw = errors(raw, scene, 8);
  const Errors e_quadratic = errors(quadratic, scene, 8);
  EXPECT_LT(e_quadratic.median_abs, 0.45 * e_raw.median_abs) << "as quiet as the 5 x 5 mean";
  for (int q : {1, 2, 7}) {
    DecodeOptions bad;
    bad.quadratic_radius = q;
    EXPECT_THROW(bad.check(), std::invalid_argument) << q;
  }
}

TEST(Decode, SmoothingReducesNoiseWithoutBiasAtMaskEdges) {
  const PatternPlan plan;
  SceneModel scene;
  scene.coordinate = ramp;
  scene.noise_dn = 2.0;
  scene.gamma = 2.2;
  scene.gain = [](int u, int) { return u < 100 ? 0.0 : 120.0; };  // a dark band: masked
  DecodeOptions raw_options;
  raw_options.smoothing_radius = 0;
  const DecodedView raw = decode(plan, scene, raw_options);
  const DecodedView smoothed = decode(plan, scene);
  const Errors e_raw = errors(raw, scene, 8);
  const Errors e_smoothed = errors(smoothed, scene, 8);
  EXPECT_EQ(e_raw.compared, e_smoothed.compared);
  EXPECT_LT(e_smoothed.median_abs, 0.45 * e_raw.median_abs);
  // Next to the masked band the window is one-sided; a plain mean would be off by the ramp's
  // slope (3.5 px per camera pixel) times the window's offset. The plane fit is unbiased.
  double signed_sum = 0;
  int n = 0;
  for (int v = 2; v < scene.height - 2; ++v)
    for (int u = 100; u < 102; ++u) {
      const auto i = pixel(u, v, scene.width);
      ASSERT_EQ(smoothed.mask[i], DecodeMask::valid);
      signed_sum += smoothed.coordinate[i] - scene.coordinate(u, v);
      ++n;
    }
  EXPECT_LT(std::abs(signed_sum / n), 0.02);
  DecodeOptions bad;
  bad.smoothing_radius = 3;
  EXPECT_THROW(bad.check(), std::invalid_argument);
}

}  // namespace
