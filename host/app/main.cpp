// slscan: the host command. A thin table of subcommands over the run_* functions.
#include <CLI/CLI.hpp>
#include <iostream>

#include "calibrate.hpp"
#include "real_data.hpp"
#include "run.hpp"
#include "slscan/io/ply.hpp"
#include "status.hpp"

namespace {

using namespace slscan::app;

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"slscan: structured-light 3D scanning host (scan, reprocess, calibrate, measure, demo)"};
  app.require_subcommand(1);
  Console console;
  app.add_flag("-q,--quiet", console.quiet, "Print nothing but errors and the final figures");
  app.add_flag("--json-log", console.json_log, "Log as one JSON object per line on stderr");

  ReprocessRequest reprocess;
  auto* reprocess_cmd = app.add_subcommand("reprocess", "Reconstruct a recorded capture file");
  reprocess_cmd->add_option("capture", reprocess.capture_path, "Capture file (.slcap)")
      ->required()
      ->check(CLI::ExistingFile);
  reprocess_cmd->add_option("--calib", reprocess.calibration_path, "Calibration file (JSON)")
      ->required()
      ->check(CLI::ExistingFile);
  reprocess_cmd->add_option("--out", reprocess.output_dir, "Output folder")->required();
  reprocess_cmd->add_option("--config", reprocess.config_path, "Reconstruction parameters (JSON)")
      ->check(CLI::ExistingFile);

  ScanCommand scan;
  std::string connect = "127.0.0.1:7878";
  auto* scan_cmd = app.add_subcommand("scan", "Scan with a connected scanner, record the capture and reconstruct it");
  scan_cmd->add_option("--connect", connect, "Scanner address HOST:PORT")->capture_default_str();
  scan_cmd->add_option("--calib", scan.calibration_path, "Calibration file (JSON)")
      ->required()
      ->check(CLI::ExistingFile);
  scan_cmd->add_option("--out", scan.output_dir, "Output folder")->required();
  scan_cmd->add_option("--config", scan.config_path, "Reconstruction parameters (JSON)")->check(CLI::ExistingFile);
  scan_cmd->add_option("--angles", scan.angles_deg, "Turntable angles in degrees")->capture_default_str();
  scan_cmd->add_option("--projectors", scan.projectors, "Projector ids (0 left, 1 right)")->capture_default_str();
  scan_cmd->add_option("--exposure-us", scan.exposure_us, "Exposure per pattern")->capture_default_str();
  scan_cmd->add_option("--period-us", scan.pattern_period_us, "Pattern period")->capture_default_str();
  scan_cmd->add_option("--settle-ms", scan.settle_ms, "Turntable settle time")->capture_default_str();
  scan_cmd->add_option("--token-file", scan.token_file, "File holding the scanner's shared token");
  scan_cmd->add_flag("--measure-ballbar", scan.measure_ball_bar,
                     "Fit the ball bar in the model and put its figures in the reports");

  StatusCommand status;
  auto* status_cmd =
      app.add_subcommand("status", "Show a scanner's board, firmware and protocol versions and its last scan");
  status_cmd->add_option("scanner", status.address, "HOST[:PORT] (port 7878 unless given)")->required();
  status_cmd->add_option("--token-file", status.token_file, "File holding the scanner's shared token");
  status_cmd->add_flag("--json", status.json, "Print the status as JSON");

  DiscoverCommand discover;
  auto* discover_cmd = app.add_subcommand("discover", "Find scanners on the local network (mDNS/DNS-SD via Avahi)");
  discover_cmd->add_option("--wait", discover.wait_s, "Seconds to listen for answers")->capture_default_str();
  discover_cmd->add_flag("--json", discover.json, "Print the scanners as JSON");

  MeasureCommand measure;
  auto* measure_cmd = app.add_subcommand("measure", "Fit an artefact in a model and print its figures");
  measure_cmd->add_option("model", measure.model_path, "Point cloud (PLY)")->required()->check(CLI::ExistingFile);
  bool want_ballbar = false, want_sphere = false, want_plane = false;
  auto* ballbar_flag = measure_cmd->add_flag("--ballbar", want_ballbar,
                                             "Two spheres: diameters, form errors, centre distance (default)");
  auto* sphere_flag = measure_cmd->add_flag("--sphere", want_sphere, "One sphere: diameter and form error");
  auto* plane_flag = measure_cmd->add_flag("--plane", want_plane, "A plane: flatness");
  ballbar_flag->excludes(sphere_flag)->excludes(plane_flag);
  sphere_flag->excludes(plane_flag);
  measure_cmd->add_option("--reference-mm", measure.reference_distance_mm, "Ball bar's calibrated centre distance")
      ->capture_default_str();
  measure_cmd->add_flag("--json", measure.json, "Print the figures as JSON");

  CalibrateCommand calibrate;
  auto* calibrate_cmd =
      app.add_subcommand("calibrate", "Calibrate camera, projectors and turntable from a calibration capture");
  calibrate_cmd->add_option("capture", calibrate.capture_dir, "Calibration capture folder (manifest.json + PNGs)")
      ->check(CLI::ExistingDirectory);
  calibrate_cmd->add_option("--out", calibrate.output_path, "Calibration file to write (JSON)")->required();
  calibrate_cmd->add_option("--report", calibrate.report_path, "Also write the calibration report (JSON)");
  calibrate_cmd->add_flag("--no-turntable", calibrate.no_turntable, "Camera and projectors only");
#ifdef SLSCAN_WITH_DEMO
  calibrate_cmd
      ->add_option("--virtual", calibrate.virtual_rig,
                   "Render the virtual rig's calibration capture (small or full) instead of reading one")
      ->check(CLI::IsMember({"small", "full"}));
  calibrate_cmd->add_option("--write-capture", calibrate.write_capture_dir,
                            "With --virtual: also write the rendered capture folder");
#endif

  ImportCommand import;
  auto* import_cmd = app.add_subcommand(
      "import", "Turn another scanner's images, sequence description and calibration into a capture");
  import_cmd->add_option("description", import.description_path, "Sequence description (JSON, docs/real-data.md)")
      ->required()
      ->check(CLI::ExistingFile);
  import_cmd->add_option("--calib", import.calibration_path, "Calibration: OpenCV FileStorage or ours (JSON)")
      ->required()
      ->check(CLI::ExistingFile);
  import_cmd->add_option("--out", import.output_dir, "Output folder (capture.slcap, calibration.json)")->required();
  import_cmd->add_option("--pose-direction", import.pose_direction, "How the file's R, T map points")
      ->check(CLI::IsMember({"proj_from_cam", "cam_from_proj"}))
      ->capture_default_str();

  CompareCommand compare;
  auto* compare_cmd = app.add_subcommand("compare", "Differences between a measured cloud and a reference cloud");
  compare_cmd->add_option("measured", compare.measured_path, "Measured cloud (PLY)")
      ->required()
      ->check(CLI::ExistingFile);
  compare_cmd->add_option("reference", compare.reference_path, "Reference cloud (PLY)")
      ->required()
      ->check(CLI::ExistingFile);
  compare_cmd
      ->add_option("--calib", compare.calibration_path, "Calibration, to find camera pixels of clouds without u, v")
      ->check(CLI::ExistingFile);
  compare_cmd->add_option("--max-distance", compare.max_distance_mm, "Farther points count as unmatched (mm)")
      ->capture_default_str();
  compare_cmd->add_option("--neighbors", compare.surface_neighbors, "Reference points per local surface")
      ->capture_default_str();
  compare_cmd
      ->add_flag("--project-pixels", compare.project_pixels,
                 "Pixels of both clouds from --calib's camera even where the PLY has u, v (SLStudio's u, v are of "
                 "its undistorted image)")
      ->needs("--calib");
  compare_cmd->add_flag("--json", compare.json, "Print the figures as JSON");
  compare_cmd->add_option("--report", compare.report_path, "Also write the figures to this JSON file");

#ifdef SLSCAN_WITH_DEMO
  DemoCommand demo;
  auto* demo_cmd = app.add_subcommand("demo", "Start slscand on the sim board, scan a scene and reconstruct it");
  demo_cmd->add_option("--scene", demo.scene, "ballbar, sphere, plane, blade or teacup")->capture_default_str();
  demo_cmd->add_option("--out", demo.output_dir, "Output folder")->capture_default_str();
  demo_cmd->add_flag("--small", demo.small, "The 640 x 512 rig: a quick run");
  demo_cmd->add_flag("--true-calibration", demo.true_calibration,
                     "Scan with the rig's exact calibration instead of calibrating it first");
  demo_cmd->add_option("--config", demo.config_path, "Reconstruction parameters (JSON)")->check(CLI::ExistingFile);
  demo_cmd->add_option("--slscand", demo.slscand_path, "slscand executable")->check(CLI::ExistingFile);
  demo_cmd->add_option("--board", demo.board_path, "Sim board file to start from")->check(CLI::ExistingFile);

#endif

  CLI11_PARSE(app, argc, argv);
  install_interrupt_handler();
  try {
    if (*reprocess_cmd) return run_reprocess(reprocess, console);
    if (*scan_cmd) {
      std::tie(scan.host, scan.port) = parse_scanner_address(connect);
      return run_scan(scan, console);
    }
    if (*status_cmd) return run_status(status, console);
    if (*discover_cmd) return run_discover(discover, console);
    if (*import_cmd) return run_import(import, console);
    if (*calibrate_cmd) return run_calibrate(calibrate, console);
    if (*compare_cmd) return run_compare(compare, console);
#ifdef SLSCAN_WITH_DEMO
    if (*demo_cmd) return run_demo(demo, console);
#endif
    if (*measure_cmd) {
      measure.artefact = want_sphere ? Artefact::sphere : (want_plane ? Artefact::plane : Artefact::ball_bar);
      return run_measure(measure, console);
    }
  } catch (const slscan::io::IoError& e) {
    std::cerr << "slscan: " << e.what() << "\n";
    return exit_bad_input;
  } catch (const std::invalid_argument& e) {
    std::cerr << "slscan: " << e.what() << "\n";
    return exit_bad_input;
  } catch (const DeviceError& e) {
    std::cerr << "slscan: " << e.what() << "\n";
    return exit_device;
  } catch (const std::exception& e) {
    std::cerr << "slscan: internal error: " << e.what() << "\n";
    return exit_internal;
  }
  return exit_usage;
}
