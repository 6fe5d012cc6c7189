// Decode and triangulation run the same C++ compiled for each SIMD target Highway knows
// (x86: SSE2 (EMU128), SSSE3, SSE4, AVX2, AVX-512; Arm: NEON, SVE) and picked at run time.
// Every target this CPU runs must give the same bits: the outputs of a scan must not depend on
// the machine that reprocesses it. Each plan shape takes its own branch of the decoder (phase
// with the complementary bit, phase alone, inverse Gray frames, Gray code alone), at 8 and
// 12 bits, on a virtual-rig view (small rig) with shadows, saturation and both coding axes' code.
#include <gtest/gtest.h>

#if __has_include("slrig/rig.hpp")
#include <hwy/targets.h>

#include <bit>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "slrig/rig.hpp"
#include "slscan/core/decode.hpp"
#include "slscan/core/triangulate.hpp"

namespace {

using slproto::PatternPlanConfig;
using slproto::ProjectorSide;

struct Outputs {
  slscan::core::DecodedView decoded;
  slscan::core::OrganizedCloud cloud;
};

template <class T>
bool same_bits(const std::vector<T>& a, const std::vector<T>& b) {
  return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(T)) == 0);
}

// The first index where two float buffers differ in their bits, for the failure message.
std::string first_difference(const std::vector<float>& a, const std::vector<float>& b) {
  for (std::size_t i = 0; i < a.size() && i < b.size(); ++i)
    if (std::bit_cast<std::uint32_t>(a[i]) != std::bit_cast<std::uint32_t>(b[i]))
      return "pixel " + std::to_string(i) + ": " + std::to_string(a[i]) + " vs " + std::to_string(b[i]);
  return "sizes " + std::to_string(a.size()) + " vs " + std::to_string(b.size());
}

class SimdDispatch : public ::testing::Test {
 protected:
  void TearDown() override { hwy::SetSupportedTargetsForTest(0); }  // back to the CPU's own
};

void check_plan(const PatternPlanConfig& config, int bit_depth) {
  auto scene = slrig::scene_preset("teacup", slrig::RigSize::small);
  ASSERT_TRUE(scene) << scene.error().message;
  scene->pattern_plan = config;
  const auto calibration = slrig::ground_truth_calibration(*scene);
  slrig::ViewRenderer renderer(*scene, scene->view_angles_deg.at(0), 0);
  const int width = renderer.width(), height = renderer.height();
  const slproto::PatternPlan plan(calibration.pattern_plan);
  // The rig's 8-bit frames, or the same scaled to 12 bits for the 16-bit path.
  std::vector<std::vector<std::uint8_t>> frames(plan.size());
  std::vector<std::vector<std::uint16_t>> wide(plan.size());
  for (std::size_t p = 0; p < plan.size(); ++p) {
    frames[p].resize(renderer.frame_bytes());
    renderer.render(ProjectorSide::left, p, frames[p]);
    wide[p].assign(frames[p].begin(), frames[p].end());
    for (auto& v : wide[p]) v = static_cast<std::uint16_t>(v * 16 + (v & 15));
  }
  slscan::core::DecodeOptions options;
  options.bit_depth = bit_depth;
  const auto rays =
      std::make_shared<const slscan::core::CameraRayTable>(slscan::core::CameraRayTable::build(calibration.camera));
  const slscan::core::ProjectorTriangulator triangulator(rays, calibration.projector(ProjectorSide::left), config.axis);
  auto run = [&] {
    Outputs out;
    slscan::core::ProjectorViewDecoder decoder(plan, width, height, options);
    for (std::size_t p = 0; p < plan.size(); ++p) {
      if (bit_depth > 8)
        decoder.add_frame(p, wide[p].data(), static_cast<std::size_t>(width));
      else
        decoder.add_frame(p, frames[p].data(), static_cast<std::size_t>(width));
    }
    out.decoded = decoder.finish();
    triangulator.triangulate(out.decoded, out.cloud);
    return out;
  };

  const std::vector<std::int64_t> targets = hwy::SupportedAndGeneratedTargets();
  ASSERT_FALSE(targets.empty());
  if (targets.size() < 2)
    GTEST_SKIP() << "only " << hwy::TargetName(targets.front())
                 << " is compiled and supported here (a -march=native build?): nothing to compare";
  std::string names;
  for (const std::int64_t target : targets) names += std::string(names.empty() ? "" : ", ") + hwy::TargetName(target);
  std::printf("targets compared: %s\n", names.c_str());
  hwy::SetSupportedTargetsForTest(targets.front());
  const Outputs reference = run();
  const auto& d0 = reference.decoded;
  // A view worth comparing: most pixels decode, and some of every kind of mask occur.
  ASSERT_GT(d0.counts.valid, static_cast<std::size_t>(width * height) / 4);
  ASSERT_GT(reference.cloud.count_valid(), d0.counts.valid / 2);
  ASSERT_GT(d0.counts.low_contrast + d0.counts.low_modulation, 0u);
  for (std::size_t k = 1; k < targets.size(); ++k) {
    SCOPED_TRACE(std::string(hwy::TargetName(targets[k])) + " against " + hwy::TargetName(targets.front()));
    hwy::SetSupportedTargetsForTest(targets[k]);
    const Outputs other = run();
    const auto& d = other.decoded;
    EXPECT_TRUE(same_bits(d.coordinate, d0.coordinate)) << first_difference(d.coordinate, d0.coordinate);
    EXPECT_TRUE(same_bits(d.quality, d0.quality)) << first_difference(d.quality, d0.quality);
    EXPECT_TRUE(same_bits(d.intensity, d0.intensity)) << first_difference(d.intensity, d0.intensity);
    EXPECT_TRUE(same_bits(d.mask, d0.mask));
    EXPECT_EQ(d.counts.valid, d0.counts.valid);
    EXPECT_EQ(d.counts.clipped.gray, d0.counts.clipped.gray);
    EXPECT_EQ(d.counts.clipped.phase, d0.counts.clipped.phase);
    EXPECT_TRUE(same_bits(other.cloud.points, reference.cloud.points));
    EXPECT_TRUE(same_bits(other.cloud.quality, reference.cloud.quality));
    EXPECT_TRUE(same_bits(other.cloud.valid, reference.cloud.valid));
    EXPECT_TRUE(same_bits(other.cloud.intensity, reference.cloud.intensity));
  }
}

PatternPlanConfig plan(bool white_black, bool inverse, int phase_steps, bool complementary) {
  PatternPlanConfig c;
  c.with_white_black = white_black;
  c.inverse_gray = inverse;
  c.phase_steps = phase_steps;
  c.complementary_bit = complementary;
  return c;
}

TEST_F(SimdDispatch, PhaseWithComplementaryBitEveryTargetSameBits) { check_plan(plan(true, false, 4, true), 8); }

TEST_F(SimdDispatch, TwelveBitFramesEveryTargetSameBits) { check_plan(plan(true, false, 4, true), 12); }

TEST_F(SimdDispatch, PhaseAloneEveryTargetSameBits) { check_plan(plan(false, false, 4, false), 8); }

TEST_F(SimdDispatch, InverseGrayEveryTargetSameBits) { check_plan(plan(false, true, 0, true), 8); }

TEST_F(SimdDispatch, GrayWithWhiteBlackEveryTargetSameBits) { check_plan(plan(true, false, 0, false), 8); }

}  // namespace

#else
TEST(SimdDispatch, NeedsTheVirtualRig) { GTEST_SKIP() << "built without the virtual rig (slrig)"; }
#endif
