#include "calibrate.hpp"

#include <cstdio>
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>

#include "simulated_scanner.hpp"
#include "slproto/calibration.hpp"
#include "slscan/core/calibration_compare.hpp"
#include "slscan/io/calibration_capture_files.hpp"
#include "slscan/io/io_error.hpp"
#include "slscan/session/calibration_capture.hpp"
#include "status.hpp"

namespace slscan::app {

using json = nlohmann::json;
namespace fs = std::filesystem;

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

// The capture through a scanner (session::capture_calibration), measured pose by pose.
// Returns the exit code for a capture that stopped, or nullopt with `measured` filled.
std::optional<int> capture_through_scanner(const CalibrateCommand& command, const session::ScannerAddress& scanner,
                                           bool automatic, const std::string& source, const Console& console,
                                           core::CalibrationMeasurements& measured) {
  session::CalibrationCaptureRequest request;
  request.scanner = scanner;
  request.source = source;
  request.target = command.target;
  request.platform_radius_mm = command.platform_radius_mm;
  request.turntable = !command.no_turntable;
  request.folder = command.resume_dir.empty() ? command.write_capture_dir : command.resume_dir;
  request.resume = !command.resume_dir.empty();
  request.exposure_us = command.exposure_us;
  request.pattern_period_us = command.pattern_period_us;
  request.settle_ms = command.settle_ms;
  request.stop = &interrupted;
  if (!automatic) request.ask = ask_user;
  try {
    measured = session::capture_calibration(request, ConsoleLog(console));
  } catch (const session::CalibrationCaptureStopped& e) {
    console.warn(std::string("calibrate: ") + e.what());
    return e.why == session::CalibrationCaptureStopped::Why::pose_rejected ? exit_measurement : exit_interrupted;
  }
  return std::nullopt;
}

}  // namespace

int run_calibrate(const CalibrateCommand& command, const Console& console) {
  core::CalibrationMeasurements measured;
  core::CalibrationOptions options;
  options.turntable = !command.no_turntable;
  std::optional<slproto::RigCalibration> truth;  // --virtual: the sim board's exact calibration
  const int sources = static_cast<int>(!command.capture_dir.empty()) + static_cast<int>(!command.virtual_rig.empty()) +
                      static_cast<int>(!command.connect.empty());
  if (sources > 1)
    throw std::invalid_argument("calibrate: give a capture folder, --virtual or --connect, not two of them");
  if (!command.resume_dir.empty() && command.connect.empty())
    throw std::invalid_argument("calibrate: --resume continues a capture through a scanner: it needs --connect");
  if (!command.connect.empty()) {
    if (!command.resume_dir.empty() && !command.write_capture_dir.empty() &&
        command.resume_dir != command.write_capture_dir)
      throw std::invalid_argument("calibrate: --resume " + command.resume_dir +
                                  " writes to that folder; --write-capture " + command.write_capture_dir +
                                  " names another");
    const auto [host, port] = parse_scanner_address(command.connect);
    if (auto stopped = capture_through_scanner(command, {host, port, read_token_file(command.token_file)},
                                               command.auto_mode, {}, console, measured))
      return *stopped;
  } else if (!command.virtual_rig.empty()) {
    if (command.virtual_rig != "small" && command.virtual_rig != "full")
      throw std::invalid_argument("calibrate: --virtual takes \"small\" or \"full\", not \"" + command.virtual_rig +
                                  "\"");
    // The virtual rig is calibrated as a real scanner is: through slscand on the sim board,
    // which places the checkerboard at each pose and steps its table.
    const std::string slscand = find_slscand(command.slscand_path);
    const TemporaryFolder work("slscan-calibrate-virtual-");
    const fs::path board = work.path() / "board.toml";
    write_sim_board(command.board_path, "sphere",
                    command.virtual_rig == "full" ? VirtualRigSize::full : VirtualRigSize::small, board);
    write_true_calibration(slscand, board, work.path() / "truth.json");
    auto loaded = slproto::load_calibration((work.path() / "truth.json").string());
    if (!loaded) throw DeviceError("the sim board's true calibration: " + loaded.error().message);
    truth = std::move(*loaded);
    console.info("calibrating the virtual rig (" + command.virtual_rig + ") through slscand on the sim board");
    SimulatedScanner scanner(slscand, board, work.path() / "slscand.log");
    CalibrateCommand virtual_command = command;
    // The sim board's own timing (boards/sim.toml): a real DLP4500 needs the slower defaults.
    virtual_command.exposure_us = 2000;
    virtual_command.pattern_period_us = 5000;
    virtual_command.settle_ms = 50;
    const std::string source = "virtual rig (" + command.virtual_rig + "), through slscand on the sim board";
    if (auto stopped = capture_through_scanner(virtual_command, {scanner.host(), scanner.port(), ""}, true, source,
                                               console, measured))
      return *stopped;
    scanner.stop();
  } else {
    if (command.capture_dir.empty()) throw std::invalid_argument("calibrate: no capture folder given");
    // Read and measured pose by pose (one pose's images in memory), then solved below.
    const io::CalibrationCaptureFolder folder(command.capture_dir);
    const core::CalibrationCapture& capture = folder.capture();
    measured = core::measurements_of(capture);
    measured.poses = capture.poses;
    core::CalibrationPoseMeasurer measurer(options);
    for (std::size_t p = 0; p < capture.poses.size(); ++p) {
      const int pose = static_cast<int>(p);
      console.progress({"measuring poses", p, capture.poses.size(), "poses", capture.poses[p].name});
      measured.measured.push_back(measurer.measure(folder.read_pose(pose), pose));
    }
    console.end_progress();
    console.info("measured " + std::to_string(capture.frames.size()) + " frames of " +
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
    result = core::calibrate_rig(measured, options);
    console.end_progress();
  } catch (const std::runtime_error& e) {
    console.end_progress();
    // Too few usable poses: the message names the counts and every skipped image.
    console.warn(std::string("calibration failed: ") + e.what());
    return exit_bad_input;
  }
  if (!console.quiet) std::fputs(result.report.summary().c_str(), stdout);
  if (truth && !console.quiet)
    std::printf("against the virtual rig's truth:\n%s",
                core::calibration_difference(result.calibration, *truth).table().c_str());
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
