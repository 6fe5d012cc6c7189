// slscan demo: the whole product on one machine. Starts slscand on the sim board (the virtual
// rig) on loopback, scans a scene, reconstructs it live, measures the artefact and writes
// everything to the output folder.
#include <chrono>
#include <filesystem>

#include "calibrate.hpp"
#include "run.hpp"
#include "simulated_scanner.hpp"

namespace slscan::app {

namespace fs = std::filesystem;

int run_demo(const DemoCommand& command, const Console& console) {
  const auto start = std::chrono::steady_clock::now();
  const fs::path out = command.output_dir;
  if (const std::string capture = capture_in(out.string()); !capture.empty() && !command.overwrite)
    return refuse_to_overwrite("demo", capture);
  fs::create_directories(out);
  const std::string slscand = find_slscand(command.slscand_path);
  const VirtualRigSize size = command.small ? VirtualRigSize::small : VirtualRigSize::full;
  const std::string board_path = (out / "board.toml").string();
  write_sim_board(command.board_path, command.scene, size, board_path);
  {
    // The scenes are the sim board's to know: asking it for the scene's truth refuses an
    // unknown one at once, before minutes of calibration.
    const TemporaryFolder work("slscan-demo-");
    try {
      write_true_calibration(slscand, board_path, work.path() / "truth.json");
    } catch (const DeviceError& e) {
      throw std::invalid_argument("demo --scene " + command.scene + ": " + e.what());
    }
  }

  // The calibration: estimated from the virtual rig's calibration capture (checkerboard at ten
  // free poses and six table angles, docs/calibration.md), taken through slscand as on a real
  // rig; or, on request, the rig's exact one, said plainly in the report.
  const std::string calibration_path = (out / "calibration.json").string();
  if (command.true_calibration) {
    write_true_calibration(slscand, board_path, calibration_path);
    console.info("calibration: the virtual rig's ground truth -> " + calibration_path);
  } else {
    CalibrateCommand calibrate;
    calibrate.virtual_rig = command.small ? "small" : "full";
    calibrate.slscand_path = slscand;
    calibrate.board_path = command.board_path;
    calibrate.output_path = calibration_path;
    calibrate.report_path = (out / "calibration_report.json").string();
    if (const int rc = run_calibrate(calibrate, console); rc != exit_ok) return rc;
  }

  console.info("starting slscand on the sim board (scene '" + command.scene + "', " +
               (command.small ? "640 x 512" : "2464 x 2056") + ")");
  SimulatedScanner daemon(slscand, board_path, out / "slscand.log");

  ScanCommand scan;
  scan.host = daemon.host();
  scan.port = daemon.port();
  scan.calibration_path = calibration_path;
  scan.output_dir = out.string();
  scan.config_path = command.config_path;
  scan.exposure_us = 2000;
  scan.exposure_bracket_us = command.exposure_bracket_us;
  scan.exposure_mode = command.exposure_mode;
  scan.auto_exposure = command.auto_exposure;
  scan.fringe_period_px = command.fringe_period_px;
  scan.pattern_period_us = 5000;
  scan.settle_ms = 50;
  if (command.scene == "ballbar") scan.measure_ball_bar = true;
  scan.overwrite = command.overwrite;
  const int rc = run_scan(scan, console);
  daemon.stop();
  if (rc != exit_ok) return rc;
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  console.info("demo finished in " + std::to_string(static_cast<int>(seconds)) + " s; results in " +
               fs::absolute(out).string() +
               " (open report.html in a browser; model.ply, mesh.ply, mesh.stl, report.json, pictures/)");
  return exit_ok;
}

}  // namespace slscan::app
