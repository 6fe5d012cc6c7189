// Real captures from other scanners: `slscan import` (images + description + foreign
// calibration -> our capture and calibration files) and `slscan compare` (a reconstruction
// against a reference cloud). docs/real-data.md has the formats and the figures.
#pragma once

#include <string>
#include <vector>

#include "run.hpp"
#include "slscan/core/cloud_compare.hpp"
#include "slscan/io/io_error.hpp"

namespace slscan::app {

struct ImportCommand {
  std::string description_path;  // JSON sequence description (images resolve next to it)
  std::string calibration_path;  // OpenCV FileStorage (Kc/kc/Kp/kp/Rp/Tp or K1/D1/K2/D2/R/T) or our JSON
  std::vector<std::string> more_calibration_paths;  // further files of the calibration (merged; ROS: the projector's)
  std::string output_dir;                           // gets capture.slcap and calibration.json
  std::string pose_direction = "proj_from_cam";     // how the file's R, T map points (or "cam_from_proj")
  // Try the conventions a description can get wrong and import with the one the data agrees
  // with best; writes DIR/description.json (the corrected description) and DIR/detect.json.
  bool detect = false;
  // Write the capture even when the self-checks find that it contradicts its description.
  bool force = false;
};
int run_import(const ImportCommand& command, const Console& console);

struct CompareCommand {
  std::string measured_path;   // PLY
  std::string reference_path;  // PLY
  // Optional calibration (ours, JSON): a camera-frame cloud without u/v properties gets its
  // pixels by projecting its points into the camera (our views/view_N.ply are such clouds).
  std::string calibration_path;
  // Take both clouds' pixels from the calibration's camera even when the PLY has u/v: for
  // clouds whose u/v are not the frames' pixels (SLStudio stores its undistorted image's).
  bool project_pixels = false;
  double max_distance_mm = 5.0;  // > 0
  // Fewer than this share of the measured points within max_distance_mm of the reference: a
  // warning naming the likely cause (the clouds are in different frames) and exit_unmatched.
  double min_matched = 0.5;
  int surface_neighbors = 8;
  bool json = false;        // print the figures as JSON on stdout
  std::string report_path;  // also write them as JSON here ("" = no file)
};
int run_compare(const CompareCommand& command, const Console& console);

// A PLY file as a cloud with pixels: u/v properties when it has them (unless
// `ignore_stored_pixels`), else the projection of its points by `camera` when given (points
// behind the camera or outside the image get no pixel), else none.
core::PixelTaggedCloud read_pixel_tagged_ply(const std::string& path, const slproto::PinholeModel* camera,
                                             bool ignore_stored_pixels = false);

}  // namespace slscan::app
