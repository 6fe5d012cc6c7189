// Calibrations written by other scanners' software, turned into our RigCalibration.
//
// Read formats (docs/real-data.md, "Calibration formats"):
//  * OpenCV FileStorage (.xml / .yml / .yaml / .json written by cv::FileStorage), one file or
//    several (OpenCV's stereo sample writes intrinsics.yml and extrinsics.yml), with one of the
//    built-in key sets (kCalibrationKeySets: SLStudio's Kc kc Kp kp Rp Tp; the OpenCV stereo
//    sample's M1 D1 M2 D2 R T and its variants K1/D1/K2/D2, cameraMatrix1/distCoeffs1/...,
//    K_cam/K_proj; MATLAB's stereoParametersToOpenCV names intrinsicMatrix1/...), or the
//    names given explicitly (CalibrationKeys, the import description's calibration_keys).
//    Distortion vectors hold 4, 5, 8, 12 or 14 OpenCV coefficients; only k1 k2 p1 p2 k3 are
//    modelled, and a non-zero higher coefficient is an error rather than silently dropped.
//  * ROS camera_info YAML, two files (camera, then projector): camera_matrix, distortion
//    coefficients, image size; the pose from the rectification matrices and the projector's
//    projection matrix (its Tx = -fx B), in metres.
//  * Kalibr camchain YAML: cam0 (camera) and cam1 (projector) with intrinsics [fu fv pu pv],
//    radtan distortion_coeffs, resolution, and cam1's T_cn_cnm1 (cam1 from cam0), in metres.
//  * Our own JSON calibration (slproto::parse_calibration), passed through unchanged.
//
// A foreign file describes one camera and one projector. Our RigCalibration has two projector
// slots (left, right): the projector goes into the left slot and is copied into the right one
// so the calibration passes check(); captures imported from such a rig only ever use
// projector 0. There is no turntable: a placeholder turntable is written whose platform lies
// far behind the camera's working volume, facing the camera, so the turntable clean-up keeps
// every point (see docs/real-data.md).
#pragma once

#include <map>
#include <optional>
#include <string>
#include <vector>

#include "slproto/calibration.hpp"

namespace slscan::io {

// Which way the file's projector pose (R, T) maps points. OpenCV's stereoCalibrate and
// SLStudio give proj_from_cam (X_proj = R X_cam + T), the default; some tools store the
// projector's pose in the camera frame (cam_from_proj).
enum class PoseDirection { proj_from_cam, cam_from_proj };

// The names of one calibration's entries (matrices as cv::FileStorage matrices or lists).
struct CalibrationKeys {
  std::string name;  // of the set, for messages
  std::string camera_matrix, camera_distortion, projector_matrix, projector_distortion, rotation, translation;
  std::string camera_width, camera_height, projector_width, projector_height;  // optional
  std::string camera_error, projector_error;                                   // optional
  double translation_to_mm = 1;                                                // 1000 for a calibration in metres
};

// The built-in sets, tried in this order.
const std::vector<CalibrationKeys>& calibration_key_sets();

// An explicit mapping (the description's calibration_keys): field -> key in the file, plus
// "translation_unit": "mm" (default) or "m". Throws IoError naming an unknown field.
CalibrationKeys calibration_keys_from(const std::map<std::string, std::string>& mapping, const std::string& origin);

struct ForeignCalibrationOptions {
  std::vector<std::string> more_paths;  // further files of the same calibration (merged)
  std::optional<CalibrationKeys> keys;  // explicit names instead of the built-in sets
  PoseDirection pose_direction = PoseDirection::proj_from_cam;
  // Sizes the file may lack (SLStudio stores them; plain stereo files often don't); a size
  // in the file wins when it disagrees with 0 here, and a conflict with a non-zero value is an
  // error.
  int camera_width = 0, camera_height = 0;
  int projector_width = 0, projector_height = 0;
  // The parser's budget. OpenCV's FileStorage hangs on some malformed YAML and allocates what a
  // file declares (docs/security.md, fuzz findings 11-12): the files are parsed in a child
  // process limited to this much CPU time and this much address space beyond the parent's; a
  // hang, a crash or an exhausted budget there is an IoError naming the file.
  int parser_cpu_seconds = 3;
  int parser_memory_mb = 1024;
};

// Reads `path` (format chosen by content: JSON with "format_version" is ours, anything else
// goes through cv::FileStorage) in a child process within options' CPU and memory budget; the
// result is passed back as our JSON calibration (exactly what the parser built). Throws
// IoError naming the file and the missing or bad entry, or what ended the parser.
slproto::RigCalibration read_foreign_calibration(const std::string& path,
                                                 const ForeignCalibrationOptions& options = {});

// The same parser in this process, without the budget: what the child runs, and what the fuzz
// target calls (coverage is only seen in-process). Never call it on untrusted files elsewhere.
slproto::RigCalibration read_foreign_calibration_in_process(const std::string& path,
                                                            const ForeignCalibrationOptions& options = {});

// The placeholder turntable of a rig without one (see above).
slproto::TurntableCalibration placeholder_turntable();

}  // namespace slscan::io
