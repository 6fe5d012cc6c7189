#include "slscan/session/exposure_metering.hpp"

#include <algorithm>
#include <cstring>
#include <map>
#include <string>
#include <utility>

#include "slproto/number_text.hpp"
#include "slproto/pattern_plan.hpp"

namespace slscan::session {

using Clock = std::chrono::steady_clock;

namespace {

constexpr double kProjectorMinimumUs = 235;  // the DLP's shortest 1-bit pattern (make_scan_plan)
constexpr double kLongestExposureUs = 1e6;   // the board's limit (make_scan_plan)

// White and black only: the scan's projector and axis, one period as wide as the coded extent
// (no Gray bits), no phase steps.
slproto::PatternPlanConfig white_and_black(slproto::PatternPlanConfig config) {
  config.period_px = config.coded_extent();
  config.phase_steps = 0;
  config.complementary_bit = false;
  config.inverse_gray = false;
  config.gray_low_bits = slproto::GrayLowBits::centre;
  config.phase_offset_rad = 0;
  config.phase_offset_steps = 0;
  config.with_white_black = true;
  return config;
}

std::vector<std::uint16_t> pixels_of(const slproto::pb::FrameHeader& header, std::span<const std::byte> payload) {
  const std::size_t width = header.width();
  const std::size_t height = header.height();
  const std::size_t stride = header.stride_bytes();
  const bool wide = slproto::bytes_per_pixel(header.pixel_format()) == 2;
  std::vector<std::uint16_t> out(width * height);
  for (std::size_t y = 0; y < height; ++y) {
    const std::byte* row = payload.data() + y * stride;
    std::uint16_t* dst = out.data() + y * width;
    if (wide) {
      std::memcpy(dst, row, width * 2);  // little-endian on the wire and on every host we build for
    } else {
      for (std::size_t x = 0; x < width; ++x) dst[x] = std::to_integer<std::uint16_t>(row[x]);
    }
  }
  return out;
}

}  // namespace

MeteredExposure meter_exposure(ScannerConnection& scanner, const MeteringScan& scan, const AutoExposureRequest& request,
                               const slproto::RigCalibration& calibration, const core::ReconstructionOptions& options,
                               const SessionLog& log) {
  const slproto::pb::HelloReply& board = scanner.board;
  if ((board.capabilities() & slproto::pb::CAPABILITY_EXPOSURE_BRACKET) == 0)
    throw DeviceError("--exposure auto: the scanner '" + board.board_name() + "' (" + board.software_version() +
                      ") cannot sequence an exposure bracket (no CAPABILITY_EXPOSURE_BRACKET), which metering "
                      "needs; upgrade slscand, or scan with --exposure-us");
  const PatternTiming timing = pattern_timing(scan.exposure_us, scan.period_us, board);
  if (timing.period_us <= timing.exposure_us)
    throw std::invalid_argument("--exposure auto: the pattern period " + std::to_string(timing.period_us) +
                                " us leaves no read-out time after the exposure " + std::to_string(timing.exposure_us) +
                                " us");
  // The board's own timing fits its read-out: the same margin after any exposure does too.
  const double allowance_us = timing.period_us - timing.exposure_us;
  double longest_us = kLongestExposureUs;
  if (request.time_budget_s > 0 && scan.scan_frames_per_exposure > 0)
    longest_us = std::min(
        longest_us, request.time_budget_s * 1e6 / static_cast<double>(scan.scan_frames_per_exposure) - allowance_us);
  if (longest_us < kProjectorMinimumUs)
    throw std::invalid_argument("--time-budget-s " + slproto::short_number(request.time_budget_s) +
                                ": too short for the scan at any exposure (" +
                                std::to_string(scan.scan_frames_per_exposure) + " frames of at least " +
                                slproto::short_number(kProjectorMinimumUs + allowance_us) + " us each)");
  const std::vector<double> ladder =
      core::metering_ladder(timing.exposure_us, kProjectorMinimumUs, longest_us, request.mains_hz);

  const slproto::PatternPlan plan(white_and_black(calibration.pattern_plan));
  slproto::pb::ScanRequest metering;
  metering.set_scan_id(static_cast<std::uint64_t>(std::chrono::system_clock::now().time_since_epoch().count()));
  metering.add_turntable_angles_deg(scan.first_angle_deg);
  for (const std::uint32_t projector : scan.projectors) metering.add_projectors(projector);
  *metering.mutable_plan() = slproto::to_proto(plan.config());
  metering.set_exposure_us(timing.exposure_us);
  for (const double rung : ladder) metering.add_exposure_bracket_us(static_cast<std::uint32_t>(rung));
  metering.set_pattern_period_us(std::max(timing.period_us, static_cast<std::uint32_t>(ladder.back() + allowance_us)));
  metering.set_settle_ms(scan.settle_ms);
  const int bit_depth = options.decode.bit_depth;
  metering.set_pixel_format(bit_depth > 8
                                ? (bit_depth > 10 ? slproto::pb::PIXEL_FORMAT_MONO12 : slproto::pb::PIXEL_FORMAT_MONO10)
                                : slproto::pb::PIXEL_FORMAT_MONO8);
  if (auto status = slproto::check_scan_request(metering); !status)
    throw std::invalid_argument("--exposure auto: the metering request: " + status.error().message);
  log.info("metering the exposure: white and black at " + std::to_string(ladder.size()) + " exposures, " +
           slproto::short_number(ladder.front()) + " to " + slproto::short_number(ladder.back()) + " us");

  slproto::Connection& connection = scanner.connection;
  if (auto status = connection.send(metering); !status)
    throw DeviceError("--exposure auto: sending the metering request: " + status.error().message);
  auto abort = [&](const std::string& reason) {
    slproto::pb::Abort message;
    message.set_scan_id(metering.scan_id());
    message.set_reason(reason);
    (void)connection.send(message);
  };
  const std::size_t expected = plan.size() * ladder.size() * scan.projectors.size();
  // (exposure index, projector) -> the white and black frames
  std::map<std::pair<std::uint32_t, std::uint32_t>, core::MeteringFrames> frames;
  std::size_t received = 0;
  auto last_frame_at = Clock::now();
  for (;;) {
    if (scan.stop != nullptr && scan.stop->load()) {
      abort("interrupted on the host (Ctrl-C)");
      throw DeviceError("--exposure auto: interrupted (Ctrl-C) while metering; nothing was captured");
    }
    auto message = connection.receive(std::chrono::milliseconds(200));
    if (!message) {
      if (message.error().code == slproto::Errc::timeout) {
        if (Clock::now() - last_frame_at >= scan.stall_timeout) {
          abort("the host timed out waiting for frames");
          throw DeviceError("--exposure auto: the scanner sent no metering frame for " +
                            std::to_string(scan.stall_timeout.count() / 1000) + " s after " + std::to_string(received) +
                            " of " + std::to_string(expected) + " frames");
        }
        continue;
      }
      throw DeviceError("--exposure auto: connection to the scanner while metering: " + message.error().message);
    }
    if (const auto* header = message->get<slproto::pb::FrameHeader>()) {
      const auto kind =
          header->pattern_index() < plan.size() ? plan[header->pattern_index()].kind : slproto::PatternKind::phase_step;
      const bool known_projector = std::ranges::find(scan.projectors, header->projector_id()) != scan.projectors.end();
      if (header->scan_id() != metering.scan_id() || header->view_index() != 0 || !known_projector ||
          header->pattern_index() >= plan.size() || header->exposure_index() >= ladder.size() ||
          header->pixel_format() != metering.pixel_format()) {
        abort("the host refused a metering frame");
        throw DeviceError("--exposure auto: the scanner sent a metering frame the request has no slot for (view " +
                          std::to_string(header->view_index()) + ", projector " +
                          std::to_string(header->projector_id()) + ", pattern " +
                          std::to_string(header->pattern_index()) + ", exposure index " +
                          std::to_string(header->exposure_index()) + ")");
      }
      if (auto status = slproto::check_frame_geometry(*header, message->payload.size()); !status) {
        abort("the host refused a metering frame");
        throw DeviceError("--exposure auto: metering frame " + std::to_string(received) + ": " +
                          status.error().message);
      }
      core::MeteringFrames& slot = frames[{header->exposure_index(), header->projector_id()}];
      slot.exposure_us = ladder[header->exposure_index()];
      slot.projector = static_cast<int>(header->projector_id());
      auto& image = kind == slproto::PatternKind::white ? slot.white : slot.black;
      if (!image.empty()) {
        abort("the host refused a metering frame");
        throw DeviceError("--exposure auto: the scanner sent the metering frame of projector " +
                          std::to_string(header->projector_id()) + ", pattern " +
                          std::to_string(header->pattern_index()) + " at " + slproto::short_number(slot.exposure_us) +
                          " us twice");
      }
      image = pixels_of(*header, message->payload);
      ++received;
      last_frame_at = Clock::now();
    } else if (const auto* done = message->get<slproto::pb::ScanDone>()) {
      if (done->final_state() != slproto::pb::SCAN_STATE_DONE)
        throw DeviceError("--exposure auto: the metering pass ended early: " + done->text());
      break;
    } else if (const auto* error = message->get<slproto::pb::Error>()) {
      throw DeviceError("--exposure auto: the scanner reported while metering: " + error->text());
    }
  }
  if (received != expected)
    throw DeviceError("--exposure auto: " + std::to_string(received) + " metering frames arrived of " +
                      std::to_string(expected));

  std::vector<core::MeteringFrames> metered;
  metered.reserve(frames.size());
  for (auto& entry : frames) metered.push_back(std::move(entry.second));
  core::AutoExposureOptions choose;
  choose.max_saturated_share = request.max_saturated_share;
  choose.max_dark_share = request.max_dark_share;
  // The decoder's own floors: white - black, and twice the phase modulation (a full-contrast
  // sinusoid's amplitude is half of white - black). A margin above them made matte parts ask
  // for a second exposure for their grazing edges (measured on the rig's presets, docs/hdr.md).
  choose.min_contrast_dn =
      std::max(static_cast<double>(options.decode.min_contrast_dn), 2.0 * options.decode.min_modulation_dn);
  choose.saturation_dn = options.decode.saturation_level();
  choose.frames_per_exposure = scan.scan_frames_per_exposure;
  choose.readout_allowance_us = allowance_us;
  choose.min_period_us = timing.period_us;
  choose.time_budget_s = request.time_budget_s;
  choose.reference_us = timing.exposure_us;

  MeteredExposure out;
  out.choice = core::choose_exposures(metered, choose);
  out.exposure_us = timing.exposure_us;
  if (out.choice.exposures_us.size() == 1) {
    out.exposure_us = static_cast<std::uint32_t>(out.choice.exposures_us.front());
  } else {
    for (const double e : out.choice.exposures_us) out.bracket_us.push_back(static_cast<std::uint32_t>(e));
  }
  out.period_us = static_cast<std::uint32_t>(out.choice.period_us);
  return out;
}

}  // namespace slscan::session
