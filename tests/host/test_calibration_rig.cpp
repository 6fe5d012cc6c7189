// Calibration end to end on the virtual rig (small 640 x 512 rig, default sensor noise): a
// checkerboard at free poses lit by both projectors' full pattern plans along columns and rows,
// then lying on the turntable at six angles; calibrate_rig must recover the rig's ground truth.
// The rig integrates the board's albedo over each pixel's footprint, so its edges are
// anti-aliased as a real camera's are and sub-pixel corners are meaningful.
//
// Tolerances: the targets where the small rig reaches them (camera focal 0.1 %,
// principal point 1 px, RMS 0.1 px; projector focal 0.2 %, RMS 0.15 px; turntable steps
// 0.02 deg). The metric figures (projector extrinsics, turntable axis and plane) are scaled
// for the small rig, each with its reason at the assertion: a small-rig pixel covers 0.62 mm
// at the aim point, 3.85 times the full rig's 0.161 mm, and corners are located to ~0.04 px
// either way, so millimetre and angle errors grow by about that factor.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <numbers>
#include <stdexcept>

#include "calibrate.hpp"
#include "slrig/rig.hpp"
#include "slscan/core/calibration_rig.hpp"
#include "slscan/io/calibration_capture_files.hpp"
#include "slscan/virtual_rig/virtual_calibration.hpp"

namespace slscan::core {
namespace {

using slproto::RigidTransform;
using slproto::Vec3;
constexpr double kRad = std::numbers::pi / 180.0;

struct Fixture {
  slrig::Scene scene;
  slrig::SceneObject board;
  virtual_rig::VirtualCalibrationCapture rendered;  // capture + truth
  CalibrationCapture capture;                       // read back from the capture folder
  std::vector<double> actual_table_deg;
  std::vector<RigidTransform> cam_from_board;  // per pose, the truth
  std::string summary;
  RigCalibrationResult result;      // what `slscan calibrate FOLDER` computed
  slproto::RigCalibration written;  // the file it wrote
  nlohmann::json report_json;       // the report it wrote
  slproto::RigCalibration truth;
};

const Fixture& fixture() {
  static const Fixture f = [] {
    Fixture out;
    out.scene = slrig::scene_preset("calibration", slrig::RigSize::small).value();
    out.board = out.scene.objects.at(0);
    out.rendered =
        virtual_rig::render_virtual_calibration_capture(out.scene, "virtual rig, calibration preset (small)");
    out.truth = out.rendered.truth;
    out.actual_table_deg = out.rendered.actual_table_deg;
    out.cam_from_board = out.rendered.cam_from_board;
    out.scene.objects.clear();

    // The user's path: the capture as a folder on disk, `slscan calibrate FOLDER --out FILE`.
    const auto dir = std::filesystem::temp_directory_path() / ("slscan_calib_" + std::to_string(::getpid()));
    std::filesystem::remove_all(dir);
    std::filesystem::create_directories(dir);
    const std::string folder = (dir / "capture").string();
    io::write_calibration_capture(out.rendered.capture, folder);
    out.capture = io::read_calibration_capture(folder);
    app::CalibrateCommand command;
    command.capture_dir = folder;
    command.output_path = (dir / "calibration.json").string();
    command.report_path = (dir / "calibration_report.json").string();
    command.result = &out.result;
    app::Console console;
    console.quiet = true;
    if (app::run_calibrate(command, console) != app::exit_ok) throw std::runtime_error("slscan calibrate failed");
    out.written = slproto::load_calibration(command.output_path).value();
    std::ifstream report(command.report_path);
    out.report_json = nlohmann::json::parse(report);
    out.summary = out.result.report.summary();
    std::filesystem::remove_all(dir);
    return out;
  }();
  return f;
}

// The rig's anti-aliased board edges are what sub-pixel corners need: every corner the
// detector finds, against the board's true corners projected through the true camera.
void detected_corners_match_the_rigs_truth(const Fixture& f) {
  const auto corners = slrig::checkerboard_corners(f.board);
  const slproto::PatternPlan columns = f.capture.plan(slproto::CodingAxis::columns);
  const auto white = static_cast<std::size_t>(columns.index_of(slproto::PatternKind::white));
  double worst_rms = 0, sum2 = 0;
  std::size_t count = 0;
  for (std::size_t p = 0; p < f.capture.poses.size(); ++p) {
    // What calibrate_rig looks at: the camera image, else every white frame summed (both
    // projectors, both axes; the plans of both axes put white at the same index).
    cv::Mat image;
    for (const CalibrationFrame& frame : f.capture.frames) {
      if (frame.pose != static_cast<int>(p)) continue;
      if (frame.kind == CalibrationFrame::Kind::camera) {
        image = frame.image;
        break;
      }
      if (frame.pattern_index == white) {
        if (image.empty()) image = cv::Mat::zeros(frame.image.size(), CV_16U);
        cv::add(image, frame.image, image, cv::noArray(), CV_16U);
      }
    }
    if (image.depth() == CV_16U) {
      double hi = 0;
      cv::minMaxLoc(image, nullptr, &hi);
      image.convertTo(image, CV_8U, 255.0 / hi);
    }
    const CornerDetection detection = detect_checkerboard(image, f.capture.target);
    ASSERT_TRUE(detection.found) << f.capture.poses[p].name << ": " << detection.reason;
    ASSERT_EQ(detection.view.corners.size(), corners.size());
    // A point-symmetric board may be listed from either end: compare with both orders.
    std::array<double, 2> err2{0, 0};
    for (std::size_t order = 0; order < 2; ++order)
      for (const CornerObservation& c : detection.view.corners) {
        const std::size_t id = order == 0 ? static_cast<std::size_t>(c.id) : corners.size() - 1 - c.id;
        double u = 0, v = 0;
        ASSERT_TRUE(f.scene.camera.project(f.cam_from_board[p].apply(corners[id]), u, v));
        err2[order] += (c.pixel.x() - u) * (c.pixel.x() - u) + (c.pixel.y() - v) * (c.pixel.y() - v);
      }
    const double e2 = std::min(err2[0], err2[1]);
    const double rms = std::sqrt(e2 / static_cast<double>(corners.size()));
    std::printf("%s: corner RMS %.4f px\n", f.capture.poses[p].name.c_str(), rms);
    worst_rms = std::max(worst_rms, rms);
    sum2 += e2;
    count += corners.size();
  }
  std::printf("all corners: RMS %.4f px, worst pose %.4f px\n", std::sqrt(sum2 / static_cast<double>(count)),
              worst_rms);
  // Measured 0.044 px RMS, worst pose 0.064 px (0.037 px with the noise off: the rest is the
  // detector's own bias). Aliased edges gave corners snapped to half pixels (~0.3 px).
  EXPECT_LT(std::sqrt(sum2 / static_cast<double>(count)), 0.07);
  EXPECT_LT(worst_rms, 0.1);
}

void every_pose_is_used(const Fixture& f) {
  const CalibrationReport& report = f.result.report;
  std::cout << f.summary;
  EXPECT_TRUE(report.skipped.empty()) << f.summary;
  EXPECT_EQ(report.camera_views, 20);
  EXPECT_EQ(report.projector_views[0], 20);
  EXPECT_EQ(report.projector_views[1], 20);
  ASSERT_EQ(report.turntable.size(), 6u);
  EXPECT_EQ(f.result.calibration.source, f.capture.source);
  EXPECT_EQ(f.result.calibration.pattern_plan, f.capture.pattern_plan);
}

// The targets, with the small rig's scaling: a small-rig pixel covers 0.62 mm at the aim
// point, 3.85 times the full rig's 0.161 mm, while corners are located to ~0.04 px either way,
// so millimetre and angle figures grow by about that factor (the tolerances are the targets x
// 3.85, rounded down). Measured figures are from this test (20 poses: 14 free, 6 on the table,
// every one lit by both projectors' patterns along both axes);
// the full rig's, which meet the unscaled targets, are in docs/calibration.md.
void camera_matches_truth(const virtual_rig::CalibrationErrors& e) {
  // Measured fx -0.004 %, fy -0.001 %, cx +0.17 px, cy -0.11 px, RMS 0.038 px.
  EXPECT_LT(std::abs(e.camera_fx_pct), 0.1);
  EXPECT_LT(std::abs(e.camera_fy_pct), 0.1);
  EXPECT_LT(std::abs(e.camera_cx_px), 1.0);
  EXPECT_LT(std::abs(e.camera_cy_px), 1.0);
  EXPECT_LT(e.camera_rms_px, 0.1);
}

void projectors_match_truth(const virtual_rig::CalibrationErrors& e) {
  for (std::size_t s = 0; s < 2; ++s) {
    const auto& p = e.projectors[s];
    // Measured focal within 0.024 %, translation 0.16 / 0.06 mm, rotation 0.027 / 0.036 deg,
    // RMS 0.063 / 0.061 px. Issue: 0.2 %, 0.2 mm, 0.02 deg (scaled: 0.77 mm, 0.077 deg), 0.15 px.
    EXPECT_LT(std::abs(p.fx_pct), 0.2) << "side " << s;
    EXPECT_LT(std::abs(p.fy_pct), 0.2) << "side " << s;
    EXPECT_LT(p.translation_mm, 0.5) << "side " << s;
    EXPECT_LT(p.rotation_deg, 0.075) << "side " << s;
    EXPECT_LT(p.rms_px, 0.15) << "side " << s;
  }
}

void turntable_matches_truth(const Fixture& f, const virtual_rig::CalibrationErrors& e) {
  // Issue: axis 0.02 deg, position 0.1 mm (full rig); scaled 0.077 deg, 0.385 mm; measured
  // 0.008 deg, 0.12 mm.
  EXPECT_LT(e.axis_direction_deg, 0.05);
  EXPECT_LT(e.axis_position_mm, 0.385);
  // Issue: plane 0.05 mm (scaled 0.19 mm). The board's face on the table, its depth pinned by
  // both projectors' corners (camera alone, i.e. PnP, it follows the focal error: +0.42 mm
  // before the table poses had pattern frames); measured +0.059 mm.
  EXPECT_LT(std::abs(e.plane_mm), 0.19);
  const auto& steps = f.result.report.turntable;
  ASSERT_EQ(steps.size(), f.actual_table_deg.size());
  for (std::size_t i = 1; i < steps.size(); ++i) {
    const double actual_step = f.actual_table_deg[i] - f.actual_table_deg[i - 1];
    std::printf("  step %zu: measured %.4f, actual %.4f deg\n", i, steps[i].step_deg, actual_step);
    EXPECT_NEAR(steps[i].step_deg, actual_step, 0.02) << steps[i].pose;
  }
}

// What calibrate read from the folder is what the rig rendered, bit for bit.
void capture_folder_round_trips(const Fixture& f) {
  const CalibrationCapture& a = f.rendered.capture;
  const CalibrationCapture& b = f.capture;
  EXPECT_EQ(b.target.squares_x, a.target.squares_x);
  EXPECT_EQ(b.target.squares_y, a.target.squares_y);
  EXPECT_EQ(b.target.square_mm, a.target.square_mm);
  EXPECT_EQ(b.target.thickness_mm, a.target.thickness_mm);
  EXPECT_EQ(b.pattern_plan, a.pattern_plan);
  EXPECT_EQ(b.bit_depth, a.bit_depth);
  EXPECT_EQ(b.source, a.source);
  ASSERT_EQ(b.poses.size(), a.poses.size());
  for (std::size_t i = 0; i < a.poses.size(); ++i) {
    EXPECT_EQ(b.poses[i].name, a.poses[i].name);
    EXPECT_EQ(b.poses[i].on_turntable, a.poses[i].on_turntable);
    EXPECT_EQ(b.poses[i].table_angle_deg, a.poses[i].table_angle_deg);
  }
  ASSERT_EQ(b.frames.size(), a.frames.size());
  for (std::size_t i = 0; i < a.frames.size(); ++i) {
    const CalibrationFrame &fa = a.frames[i], &fb = b.frames[i];
    ASSERT_TRUE(fb.pose == fa.pose && fb.kind == fa.kind && fb.side == fa.side && fb.axis == fa.axis &&
                fb.pattern_index == fa.pattern_index)
        << "frame " << i;
    ASSERT_EQ(fb.image.type(), fa.image.type()) << "frame " << i;
    ASSERT_EQ(cv::norm(fa.image, fb.image, cv::NORM_INF), 0.0) << "frame " << i;
  }
}

// The CLI's file and report say what the calibration computed.
void cli_outputs_match_the_result(const Fixture& f) {
  EXPECT_EQ(f.written, f.result.calibration);
  EXPECT_EQ(f.report_json.at("camera_views").get<int>(), f.result.report.camera_views);
  EXPECT_DOUBLE_EQ(f.report_json.at("camera_rms_px").get<double>(), f.result.report.camera_rms_px);
  ASSERT_EQ(f.report_json.at("poses").size(), f.result.report.poses.size());
  ASSERT_EQ(f.report_json.at("turntable").size(), f.result.report.turntable.size());
  for (std::size_t i = 0; i < f.result.report.turntable.size(); ++i)
    EXPECT_DOUBLE_EQ(f.report_json.at("turntable")[i].at("step_deg").get<double>(),
                     f.result.report.turntable[i].step_deg);
}

void result_round_trips_through_the_file(const Fixture& f) {
  auto parsed = slproto::parse_calibration(slproto::format_calibration(f.result.calibration));
  ASSERT_TRUE(parsed.ok()) << parsed.error().message;
  EXPECT_EQ(*parsed, f.result.calibration);
}

// `slscan calibrate` measures the poses one at a time and lets each pose's frames go
// (measure_calibration_pose, then calibrate_rig on the measurements), as a capture through a
// scanner does: the same file as measuring the whole capture held in memory.
void measuring_pose_by_pose_gives_the_same_calibration(const Fixture& f) {
  const RigCalibrationResult whole = calibrate_rig(f.capture);
  EXPECT_EQ(slproto::format_calibration(whole.calibration), slproto::format_calibration(f.result.calibration));
  EXPECT_EQ(whole.report.summary(), f.summary);
  // Measurements of another size than the first pose's cannot be solved together.
  CalibrationMeasurements measured = measurements_of(f.capture);
  measured.poses = f.capture.poses;
  for (std::size_t p = 0; p < f.capture.poses.size(); ++p)
    measured.measured.push_back(measure_calibration_pose(f.capture, static_cast<int>(p), {}, false));
  // One measurer keeps its decoders from pose to pose (as the folder and the guided capture
  // measure): a pose measured after another gives what a fresh measurer gives, bit for bit.
  CalibrationPoseMeasurer measurer;
  const std::size_t last = f.capture.poses.size() - 1;
  (void)measurer.measure(f.capture, 0);
  const CalibrationPoseMeasurement reused = measurer.measure(f.capture, static_cast<int>(last));
  const CalibrationPoseMeasurement fresh = measure_calibration_pose(f.capture, static_cast<int>(last));
  int sides_compared = 0;
  for (std::size_t s = 0; s < 2; ++s) {
    ASSERT_EQ(reused.projectors[s].has_value(), fresh.projectors[s].has_value());
    if (!fresh.projectors[s]) continue;
    ++sides_compared;
    const auto& a = reused.projectors[s]->view.corners;
    const auto& b = fresh.projectors[s]->view.corners;
    ASSERT_EQ(a.size(), b.size());
    ASSERT_GT(b.size(), 6u);
    for (std::size_t i = 0; i < b.size(); ++i) {
      EXPECT_EQ(a[i].id, b[i].id);
      EXPECT_EQ(a[i].pixel, b[i].pixel);
    }
  }
  EXPECT_GT(sides_compared, 0);
  measured.measured.back().width += 2;
  EXPECT_THROW(calibrate_rig(measured), std::invalid_argument);
  measured.measured.pop_back();
  EXPECT_THROW(calibrate_rig(measured), std::invalid_argument);  // a pose without its measurement
}

// One test: the capture takes ~15 s to render and calibrate, and CTest runs every TEST in its
// own process, so separate TESTs would each pay for it (the suite runs twice in CI, once
// under ASan). Each part keeps its name in the failure trace.
TEST(CalibrationRig, RecoversTheRigsTruth) {
  const Fixture& f = fixture();
  {
    SCOPED_TRACE("DetectedCornersMatchTheRigsTruth");
    detected_corners_match_the_rigs_truth(f);
  }
  {
    SCOPED_TRACE("EveryPoseIsUsed");
    every_pose_is_used(f);
  }
  const virtual_rig::CalibrationErrors errors = virtual_rig::calibration_errors(f.result, f.rendered);
  std::printf("against the rig's truth:\n%s", errors.table().c_str());
  {
    SCOPED_TRACE("CameraMatchesTruth");
    camera_matches_truth(errors);
  }
  {
    SCOPED_TRACE("ProjectorsMatchTruth");
    projectors_match_truth(errors);
  }
  {
    SCOPED_TRACE("TurntableMatchesTruth");
    turntable_matches_truth(f, errors);
  }
  {
    SCOPED_TRACE("CaptureFolderRoundTrips");
    capture_folder_round_trips(f);
  }
  {
    SCOPED_TRACE("CliOutputsMatchTheResult");
    cli_outputs_match_the_result(f);
  }
  {
    SCOPED_TRACE("ResultRoundTripsThroughTheFile");
    result_round_trips_through_the_file(f);
  }
  {
    SCOPED_TRACE("MeasuringPoseByPoseGivesTheSameCalibration");
    measuring_pose_by_pose_gives_the_same_calibration(f);
  }
}

}  // namespace
}  // namespace slscan::core
