// A scan with a connected scanner: the request sent, every record the board sends recorded to
// a capture file as it arrives (so the scan can be reprocessed and nothing received is lost),
// frames reconstructed while they stream, the model finished after the last frame.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "slproto/calibration.hpp"
#include "slproto/messages.hpp"
#include "slscan/core/scan_reconstruction.hpp"
#include "slscan/session/exposure_metering.hpp"
#include "slscan/session/scanner_connection.hpp"
#include "slscan/session/session_log.hpp"

namespace slscan::session {

struct LiveScanRequest {
  ScannerAddress scanner;
  std::vector<double> angles_deg{0, 60, 120, 180, 240, 300};
  std::vector<std::uint32_t> projectors{0, 1};
  std::uint32_t exposure_us = 0;  // 0: the board's (pattern_timing)
  // HDR: every view captured at each of these exposures (us), merged per pixel by the host
  // (docs/hdr.md); exposure_us is then the reference intensities are scaled to. Empty: one.
  std::vector<std::uint32_t> exposure_bracket_us;
  // Set: a metering pass picks the exposure or the bracket (and the period) first
  // (exposure_metering.hpp); exposure_us is then where its ladder centres, and
  // exposure_bracket_us must be empty.
  std::optional<AutoExposureRequest> auto_exposure;
  std::uint32_t pattern_period_us = 0;  // 0: the board's
  std::uint32_t settle_ms = 200;
  std::string capture_path;  // the capture file to record (written to a partial name, renamed when complete)
  bool compress = false;     // store frames zstd-compressed (lossless; docs/scale.md)
  StopFlag stop = nullptr;   // set: ask the board to abort, keep what arrived
  // No frame for this long (the board alive, its heartbeats arriving): the scan fails, keeping
  // what arrived. Covers the longest turntable move plus settle between two views.
  std::chrono::milliseconds stall_timeout{60000};
};

struct LiveScanResult {
  slproto::pb::HelloReply board;
  bool aborted = false;                          // stopped on request; `reconstruction` is empty
  std::size_t frames = 0;                        // frames received (every one is in the capture)
  std::size_t frames_expected = 0;               // frames the scan request asks for
  std::optional<slproto::pb::ScanDone> done;     // the board's end-of-scan statistics
  std::optional<MeteredExposure> auto_exposure;  // what the metering pass chose
  // Set: the host ran out of memory in this stage while frames arrived; `reconstruction` is
  // empty and the capture holds every frame received (all of them when `done` is set and the
  // scan was not aborted: decoding was given up, recording went on).
  std::optional<std::string> out_of_memory_stage;
  std::optional<core::ScanResult> reconstruction;
  double last_frame_to_model_s = 0;
  std::string capture_sha256;  // of the complete capture, set with `reconstruction`
};

// Throws DeviceError (connection, the board's errors; the message says where the partial
// capture is), io::IoError (the capture cannot be written) or std::invalid_argument (an
// impossible request).
LiveScanResult run_live_scan(const LiveScanRequest& request, const slproto::RigCalibration& calibration,
                             const core::ReconstructionOptions& options, const SessionLog& log);

}  // namespace slscan::session
