// ScanReconstructor with an exposure bracket (docs/hdr.md): each projector-view arrives at every
// exposure, is decoded per exposure and merged per pixel before it is triangulated. On the
// virtual rig's shiny blade (small rig, one view rendered at the reference and at 1/8 of it):
// the bracket gives more points than the reference alone, the same points whichever order the
// exposures' frames arrive in and on one thread or two, a projector-view missing an exposure is
// merged from what came (and says so), and frames the bracket has no place for are refused.
#include <gtest/gtest.h>

#if __has_include("slrig/rig.hpp")
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <cstring>
#include <string>
#include <vector>

#include "slrig/rig.hpp"
#include "slscan/core/scan_reconstruction.hpp"

namespace {

using slproto::ProjectorSide;
using slscan::core::FrameInfo;
using slscan::core::ScanReconstructor;
using slscan::core::ScanResult;
using slscan::core::ViewProducts;

constexpr double kFractions[2] = {1.0, 0.125};

struct Frames {
  slproto::RigCalibration calibration;
  slproto::PatternPlan plan{slproto::PatternPlanConfig{}};
  double reference_us = 0;
  int width = 0, height = 0;
  // [exposure][projector][pattern]
  std::array<std::array<std::vector<std::vector<std::uint8_t>>, 2>, 2> frames;
};

const Frames& rendered() {
  static const Frames f = [] {
    auto scene = slrig::scene_preset("shiny_blade", slrig::RigSize::small);
    if (!scene) throw std::runtime_error(scene.error().message);
    Frames out;
    out.calibration = slrig::ground_truth_calibration(*scene);
    out.plan = slproto::PatternPlan(scene->pattern_plan);
    out.reference_us = scene->sensor.exposure_us;
    const slrig::ViewRenderer renderer(*scene, scene->view_angles_deg.at(0), 0);
    out.width = renderer.width();
    out.height = renderer.height();
    for (std::size_t e = 0; e < 2; ++e)
      for (std::size_t side = 0; side < 2; ++side)
        for (std::size_t p = 0; p < out.plan.size(); ++p) {
          std::vector<std::uint8_t> frame(renderer.frame_bytes());
          renderer.render(side == 0 ? ProjectorSide::left : ProjectorSide::right, out.plan, p, frame,
                          {.exposure_us = out.reference_us * kFractions[e]});
          out.frames[e][side].push_back(std::move(frame));
        }
    return out;
  }();
  return f;
}

struct Frame {
  int projector = 0;
  std::size_t exposure = 0, pattern = 0;
};

// As the board sends a bracket: each exposure's passes, projector by projector.
std::vector<Frame> board_order() {
  std::vector<Frame> order;
  for (std::size_t e = 0; e < 2; ++e)
    for (int side = 0; side < 2; ++side)
      for (std::size_t p = 0; p < rendered().plan.size(); ++p) order.push_back({side, e, p});
  return order;
}

// The short exposure first, patterns interleaved across everything.
std::vector<Frame> shuffled_order() {
  std::vector<Frame> order;
  for (std::size_t p = 0; p < rendered().plan.size(); ++p)
    for (std::size_t e : {1, 0})
      for (int side : {1, 0}) order.push_back({side, e, p});
  return order;
}

slscan::core::ReconstructionOptions options() {
  slscan::core::ReconstructionOptions o;
  o.register_views = false;
  o.select_best_views = false;
  o.build_mesh = false;
  return o;
}

FrameInfo info_of(const Frame& frame) {
  FrameInfo info;
  info.projector = frame.projector;
  info.pattern_index = frame.pattern;
  info.exposure_index = frame.exposure;
  info.bytes_per_pixel = 1;
  info.stride_bytes = static_cast<std::size_t>(rendered().width);
  return info;
}

void add(ScanReconstructor& r, const Frame& frame) {
  // An exposure index the test made up (beyond the two rendered) sends the first one's pixels.
  const auto& pixels =
      rendered()
          .frames[frame.exposure < 2 ? frame.exposure : 0][static_cast<std::size_t>(frame.projector)][frame.pattern];
  r.add_frame(info_of(frame), std::as_bytes(std::span(pixels)));
}

ScanResult reconstruct(const std::vector<Frame>& order, bool bracket) {
  const Frames& f = rendered();
  ScanReconstructor r(f.calibration, f.plan, f.width, f.height, options());
  if (bracket) r.set_exposure_bracket({f.reference_us, f.reference_us * kFractions[1]}, f.reference_us);
  for (const Frame& frame : order)
    if (bracket || frame.exposure == 0) add(r, frame);
  return r.finish();
}

bool same_points(const ScanResult& a, const ScanResult& b) {
  if (a.view_products.size() != b.view_products.size()) return false;
  for (std::size_t v = 0; v < a.view_products.size(); ++v) {
    const auto &pa = a.view_products[v].points.points, &pb = b.view_products[v].points.points;
    if (pa.size() != pb.size() || std::memcmp(pa.data(), pb.data(), pa.size() * sizeof(pa[0])) != 0) return false;
  }
  return true;
}

TEST(HdrReconstruction, TheBracketAddsWhatTheReferenceClipsAndReportsEachExposuresShare) {
  const ScanResult single = reconstruct(board_order(), false), hdr = reconstruct(board_order(), true);
  ASSERT_EQ(single.views.size(), 1u);
  ASSERT_EQ(hdr.views.size(), 1u);
  for (std::size_t side = 0; side < 2; ++side) {
    const auto &s = single.views[0].projectors[side], &h = hdr.views[0].projectors[side];
    EXPECT_TRUE(s.exposures.empty());
    ASSERT_EQ(h.exposures.size(), 2u);
    EXPECT_GT(s.decode.saturated, 1000u) << side;
    EXPECT_LT(h.decode.saturated, s.decode.saturated / 20) << side;
    EXPECT_EQ(h.exposures[0].decoded, s.decode.valid) << "the reference exposure decodes as it does alone";
    EXPECT_EQ(h.exposures[0].chosen + h.exposures[1].chosen, h.decode.valid);
    EXPECT_GT(h.exposures[1].chosen, s.decode.saturated * 9 / 10) << side;
    EXPECT_GT(h.triangulate.valid, s.triangulate.valid) << side;
    // The "which exposure" map (the view's exposure picture): each decoded pixel's member,
    // counting as the shares do; not-decoded elsewhere; none without a bracket.
    EXPECT_TRUE(single.view_products[0].exposure_member[side].empty());
    const std::vector<std::uint8_t>& member = hdr.view_products[0].exposure_member[side];
    ASSERT_EQ(member.size(), static_cast<std::size_t>(rendered().width) * static_cast<std::size_t>(rendered().height));
    std::array<std::size_t, 2> counted{};
    std::size_t not_decoded = 0;
    for (const std::uint8_t m : member) {
      if (m == ViewProducts::kNotDecoded)
        ++not_decoded;
      else if (m < 2)
        ++counted[m];
      else
        ADD_FAILURE() << "member " << int{m} << " beyond the bracket of 2";
    }
    EXPECT_EQ(counted[0], h.exposures[0].chosen) << side;
    EXPECT_EQ(counted[1], h.exposures[1].chosen) << side;
    EXPECT_EQ(not_decoded, member.size() - h.decode.valid) << side;
  }
  EXPECT_GT(hdr.view_products[0].points.size(), single.view_products[0].points.size() * 11 / 10);
}

TEST(HdrReconstruction, TheOrderOfArrivalAndTheThreadCountChangeNoPoint) {
  const ScanResult reference = reconstruct(board_order(), true);
  EXPECT_TRUE(same_points(reference, reconstruct(shuffled_order(), true)));
  tbb::task_arena one_thread(1);
  ScanResult single_thread;
  one_thread.execute([&] { single_thread = reconstruct(shuffled_order(), true); });
  EXPECT_TRUE(same_points(reference, single_thread));
}

TEST(HdrReconstruction, AProjectorViewMissingAnExposureIsMergedFromWhatCameAndSaysSo) {
  const Frames& f = rendered();
  ScanReconstructor r(f.calibration, f.plan, f.width, f.height, options());
  r.set_exposure_bracket({f.reference_us, f.reference_us * kFractions[1]}, f.reference_us);
  for (const Frame& frame : board_order())
    if (!(frame.projector == 1 && frame.exposure == 1)) add(r, frame);  // the right one's short pass lost
  const ScanResult result = r.finish();
  ASSERT_EQ(result.views.size(), 1u);
  const auto &left = result.views[0].projectors[0], &right = result.views[0].projectors[1];
  EXPECT_TRUE(left.present);
  EXPECT_TRUE(right.present);
  ASSERT_EQ(right.exposures.size(), 2u);
  EXPECT_EQ(right.exposures[1].chosen, 0u);
  EXPECT_EQ(right.exposures[0].chosen, right.decode.valid);
  const auto finding = std::find_if(right.checks.findings.begin(), right.checks.findings.end(),
                                    [](const auto& x) { return x.check == "exposures"; });
  ASSERT_NE(finding, right.checks.findings.end());
  EXPECT_NE(finding->cause.find("only 1 of the bracket's 2 exposures arrived (missing or incomplete: 1041.62 us)"),
            std::string::npos)
      << finding->cause;
  EXPECT_TRUE(std::none_of(left.checks.findings.begin(), left.checks.findings.end(),
                           [](const auto& x) { return x.check == "exposures"; }));
  EXPECT_GT(right.triangulate.valid, 1000u);
}

TEST(HdrReconstruction, FramesTheBracketHasNoPlaceForAreRefused) {
  const Frames& f = rendered();
  {
    ScanReconstructor r(f.calibration, f.plan, f.width, f.height, options());
    try {
      add(r, {0, 1, 0});
      FAIL() << "an exposure index without a bracket must be refused";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("exposure index 1 but the scan has no exposure bracket"), std::string::npos)
          << e.what();
    }
    add(r, {0, 0, 0});
    EXPECT_THROW(r.set_exposure_bracket({1000, 500}, 1000), std::invalid_argument);
  }
  ScanReconstructor r(f.calibration, f.plan, f.width, f.height, options());
  EXPECT_THROW(r.set_exposure_bracket({}, 1000), std::invalid_argument);
  EXPECT_THROW(r.set_exposure_bracket({1000, 0}, 1000), std::invalid_argument);
  r.set_exposure_bracket({f.reference_us, f.reference_us * kFractions[1]}, f.reference_us);
  try {
    add(r, {0, 2, 0});
    FAIL() << "an exposure index beyond the bracket must be refused";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("exposure index 2 is beyond the bracket of 2"), std::string::npos) << e.what();
  }
  for (std::size_t p = 0; p < f.plan.size(); ++p) add(r, {0, 1, p});
  try {
    add(r, {0, 1, 0});
    FAIL() << "a complete exposure given again must be refused";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("already complete at this exposure"), std::string::npos) << e.what();
  }
  add(r, {0, 0, 0});  // the other exposure of the same projector-view still takes frames
}

}  // namespace

#else
TEST(HdrReconstruction, NeedsTheVirtualRig) { GTEST_SKIP() << "built without slrig"; }
#endif
