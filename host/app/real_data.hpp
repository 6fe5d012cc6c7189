// Real captures from other scanners: `slscan import` (images + description + foreign
// calibration -> our capture and calibration files) and `slscan compare` (a reconstruction
// against a reference cloud). docs/real-data.md has the formats and the figures.
#pragma once

#include <string>
#include <vector>

#include "run.hpp"
#include "slscan/core/cloud_compare.hpp"
#include "slscan/io/ply.hpp"

namespace slscan::app {

struct ImportCommand {
  std::string description_path;  // JSON sequence description (images resolve next to it)
  std::string calibration_path;  // OpenCV FileStorage (Kc/kc/Kp/kp/Rp/Tp or K1/D1/K2/D2/R/T) or our JSON
  std::string output_dir;        // gets capture.slcap and calibration.json
  std::string pose_direction = "proj_from_cam";  // how the file's R, T map points (or "cam_from_proj")
};
int run_import(const ImportCommand& command, const Console& console);

struct CompareCommand {
  std::string measured_path;   // PLY
  std::string reference_path;  // PLY
  // Optional calibration (ours, JSON): a camera-frame cloud without u/v properties gets its
  // pixels by projecting its points into the camera (our views/view_N.ply are such clouds).
  std::string calibration_path;
  double max_distance_mm = 5.0;
  int surface_neighbors = 8;
  bool json = false;        // print the figures as JSON on stdout
  std::string report_path;  // also write them as JSON here ("" = no file)
};
int run_compare(const CompareCommand& command, const Console& console);

// A PLY file as a cloud with pixels: u/v properties when it has them, else the projection of
// its points by `camera` when given (points behind the camera or outside the image get no
// pixel), else none.
core::PixelTaggedCloud read_pixel_tagged_ply(const std::string& path, const slproto::PinholeModel* camera);

// SLStudio's Gray-code convention, to compare like with like against its reconstructions.
// Of a Gray code whose `bits_not_projected` (s) lowest bits were not shown, a decoded prefix c
// numbers the 2^s projector columns c 2^s ... (c + 1) 2^s - 1; our decoder returns their centre
// (c 2^s + (2^s - 1) / 2). SLStudio's DecoderGrayCode reads the unshown bits as 0 and converts
// that word to binary, whose low s bits all equal the parity of gray(c), i.e. c's own lowest
// bit: it returns the column c 2^s + (c & 1) (2^s - 1), the first of the group for even c and
// the last for odd c (for s = 1: 2c, 2c + 1, 2c + 2, 2c + 5, ... alternately half a column
// either side of the centre). Rewrites our coordinates (NaN stays NaN) into that convention.
void to_slstudio_gray_columns(std::vector<float>& coordinate, int bits_not_projected);

}  // namespace slscan::app
