// `slscan calibrate`: a calibration capture -> one calibration file, with the report printed
// and, on request, written as JSON. The capture comes from a folder (manifest.json + PNGs,
// io::read_calibration_capture), from a scanner pose by pose (--connect,
// session::capture_calibration), or from the virtual rig (--virtual: slscand started on the sim
// board and driven as a scanner, the result also compared with the rig's exact calibration).
#pragma once

#include <cstdint>
#include <string>

#include "run.hpp"
#include "slproto/calibration_poses.hpp"
#include "slscan/core/calibration_rig.hpp"

namespace slscan::app {

struct CalibrateCommand {
  std::string capture_dir;        // calibration capture folder ("" with virtual_rig)
  std::string output_path;        // calibration file (JSON), written atomically
  std::string report_path;        // "" = no JSON report
  bool no_turntable = false;      // camera and projectors only
  std::string virtual_rig;        // "", "small" or "full": capture through slscand on the sim board
  std::string slscand_path;       // --virtual: "" = find_slscand's
  std::string board_path;         // --virtual: sim board file to start from ("" = boards/sim.toml)
  std::string write_capture_dir;  // --virtual / --connect: also write the capture folder
  // --connect HOST[:PORT]: capture through the scanner, pose by pose (session::capture_calibration).
  std::string connect;
  std::string token_file;
  bool auto_mode = false;            // --auto: do not wait for the user at each pose
  std::string resume_dir;            // --resume DIR: continue the capture in DIR (and keep writing there)
  slproto::CheckerboardSize target;  // the printed checkerboard
  double platform_radius_mm = 150;
  std::uint32_t exposure_us = 0;        // 0: the board's [timing] pattern_exposure_us
  std::uint32_t pattern_period_us = 0;  // 0: the board's pattern_period_us
  std::uint32_t settle_ms = 200;
  core::RigCalibrationResult* result = nullptr;  // programmatic callers: the result and report, too
};
int run_calibrate(const CalibrateCommand& command, const Console& console);

// The calibration report as JSON (report.json's "calibration" section and `--report`).
std::string calibration_report_json(const core::CalibrationReport& report);

}  // namespace slscan::app
