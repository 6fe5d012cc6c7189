// A calibration capture on disk: a folder with `manifest.json` and one PNG per frame (8-bit, or
// 16-bit for 10/12-bit sensors), the layout `slscan calibrate CAPTURE` reads. Any camera
// software can produce it on a real rig; docs/calibration.md describes the manifest.
#pragma once

#include <nlohmann/json_fwd.hpp>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "slscan/core/calibration_rig.hpp"

namespace slscan::io {

// A capture folder read pose by pose: the manifest is read and checked at once, a pose's images
// when asked. `slscan calibrate FOLDER` measures each pose and lets its images go, so a capture
// larger than memory (7.7 GB at full resolution) calibrates in one pose's worth (~380 MB).
// Throws IoError naming the file and the field that is wrong (missing image, wrong size or bit
// depth, a frame naming a pose or pattern that does not exist).
class CalibrationCaptureFolder {
 public:
  explicit CalibrationCaptureFolder(const std::string& folder);
  // Every pose and frame, the frames without their images.
  const core::CalibrationCapture& capture() const { return capture_; }
  // The capture with only pose `pose`'s frames, their images read and checked (one channel, the
  // manifest's bit depth, the size of the first image read).
  core::CalibrationCapture read_pose(int pose) const;
  // The image of frame `i` of capture(), checked as above.
  cv::Mat read_frame(std::size_t i) const;

 private:
  void read_manifest(const nlohmann::json& doc, const std::string& origin);

  std::string folder_;
  core::CalibrationCapture capture_;
  std::vector<std::string> files_;    // per frame: its image file
  std::vector<std::string> entries_;  // per frame: its manifest entry ("frames[3]")
  mutable cv::Size size_;             // of the first image read
  mutable std::string size_file_;
};

// Reads and validates the whole folder, every image in memory.
core::CalibrationCapture read_calibration_capture(const std::string& folder);

// Writes the folder complete or not at all: everything goes to `folder.tmp.<pid>` first, which is
// renamed into place at the end (an existing `folder` is an error, nothing is overwritten).
void write_calibration_capture(const core::CalibrationCapture& capture, const std::string& folder);

// For a capture taken pose by pose (`slscan calibrate --connect`): writes the images of pose
// `pose` into `folder` (created if needed), then replaces manifest.json atomically with one
// listing every pose and frame of `capture`. The folder therefore always reads back as the
// poses completed so far: images of a pose cut short are on disk but not in the manifest, and
// are overwritten when it is taken again.
void write_calibration_capture_pose(const core::CalibrationCapture& capture, int pose, const std::string& folder);

}  // namespace slscan::io
