// A calibration capture taken through a connected scanner (`slscan calibrate --connect`): for
// each pose of slproto::calibration_pose_guide the user sets the checkerboard (or, on a board
// offering CAPABILITY_CALIBRATION_TARGET, the simulated board places it), the board runs the
// pattern plan along columns and then rows for both projectors, and the host checks at once
// that the board is found and lit (core::check_calibration_pose) and that the pose is not one
// taken already (core::too_similar_problem); after each pose the log says how the poses cover
// the image and the depths (core::pose_set_coverage). Turntable poses are stepped
// by the board (ScanRequest.turntable_angles_deg). Each accepted pose is written to the capture
// folder before the next one starts, so an interrupted capture resumes where it stopped.
#pragma once

#include <chrono>
#include <functional>
#include <stdexcept>
#include <string>

#include "slproto/calibration_poses.hpp"
#include "slscan/core/calibration_coverage.hpp"
#include "slscan/core/calibration_rig.hpp"
#include "slscan/session/scanner_connection.hpp"
#include "slscan/session/session_log.hpp"

namespace slscan::session {

// How the user answers, in interactive mode.
enum class PoseAnswer { ready, quit };

struct CalibrationCaptureRequest {
  ScannerAddress scanner;
  slproto::CheckerboardSize target;         // the printed checkerboard (default: the virtual rig's)
  slproto::PatternPlanConfig pattern_plan;  // along columns; rows use it with axis = rows
  double platform_radius_mm = 150;
  bool turntable = true;                // false: free poses only
  std::string folder;                   // capture folder, written pose by pose ("" = in memory only)
  bool resume = false;                  // `folder` holds poses already: continue after them
  std::uint32_t exposure_us = 0;        // 0: the board's (pattern_timing)
  std::uint32_t pattern_period_us = 0;  // 0: the board's
  std::uint32_t settle_ms = 200;
  std::chrono::milliseconds stall_timeout{60000};  // no frame for this long: the scanner is stuck
  std::string source;                              // for the calibration file; "" = the scanner's address and board
  core::CalibrationOptions options;                // how poses are measured (detection, projector corners, decoding)
  double min_lit_fraction = 0.75;                  // of the board's corners, per projector (core::CalibrationPoseCheck)
  // A pose whose board lies within this share of the board's size in the image of a pose taken
  // (mean corner distance, core::too_similar_problem) is retaken, or refused with --auto; 0: no check.
  double min_pose_shift = core::kMinPoseShiftOfBoard;
  StopFlag stop = nullptr;  // Ctrl-C: abort the running pose, keep the completed ones
  // Interactive mode: asked before every pose the user has to set (the instruction says what),
  // and after a pose that failed its check (`problem` non-empty: answering `ready` retakes it).
  // Unset (--auto): nothing is asked, and a pose that fails its check is an error.
  std::function<PoseAnswer(const slproto::GuidedCalibrationPose& pose, const std::string& problem)> ask;
};

// The capture stopped before its last pose (Ctrl-C, the user quit, a pose that failed its check
// in --auto mode): the message names the pose and where the completed ones are kept.
class CalibrationCaptureStopped : public std::runtime_error {
 public:
  enum class Why { interrupted, quit, pose_rejected };
  CalibrationCaptureStopped(Why reason, const std::string& what) : std::runtime_error(what), why(reason) {}
  Why why;
};

// Throws DeviceError (connection, the board's errors), CalibrationCaptureStopped, io::IoError
// (the folder), std::invalid_argument (a resumed folder that is not this capture). Every
// message that ends a capture with poses completed says where they are and how to resume.
// Returns the poses' measurements (core::calibrate_rig solves from them); the frames are let go
// pose by pose once measured (and written to `folder`), so memory holds one pose's frames at a
// time, not the capture's (~380 MB against ~7.7 GB at full resolution).
core::CalibrationMeasurements capture_calibration(const CalibrationCaptureRequest& request, const SessionLog& log);

}  // namespace slscan::session
