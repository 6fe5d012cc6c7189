// The camera interface every camera backend implements (V4L2, libcamera, sim).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "slproto/result.hpp"
#include "slscand/hal/clock.hpp"

namespace slscand::hal {

using slproto::Result;
using slproto::Status;

// Mono formats only: structured light needs intensity, not colour. 10/12-bit samples are
// little-endian uint16 with the value in the low bits (slproto PIXEL_FORMAT_MONO10/12).
enum class PixelFormat : std::uint8_t { mono8, mono10, mono12 };
const char* pixel_format_name(PixelFormat format) noexcept;
Result<PixelFormat> parse_pixel_format(const std::string& name);
int bytes_per_pixel(PixelFormat format) noexcept;

struct CameraFormat {
  int width = 0;
  int height = 0;
  PixelFormat pixel_format = PixelFormat::mono8;
  std::size_t stride_bytes = 0;  // filled by the backend; 0 in a request means "packed"
  std::size_t frame_bytes() const { return stride_bytes * static_cast<std::size_t>(height); }
};

enum class TriggerMode : std::uint8_t {
  free_run,  // the sensor runs at its own frame rate
  external,  // one exposure per rising edge on the camera's trigger input
  software,  // one exposure per software_trigger() (bench tests; Aravis cameras only)
};
const char* trigger_mode_name(TriggerMode mode) noexcept;

struct Frame {
  CameraFormat format;
  std::vector<std::uint8_t> pixels;  // format.frame_bytes() bytes, rows of stride_bytes
  std::uint64_t sequence = 0;        // the driver's frame counter; gaps are dropped frames
  Nanos exposure_start_ns = 0;       // CLOCK_MONOTONIC; 0 when the backend cannot tell
  Nanos exposure_end_ns = 0;
  Nanos dequeued_ns = 0;  // when the frame reached user space
};

// A network camera's transport counters since the camera was opened (GigE Vision: resent and
// missing packets; every camera: frames that arrived incomplete or not at all). Backends
// without a transport of their own report zeros.
struct CameraLinkStats {
  std::uint64_t frames_completed = 0;
  std::uint64_t frames_failed = 0;  // incomplete (missing packets) or timed out in the stream
  std::uint64_t underruns = 0;      // a frame arrived with no free buffer in the pool
  std::uint64_t packets_missing = 0;
  std::uint64_t packets_resent = 0;
  std::uint64_t resend_requests = 0;
};
CameraLinkStats operator-(const CameraLinkStats& after, const CameraLinkStats& before) noexcept;

// One line of `slscand --check` about the camera ("camera features", "camera link").
struct CameraDetail {
  std::string name;
  std::string detail;
};

class Camera {
 public:
  virtual ~Camera() = default;
  virtual std::string describe() const = 0;
  // Negotiates the nearest format the device offers; refuses one it cannot honour exactly in
  // size or pixel format (a scan with the wrong geometry would decode to garbage).
  virtual Result<CameraFormat> set_format(const CameraFormat& wanted) = 0;
  virtual Status set_exposure_us(double exposure_us) = 0;
  virtual Status set_gain(double gain) = 0;
  virtual Status set_trigger_mode(TriggerMode mode) = 0;
  virtual Status start() = 0;
  virtual Status stop() = 0;  // idempotent
  // The next frame, or Errc::timeout after `timeout_ns`.
  virtual Result<Frame> wait_frame(Nanos timeout_ns) = 0;
  // In TriggerMode::software: expose one frame now.
  virtual Status software_trigger() {
    return slproto::make_error(slproto::Errc::unsupported, describe() + " has no software trigger");
  }
  virtual CameraLinkStats link_stats() const { return {}; }
  // What `slscand --check` reports beyond describe(): features, link speed, clock mapping.
  virtual std::vector<CameraDetail> check_details() const { return {}; }
};

}  // namespace slscand::hal
