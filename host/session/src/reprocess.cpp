#include "slscan/session/reprocess.hpp"

#include <new>
#include <stdexcept>

#include "slscan/io/io_error.hpp"
#include "slscan/session/stream_reconstruction.hpp"

namespace slscan::session {

ReprocessResult reprocess_capture(const std::string& capture_path, const slproto::RigCalibration& calibration,
                                  const core::ReconstructionOptions& options, const SessionLog& log, StopFlag stop) {
  StreamReconstruction stream(calibration, options);
  std::size_t expected_frames = 0;
  ReprocessResult out;
  auto replay = [&](auto&& on_request, auto&& on_frame) {
    try {
      return io::replay_capture(capture_path, on_request, on_frame);
    } catch (const std::bad_alloc&) {
      throw core::ReconstructionOutOfMemory("reading the capture's frames");
    }
  };
  out.summary = replay(
      [&](const slproto::pb::ScanRequest& scan_request) {
        const slproto::PatternPlan plan = io::plan_of(scan_request);
        stream.set_plan(plan);
        stream.set_exposures(scan_request);
        expected_frames = plan.size() * slproto::exposures_of(scan_request).size() *
                          static_cast<std::size_t>(scan_request.turntable_angles_deg_size()) *
                          static_cast<std::size_t>(scan_request.projectors_size());
      },
      [&](const slproto::pb::FrameHeader& header, std::span<const std::byte> payload) {
        if (stop != nullptr && stop->load()) throw core::ReconstructionInterrupted("frames");
        stream.add(header, payload);
        log.progress({"frames", stream.received().size(), expected_frames, "frames", {}});
      });
  log.end_progress();
  if (!out.summary.request) throw io::IoError(capture_path + ": the capture has no scan request");
  out.missing = io::describe_missing_frames(*out.summary.request, stream.received());
  if (out.summary.truncation)
    log.warn(capture_path + " is truncated at byte " + std::to_string(out.summary.truncation->record_offset) + " (" +
             out.summary.truncation->what + "); reconstructing the " + std::to_string(out.summary.frames) +
             " complete frames before it");
  for (const auto& line : out.missing) log.warn("missing: " + line);
  for (const auto& error : out.summary.errors) log.warn("the board reported: " + error.text());
  log.info("reconstructing " + std::to_string(out.summary.frames) + " frames");
  try {
    out.reconstruction = stream.finish(stop, &log);
  } catch (const std::invalid_argument& e) {
    // A stage refusing its input (its message names the stage and the item): say which capture.
    throw std::invalid_argument(capture_path + ": reconstructing the capture: " + e.what());
  }
  return out;
}

}  // namespace slscan::session
