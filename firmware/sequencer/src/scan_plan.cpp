#include "slscand/sequencer/scan_plan.hpp"

#include <algorithm>
#include <string>

namespace slscand {

using slproto::Errc;
using slproto::make_error;

slproto::pb::PixelFormat to_proto(hal::PixelFormat format) noexcept {
  switch (format) {
    case hal::PixelFormat::mono8:
      return slproto::pb::PIXEL_FORMAT_MONO8;
    case hal::PixelFormat::mono10:
      return slproto::pb::PIXEL_FORMAT_MONO10;
    case hal::PixelFormat::mono12:
      return slproto::pb::PIXEL_FORMAT_MONO12;
  }
  return slproto::pb::PIXEL_FORMAT_UNSPECIFIED;
}

slproto::Result<ScanPlan> make_scan_plan(const slproto::pb::ScanRequest& request, const hal::BoardConfig& board,
                                         const hal::CameraFormat& camera_format) {
  auto refuse = [&](Errc code, const std::string& why) {
    return make_error(code,
                      "scan " + std::to_string(request.scan_id()) + " refused by board '" + board.name + "': " + why);
  };
  if (auto s = slproto::check_scan_request(request, 2); !s) return refuse(s.error().code, s.error().message);
  auto over = [&](const char* field, std::uint64_t value, std::uint64_t limit) {
    return refuse(Errc::invalid_argument,
                  std::string(field) + " " + std::to_string(value) + " is over the limit of " + std::to_string(limit));
  };
  if (request.turntable_angles_deg_size() > kMaxScanViews)
    return over("views (turntable_angles_deg)", static_cast<std::uint64_t>(request.turntable_angles_deg_size()),
                kMaxScanViews);
  if (request.exposure_us() > kMaxExposureUs) return over("exposure_us", request.exposure_us(), kMaxExposureUs);
  if (request.pattern_period_us() > kMaxPatternPeriodUs)
    return over("pattern_period_us", request.pattern_period_us(), kMaxPatternPeriodUs);
  if (request.trigger_delay_us() > kMaxTriggerDelayUs)
    return over("trigger_delay_us", request.trigger_delay_us(), kMaxTriggerDelayUs);
  if (request.settle_ms() > kMaxSettleMs) return over("settle_ms", request.settle_ms(), kMaxSettleMs);
  auto config = slproto::from_proto(request.plan());
  if (!config) return refuse(Errc::invalid_argument, config.error().message);
  auto patterns = slproto::PatternPlan::make(*config);
  if (!patterns) return refuse(Errc::invalid_argument, patterns.error().message);

  ScanPlan plan;
  plan.scan_id = request.scan_id();
  plan.angles_deg.assign(request.turntable_angles_deg().begin(), request.turntable_angles_deg().end());
  plan.projectors.assign(request.projectors().begin(), request.projectors().end());
  plan.patterns = std::move(*patterns);
  plan.exposure_ns = static_cast<Nanos>(request.exposure_us()) * kMicro;
  for (const std::uint32_t exposure_us : slproto::exposures_of(request))
    plan.exposures_ns.push_back(static_cast<Nanos>(exposure_us) * kMicro);
  plan.period_ns = static_cast<Nanos>(request.pattern_period_us()) * kMicro;
  plan.trigger_delay_ns = static_cast<Nanos>(request.trigger_delay_us()) * kMicro;
  plan.settle_ns = static_cast<Nanos>(request.settle_ms() != 0 ? request.settle_ms() : board.settle_ms * 1000) * kMicro;
  plan.timing_events = request.timing_events();
  if (request.has_calibration_target()) {
    auto target = slproto::from_proto(request.calibration_target());
    if (!target) return refuse(Errc::invalid_argument, target.error().message);
    plan.calibration_target = std::move(*target);
  }

  // The DLP4500 shows one 8-bit pattern for at least 8333 us; 1-bit patterns go down to 235 us.
  if (request.exposure_us() < 235) {
    return refuse(Errc::unsupported,
                  "exposure_us " + std::to_string(request.exposure_us()) + " is below the projector's 235 us minimum");
  }
  for (int i = 0; i < request.exposure_bracket_us_size(); ++i) {
    const std::uint32_t exposure_us = request.exposure_bracket_us(i);
    const std::string name = "exposure_bracket_us[" + std::to_string(i) + "] = " + std::to_string(exposure_us);
    if (exposure_us < 235) return refuse(Errc::unsupported, name + " is below the projector's 235 us minimum");
    if (exposure_us > kMaxExposureUs)
      return over(("exposure_bracket_us[" + std::to_string(i) + "]").c_str(), exposure_us, kMaxExposureUs);
  }
  if (plan.patterns.size() > 32) {
    return refuse(Errc::unsupported, "the plan has " + std::to_string(plan.patterns.size()) +
                                         " patterns; the projectors hold 32 8-bit patterns");
  }
  const double readout_us = board.readout_us;
  const std::uint32_t longest_us = std::ranges::max(slproto::exposures_of(request));
  const double needed_us = static_cast<double>(request.trigger_delay_us()) +
                           std::max(request.exposure_us(), longest_us) + readout_us + board.projector_latency_us;
  if (request.pattern_period_us() < needed_us) {
    return refuse(Errc::unsupported, "pattern_period_us " + std::to_string(request.pattern_period_us()) +
                                         " is shorter than trigger delay + exposure + read-out (" +
                                         std::to_string(static_cast<long long>(needed_us)) + " us on this board)");
  }
  if (board.trigger_source == hal::CameraTriggerSource::projector && request.trigger_delay_us() != 0) {
    return refuse(Errc::unsupported,
                  "trigger_delay_us must be 0: on this board the projectors' TRIG_OUT_1 trigger the "
                  "camera directly");
  }
  if (request.pixel_format() != slproto::pb::PIXEL_FORMAT_UNSPECIFIED &&
      request.pixel_format() != to_proto(camera_format.pixel_format)) {
    return refuse(Errc::unsupported, std::string("pixel_format ") + slproto::pixel_format_name(request.pixel_format()) +
                                         ": the camera is set up for " +
                                         hal::pixel_format_name(camera_format.pixel_format));
  }
  plan.pixel_format = camera_format.pixel_format;
  return plan;
}

std::uint64_t ScanPlan::capture_periods(int exposure_change_frames) const {
  // Each view waits for the change to every bracket member but the first: the change back to
  // the first is made before the turntable moves, and the move and settling cover it.
  const std::uint64_t changes_per_view = exposures_ns.size() - std::min<std::size_t>(exposures_ns.size(), 1);
  return frames_total() +
         angles_deg.size() * changes_per_view * static_cast<std::uint64_t>(std::max(0, exposure_change_frames));
}

}  // namespace slscand
