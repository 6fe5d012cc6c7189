// Reading a recorded scan back: the capture file is the stream the board sent (preceded by
// the scan request the host sent), so replaying it feeds the reconstruction exactly what the
// live run saw.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <span>
#include <string>
#include <tuple>
#include <vector>

#include "slproto/capture.hpp"
#include "slproto/messages.hpp"
#include "slscan/core/scan_reconstruction.hpp"

namespace slscan::io {

struct CaptureSummary {
  std::optional<slproto::pb::ScanRequest> request;  // the plan the scan was made with
  std::optional<slproto::pb::ScanDone> done;        // absent: the scan did not finish
  std::vector<slproto::pb::Error> errors;           // errors the board reported
  std::size_t frames = 0;
  std::size_t records = 0;
  std::optional<slproto::CaptureTruncation> truncation;  // the file was cut inside a record
};

// Called for each frame record, in stream order. The payload is valid during the call only.
using FrameSink = std::function<void(const slproto::pb::FrameHeader& header, std::span<const std::byte> payload)>;

using RequestSink = std::function<void(const slproto::pb::ScanRequest& request)>;

// The (view, projector, pattern) slots of a scan request, each of which one frame may fill
// once: the check a recorded frame (replay_capture) and a frame arriving live (slscan scan)
// both pass, so what either builds is bounded by the request's checked sizes.
class FrameSlots {
 public:
  // `request` must have passed slproto::check_scan_request; `request_offset` is where it is in
  // the stream (named in messages).
  FrameSlots(const slproto::pb::ScanRequest& request, std::uint64_t request_offset);
  // Takes the frame's slot. Empty when it fits a free one; otherwise what is wrong with it,
  // starting with "frame (view V, projector P, pattern K) " (geometry, a view, projector or
  // pattern the request does not have, an absurd turntable angle, a frame given twice).
  std::optional<std::string> take(const slproto::pb::FrameHeader& header, std::size_t payload_size,
                                  std::uint64_t offset);
  std::size_t slots() const noexcept { return views_ * projectors_.size() * exposures_ * plan_size_; }
  std::size_t taken() const noexcept { return taken_.size(); }

 private:
  std::uint64_t request_offset_ = 0;
  std::size_t views_ = 0, plan_size_ = 0, exposures_ = 1;
  std::vector<std::uint32_t> projectors_;
  // (view, projector, exposure index, pattern) -> the frame's offset
  std::map<std::tuple<std::uint32_t, std::uint32_t, std::uint32_t, std::uint32_t>, std::uint64_t> taken_;
};

// Replays a capture file: `on_request` for the scan request (first in the file), `on_frame` for
// each frame. Throws IoError naming the file and offset for unreadable or corrupt files, for
// frames whose geometry doesn't match their payload, and for an inconsistent capture: a scan
// request that check_scan_request refuses (more than 3600 views, ...), a
// second scan request, a frame before the request, a frame of a view, projector or pattern the
// request does not have, or a frame given twice.
CaptureSummary replay_capture(const std::string& path, const RequestSink& on_request, const FrameSink& on_frame);

// Summary of a capture's storage: records, frames, payload bytes stored and decoded, codec.
struct CaptureStorage {
  std::uint16_t format_version = 0;
  slproto::FrameCodecId codec = slproto::FrameCodecId::none;
  std::size_t records = 0, frames = 0;
  std::uint64_t file_bytes = 0, payload_stored = 0, payload_decoded = 0;
  std::optional<slproto::CaptureTruncation> truncation;
};

// Opens a capture for reading with every codec this build has (raw and zstd-compressed);
// throws IoError naming the file for what cannot be read.
slproto::CaptureReader open_capture(const std::string& path);

// Copies a capture record by record into `out` (written to out.partial, renamed when complete),
// compressing frames with `codec` (nullptr: raw). Records are decoded and re-encoded
// losslessly: converting back gives the original file byte for byte (the creation time is
// kept). A truncated input converts up to its last complete record (the result says so).
CaptureStorage convert_capture(const std::string& in, const std::string& out, const slproto::FrameCodec* codec);

// The reconstruction's view of a frame header.
core::FrameInfo frame_info(const slproto::pb::FrameHeader& header);

// The pattern plan a scan request carries; throws IoError naming the bad field.
slproto::PatternPlan plan_of(const slproto::pb::ScanRequest& request);

// What a capture lacks compared with its request, in words ("view 3 projector 1: 12 of 19
// frames"), empty when complete. Counts frames per (view, projector); at most `max_lines`
// pairs are named, the rest summed up in one last line ("and 40 more (view, projector) pairs,
// 760 frames in all").
std::vector<std::string> describe_missing_frames(const slproto::pb::ScanRequest& request,
                                                 const std::vector<slproto::pb::FrameHeader>& received,
                                                 std::size_t max_lines = 20);

}  // namespace slscan::io
