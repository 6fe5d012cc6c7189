// From images to corner observations: the checkerboard's inner corners in a camera image,
// and each corner's projector coordinates from the decoded pattern maps in both axes through a
// local homography fitted to the decoded pixels around the corner (Moreno and Taubin, "Simple,
// accurate, and robust projector-camera calibration", 3DIMPVT 2012). The homography is the
// right local model: near a corner the target is a plane, and camera pixel -> target plane ->
// projector pixel is a homography up to the lenses' (slowly varying) distortion.
#pragma once

#include <array>
#include <opencv2/core.hpp>
#include <string>

#include "slscan/core/calibration_target.hpp"
#include "slscan/core/decode.hpp"

namespace slscan::core {

struct CornerDetectionOptions {
  // false: the sector-based cv::findChessboardCornersSB, falling back to the classic
  // cv::findChessboardCorners where it fails; true: the sector-based one only. Either way
  // the corners are refined with cv::cornerSubPix (the sector-based corners alone scatter by
  // ~0.25 px on a synthetic board with 1 DN of noise, refined ones by ~0.07 px).
  bool sector_based = false;
  int subpixel_half_window = 10;  // upper bound; also kept within 0.35 of the corner spacing
  // Gaussian blur (camera px) of the image cornerSubPix works on. Edges only a pixel wide lock
  // the refined corner to the pixel grid (virtual rig, noise off: 0.053 px RMS to the truth
  // unblurred, 0.037 px at 0.7); a real lens's blur does the same job. 0: none.
  double subpixel_smoothing_sigma = 0.7;
  // The sector-based search on an image of more pixels than this looks at a half-size copy
  // first (the full image where that finds no board); cornerSubPix refines its corners on the
  // full image either way. Its time and memory grow with the pixels (4.7 s a pose at 2464 x 2056,
  // mostly on one core: docs/calibration.md, "Memory and time"). 0: always the full image.
  std::size_t search_max_pixels = 2'000'000;
};

struct CornerDetection {
  bool found = false;
  std::string reason;    // why not, when !found
  int search_scale = 1;  // 2: the board was found on a half-size copy (search_max_pixels)
  TargetView view;       // every inner corner, ids row-major as in CheckerboardTarget
};

// Finds all inner corners of `target` in an 8- or 16-bit single-channel image. A missing or
// partly hidden board is not an error: found = false with the reason.
CornerDetection detect_checkerboard(const cv::Mat& image, const CheckerboardTarget& target,
                                    const CornerDetectionOptions& options = {});

struct ProjectorCornerOptions {
  // Half size of the square window of camera pixels around each corner; 0 picks 0.45 of the
  // distance to the nearest neighbouring corner, so the window stays on the target's squares.
  int half_window_px = 0;
  int min_pixels = 24;                 // decoded pixels (both axes) needed in the window
  double max_pixel_residual_px = 1.0;  // pixels farther than this from the first fit are dropped
  double max_fit_rms_px = 0.5;         // a corner whose fit is worse than this is not used
};

struct ProjectorCorners {
  TargetView view;  // projector (x, y) of the corners that could be measured
  int rejected_few_pixels = 0, rejected_bad_fit = 0;
  double mean_fit_rms_px = 0;  // RMS of the decoded pixels about their local homography
};

// `columns` and `rows` are the same camera view decoded along each axis (same size).
ProjectorCorners projector_corners(const TargetView& camera_corners, const DecodedView& columns,
                                   const DecodedView& rows, const ProjectorCornerOptions& options = {});

}  // namespace slscan::core
