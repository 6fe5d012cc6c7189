#include "calibrate.hpp"

#include <cstdio>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>

#include "slproto/calibration.hpp"
#include "slscan/io/calibration_capture_files.hpp"
#include "slscan/io/io_error.hpp"
#include "slscan/session/calibration_capture.hpp"
#include "status.hpp"
#ifdef SLSCAN_WITH_DEMO
#include "slrig/rig.hpp"
#include "slscan/virtual_rig/virtual_calibration.hpp"
#endif

namespace slscan::app {

using json = nlohmann::json;

std::string calibration_report_json(const core::CalibrationReport& report) {
  json poses = json::array();
  for (const core::PoseReport& p : report.poses)
    poses.push_back({{"name", p.name},
                     {"on_turntable", p.on_turntable},
                     {"table_angle_deg", p.table_angle_deg},
                     {"board_found", p.board_found},
                     {"camera_rms_px", p.camera_rms_px},
                     {"projector_corners", p.projector_corners},
                     {"projector_rms_px", p.projector_rms_px},
                     {"local_fit_rms_px", p.local_fit_rms_px}});
  json skipped = json::array();
  for (const core::SkippedImage& s : report.skipped)
    skipped.push_back({{"pose", s.pose}, {"what", s.what}, {"reason", s.reason}});
  json steps = json::array();
  for (const core::TurntableStep& t : report.turntable)
    steps.push_back({{"pose", t.pose},
                     {"commanded_deg", t.commanded_deg},
                     {"measured_deg", t.measured_deg},
                     {"step_deg", t.step_deg},
                     {"residual_mm", t.residual_mm},
                     {"reprojection_px", t.reprojection_px},
                     {"corner_order_reversed", t.corner_order_reversed}});
  return json{{"camera_views", report.camera_views},
              {"camera_rms_px", report.camera_rms_px},
              {"projector_views", report.projector_views},
              {"projector_rms_px", report.projector_rms_px},
              {"turntable_rms_px", report.turntable_rms_px},
              {"target_tilt_deg", report.target_tilt_deg},
              {"poses", poses},
              {"skipped", skipped},
              {"turntable", steps}}
      .dump(1);
}

namespace {

// Interactive capture: the pose to set, then Enter (or q and Enter to stop).
session::PoseAnswer ask_user(const slproto::GuidedCalibrationPose& pose, const std::string& problem) {
  if (!problem.empty())
    std::printf(
        "%s: %s\n  adjust the board and press Enter to take it again (q, Enter: stop; the poses so far "
        "are kept)\n",
        pose.name.c_str(), problem.c_str());
  else
    std::printf("%s: %s\n  press Enter when the board is set (q, Enter: stop; the poses so far are kept)\n",
                pose.name.c_str(), pose.instruction().c_str());
  std::fflush(stdout);
  std::string line;
  if (!std::getline(std::cin, line) || line == "q" || line == "Q") return session::PoseAnswer::quit;
  return session::PoseAnswer::ready;
}

}  // namespace

int run_calibrate(const CalibrateCommand& command, const Console& console) {
  core::CalibrationCapture capture;
  core::CalibrationOptions options;
  options.turntable = !command.no_turntable;
#ifdef SLSCAN_WITH_DEMO
  std::optional<virtual_rig::VirtualCalibrationCapture> rendered;
#endif
  if (!command.connect.empty()) {
    if (!command.capture_dir.empty() || !command.virtual_rig.empty())
      throw std::invalid_argument("calibrate: give a capture folder, --virtual or --connect, not two of them");
    if (!command.resume_dir.empty() && !command.write_capture_dir.empty() &&
        command.resume_dir != command.write_capture_dir)
      throw std::invalid_argument("calibrate: --resume " + command.resume_dir +
                                  " writes to that folder; --write-capture " + command.write_capture_dir +
                                  " names another");
    session::CalibrationCaptureRequest request;
    const auto [host, port] = parse_scanner_address(command.connect);
    request.scanner = {host, port, read_token_file(command.token_file)};
    request.target = command.target;
    request.platform_radius_mm = command.platform_radius_mm;
    request.turntable = !command.no_turntable;
    request.folder = command.resume_dir.empty() ? command.write_capture_dir : command.resume_dir;
    request.resume = !command.resume_dir.empty();
    request.exposure_us = command.exposure_us;
    request.pattern_period_us = command.pattern_period_us;
    request.settle_ms = command.settle_ms;
    request.stop = &interrupted;
    if (!command.auto_mode) request.ask = ask_user;
    try {
      capture = session::capture_calibration(request, ConsoleLog(console));
    } catch (const session::CalibrationCaptureStopped& e) {
      console.warn(std::string("calibrate: ") + e.what());
      return e.why == session::CalibrationCaptureStopped::Why::pose_rejected ? exit_measurement : exit_interrupted;
    }
    console.info("captured " + std::to_string(capture.frames.size()) + " frames of " +
                 std::to_string(capture.poses.size()) + " poses" +
                 (request.folder.empty() ? std::string() : " (in " + request.folder + ")"));
  } else if (!command.virtual_rig.empty()) {
#ifdef SLSCAN_WITH_DEMO
    if (!command.capture_dir.empty())
      throw std::invalid_argument("calibrate: give a capture folder or --virtual, not both");
    if (command.virtual_rig != "small" && command.virtual_rig != "full")
      throw std::invalid_argument("calibrate: --virtual takes \"small\" or \"full\", not \"" + command.virtual_rig +
                                  "\"");
    const auto size = command.virtual_rig == "full" ? slrig::RigSize::full : slrig::RigSize::small;
    console.info("rendering the virtual rig's calibration capture (" + command.virtual_rig + ")");
    rendered = virtual_rig::render_virtual_calibration_capture(
        slrig::scene_preset("calibration", size).value(),
        "virtual rig, calibration preset (" + command.virtual_rig + ")", 0.05,
        [&](std::size_t done, std::size_t total, const std::string& pose) {
          console.progress({"rendering", done, total, "poses", pose});
        });
    console.end_progress();
    capture = rendered->capture;
    if (!command.write_capture_dir.empty()) {
      io::write_calibration_capture(capture, command.write_capture_dir);
      console.info("wrote the capture to " + command.write_capture_dir);
    }
#else
    throw std::invalid_argument("calibrate: --virtual needs a build with the virtual rig");
#endif
  } else {
    if (command.capture_dir.empty()) throw std::invalid_argument("calibrate: no capture folder given");
    capture = io::read_calibration_capture(command.capture_dir);
    console.info("read " + std::to_string(capture.frames.size()) + " frames of " +
                 std::to_string(capture.poses.size()) + " poses from " + command.capture_dir);
  }
  core::RigCalibrationResult result;
  // Poses measured, then the solves: one progress line each.
  std::optional<core::CalibrationProgress::Phase> phase;
  options.progress = [&](const core::CalibrationProgress& p) {
    if (phase && *phase != p.phase) console.end_progress();
    phase = p.phase;
    if (p.phase == core::CalibrationProgress::Phase::poses)
      console.progress({"measuring poses", p.done, p.total, "poses", p.step});
    else
      console.progress({"solving", p.done, p.total, {}, p.step});
  };
  try {
    result = core::calibrate_rig(capture, options);
    console.end_progress();
  } catch (const std::runtime_error& e) {
    console.end_progress();
    // Too few usable poses: the message names the counts and every skipped image.
    console.warn(std::string("calibration failed: ") + e.what());
    return exit_bad_input;
  }
  if (!console.quiet) std::fputs(result.report.summary().c_str(), stdout);
#ifdef SLSCAN_WITH_DEMO
  if (rendered && !console.quiet)
    std::printf("against the virtual rig's truth:\n%s",
                virtual_rig::calibration_errors(result, *rendered).table().c_str());
#endif
  if (auto status = slproto::save_calibration(command.output_path, result.calibration); !status)
    throw io::IoError(status.error().message);
  if (!command.report_path.empty())
    if (auto status = slproto::write_file_atomically(command.report_path, calibration_report_json(result.report));
        !status)
      throw io::IoError(status.error().message);
  console.info("wrote " + command.output_path);
  if (command.result != nullptr) *command.result = std::move(result);
  return exit_ok;
}

}  // namespace slscan::app
