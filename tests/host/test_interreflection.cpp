// Light that bounces inside a concave part (issue 21, item 5; docs/hdr.md, "Interreflection"):
// the virtual rig's teacup with its one-bounce term on, one projector-view decoded with the
// default plan (fringe period 8 projector pixels) and with a period of 4, each decoded
// coordinate against the rig's truth. The bounce hardly touches the fringe orders (the Gray
// code's coarse stripes are read against the white/black threshold, and the complementary bit
// with the phase corrects an order misread at its edge), but it shifts the phase: light from
// elsewhere on the cup arrives with its own phase, which averages out the better the shorter
// the period. So a short period is the plan option that resists it.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include "slrig/rig.hpp"
#include "slscan/core/decode.hpp"

namespace {

using slscan::core::DecodedView;
using slscan::core::DecodeMask;
using slscan::core::ProjectorViewDecoder;

struct Figures {
  std::size_t lit = 0;          // pixels the left projector lights, on the cup or the platform
  std::size_t decoded = 0;      // of those, decoded
  std::size_t wrong_order = 0;  // decoded more than half a period from the truth
  double rms_px = 0;            // RMS of the rest against the truth, projector pixels
  double wrong_share() const { return decoded > 0 ? static_cast<double>(wrong_order) / decoded : 1.0; }
  double decoded_share() const { return lit > 0 ? static_cast<double>(decoded) / lit : 0.0; }
};

slrig::Scene teacup(bool interreflection) {
  slrig::Scene scene = slrig::scene_preset("teacup", slrig::RigSize::small).value();
  scene.interreflection = interreflection;
  scene.interreflection_samples = 16;  // 4 x 4 strata: the bounce's mean, a little noisier
  return scene;
}

Figures decode_view(const slrig::ViewRenderer& renderer, const slrig::Scene& scene, int period_px) {
  slproto::PatternPlanConfig config = scene.pattern_plan;
  config.period_px = period_px;
  const slproto::PatternPlan plan(config);
  ProjectorViewDecoder decoder(plan, renderer.width(), renderer.height());
  std::vector<std::uint8_t> frame(renderer.frame_bytes());
  for (std::size_t k = 0; k < plan.size(); ++k) {
    renderer.render(slproto::ProjectorSide::left, plan, k, frame);
    decoder.add_frame(k, frame.data(), static_cast<std::size_t>(renderer.width()));
  }
  const DecodedView view = decoder.finish();
  const slrig::ViewGroundTruth& truth = renderer.ground_truth();
  const std::vector<float>& coordinate = truth.projector_coord[0];
  Figures f;
  double sum = 0;
  std::size_t n = 0;
  for (std::size_t i = 0; i < coordinate.size(); ++i) {
    // The cup (2) and the platform (0) it stands on; not the wall behind.
    if (!std::isfinite(coordinate[i]) || truth.lit[0][i] == 0 || truth.object_id[i] < 0 || truth.object_id[i] == 1)
      continue;
    ++f.lit;
    if (view.mask[i] != DecodeMask::valid) continue;
    ++f.decoded;
    const double d = view.coordinate[i] - coordinate[i];
    if (std::abs(d) > 0.5 * period_px) {
      ++f.wrong_order;
      continue;
    }
    sum += d * d;
    ++n;
  }
  f.rms_px = n > 0 ? std::sqrt(sum / static_cast<double>(n)) : 0.0;
  return f;
}

void print(const char* name, const Figures& f) {
  std::printf("%-28s lit %zu, decoded %.2f %%, wrong order %zu (%.3f %% of decoded), RMS %.3f px\n", name, f.lit,
              100.0 * f.decoded_share(), f.wrong_order, 100.0 * f.wrong_share(), f.rms_px);
}

// [light][period]: direct / one bounce, period 8 / 4.
class Interreflection : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    const slrig::Scene direct = teacup(false);
    const slrig::Scene bounce = teacup(true);
    const slrig::ViewRenderer direct_view(direct, direct.view_angles_deg.at(0), 0);
    const slrig::ViewRenderer bounce_view(bounce, bounce.view_angles_deg.at(0), 0);
    figures_[0][0] = decode_view(direct_view, direct, 8);
    figures_[0][1] = decode_view(direct_view, direct, 4);
    figures_[1][0] = decode_view(bounce_view, bounce, 8);
    figures_[1][1] = decode_view(bounce_view, bounce, 4);
    print("direct light, period 8 px", figures_[0][0]);
    print("direct light, period 4 px", figures_[0][1]);
    print("one bounce, period 8 px", figures_[1][0]);
    print("one bounce, period 4 px", figures_[1][1]);
  }
  static Figures figures_[2][2];
};
Figures Interreflection::figures_[2][2];

// Measured (small rig, view 0, left projector): direct 0.026 / 0.024 px RMS for periods 8 / 4,
// no order wrong; one bounce 0.049 / 0.028 px, 22 / 12 of ~103,000 pixels a period off.
TEST_F(Interreflection, TheBounceShiftsThePhaseAndBarelyTouchesTheOrders) {
  const Figures& direct = figures_[0][0];
  const Figures& bounce = figures_[1][0];
  ASSERT_GT(direct.lit, 50000u);
  EXPECT_EQ(direct.lit, bounce.lit) << "the bounce adds light, not geometry";
  EXPECT_GT(bounce.rms_px, 1.5 * direct.rms_px) << "the bounce should move the phase measurably";
  EXPECT_LT(direct.wrong_share(), 1e-4);
  EXPECT_LT(bounce.wrong_share(), 1e-3);
  EXPECT_NEAR(bounce.decoded_share(), direct.decoded_share(), 0.005);
}

TEST_F(Interreflection, AShorterFringePeriodResistsIt) {
  const Figures& long_period = figures_[1][0];
  const Figures& short_period = figures_[1][1];
  EXPECT_LT(short_period.rms_px, 0.7 * long_period.rms_px);
  // Close to what the short period measures without the bounce.
  EXPECT_LT(short_period.rms_px, 1.3 * figures_[0][1].rms_px);
  EXPECT_LE(short_period.wrong_share(), long_period.wrong_share());
  EXPECT_GT(short_period.decoded_share(), long_period.decoded_share() - 0.01);
}

}  // namespace
