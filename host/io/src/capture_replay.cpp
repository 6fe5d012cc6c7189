#include "slscan/io/capture_replay.hpp"

#include <map>

#include "slscan/io/ply.hpp"

namespace slscan::io {

core::FrameInfo frame_info(const slproto::pb::FrameHeader& header) {
  core::FrameInfo info;
  info.view_index = static_cast<int>(header.view_index());
  info.commanded_angle_deg = header.commanded_angle_deg();
  info.reported_angle_deg = header.reported_angle_deg();
  info.projector = static_cast<int>(header.projector_id());
  info.pattern_index = header.pattern_index();
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

CaptureSummary replay_capture(const std::string& path, const RequestSink& on_request, const FrameSink& on_frame) {
  auto reader = slproto::CaptureReader::open(path);
  if (!reader) throw IoError(reader.error().message);
  CaptureSummary summary;
  for (;;) {
    auto next = reader->next();
    if (!next) throw IoError(next.error().message);
    const slproto::Message* message = *next;
    if (message == nullptr) break;
    ++summary.records;
    if (const auto* request = message->get<slproto::pb::ScanRequest>()) {
      summary.request = *request;
      if (on_request) on_request(*request);
    } else if (const auto* header = message->get<slproto::pb::FrameHeader>()) {
      if (auto status = slproto::check_frame_geometry(*header, message->payload.size()); !status)
        throw IoError(path + ": frame at offset " + std::to_string(message->stream_offset) + ": " +
                      status.error().message);
      ++summary.frames;
      on_frame(*header, message->payload);
    } else if (const auto* done = message->get<slproto::pb::ScanDone>()) {
      summary.done = *done;
    } else if (const auto* error = message->get<slproto::pb::Error>()) {
      summary.errors.push_back(*error);
    }
  }
  summary.truncation = reader->truncation();
  return summary;
}

std::vector<std::string> describe_missing_frames(const slproto::pb::ScanRequest& request,
                                                 const std::vector<slproto::pb::FrameHeader>& received) {
  std::map<std::pair<std::uint32_t, std::uint32_t>, std::size_t> counts;
  for (const auto& header : received) ++counts[{header.view_index(), header.projector_id()}];
  std::size_t per_projector_view = 0;
  if (auto config = slproto::from_proto(request.plan()); config) {
    per_projector_view = slproto::PatternPlan(*config).size();
  }
  std::vector<std::string> missing;
  for (int view = 0; view < request.turntable_angles_deg_size(); ++view)
    for (std::uint32_t projector : request.projectors()) {
      const std::size_t have = counts[{static_cast<std::uint32_t>(view), projector}];
      if (have < per_projector_view)
        missing.push_back("view " + std::to_string(view) + " projector " + std::to_string(projector) + ": " +
                          std::to_string(have) + " of " + std::to_string(per_projector_view) + " frames");
    }
  return missing;
}

}  // namespace slscan::io
