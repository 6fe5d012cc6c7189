// Auto-exposure's metering pass (docs/hdr.md, "Auto-exposure"): before a scan, the board shows
// white and black at the first view over a ladder of exposures (one bracketed scan of a
// two-frame plan); core::choose_exposures picks the scan's exposure or bracket from them.
// Nothing of the metering pass is recorded: the scan's capture starts with the request that
// carries the chosen exposures, and its report holds the choice.
#pragma once

#include <chrono>
#include <cstdint>
#include <vector>

#include "slproto/calibration.hpp"
#include "slproto/messages.hpp"
#include "slproto/transport.hpp"
#include "slscan/core/auto_exposure.hpp"
#include "slscan/core/scan_reconstruction.hpp"
#include "slscan/session/scanner_connection.hpp"
#include "slscan/session/session_log.hpp"

namespace slscan::session {

struct AutoExposureRequest {
  double time_budget_s = 0;  // the scan's pattern frames, not counting turntable moves; 0: none
  int mains_hz = 0;          // 50 / 60: exposures in whole periods of the lights' flicker
  double max_saturated_share = 0.01;
  double max_dark_share = 0.01;
};

// What the scan is to be: the exposure (the reference), the bracket (empty: one exposure) and
// the period, with the choice as metered.
struct MeteredExposure {
  std::uint32_t exposure_us = 0;
  std::vector<std::uint32_t> bracket_us;
  std::uint32_t period_us = 0;
  core::AutoExposureChoice choice;
};

struct MeteringScan {
  double first_angle_deg = 0;
  std::vector<std::uint32_t> projectors;
  std::uint32_t exposure_us = 0;  // 0: the board's
  std::uint32_t period_us = 0;    // 0: the board's
  std::uint32_t settle_ms = 200;
  std::size_t scan_frames_per_exposure = 0;  // views x projectors x the plan's frames
  std::chrono::milliseconds stall_timeout{60000};
  StopFlag stop = nullptr;
};

// Throws DeviceError (a board without brackets, the connection, the board's errors, Ctrl-C)
// or std::invalid_argument (limits nothing fits: the time budget, the mains).
MeteredExposure meter_exposure(ScannerConnection& scanner, const MeteringScan& scan, const AutoExposureRequest& request,
                               const slproto::RigCalibration& calibration, const core::ReconstructionOptions& options,
                               const SessionLog& log);

}  // namespace slscan::session
