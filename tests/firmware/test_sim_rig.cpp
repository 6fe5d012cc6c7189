// The sim backend on its own: virtual DLPs obey their trigger lines and acknowledge on
// TRIG_OUT_1, the virtual camera exposes on the projectors' TRIG_OUT_1 and returns exactly
// what slrig renders for the lit pattern, the bus records every edge, faults behave.
#include <gtest/gtest.h>

#include <chrono>
#include <thread>

#include "slscand/hal/backends.hpp"
#include "slscand/hal/sim/sim_rig.hpp"

using namespace slscand;
using namespace slscand::hal;

namespace {

BoardConfig sim_board() {
  auto board = load_board(std::string(SLSCAN_SOURCE_DIR) + "/boards/sim.toml");
  EXPECT_TRUE(board.ok());
  board->frame_timeout_ms = 20000;  // the renderer's speed (ASan, a loaded machine) is not the model
  return *board;
}

}  // namespace

TEST(SimRig, CameraSeesTheLitPatternOfTheTriggeredProjector) {
  const BoardConfig board = sim_board();
  auto devices = open_board_devices(board);
  ASSERT_TRUE(devices.ok()) << devices.error().message;
  ASSERT_TRUE(devices->sim_rig);
  Camera& camera = *devices->camera;
  ASSERT_TRUE(camera.start().ok());
  DlpProjector& right = *devices->projectors[1];
  ASSERT_TRUE(right.start().ok());

  const slrig::ViewRenderer reference(devices->sim_rig->scene(), 0.0, 0);
  std::vector<std::uint8_t> expected(reference.frame_bytes());
  for (std::size_t pattern = 0; pattern < 3; ++pattern) {
    auto trigger = right.advance();
    ASSERT_TRUE(trigger.ok());
    auto shown = right.wait_exposure_start(kSecond);
    ASSERT_TRUE(shown.ok()) << shown.error().message;
    EXPECT_GE(shown->timestamp_ns, *trigger);
    EXPECT_EQ(shown->offset, board.projectors[1].trig_out_1);
    auto frame = camera.wait_frame(20 * kSecond);
    ASSERT_TRUE(frame.ok()) << frame.error().message;
    EXPECT_GE(frame->exposure_start_ns, shown->timestamp_ns);
    EXPECT_EQ(frame->exposure_end_ns - frame->exposure_start_ns,
              static_cast<Nanos>(board.pattern_exposure_us * kMicro));
    EXPECT_GE(frame->dequeued_ns, frame->exposure_end_ns);
    reference.render(slproto::ProjectorSide::right, pattern, expected);
    ASSERT_EQ(frame->pixels.size(), expected.size());
    EXPECT_TRUE(frame->pixels == expected) << "pattern " << pattern << " does not match the rig's render";
    auto end = right.wait_exposure_end(kSecond);
    ASSERT_TRUE(end.ok());
    EXPECT_GT(end->timestamp_ns, shown->timestamp_ns);
  }
  ASSERT_TRUE(right.stop().ok());
  ASSERT_TRUE(camera.stop().ok());

  // One projector lit per exposure, and the bus saw every edge in order.
  for (const auto& exposure : devices->sim_rig->exposures()) {
    EXPECT_EQ(exposure.lit_count, 1);
    EXPECT_EQ(exposure.side, 1);
  }
  const auto edges = devices->sim_rig->recorded_edges();
  int advances = 0, acks = 0;
  for (std::size_t i = 1; i < edges.size(); ++i) EXPECT_LE(edges[i - 1].timestamp_ns, edges[i].timestamp_ns);
  for (const auto& e : edges) {
    advances += e.offset == board.projectors[1].trig_in_1 && e.rising;
    acks += e.offset == board.projectors[1].trig_out_1 && e.rising;
  }
  EXPECT_EQ(advances, 3);
  EXPECT_EQ(acks, 3);
  EXPECT_FALSE(devices->sim_rig->line_value(board.projectors[1].trig_in_2));  // dark
}

TEST(SimRig, SilentProjectorAndCameraAreReported) {
  BoardConfig board = sim_board();
  auto devices = open_board_devices(board);
  ASSERT_TRUE(devices.ok()) << devices.error().message;
  sim::SimFaults faults;
  faults.projector_silent[0] = true;
  devices->sim_rig->set_faults(faults);
  DlpProjector& left = *devices->projectors[0];
  ASSERT_TRUE(left.start().ok());
  ASSERT_TRUE(left.advance().ok());
  auto shown = left.wait_exposure_start(30 * kMilli);
  ASSERT_FALSE(shown.ok());
  EXPECT_EQ(shown.error().code, slproto::Errc::hardware);
  EXPECT_NE(shown.error().message.find("projector.left did not acknowledge pattern 0"), std::string::npos)
      << shown.error().message;
  ASSERT_TRUE(left.stop().ok());

  faults = {};
  faults.camera_silent = true;
  devices->sim_rig->set_faults(faults);
  ASSERT_TRUE(devices->camera->start().ok());
  ASSERT_TRUE(left.start().ok());
  ASSERT_TRUE(left.advance().ok());
  ASSERT_TRUE(left.wait_exposure_start(kSecond).ok());
  auto frame = devices->camera->wait_frame(100 * kMilli);
  ASSERT_FALSE(frame.ok());
  EXPECT_EQ(frame.error().code, slproto::Errc::timeout);
}

TEST(SimRig, RefusesAFormatItCannotRenderAndBusyLines) {
  auto devices = open_board_devices(sim_board());
  ASSERT_TRUE(devices.ok()) << devices.error().message;
  auto format = devices->camera->set_format({1280, 1024, PixelFormat::mono8, 0});
  ASSERT_FALSE(format.ok());
  EXPECT_NE(format.error().message.find("renders 640x512"), std::string::npos) << format.error().message;
  // The projectors hold their lines: a second request for one is refused by name.
  LineRequestConfig config;
  config.lines = {{17, LineDirection::output, false, EdgeDetection::none, false, "intruder"}};
  auto request = devices->chip->request_lines(config);
  ASSERT_FALSE(request.ok());
  EXPECT_NE(request.error().message.find("line 17 (intruder) is already requested"), std::string::npos);
}

// A scene the renderer cannot draw (here a mesh file that is not there) is the frame's error,
// named by wait_frame; before, the renderer's exception left the camera thread and ended the
// process (slscand). The camera keeps answering: the next wait says the same, nothing hangs.
TEST(SimRig, AFrameTheRendererCannotDrawIsAnErrorNotACrash) {
  const BoardConfig board = sim_board();
  slrig::Scene scene =
      slrig::scene_preset(board.sim_scene, board.sim_rig_size == "full" ? slrig::RigSize::full : slrig::RigSize::small)
          .value();
  ASSERT_FALSE(scene.objects.empty());
  scene.objects[0].kind = slrig::ObjectKind::mesh;
  scene.objects[0].mesh_path = "/nonexistent/slscan_sim_rig_missing.stl";
  scene.objects[0].mesh_scale = 1;
  OpenOptions options;
  options.sim_scene = &scene;
  auto devices = open_board_devices(board, options);
  ASSERT_TRUE(devices.ok()) << devices.error().message;
  std::this_thread::sleep_for(std::chrono::milliseconds(50));  // the idle warm-up meets the scene first
  Camera& camera = *devices->camera;
  ASSERT_TRUE(camera.start().ok());
  DlpProjector& left = *devices->projectors[0];
  ASSERT_TRUE(left.start().ok());
  for (int attempt = 0; attempt < 2; ++attempt) {
    ASSERT_TRUE(left.advance().ok());
    ASSERT_TRUE(left.wait_exposure_start(kSecond).ok());
    auto frame = camera.wait_frame(20 * kSecond);
    ASSERT_FALSE(frame.ok());
    EXPECT_EQ(frame.error().code, slproto::Errc::hardware);
    EXPECT_NE(frame.error().message.find("sim camera: cannot render the scene"), std::string::npos)
        << frame.error().message;
    EXPECT_NE(frame.error().message.find("slscan_sim_rig_missing.stl"), std::string::npos) << frame.error().message;
    ASSERT_TRUE(left.wait_exposure_end(kSecond).ok());
  }
  ASSERT_TRUE(left.stop().ok());
  ASSERT_TRUE(camera.stop().ok());
}
