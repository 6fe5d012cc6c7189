#include "slscan/io/capture_replay.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <set>
#include <tuple>

#include "slproto/zstd_codec.hpp"
#include "slscan/io/io_error.hpp"

namespace slscan::io {

core::FrameInfo frame_info(const slproto::pb::FrameHeader& header) {
  core::FrameInfo info;
  info.view_index = static_cast<int>(header.view_index());
  info.commanded_angle_deg = header.commanded_angle_deg();
  info.reported_angle_deg = header.reported_angle_deg();
  info.projector = static_cast<int>(header.projector_id());
  info.pattern_index = header.pattern_index();
  info.exposure_index = header.exposure_index();
  info.stride_bytes = header.stride_bytes();
  info.bytes_per_pixel = slproto::bytes_per_pixel(header.pixel_format());
  return info;
}

slproto::PatternPlan plan_of(const slproto::pb::ScanRequest& request) {
  auto config = slproto::from_proto(request.plan());
  if (!config) throw IoError("scan request: " + config.error().message);
  auto plan = slproto::PatternPlan::make(*config);
  if (!plan) throw IoError("scan request: " + plan.error().message);
  return std::move(plan).value();
}

slproto::CaptureReader open_capture(const std::string& path) {
  auto reader = slproto::CaptureReader::open(path, {}, slproto::zstd_codec());
  if (!reader) throw IoError(reader.error().message);
  return std::move(reader).value();
}

CaptureStorage convert_capture(const std::string& in, const std::string& out, const slproto::FrameCodec* codec) {
  slproto::CaptureReader reader = open_capture(in);
  std::error_code ignored;
  if (std::filesystem::equivalent(in, out, ignored))
    throw IoError("convert: " + in + " and " + out + " are the same file");
  auto writer = slproto::CaptureWriter::create(out, {codec, reader.created_unix_ns()});
  if (!writer) throw IoError(writer.error().message);
  CaptureStorage storage;
  for (;;) {
    auto next = reader.next();
    if (!next) throw IoError(next.error().message);  // the writer's destructor leaves out.partial
    if (*next == nullptr) break;
    ++storage.records;
    if ((*next)->type() == slproto::MessageType::frame) ++storage.frames;
    if (auto status = writer->append(**next); !status) throw IoError(status.error().message);
  }
  if (auto status = writer->finish(); !status) throw IoError(status.error().message);
  storage.format_version = codec == nullptr ? slproto::capture_format_version_raw : slproto::capture_format_version;
  storage.codec = writer->codec();
  storage.file_bytes = writer->bytes_written();
  storage.payload_decoded = writer->payload_bytes_in();
  storage.payload_stored = writer->payload_bytes_stored();
  storage.truncation = reader.truncation();
  return storage;
}

namespace {

std::string at(const std::string& path, std::uint64_t offset) {
  return path + ": record at offset " + std::to_string(offset) + ": ";
}

}  // namespace

FrameSlots::FrameSlots(const slproto::pb::ScanRequest& request, std::uint64_t request_offset)
    : request_offset_(request_offset),
      views_(static_cast<std::size_t>(request.turntable_angles_deg_size())),
      plan_size_(plan_of(request).size()),
      exposures_(slproto::exposures_of(request).size()),
      projectors_(request.projectors().begin(), request.projectors().end()) {}

std::optional<std::string> FrameSlots::take(const slproto::pb::FrameHeader& header, std::size_t payload_size,
                                            std::uint64_t offset) {
  const std::string frame = "frame (view " + std::to_string(header.view_index()) + ", projector " +
                            std::to_string(header.projector_id()) + ", pattern " +
                            std::to_string(header.pattern_index()) + ") ";
  if (auto status = slproto::check_frame_geometry(header, payload_size); !status) return frame + status.error().message;
  if (header.view_index() >= views_)
    return frame + "is of a view the scan request (offset " + std::to_string(request_offset_) +
           ") does not have: it has " + std::to_string(views_) + " views";
  if (std::find(projectors_.begin(), projectors_.end(), header.projector_id()) == projectors_.end())
    return frame + "is of a projector the scan request (offset " + std::to_string(request_offset_) + ") does not use";
  if (header.pattern_index() >= plan_size_)
    return frame + "is beyond the scan request's pattern plan of " + std::to_string(plan_size_) + " patterns";
  if (header.exposure_index() >= exposures_)
    return frame + "has exposure index " + std::to_string(header.exposure_index()) + " but the scan request has " +
           (exposures_ == 1 ? std::string("no exposure bracket")
                            : "a bracket of " + std::to_string(exposures_) + " exposures");
  for (const double angle : {header.commanded_angle_deg(), header.reported_angle_deg()})
    if (!(std::abs(angle) <= 1e6)) {
      char shown[32];
      std::snprintf(shown, sizeof shown, "%.6g", angle);
      return frame + "has a turntable angle of " + shown + " deg";
    }
  const auto [slot, added] = taken_.emplace(
      std::tuple{header.view_index(), header.projector_id(), header.exposure_index(), header.pattern_index()}, offset);
  if (!added) return frame + "repeats the frame at offset " + std::to_string(slot->second);
  return std::nullopt;
}

CaptureSummary replay_capture(const std::string& path, const RequestSink& on_request, const FrameSink& on_frame) {
  slproto::CaptureReader reader = open_capture(path);
  CaptureSummary summary;
  // The request's sizes, once checked: every frame must be one of its (view, projector, pattern)
  // slots, each at most once, so what replay builds is bounded by the request's checked sizes
  // (docs/security.md) and a capture holds one consistent scan.
  std::uint64_t request_offset = 0;
  std::optional<FrameSlots> slots;
  for (;;) {
    auto next = reader.next();
    if (!next) throw IoError(next.error().message);
    const slproto::Message* message = *next;
    if (message == nullptr) break;
    ++summary.records;
    const std::uint64_t offset = message->stream_offset;
    if (const auto* request = message->get<slproto::pb::ScanRequest>()) {
      if (summary.request)
        throw IoError(at(path, offset) + "a second scan request (the first is at offset " +
                      std::to_string(request_offset) + "): a capture holds one scan");
      if (summary.frames != 0)
        throw IoError(at(path, offset) + "the scan request comes after " + std::to_string(summary.frames) +
                      " frames; it must come first");
      if (auto status = slproto::check_scan_request(*request); !status)
        throw IoError(at(path, offset) + status.error().message);
      request_offset = offset;
      slots.emplace(*request, offset);
      summary.request = *request;
      if (on_request) on_request(*request);
    } else if (const auto* header = message->get<slproto::pb::FrameHeader>()) {
      if (auto status = slproto::check_frame_geometry(*header, message->payload.size()); !status)
        throw IoError(path + ": frame at offset " + std::to_string(offset) + ": " + status.error().message);
      if (!slots) {
        throw IoError(at(path, offset) + "frame (view " + std::to_string(header->view_index()) + ", projector " +
                      std::to_string(header->projector_id()) + ", pattern " + std::to_string(header->pattern_index()) +
                      ") comes before the scan request: the capture does not say its plan");
      }
      if (auto problem = slots->take(*header, message->payload.size(), offset))
        throw IoError(at(path, offset) + *problem);
      ++summary.frames;
      on_frame(*header, message->payload);
    } else if (const auto* done = message->get<slproto::pb::ScanDone>()) {
      summary.done = *done;
    } else if (const auto* error = message->get<slproto::pb::Error>()) {
      summary.errors.push_back(*error);
    }
  }
  summary.truncation = reader.truncation();
  return summary;
}

std::vector<std::string> describe_missing_frames(const slproto::pb::ScanRequest& request,
                                                 const std::vector<slproto::pb::FrameHeader>& received,
                                                 std::size_t max_lines) {
  std::size_t per_projector_view = 0;
  if (auto config = slproto::from_proto(request.plan()); config) {
    per_projector_view = slproto::PatternPlan(*config).size() * slproto::exposures_of(request).size();
  }
  // One count per (view, projector) of a request check_scan_request bounds (at most 3600 views,
  // projectors unique and < 2): never an entry per pair a lying request names.
  const std::size_t views = static_cast<std::size_t>(request.turntable_angles_deg_size());
  const std::vector<std::uint32_t> projectors(request.projectors().begin(), request.projectors().end());
  std::vector<std::size_t> counts;
  if (auto status = slproto::check_scan_request(request); !status) return {status.error().message};
  counts.assign(views * projectors.size(), 0);
  for (const auto& header : received) {
    const auto p = std::find(projectors.begin(), projectors.end(), header.projector_id());
    if (header.view_index() < views && p != projectors.end())
      ++counts[header.view_index() * projectors.size() + static_cast<std::size_t>(p - projectors.begin())];
  }
  std::vector<std::string> missing;
  std::size_t more_pairs = 0, more_frames = 0;
  for (std::size_t view = 0; view < views; ++view)
    for (std::size_t k = 0; k < projectors.size(); ++k) {
      const std::size_t have = counts[view * projectors.size() + k];
      if (have >= per_projector_view) continue;
      if (missing.size() < max_lines) {
        missing.push_back("view " + std::to_string(view) + " projector " + std::to_string(projectors[k]) + ": " +
                          std::to_string(have) + " of " + std::to_string(per_projector_view) + " frames");
      } else {
        ++more_pairs;
        more_frames += per_projector_view - have;
      }
    }
  if (more_pairs != 0)
    missing.push_back("and " + std::to_string(more_pairs) + " more (view, projector) pairs, " +
                      std::to_string(more_frames) + " frames in all");
  return missing;
}

}  // namespace slscan::io
