// Reading a recorded scan back: the capture file is the stream the board sent (preceded by
// the scan request the host sent), so replaying it feeds the reconstruction exactly what the
// live run saw.
#pragma once

#include <cstddef>
#include <functional>
#include <optional>
#include <span>
#include <string>
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

// Replays a capture file: `on_request` for the scan request (first in the file), `on_frame` for
// each frame. Throws IoError naming the file and offset for unreadable or corrupt files and
// for frames whose geometry doesn't match their payload.
CaptureSummary replay_capture(const std::string& path, const RequestSink& on_request, const FrameSink& on_frame);

// The reconstruction's view of a frame header.
core::FrameInfo frame_info(const slproto::pb::FrameHeader& header);

// The pattern plan a scan request carries; throws IoError naming the bad field.
slproto::PatternPlan plan_of(const slproto::pb::ScanRequest& request);

// What a capture lacks compared with its request, in words ("view 3 projector 1: 12 of 19
// frames"), empty when complete. Counts frames per (view, projector).
std::vector<std::string> describe_missing_frames(const slproto::pb::ScanRequest& request,
                                                 const std::vector<slproto::pb::FrameHeader>& received);

}  // namespace slscan::io
