// GenICam camera backend on Aravis 0.8 (GigE Vision and USB3 Vision machine-vision cameras):
// open by id or the first camera found, Mono8/10/12 in the camera's packed or unpacked wire
// formats (unpacked to the protocol's little-endian uint16), ROI, exposure, gain, frame-start
// trigger on a named input line (or in software, for the bench), a stream with a buffer pool,
// frame timestamps mapped onto CLOCK_MONOTONIC, and the transport's resend and loss counters.
// The mapping from our settings to GenICam is exposed as pure functions, tested without a
// camera; the rest is tested against Aravis' fake GigE Vision camera (tests/firmware).
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "slscand/hal/camera.hpp"

namespace slscand::hal {

struct AravisOptions {
  std::string device = "auto";  // "auto" = the first camera; else an Aravis id, serial number or IP address
  int offset_x = 0, offset_y = 0;
  std::string trigger_input = "Line0";  // TriggerSource for TriggerMode::external
  std::string trigger_activation = "RisingEdge";
  int packet_size = 0;  // GigE Vision: 0 = negotiate the largest the path carries
  int buffers = 8;
};

Result<std::unique_ptr<Camera>> open_aravis_camera(const AravisOptions& options);

// The cameras Aravis finds, one line each ("id (vendor model, serial S) at address").
std::vector<std::string> list_aravis_cameras();

// GenICam pixel formats a camera sends on the wire for each of ours.
enum class GenicamWireFormat : std::uint8_t { mono8, mono10, mono12, mono10p, mono12p, mono10_packed, mono12_packed };
const char* genicam_wire_format_name(GenicamWireFormat format) noexcept;  // "Mono10p", ...
int genicam_bits_per_pixel(GenicamWireFormat format) noexcept;            // on the wire
PixelFormat genicam_pixel_format(GenicamWireFormat format) noexcept;      // what it unpacks to

// The wire format to ask for: unpacked first (no conversion), then PFNC packed (Mono10p), then
// GigE Vision 1.x packed (Mono10Packed). An error lists what the camera offers.
Result<GenicamWireFormat> choose_genicam_wire_format(PixelFormat wanted, const std::vector<std::string>& available);

// Bytes a width x height image takes on the wire (packed formats: rows are not padded).
std::size_t genicam_image_bytes(GenicamWireFormat format, int width, int height) noexcept;

// Wire bytes -> the protocol's pixels (Mono8 bytes, or uint16 little-endian with the value in the
// low bits). `dst` holds width * height * bytes_per_pixel bytes. An image shorter than
// genicam_image_bytes() is an error naming both sizes.
Status genicam_unpack(GenicamWireFormat format, const std::uint8_t* src, std::size_t src_bytes, int width, int height,
                      std::uint8_t* dst);

// A frame counter that never wraps, from the camera's block ids: GigE Vision 1.x ids are 16 bits
// (and skip 0 on wrap-around), GigE Vision 2 / USB3 Vision ids are 64 bits.
class FrameIdUnwrapper {
 public:
  std::uint64_t next(std::uint64_t raw_id);
  void reset() { have_last_ = false; }

 private:
  bool have_last_ = false;
  std::uint64_t last_raw_ = 0;
  std::uint64_t counter_ = 0;
};

// Camera timestamps -> CLOCK_MONOTONIC. `latch` samples (monotonic before, camera time, monotonic
// after) from TimestampLatch/GevTimestampControlLatch give the offset of the sample with the
// shortest round trip.
struct ClockLatchSample {
  Nanos monotonic_before_ns = 0;
  std::int64_t device_ns = 0;
  Nanos monotonic_after_ns = 0;
};
struct ClockMapping {
  enum class Kind : std::uint8_t { none, latched, wall_clock } kind = Kind::none;
  std::int64_t device_to_monotonic_ns = 0;  // latched: monotonic = device + offset
  Nanos uncertainty_ns = 0;                 // half the best round trip
};
Result<ClockMapping> clock_mapping_from_latches(const std::vector<ClockLatchSample>& samples);
// Cameras without a latch whose clock is the wall clock (Aravis' fake camera; PTP cameras whose
// grandmaster is the board): a device stamp within 2 s of the host's CLOCK_REALTIME at arrival.
bool looks_like_wall_clock(std::int64_t device_ns, std::int64_t realtime_at_arrival_ns) noexcept;

}  // namespace slscand::hal
