#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "slproto/pattern_plan.hpp"

namespace slproto {
namespace {

TEST(PatternPlan, DefaultIsThePapers19Frames) {
  PatternPlan plan;
  ASSERT_EQ(plan.size(), 19u);
  EXPECT_EQ(plan.config().gray_bits(), 8);  // ceil(1140 / 8) = 143 periods
  EXPECT_EQ(plan.config().period_count(), 143);
  EXPECT_EQ(plan[0].kind, PatternKind::white);
  EXPECT_EQ(plan[1].kind, PatternKind::black);
  for (int i = 0; i < 8; ++i) EXPECT_EQ(plan[2 + i].kind, PatternKind::gray_bit);
  EXPECT_EQ(plan[10].kind, PatternKind::complementary_bit);
  for (int n = 0; n < 8; ++n) {
    EXPECT_EQ(plan[11 + n].kind, PatternKind::phase_step);
    EXPECT_EQ(plan[11 + n].index, n);
  }
  EXPECT_EQ(plan.index_of(PatternKind::phase_step, 3), 14);
  EXPECT_EQ(plan.index_of(PatternKind::gray_bit, 8), -1);
}

TEST(PatternPlan, GrayBitsEncodeTheFringeOrderAtEveryColumn) {
  PatternPlan plan;
  const int bits = plan.config().gray_bits();
  for (int x = 0; x < 1140; ++x) {
    std::uint32_t gray = 0;
    for (int b = 0; b < bits; ++b) gray = (gray << 1) | static_cast<std::uint32_t>(plan.value(2 + b, x) > 0.5f);
    EXPECT_EQ(gray_to_binary(gray), static_cast<std::uint32_t>(x / 8)) << "column " << x;
  }
}

TEST(PatternPlan, ComplementaryBitGivesHalfShiftedOrder) {
  PatternPlan plan;
  const int bits = plan.config().gray_bits();
  for (int x = 0; x < 1140; ++x) {
    std::uint32_t gray = 0;
    for (int b = 0; b < bits; ++b) gray = (gray << 1) | static_cast<std::uint32_t>(plan.value(2 + b, x) > 0.5f);
    gray = (gray << 1) | static_cast<std::uint32_t>(plan.value(10, x) > 0.5f);
    const std::uint32_t half_index = gray_to_binary(gray);
    EXPECT_EQ(half_index, static_cast<std::uint32_t>(2 * x / 8)) << "column " << x;
    EXPECT_EQ((half_index + 1) / 2, static_cast<std::uint32_t>((x + 4) / 8)) << "column " << x;
  }
}

TEST(PatternPlan, PhaseStepsFollowTheConvention) {
  PatternPlan plan;
  // Column 100 centre: phi = 2 pi * 100 / 8; frame n shows 0.5 + 0.5 cos(phi + 2 pi n / 8).
  for (int n = 0; n < 8; ++n) {
    const double expected = 0.5 + 0.5 * std::cos(2 * std::numbers::pi * 100.0 / 8 + 2 * std::numbers::pi * n / 8);
    EXPECT_NEAR(plan.value(11 + n, 100.0), expected, 1e-6);
  }
  // Decoding the N-step formula recovers phi at a fractional coordinate.
  const double x = 37.3;
  double s = 0, c = 0;
  for (int n = 0; n < 8; ++n) {
    const double delta = 2 * std::numbers::pi * n / 8;
    s += plan.value(11 + n, x) * std::sin(delta);
    c += plan.value(11 + n, x) * std::cos(delta);
  }
  double phi = std::atan2(-s, c);
  if (phi < 0) phi += 2 * std::numbers::pi;
  EXPECT_NEAR(phi, std::fmod(2 * std::numbers::pi * x / 8, 2 * std::numbers::pi), 1e-5);
}

TEST(PatternPlan, RenderFillsColumnsOrRows) {
  PatternPlanConfig config;
  config.projector_width = 64;
  config.projector_height = 32;
  config.axis = CodingAxis::rows;
  PatternPlan plan(config);
  std::vector<std::uint8_t> image(64 * 32);
  plan.render(static_cast<std::size_t>(plan.index_of(PatternKind::gray_bit, 0)), image);
  // Rows code: every row is constant, and the MSB switches at row 16 (orders 0..1 vs 2..3).
  for (int y = 0; y < 32; ++y)
    for (int x = 1; x < 64; ++x) ASSERT_EQ(image[y * 64 + x], image[y * 64]);
  EXPECT_EQ(image[15 * 64], 0);
  EXPECT_EQ(image[16 * 64], 255);
}

TEST(PatternPlan, RejectsImpossibleConfigurations) {
  PatternPlanConfig config;
  config.period_px = 7;  // odd period cannot carry the half-period bit
  auto plan = PatternPlan::make(config);
  ASSERT_FALSE(plan.ok());
  EXPECT_NE(plan.error().message.find("period_px"), std::string::npos);
  config.period_px = 8;
  config.phase_steps = 2;
  EXPECT_FALSE(PatternPlan::make(config).ok());
  config.phase_steps = 8;
  config.projector_width = 0;
  EXPECT_FALSE(PatternPlan::make(config).ok());
}

TEST(PatternPlan, InverseGrayFramesFollowTheirBits) {
  PatternPlanConfig config;
  config.inverse_gray = true;
  config.with_white_black = false;
  PatternPlan plan(config);
  // 8 Gray bits and the complementary bit, each followed by its inverse, then 8 phase steps.
  ASSERT_EQ(plan.size(), 26u);
  EXPECT_EQ(config.code_frames(), 18);
  for (int b = 0; b < 8; ++b) {
    EXPECT_EQ(plan[static_cast<std::size_t>(2 * b)], (Pattern{PatternKind::gray_bit, static_cast<std::uint16_t>(b)}));
    EXPECT_EQ(plan[static_cast<std::size_t>(2 * b + 1)],
              (Pattern{PatternKind::gray_bit_inverse, static_cast<std::uint16_t>(b)}));
  }
  EXPECT_EQ(plan[16].kind, PatternKind::complementary_bit);
  EXPECT_EQ(plan[17].kind, PatternKind::complementary_bit_inverse);
  EXPECT_EQ(plan[18].kind, PatternKind::phase_step);
  EXPECT_STREQ(pattern_kind_name(plan[1].kind), "gray_bit_inverse");
  // Each inverse is 1 - its bit at every column (what the projector and the rig render).
  for (int x = 0; x < 1140; ++x)
    for (std::size_t i = 0; i < 18; i += 2) ASSERT_EQ(plan.value(i + 1, x), 1.0f - plan.value(i, x)) << x;
  std::vector<std::uint8_t> bit(1140 * 912), inverse(1140 * 912);
  plan.render(0, bit);
  plan.render(1, inverse);
  for (std::size_t i = 0; i < bit.size(); ++i) ASSERT_EQ(bit[i] + inverse[i], 255) << i;
}

TEST(PatternPlan, SlstudioConventionNeedsAGrayCodeWithPowerOfTwoSteps) {
  PatternPlanConfig config;
  config.gray_low_bits = GrayLowBits::slstudio_parity;
  auto plan = PatternPlan::make(config);  // the default plan has phase steps
  ASSERT_FALSE(plan.ok());
  EXPECT_NE(plan.error().message.find("applies to a Gray code without phase steps, got phase_steps 8"),
            std::string::npos)
      << plan.error().message;
  config.phase_steps = 0;
  config.complementary_bit = false;
  config.period_px = 6;
  plan = PatternPlan::make(config);
  ASSERT_FALSE(plan.ok());
  EXPECT_NE(plan.error().message.find("a Gray step of 2^s pixels"), std::string::npos) << plan.error().message;
  config.period_px = 8;
  EXPECT_TRUE(PatternPlan::make(config).ok());
  config.complementary_bit = true;  // step 4
  EXPECT_TRUE(PatternPlan::make(config).ok());
  config.period_px = 12;  // step 6
  EXPECT_FALSE(PatternPlan::make(config).ok());
  EXPECT_STREQ(gray_low_bits_name(GrayLowBits::slstudio_parity), "slstudio_parity");
}

TEST(GrayCode, RoundTrips) {
  for (std::uint32_t n = 0; n < 70000; ++n) ASSERT_EQ(gray_to_binary(binary_to_gray(n)), n);
}

}  // namespace
}  // namespace slproto
