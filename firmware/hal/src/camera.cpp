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
  return mode == TriggerMode::external ? "external" : "free_run";
}

}  // namespace slscand::hal
