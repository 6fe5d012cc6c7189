// Reconstruction of a recorded capture (.slcap): the same stream the live scan saw, replayed.
#pragma once

#include <string>
#include <vector>

#include "slproto/calibration.hpp"
#include "slscan/core/scan_reconstruction.hpp"
#include "slscan/io/capture_replay.hpp"
#include "slscan/session/session_log.hpp"

namespace slscan::session {

struct ReprocessResult {
  io::CaptureSummary summary;
  std::vector<std::string> missing;  // what the capture lacks against its request, in words
  core::ScanResult reconstruction;
};

// Throws io::IoError for an unreadable capture, one without a request, or a plan that is not
// the calibration's. A truncated capture reconstructs the complete frames before the cut.
// `stop` (Ctrl-C) is checked after each frame and between the final stages: set, it throws
// core::ReconstructionInterrupted naming the stage; running out of memory throws
// core::ReconstructionOutOfMemory naming it.
ReprocessResult reprocess_capture(const std::string& capture_path, const slproto::RigCalibration& calibration,
                                  const core::ReconstructionOptions& options, const SessionLog& log,
                                  StopFlag stop = nullptr);

}  // namespace slscan::session
