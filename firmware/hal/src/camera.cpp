#include "slscand/hal/camera.hpp"

namespace slscand::hal {

const char* pixel_format_name(PixelFormat format) noexcept {
  switch (format) {
    case PixelFormat::mono8:
      return "mono8";
    case PixelFormat::mono10:
      return "mono10";
    case PixelFormat::mono12:
      return "mono12";
  }
  return "unknown";
}

Result<PixelFormat> parse_pixel_format(const std::string& name) {
  if (name == "mono8") return PixelFormat::mono8;
  if (name == "mono10") return PixelFormat::mono10;
  if (name == "mono12") return PixelFormat::mono12;
  return slproto::make_error(slproto::Errc::invalid_argument,
                             "unknown pixel format '" + name + "' (expected mono8, mono10 or mono12)");
}

int bytes_per_pixel(PixelFormat format) noexcept { return format == PixelFormat::mono8 ? 1 : 2; }

const char* trigger_mode_name(TriggerMode mode) noexcept {
  switch (mode) {
    case TriggerMode::free_run:
      return "free_run";
    case TriggerMode::external:
      return "external";
    case TriggerMode::software:
      return "software";
  }
  return "unknown";
}

CameraLinkStats operator-(const CameraLinkStats& after, const CameraLinkStats& before) noexcept {
  auto d = [](std::uint64_t a, std::uint64_t b) { return a >= b ? a - b : 0; };
  CameraLinkStats s;
  s.frames_completed = d(after.frames_completed, before.frames_completed);
  s.frames_failed = d(after.frames_failed, before.frames_failed);
  s.underruns = d(after.underruns, before.underruns);
  s.packets_missing = d(after.packets_missing, before.packets_missing);
  s.packets_resent = d(after.packets_resent, before.packets_resent);
  s.resend_requests = d(after.resend_requests, before.resend_requests);
  return s;
}

}  // namespace slscand::hal
