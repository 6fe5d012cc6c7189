// How far one calibration is from another, in the terms of docs/calibration.md: focal lengths
// in per cent, principal points in pixels, each projector's pose in mm and degrees, the
// turntable's axis and plane. For checking an estimated calibration against a reference (the
// virtual rig's exact one, or last month's calibration of the same scanner).
#pragma once

#include <array>
#include <string>

#include "slproto/calibration.hpp"

namespace slscan::core {

struct CalibrationDifference {
  // Estimated minus reference; focal lengths relative, in per cent. *_rms_px: the estimated
  // calibration's own reprojection RMS.
  double camera_fx_pct = 0, camera_fy_pct = 0, camera_cx_px = 0, camera_cy_px = 0, camera_rms_px = 0;
  struct Projector {
    double fx_pct = 0, fy_pct = 0, cx_px = 0, cy_px = 0, translation_mm = 0, rotation_deg = 0, rms_px = 0;
  };
  std::array<Projector, 2> projectors;
  double axis_direction_deg = 0;
  double axis_position_mm = 0;  // the reference platform centre's distance from the estimated axis
  double plane_mm = 0;          // the reference platform centre's height above the estimated plane

  std::string table() const;  // one line per device, for the console, benches and tests
};

CalibrationDifference calibration_difference(const slproto::RigCalibration& estimated,
                                             const slproto::RigCalibration& reference);

}  // namespace slscan::core
