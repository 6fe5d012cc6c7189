// `slscan calibrate`: a calibration capture folder (manifest.json + PNGs,
// io::read_calibration_capture) -> one calibration file, with the report printed and, on
// request, written as JSON. With `virtual_rig` the capture is rendered by the virtual rig instead
// (slrig::calibration_poses), and the result is also compared with the rig's truth.
#pragma once

#include <string>

#include "run.hpp"
#include "slscan/core/calibration_rig.hpp"

namespace slscan::app {

struct CalibrateCommand {
  std::string capture_dir;                       // calibration capture folder ("" with virtual_rig)
  std::string output_path;                       // calibration file (JSON), written atomically
  std::string report_path;                       // "" = no JSON report
  bool no_turntable = false;                     // camera and projectors only
  std::string virtual_rig;                       // "", "small" or "full": render the capture on the virtual rig
  std::string write_capture_dir;                 // virtual_rig only: also write the rendered capture folder
  core::RigCalibrationResult* result = nullptr;  // programmatic callers: the result and report, too
};
int run_calibrate(const CalibrateCommand& command, const Console& console);

// The calibration report as JSON (report.json's "calibration" section and `--report`).
std::string calibration_report_json(const core::CalibrationReport& report);

}  // namespace slscan::app
