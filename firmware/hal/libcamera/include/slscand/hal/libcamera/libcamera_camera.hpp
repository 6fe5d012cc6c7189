// libcamera camera backend (libcamera >= 0.3: bookworm-backports' 0.3.2, Raspberry Pi OS's
// fork). One configured raw mono stream; each request carries ExposureTime, AnalogueGain and
// FrameDurationLimits; completion timestamps come from SensorTimestamp, which is
// CLOCK_BOOTTIME and is converted to CLOCK_MONOTONIC here. Version differences stay in this
// file (<libcamera/version.h>).
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "slscand/hal/camera.hpp"

namespace libcamera {
class ControlList;
class PixelFormat;
}  // namespace libcamera

namespace slscand::hal {

// `id`: a libcamera camera id, or "auto" for the first camera found.
Result<std::unique_ptr<Camera>> open_libcamera_camera(const std::string& id);

// Mono raw formats: R8, R10, R12 (unpacked, little-endian 16-bit for 10/12).
libcamera::PixelFormat libcamera_pixel_format_for(PixelFormat format);

struct LibcameraControlSettings {
  double exposure_us = 0;
  double gain = 1.0;
  double frame_period_us = 0;  // 0: no frame-duration limit
};
// The per-request controls: auto exposure off, ExposureTime, AnalogueGain and, with a
// period, FrameDurationLimits = {period, period}. Errors name the bad setting.
Result<std::unique_ptr<libcamera::ControlList>> libcamera_request_controls(const LibcameraControlSettings& settings);

std::string libcamera_version_string();

}  // namespace slscand::hal
