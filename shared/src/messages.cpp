#include "slproto/messages.hpp"

#include <cmath>
#include <cstdio>
#include <set>

#include "slproto/calibration_poses.hpp"

namespace slproto {

const char* message_type_name(MessageType type) noexcept {
  switch (type) {
    case MessageType::hello:
      return "hello";
    case MessageType::hello_reply:
      return "hello_reply";
    case MessageType::scan_request:
      return "scan_request";
    case MessageType::progress:
      return "progress";
    case MessageType::frame:
      return "frame";
    case MessageType::scan_done:
      return "scan_done";
    case MessageType::error:
      return "error";
    case MessageType::abort:
      return "abort";
    case MessageType::heartbeat:
      return "heartbeat";
    case MessageType::status_request:
      return "status_request";
    case MessageType::status_reply:
      return "status_reply";
  }
  return "unknown";
}

bool is_known_message_type(std::uint8_t value) noexcept { return value >= 1 && value <= max_message_type; }

MessageType type_of(const Body& body) noexcept { return static_cast<MessageType>(body.index() + 1); }

// std::visit throws only on a valueless variant, which a Body never is here: slproto builds each
// in place and a failed copy (bad_alloc) propagates before the Body is used.
// NOLINTNEXTLINE(bugprone-exception-escape)
const google::protobuf::MessageLite& as_message_lite(const Body& body) noexcept {
  return std::visit([](const auto& message) -> const google::protobuf::MessageLite& { return message; }, body);
}

int bytes_per_pixel(pb::PixelFormat format) noexcept {
  switch (format) {
    case pb::PIXEL_FORMAT_MONO8:
      return 1;
    case pb::PIXEL_FORMAT_MONO10:
    case pb::PIXEL_FORMAT_MONO12:
      return 2;
    default:
      return 0;
  }
}

const char* pixel_format_name(pb::PixelFormat format) noexcept {
  switch (format) {
    case pb::PIXEL_FORMAT_MONO8:
      return "mono8";
    case pb::PIXEL_FORMAT_MONO10:
      return "mono10";
    case pb::PIXEL_FORMAT_MONO12:
      return "mono12";
    case pb::PIXEL_FORMAT_UNSPECIFIED:
      return "unspecified";
    default:
      return "unknown";
  }
}

Status check_frame_geometry(const pb::FrameHeader& header, std::size_t payload_size) {
  const int bpp = bytes_per_pixel(header.pixel_format());
  if (bpp == 0)
    return make_error(Errc::malformed, "frame header: pixel_format " + std::to_string(header.pixel_format()) +
                                           " is not mono8, mono10 or mono12");
  if (header.width() == 0 || header.width() > 65535)
    return make_error(Errc::malformed, "frame header: width " + std::to_string(header.width()) + " not in 1..65535");
  if (header.height() == 0 || header.height() > 65535)
    return make_error(Errc::malformed, "frame header: height " + std::to_string(header.height()) + " not in 1..65535");
  const std::uint64_t row_bytes = std::uint64_t{header.width()} * static_cast<std::uint64_t>(bpp);
  if (header.stride_bytes() < row_bytes)
    return make_error(Errc::malformed, "frame header: stride_bytes " + std::to_string(header.stride_bytes()) +
                                           " < width * bytes per pixel = " + std::to_string(row_bytes));
  const std::uint64_t expected = std::uint64_t{header.stride_bytes()} * header.height();
  if (expected != payload_size)
    return make_error(Errc::malformed, "frame header: stride_bytes * height = " + std::to_string(expected) +
                                           " but the payload has " + std::to_string(payload_size) + " bytes");
  return Ok{};
}

void set_frame_geometry(pb::FrameHeader& header, std::uint32_t width, std::uint32_t height, pb::PixelFormat format) {
  header.set_width(width);
  header.set_height(height);
  header.set_pixel_format(format);
  header.set_stride_bytes(width * static_cast<std::uint32_t>(bytes_per_pixel(format)));
}

pb::PatternPlanConfig to_proto(const PatternPlanConfig& config) {
  pb::PatternPlanConfig out;
  out.set_projector_width(static_cast<std::uint32_t>(config.projector_width));
  out.set_projector_height(static_cast<std::uint32_t>(config.projector_height));
  out.set_axis(config.axis == CodingAxis::rows ? pb::CODING_AXIS_ROWS : pb::CODING_AXIS_COLUMNS);
  out.set_period_px(static_cast<std::uint32_t>(config.period_px));
  out.set_phase_steps(static_cast<std::uint32_t>(config.phase_steps));
  out.set_complementary_bit(config.complementary_bit);
  out.set_with_white_black(config.with_white_black);
  out.set_inverse_gray(config.inverse_gray);
  out.set_gray_low_bits(config.gray_low_bits == GrayLowBits::slstudio_parity ? pb::GRAY_LOW_BITS_SLSTUDIO_PARITY
                                                                             : pb::GRAY_LOW_BITS_CENTRE);
  out.set_phase_offset_rad(config.phase_offset_rad);
  out.set_phase_offset_steps(static_cast<std::uint32_t>(config.phase_offset_steps));
  return out;
}

Result<PatternPlanConfig> from_proto(const pb::PatternPlanConfig& config) {
  constexpr std::uint32_t limit = 1u << 20;  // keeps the int conversion exact; check() bounds further
  auto field = [&](const char* name, std::uint32_t value) -> Status {
    if (value > limit)
      return make_error(Errc::invalid_argument,
                        std::string("pattern plan: ") + name + " = " + std::to_string(value) + " is out of range");
    return Ok{};
  };
  for (auto [name, value] :
       {std::pair{"projector_width", config.projector_width()},
        std::pair{"projector_height", config.projector_height()}, std::pair{"period_px", config.period_px()},
        std::pair{"phase_steps", config.phase_steps()}, std::pair{"phase_offset_steps", config.phase_offset_steps()}})
    if (Status status = field(name, value); !status) return status.error();
  if (config.axis() != pb::CODING_AXIS_COLUMNS && config.axis() != pb::CODING_AXIS_ROWS)
    return make_error(Errc::invalid_argument, "pattern plan: axis " + std::to_string(config.axis()) + " is unknown");
  if (config.gray_low_bits() != pb::GRAY_LOW_BITS_CENTRE && config.gray_low_bits() != pb::GRAY_LOW_BITS_SLSTUDIO_PARITY)
    return make_error(Errc::invalid_argument,
                      "pattern plan: gray_low_bits " + std::to_string(config.gray_low_bits()) + " is unknown");
  PatternPlanConfig out;
  out.projector_width = static_cast<int>(config.projector_width());
  out.projector_height = static_cast<int>(config.projector_height());
  out.axis = config.axis() == pb::CODING_AXIS_ROWS ? CodingAxis::rows : CodingAxis::columns;
  out.period_px = static_cast<int>(config.period_px());
  out.phase_steps = static_cast<int>(config.phase_steps());
  out.complementary_bit = config.complementary_bit();
  out.with_white_black = config.with_white_black();
  out.inverse_gray = config.inverse_gray();
  out.gray_low_bits =
      config.gray_low_bits() == pb::GRAY_LOW_BITS_SLSTUDIO_PARITY ? GrayLowBits::slstudio_parity : GrayLowBits::centre;
  out.phase_offset_rad = config.phase_offset_rad();
  out.phase_offset_steps = static_cast<int>(config.phase_offset_steps());
  if (Status status = out.check(); !status) return status.error();
  return out;
}

Status check_scan_request(const pb::ScanRequest& request, std::uint32_t projector_count) {
  auto bad = [](std::string what) { return make_error(Errc::invalid_argument, "scan request: " + std::move(what)); };
  if (request.turntable_angles_deg_size() == 0) return bad("no turntable angles");
  // Every view costs a turntable move and a frame set (and the host a slot per projector): 3600
  // is a view every 0.1 degree, more than any scan needs; a bigger count is a corrupt or hostile
  // request (docs/security.md).
  constexpr int kMaxViews = 3600;
  if (request.turntable_angles_deg_size() > kMaxViews)
    return bad(std::to_string(request.turntable_angles_deg_size()) + " turntable angles (at most " +
               std::to_string(kMaxViews) + ")");
  for (int i = 0; i < request.turntable_angles_deg_size(); ++i) {
    const double angle = request.turntable_angles_deg(i);
    if (!std::isfinite(angle) || std::abs(angle) > 360.0) {
      char shown[32];
      std::snprintf(shown, sizeof shown, "%.6g", angle);
      return bad("turntable_angles_deg[" + std::to_string(i) + "] = " + shown +
                 " is not a finite angle in [-360, 360]");
    }
  }
  if (request.projectors_size() == 0) return bad("no projectors");
  std::set<std::uint32_t> seen;
  for (int i = 0; i < request.projectors_size(); ++i) {
    const std::uint32_t id = request.projectors(i);
    if (id >= projector_count)
      return bad("projectors[" + std::to_string(i) + "] = " + std::to_string(id) + " but the board has " +
                 std::to_string(projector_count) + " projector(s)");
    if (!seen.insert(id).second)
      return bad("projectors[" + std::to_string(i) + "] = " + std::to_string(id) + " repeats");
  }
  if (!request.has_plan()) return bad("no pattern plan");
  if (auto plan = from_proto(request.plan()); !plan) return bad(plan.error().message);
  if (request.exposure_us() == 0) return bad("exposure_us is 0");
  if (request.pattern_period_us() < request.exposure_us())
    return bad("pattern_period_us " + std::to_string(request.pattern_period_us()) + " is shorter than exposure_us " +
               std::to_string(request.exposure_us()));
  if (request.exposure_bracket_us_size() > kMaxExposureBracket)
    return bad("exposure_bracket_us has " + std::to_string(request.exposure_bracket_us_size()) +
               " exposures (at most " + std::to_string(kMaxExposureBracket) + ")");
  for (int i = 0; i < request.exposure_bracket_us_size(); ++i) {
    const std::uint32_t exposure = request.exposure_bracket_us(i);
    const std::string name = "exposure_bracket_us[" + std::to_string(i) + "] = " + std::to_string(exposure);
    if (exposure == 0) return bad(name + " is 0");
    if (exposure > request.pattern_period_us())
      return bad(name + " is longer than pattern_period_us " + std::to_string(request.pattern_period_us()));
    for (int j = 0; j < i; ++j)
      if (request.exposure_bracket_us(j) == exposure)
        return bad(name + " repeats exposure_bracket_us[" + std::to_string(j) + "]");
  }
  if (bytes_per_pixel(request.pixel_format()) == 0)
    return bad("pixel_format " + std::to_string(request.pixel_format()) + " is not mono8, mono10 or mono12");
  if (request.has_calibration_target())
    if (auto target = from_proto(request.calibration_target()); !target) return target.error();
  return Ok{};
}

std::vector<std::uint32_t> exposures_of(const pb::ScanRequest& request) {
  if (request.exposure_bracket_us_size() == 0) return {request.exposure_us()};
  return {request.exposure_bracket_us().begin(), request.exposure_bracket_us().end()};
}

pb::Error to_proto(const Error& error, std::uint64_t scan_id, bool fatal) {
  pb::Error out;
  out.set_code(static_cast<std::uint32_t>(error.code));
  out.set_text(error.message);
  out.set_scan_id(scan_id);
  out.set_fatal(fatal);
  return out;
}

Errc errc_from_wire(std::uint32_t code) noexcept {
  if (code != 0 && code <= static_cast<std::uint32_t>(Errc::internal)) return static_cast<Errc>(code);
  return Errc::internal;
}

Error from_proto(const pb::Error& error) {
  const Errc code = errc_from_wire(error.code());
  if (code == Errc::internal && error.code() != static_cast<std::uint32_t>(Errc::internal))
    return make_error(code, "peer error code " + std::to_string(error.code()) + ": " + error.text());
  return make_error(code, error.text());
}

}  // namespace slproto
