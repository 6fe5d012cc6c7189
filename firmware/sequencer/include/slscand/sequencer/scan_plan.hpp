// A scan request checked against the board that has to run it. A request the board cannot do
// is refused with the reason (an exposure below the DLP's minimum, a period too short for
// exposure + read-out, a pixel format the camera was not set up for, ...).
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include "slproto/calibration_poses.hpp"
#include "slproto/messages.hpp"
#include "slproto/pattern_plan.hpp"
#include "slscand/hal/board.hpp"

namespace slscand {

struct ScanPlan {
  std::uint64_t scan_id = 0;
  std::vector<double> angles_deg;
  std::vector<std::uint32_t> projectors;  // 0 = left, 1 = right
  slproto::PatternPlan patterns;
  Nanos exposure_ns = 0;  // the request's exposure_us: the reference of a bracket
  // What every view is captured at, in order (slproto::exposures_of): one pass per projector at
  // each. One entry, exposure_ns, without a bracket.
  std::vector<Nanos> exposures_ns;
  Nanos period_ns = 0;
  Nanos trigger_delay_ns = 0;  // projector trigger -> camera trigger (gpio-trigger boards)
  Nanos settle_ns = 0;
  hal::PixelFormat pixel_format = hal::PixelFormat::mono8;
  bool timing_events = true;
  // ScanRequest.calibration_target: where a simulated board puts its checkerboard (hardware
  // ignores it; the user places the board).
  std::optional<slproto::CalibrationTargetPlacement> calibration_target;
  std::uint64_t frames_total() const {
    return angles_deg.size() * exposures_ns.size() * projectors.size() * patterns.size();
  }
  // The pattern periods a whole scan takes at the camera (frames plus the waits for each
  // exposure change), turntable moves and settling excluded: what the timing report compares
  // the capture time with.
  std::uint64_t capture_periods(int exposure_change_frames) const;
};

// Bounds on what one request may ask of the board (docs/security.md): beyond them a request is
// a mistake or an attempt to hold the scanner, not a scan.
inline constexpr int kMaxScanViews = 360;                   // one per degree
inline constexpr std::uint32_t kMaxExposureUs = 1'000'000;  // 1 s per pattern
inline constexpr std::uint32_t kMaxPatternPeriodUs = 2'000'000;
inline constexpr std::uint32_t kMaxTriggerDelayUs = 100'000;
inline constexpr std::uint32_t kMaxSettleMs = 60'000;

slproto::Result<ScanPlan> make_scan_plan(const slproto::pb::ScanRequest& request, const hal::BoardConfig& board,
                                         const hal::CameraFormat& camera_format);

slproto::pb::PixelFormat to_proto(hal::PixelFormat format) noexcept;

}  // namespace slscand
