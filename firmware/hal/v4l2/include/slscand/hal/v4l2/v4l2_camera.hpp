// V4L2 camera backend: mmap streaming, exposure/gain through the standard controls, buffer
// timestamps (CLOCK_MONOTONIC) and sequence numbers (gaps = dropped frames). The mapping
// from our settings to V4L2 requests is exposed as pure functions so it is tested without a
// device.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "slscand/hal/camera.hpp"

namespace slscand::hal {

Result<std::unique_ptr<Camera>> open_v4l2_camera(const std::string& device);

std::uint32_t v4l2_fourcc_for(PixelFormat format) noexcept;

// The format the driver answered to VIDIOC_S_FMT, reduced to what we check.
struct V4l2NegotiatedFormat {
  std::uint32_t width = 0, height = 0, fourcc = 0, bytes_per_line = 0;
};
// Accepts the driver's answer only if it is exactly the size and pixel format asked for, and
// names the difference otherwise.
Result<CameraFormat> v4l2_accept_format(const CameraFormat& wanted, const V4l2NegotiatedFormat& got);

struct V4l2Control {
  std::uint32_t id = 0;
  std::int32_t minimum = 0, maximum = 0, step = 1, default_value = 0;
  std::string name;
};
using V4l2ControlValues = std::vector<std::pair<std::uint32_t, std::int32_t>>;

// Manual exposure: UVC-style EXPOSURE_AUTO = manual + EXPOSURE_ABSOLUTE (100 us units), or a
// sensor's EXPOSURE in lines when `line_time_us` > 0 is known. Values are clamped to the
// control's range and rounded to its step; out of range is an error naming the limits.
Result<V4l2ControlValues> v4l2_exposure_controls(const std::vector<V4l2Control>& available, double exposure_us,
                                                 double line_time_us = 0);
// Gain as a factor of the control's default (ANALOGUE_GAIN, else GAIN).
Result<V4l2ControlValues> v4l2_gain_controls(const std::vector<V4l2Control>& available, double gain);
// A vendor "trigger mode" control (there is no standard one), if the driver has one.
const V4l2Control* v4l2_find_trigger_control(const std::vector<V4l2Control>& available);

struct V4l2FrameTimes {
  Nanos exposure_start_ns = 0;
  Nanos exposure_end_ns = 0;
};
// From a buffer's timestamp and flags: MONOTONIC only (anything else is an error), start of
// exposure (SOE) or end of frame (EOF) source.
Result<V4l2FrameTimes> v4l2_frame_times(std::uint32_t buffer_flags, std::int64_t tv_sec, std::int64_t tv_usec,
                                        Nanos exposure_ns);

}  // namespace slscand::hal
