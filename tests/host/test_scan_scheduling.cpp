// ScanReconstructor's scheduling (issue 17, fault 1; docs/architecture.md, "Threads"): a thread
// never blocks on work that is only queued. With one thread (a TBB arena of concurrency 1, as
// on one CPU) add_frame used to wait for decoders held by queued projector-views that only that
// thread could run; and input interleaving more projector-views than the decoders' bound
// waited on any number of threads. Both must complete, with the same points as the two-thread
// run in order. Small rig, sphere preset, one rendered view fed as several views.
#include <gtest/gtest.h>

#if __has_include("slrig/rig.hpp")
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdlib>
#include <future>
#include <string>
#include <thread>
#include <vector>

#include "slrig/rig.hpp"
#include "slscan/core/scan_reconstruction.hpp"

namespace {

using slproto::ProjectorSide;

struct Frames {
  slproto::RigCalibration calibration;
  slproto::PatternPlan plan{slproto::PatternPlanConfig{}};
  int width = 0, height = 0;
  std::array<std::vector<std::vector<std::uint8_t>>, 2> by_side;    // [projector][pattern]
  std::array<std::vector<std::vector<std::uint8_t>>, 2> half_dark;  // the same, its top half black
};

const Frames& frames() {
  static const Frames rendered = [] {
    auto scene = slrig::scene_preset("sphere", slrig::RigSize::small);
    if (!scene) throw std::runtime_error(scene.error().message);
    Frames f;
    f.calibration = slrig::ground_truth_calibration(*scene);
    f.plan = slproto::PatternPlan(scene->pattern_plan);
    const slrig::ViewRenderer renderer(*scene, scene->view_angles_deg.at(0), 0);
    f.width = renderer.width();
    f.height = renderer.height();
    for (std::size_t side = 0; side < 2; ++side)
      for (std::size_t p = 0; p < f.plan.size(); ++p) {
        std::vector<std::uint8_t> frame(renderer.frame_bytes());
        renderer.render(side == 0 ? ProjectorSide::left : ProjectorSide::right, p, frame);
        std::vector<std::uint8_t> half = frame;
        std::fill_n(half.begin(), half.size() / 2, std::uint8_t{0});
        f.by_side[side].push_back(std::move(frame));
        f.half_dark[side].push_back(std::move(half));
      }
    return f;
  }();
  return rendered;
}

struct Frame {
  int view = 0, projector = 0;
  std::size_t pattern = 0;
  bool half_dark = false;  // from Frames::half_dark
};

// Each view's projector-views one after the other, as the board sends them.
std::vector<Frame> in_order(int views) {
  std::vector<Frame> order;
  for (int v = 0; v < views; ++v)
    for (int side = 0; side < 2; ++side)
      for (std::size_t p = 0; p < frames().plan.size(); ++p) order.push_back({v, side, p});
  return order;
}

// Pattern by pattern across every projector-view: all of them receive at once.
std::vector<Frame> interleaved(int views) {
  std::vector<Frame> order;
  for (std::size_t p = 0; p < frames().plan.size(); ++p)
    for (int v = 0; v < views; ++v)
      for (int side = 0; side < 2; ++side) order.push_back({v, side, p});
  return order;
}

std::vector<std::vector<Eigen::Vector3f>> reconstruct(const std::vector<Frame>& order, int max_pending,
                                                      const std::atomic<bool>* stop = nullptr) {
  const Frames& f = frames();
  slscan::core::ReconstructionOptions options;
  options.register_views = false;
  options.select_best_views = false;
  options.build_mesh = false;
  options.max_pending_projector_views = max_pending;
  slscan::core::ScanReconstructor reconstructor(f.calibration, f.plan, f.width, f.height, options);
  for (const Frame& frame : order) {
    slscan::core::FrameInfo info;
    info.view_index = frame.view;
    info.commanded_angle_deg = info.reported_angle_deg = 0;
    info.projector = frame.projector;
    info.pattern_index = frame.pattern;
    info.bytes_per_pixel = 1;
    info.stride_bytes = static_cast<std::size_t>(f.width);
    const auto& source = frame.half_dark ? f.half_dark : f.by_side;
    reconstructor.add_frame(info,
                            std::as_bytes(std::span(source[static_cast<std::size_t>(frame.projector)][frame.pattern])));
  }
  const slscan::core::ScanResult result = reconstructor.finish(stop);
  std::vector<std::vector<Eigen::Vector3f>> points;
  for (const auto& products : result.view_products) points.push_back(products.points.points);
  return points;
}

// Runs `work` with a deadline: a deadlock fails the test (and ends the binary, whose thread
// cannot be taken back) instead of holding CI until ctest's timeout.
template <class F>
auto within_deadline(F work) {
  auto task = std::packaged_task<decltype(work())()>(std::move(work));
  auto result = task.get_future();
  std::thread(std::move(task)).detach();
  if (result.wait_for(std::chrono::seconds(240)) != std::future_status::ready) {
    ADD_FAILURE() << "the reconstruction did not finish: deadlocked";
    std::fflush(nullptr);
    std::_Exit(1);
  }
  return result.get();
}

TEST(ScanScheduling, OneThreadCompletesMoreProjectorViewsThanDecodersLikeTwo) {
  const auto order = in_order(4);  // 8 projector-views, 3 decoders
  const auto one = within_deadline([&] {
    tbb::task_arena single(1);
    return single.execute([&] { return reconstruct(order, 3); });
  });
  const auto two = within_deadline([&] {
    tbb::task_arena pair(2);
    return pair.execute([&] { return reconstruct(order, 3); });
  });
  ASSERT_EQ(one.size(), 4u);
  for (const auto& view : one) EXPECT_GT(view.size(), 1000u);
  EXPECT_TRUE(one == two) << "one thread and two give different points";
}

TEST(ScanScheduling, InterleavedProjectorViewsBeyondTheBoundComplete) {
  const auto reference = within_deadline([] { return reconstruct(in_order(2), 8); });
  for (const int threads : {1, 2}) {
    const auto points = within_deadline([&] {
      tbb::task_arena arena(threads);
      return arena.execute([&] { return reconstruct(interleaved(2), 1); });  // 4 receiving at once, 1 decoder
    });
    EXPECT_TRUE(points == reference) << threads << " thread(s)";
  }
}

// A view's grids, once it is fused, are passed to the next view's triangulation and fusion
// (spare_grids in scan_reconstruction.cpp): a view reconstructed after another gives the points
// it gives alone, with nothing of the first left in its grids: the second view is the first with
// the top half of its frames black, where the first view's points would show. One decoder, so
// that the first view is fused before the second is triangulated.
TEST(ScanScheduling, AViewAfterAnotherGivesThePointsItGivesAlone) {
  std::vector<Frame> alone = in_order(1);
  for (Frame& frame : alone) frame.half_dark = true;
  std::vector<Frame> after = in_order(1);
  for (Frame frame : alone) {
    frame.view = 1;
    after.push_back(frame);
  }
  const auto single = within_deadline([&] { return reconstruct(alone, 1); });
  const auto both = within_deadline([&] { return reconstruct(after, 1); });
  ASSERT_EQ(single.size(), 1u);
  ASSERT_EQ(both.size(), 2u);
  EXPECT_GT(single[0].size(), 1000u);
  EXPECT_LT(single[0].size() + 100, both[0].size()) << "half of each frame dark: fewer points";
  EXPECT_TRUE(both[1] == single[0]) << both[1].size() << " points after the first view, " << single[0].size()
                                    << " alone";
}

// Ctrl-C after the last frame (issue 17): finish() honours the stop flag at its next stage
// boundary, names the stage, and the reconstructor is torn down with its queued work dropped.
TEST(ScanScheduling, FinishStopsAtAStageBoundaryWhenAsked) {
  const std::atomic<bool> stop{true};
  for (const int threads : {1, 2}) {
    const std::string stage = within_deadline([&] {
      tbb::task_arena arena(threads);
      return arena.execute([&] {
        try {
          reconstruct(in_order(2), 8, &stop);
        } catch (const slscan::core::ReconstructionInterrupted& e) {
          return e.stage();
        }
        return std::string("(not interrupted)");
      });
    });
    EXPECT_EQ(stage, "wait_for_views") << threads << " thread(s)";
  }
}

}  // namespace
#else
TEST(ScanScheduling, NeedsTheVirtualRig) { GTEST_SKIP() << "built without slrig"; }
#endif
