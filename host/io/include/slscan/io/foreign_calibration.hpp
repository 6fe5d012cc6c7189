// Calibrations written by other scanners' software, turned into our RigCalibration.
//
// Read formats:
//  * OpenCV FileStorage (.xml / .yml / .yaml / .json written by cv::FileStorage) with either
//    SLStudio's names (camera Kc, kc; projector Kp, kp; projector pose Rp, Tp; optional
//    frameWidth/frameHeight, screenResX/screenResY, cam_error, proj_error) or the common
//    stereo names (K1/D1 or K_cam/D_cam, K2/D2 or K_proj/D_proj, R, T). Distortion vectors
//    hold 4, 5, 8, 12 or 14 OpenCV coefficients; only k1 k2 p1 p2 k3 are modelled, and a
//    non-zero higher coefficient is an error rather than silently dropped.
//  * Our own JSON calibration (slproto::parse_calibration), passed through unchanged.
//
// A foreign file describes one camera and one projector. Our RigCalibration has two projector
// slots (left, right): the projector goes into the left slot and is copied into the right one
// so the calibration passes check(); captures imported from such a rig only ever use
// projector 0. There is no turntable: a placeholder turntable is written whose platform lies
// far behind the camera's working volume, facing the camera, so the turntable clean-up keeps
// every point (see docs/real-data.md).
#pragma once

#include <optional>
#include <string>

#include "slproto/calibration.hpp"

namespace slscan::io {

// Which way the file's projector pose (R, T) maps points. OpenCV's stereoCalibrate and
// SLStudio give proj_from_cam (X_proj = R X_cam + T), the default; some tools store the
// projector's pose in the camera frame (cam_from_proj).
enum class PoseDirection { proj_from_cam, cam_from_proj };

struct ForeignCalibrationOptions {
  PoseDirection pose_direction = PoseDirection::proj_from_cam;
  // Sizes the file may lack (SLStudio stores them; plain stereo files often don't); a size
  // in the file wins when it disagrees with 0 here, and a conflict with a non-zero value is an
  // error.
  int camera_width = 0, camera_height = 0;
  int projector_width = 0, projector_height = 0;
};

// Reads `path` (format chosen by content: JSON with "format_version" is ours, anything else
// goes through cv::FileStorage). Throws IoError naming the file and the missing or bad entry.
slproto::RigCalibration read_foreign_calibration(const std::string& path,
                                                 const ForeignCalibrationOptions& options = {});

// The placeholder turntable of a rig without one (see above).
slproto::TurntableCalibration placeholder_turntable();

}  // namespace slscan::io
