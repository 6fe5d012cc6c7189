// Wrong descriptions of a foreign capture (issue 20): the small rig renders a one-projector
// capture (sphere preset, view 0, left projector) as another scanner's files, frame_00.png ...
// in its own order, with an OpenCV stereo calibration (K1 D1 K2 D2 R T). Each description a
// user gets wrong -- phase frames in file order when the scanner's phase origin is -pi, the
// phase reversed, a phase frame missing, Gray bits LSB first, the Gray files off by one, the
// wrong axis, the wrong pose direction, an undescribed 0.37 rad origin -- must be refused by
// `slscan import` with the exit code of an inconsistent capture and the right diagnosis, and
// `slscan import --detect` must find a description that decodes to the rig's true projector
// coordinate with the right geometry.
#include <gtest/gtest.h>
#include <unistd.h>

#if __has_include("slrig/rig.hpp")
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <numbers>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

#include "detect.hpp"
#include "real_data.hpp"
#include "slrig/rig.hpp"
#include "slscan/core/decode.hpp"
#include "slscan/io/image_sequence_import.hpp"

namespace fs = std::filesystem;
using nlohmann::json;
using namespace slscan;

namespace {

constexpr double kPi = std::numbers::pi;

struct Capture {
  fs::path dir;
  slrig::ViewGroundTruth truth;
  slproto::RigCalibration calibration;
};

// Renders `plan` (the foreign scanner's) and writes its frames as frame_NN.png in plan order,
// plus calib.yml.
Capture render_capture(const fs::path& dir, const slproto::PatternPlanConfig& foreign, int projector_height = 912) {
  auto scene = slrig::scene_preset("sphere", slrig::RigSize::small).value();
  for (auto& p : scene.projectors) {
    p.intrinsics.cy += 0.5 * (projector_height - p.intrinsics.height);
    p.intrinsics.height = projector_height;
  }
  scene.pattern_plan = foreign;
  scene.pattern_plan.projector_height = projector_height;
  const slproto::PatternPlan plan(scene.pattern_plan);
  const slrig::ViewRenderer renderer(scene, scene.view_angles_deg.at(0), 0);
  fs::create_directories(dir);
  std::vector<std::uint8_t> frame(renderer.frame_bytes());
  for (std::size_t p = 0; p < plan.size(); ++p) {
    renderer.render(slproto::ProjectorSide::left, plan, p, frame);
    char name[32];
    std::snprintf(name, sizeof name, "frame_%02zu.png", p);
    cv::imwrite((dir / name).string(), cv::Mat(renderer.height(), renderer.width(), CV_8UC1, frame.data()));
  }
  Capture c;
  c.dir = dir;
  c.truth = renderer.ground_truth();
  c.calibration = slrig::ground_truth_calibration(scene);
  const auto& cam = c.calibration.camera;
  const auto& proj = c.calibration.projectors[0];
  const slproto::RigidTransform proj_from_cam = proj.cam_from_proj.inverse();
  cv::FileStorage fs((dir / "calib.yml").string(), cv::FileStorage::WRITE);
  auto k = [](const slproto::PinholeModel& m) -> cv::Mat {
    return (cv::Mat_<double>(3, 3) << m.fx, 0, m.cx, 0, m.fy, m.cy, 0, 0, 1);
  };
  auto d = [](const slproto::PinholeModel& m) -> cv::Mat {
    return (cv::Mat_<double>(1, 5) << m.distortion.k1, m.distortion.k2, m.distortion.p1, m.distortion.p2,
            m.distortion.k3);
  };
  fs << "K1" << k(cam) << "D1" << d(cam) << "K2" << k(proj.intrinsics) << "D2" << d(proj.intrinsics);
  cv::Mat r(3, 3, CV_64F), t(3, 1, CV_64F);
  for (int i = 0; i < 9; ++i) r.at<double>(i / 3, i % 3) = proj_from_cam.R[static_cast<std::size_t>(i)];
  for (int i = 0; i < 3; ++i) t.at<double>(i) = proj_from_cam.t[static_cast<std::size_t>(i)];
  fs << "R" << r << "T" << t;
  return c;
}

// Our default plan's frames as frame_00 (white), 01 (black), 02-09 (Gray MSB first),
// 10 (complementary), 11-18 (phase).
json right_description(int projector_height = 912) {
  return {{"projector", {{"width", 1140}, {"height", projector_height}}},
          {"camera", {{"width", 640}, {"height", 512}}},
          {"white", "frame_00.png"},
          {"black", "frame_01.png"},
          {"gray", {{"files", {{"pattern", "frame_%02d.png"}, {"first", 2}, {"count", 8}}}}},
          {"complementary", "frame_10.png"},
          {"phase", {{"files", {{"pattern", "frame_%02d.png"}, {"first", 11}, {"count", 8}}}, {"period_px", 8}}}};
}

struct ImportRun {
  int exit_code = -1;
  std::string errors;  // what the run wrote on stderr
};

ImportRun import(const Capture& capture, const json& description, const fs::path& out, bool detect,
                 const std::string& pose = "proj_from_cam") {
  const fs::path path = capture.dir / ("description_" + out.filename().string() + ".json");
  std::ofstream(path) << description.dump(2);
  app::ImportCommand command;
  command.description_path = path.string();
  command.calibration_path = (capture.dir / "calib.yml").string();
  command.output_dir = out.string();
  command.pose_direction = pose;
  command.detect = detect;
  app::Console console;
  console.quiet = true;
  std::stringstream captured;
  auto* old = std::cerr.rdbuf(captured.rdbuf());
  ImportRun run;
  try {
    run.exit_code = app::run_import(command, console);
  } catch (const std::exception& e) {
    captured << "exception: " << e.what();
  }
  std::cerr.rdbuf(old);
  run.errors = captured.str();
  return run;
}

// The written description decodes to the rig's true projector coordinate.
void expect_decodes_to_truth(const Capture& capture, const fs::path& out) {
  std::ifstream in(out / "description.json");
  ASSERT_TRUE(in) << "no description.json in " << out;
  std::stringstream text;
  text << in.rdbuf();
  const io::SequenceDescription d = io::parse_sequence_description(text.str(), out.string());
  const io::ImportedSequence sequence = io::read_image_sequence(d);
  core::ProjectorViewDecoder decoder(sequence.plan, sequence.width, sequence.height);
  for (std::size_t p = 0; p < sequence.frames.size(); ++p)
    decoder.add_frame(p, sequence.frames[p].data(), static_cast<std::size_t>(sequence.width));
  const core::DecodedView view = decoder.finish();
  std::vector<double> errors;
  std::size_t wrong_period = 0;
  for (std::size_t i = 0; i < view.coordinate.size(); ++i) {
    const float truth = capture.truth.projector_coord[0][i];
    if (view.mask[i] != core::DecodeMask::valid || !std::isfinite(truth)) continue;
    const double e = std::abs(view.coordinate[i] - truth);
    errors.push_back(e);
    wrong_period += e > 4;
  }
  ASSERT_GT(errors.size(), 50000u);
  std::nth_element(errors.begin(), errors.begin() + static_cast<long>(errors.size() / 2), errors.end());
  EXPECT_LT(errors[errors.size() / 2], 0.05) << "median error, projector px";
  EXPECT_LT(static_cast<double>(wrong_period) / static_cast<double>(errors.size()), 0.003);
  // And the geometry: the written calibration's projector pose is the rig's.
  auto calibration = slproto::load_calibration((out / "calibration.json").string());
  ASSERT_TRUE(calibration.ok()) << calibration.error().message;
  for (int i = 0; i < 3; ++i)
    EXPECT_NEAR(calibration->projectors[0].cam_from_proj.t[static_cast<std::size_t>(i)],
                capture.calibration.projectors[0].cam_from_proj.t[static_cast<std::size_t>(i)], 1e-6);
}

class ForeignConventions : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ = fs::temp_directory_path() / ("slscan_foreign_" + std::to_string(::getpid()));
    // The foreign scanner's phase origin is -pi: its frame n shows our step n + 4.
    slproto::PatternPlanConfig foreign;
    foreign.phase_offset_rad = -kPi;
    capture_ = new Capture(render_capture(root_ / "capture", foreign));
  }
  static void TearDownTestSuite() {
    delete capture_;
    fs::remove_all(root_);
  }
  static fs::path root_;
  static Capture* capture_;
};
fs::path ForeignConventions::root_;
Capture* ForeignConventions::capture_ = nullptr;

struct Case {
  const char* name;
  json description;
  const char* check;  // the finding's check
  const char* words;  // in the message
  std::string pose = "proj_from_cam";
};

TEST_F(ForeignConventions, EveryWrongDescriptionIsCaughtAndDetectFindsTheRightOne) {
  json right = right_description();
  right["phase"]["offset_steps"] = 4;
  {
    const ImportRun run = import(*capture_, right, root_ / "right", false);
    EXPECT_EQ(run.exit_code, app::exit_ok) << run.errors;
  }
  std::vector<Case> cases;
  cases.push_back({"phase frames in file order (origin -pi)", right_description(), "phase_offset",
                   "list them from frame 4, or set phase.offset_steps = 4"});
  {
    json d = right;
    d["phase"]["files"] = {"frame_11.png", "frame_18.png", "frame_17.png", "frame_16.png",
                           "frame_15.png", "frame_14.png", "frame_13.png", "frame_12.png"};
    cases.push_back({"phase frames reversed", d, "phase_direction", "opposite shift direction"});
  }
  {
    json d = right;
    d["phase"]["files"]["count"] = 7;
    d["phase"].erase("offset_steps");
    cases.push_back({"one phase frame missing", d, "phase_frames", "1 frame missing"});
  }
  {
    json d = right;
    d["gray"]["bit_order"] = "lsb_first";
    cases.push_back({"Gray bits LSB first", d, "gray_order", "least significant bit first"});
  }
  {
    json d = right;
    d["gray"]["files"]["first"] = 3;
    cases.push_back({"Gray files one late", d, "gray_order", "one frame late"});
  }
  cases.push_back({"wrong pose direction", right, "geometry", "pose is probably read the wrong way", "cam_from_proj"});
  for (const auto& c : cases) {
    SCOPED_TRACE(c.name);
    const std::string tag = std::to_string(&c - cases.data());
    const ImportRun refused = import(*capture_, c.description, root_ / ("wrong" + tag), false, c.pose);
    EXPECT_EQ(refused.exit_code, app::exit_inconsistent) << refused.errors;
    EXPECT_NE(refused.errors.find(c.words), std::string::npos) << refused.errors;
    EXPECT_NE(refused.errors.find(std::string("[") + c.check + "]"), std::string::npos) << refused.errors;
    EXPECT_FALSE(fs::exists(root_ / ("wrong" + tag) / "capture.slcap")) << "nothing written";
    const ImportRun detected = import(*capture_, c.description, root_ / ("detect" + tag), true, c.pose);
    ASSERT_EQ(detected.exit_code, app::exit_ok) << detected.errors;
    expect_decodes_to_truth(*capture_, root_ / ("detect" + tag));
  }
}

TEST_F(ForeignConventions, TheWrongAxisIsCaughtByTheGeometry) {
  // A projector whose rows need as many Gray bits as its columns (1100 rows: 138 periods).
  const Capture capture = render_capture(root_ / "tall", slproto::PatternPlanConfig{}, 1100);
  json wrong = right_description(1100);
  wrong["axis"] = "rows";
  const ImportRun refused = import(capture, wrong, root_ / "tall_wrong", false);
  EXPECT_EQ(refused.exit_code, app::exit_inconsistent) << refused.errors;
  EXPECT_NE(refused.errors.find("[geometry]"), std::string::npos) << refused.errors;
  EXPECT_NE(refused.errors.find("coding axis"), std::string::npos) << refused.errors;
  const ImportRun detected = import(capture, wrong, root_ / "tall_detect", true);
  ASSERT_EQ(detected.exit_code, app::exit_ok) << detected.errors;
  expect_decodes_to_truth(capture, root_ / "tall_detect");
}

TEST_F(ForeignConventions, AContinuousOriginOffsetIsMeasuredAndRecovered) {
  slproto::PatternPlanConfig foreign;
  foreign.phase_offset_rad = 0.37;
  const Capture capture = render_capture(root_ / "offset", foreign);
  const ImportRun refused = import(capture, right_description(), root_ / "offset_wrong", false);
  EXPECT_EQ(refused.exit_code, app::exit_inconsistent) << refused.errors;
  EXPECT_NE(refused.errors.find("set phase.offset_rad = 0.3"), std::string::npos) << refused.errors;
  const ImportRun detected = import(capture, right_description(), root_ / "offset_detect", true);
  ASSERT_EQ(detected.exit_code, app::exit_ok) << detected.errors;
  expect_decodes_to_truth(capture, root_ / "offset_detect");
  std::ifstream in(root_ / "offset_detect" / "description.json");
  const json written = json::parse(in);
  EXPECT_NEAR(written["phase"].value("offset_rad", 0.0), 0.37, 0.03) << written.dump();
}

}  // namespace

#else
TEST(ForeignConventions, NeedsTheVirtualRig) { GTEST_SKIP() << "built without slrig (firmware/rig)"; }
#endif
