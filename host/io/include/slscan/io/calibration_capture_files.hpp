// A calibration capture on disk: a folder with `manifest.json` and one PNG per frame (8-bit, or
// 16-bit for 10/12-bit sensors), the layout `slscan calibrate CAPTURE` reads. Any camera
// software can produce it on a real rig; docs/calibration.md describes the manifest.
#pragma once

#include <string>

#include "slscan/core/calibration_rig.hpp"

namespace slscan::io {

// Reads and validates the folder; throws IoError naming the file and the field that is wrong
// (missing image, wrong size or bit depth, a frame naming a pose or pattern that does not exist).
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
