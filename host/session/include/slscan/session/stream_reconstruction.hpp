// Reconstruction fed frame by frame, as they arrive from a scanner or a recorded capture. The
// reconstructor is made on the first frame (the image size comes from the stream), and the
// stream's pattern plan must be the calibration's.
#pragma once

#include <memory>
#include <optional>
#include <span>
#include <vector>

#include "slproto/calibration.hpp"
#include "slproto/messages.hpp"
#include "slproto/pattern_plan.hpp"
#include "slscan/core/scan_reconstruction.hpp"
#include "slscan/session/session_log.hpp"

namespace slscan::session {

class StreamReconstruction {
 public:
  StreamReconstruction(const slproto::RigCalibration& calibration, const core::ReconstructionOptions& options);

  // Throws io::IoError naming every field where `plan` differs from the calibration's.
  void set_plan(const slproto::PatternPlan& plan);
  // The request's exposures (slproto::exposures_of): with a bracket, each projector-view is
  // decoded at every exposure and merged per pixel (docs/hdr.md). Before the first frame.
  void set_exposures(const slproto::pb::ScanRequest& request);
  // A std::bad_alloc while decoding (this frame's, or an earlier frame's job that ran out on a
  // worker thread) becomes core::ReconstructionOutOfMemory naming the frame.
  void add(const slproto::pb::FrameHeader& header, std::span<const std::byte> payload);
  // Gives up the reconstruction and frees its memory (out of memory while frames still arrive:
  // the rest of the scan is only recorded). add() and finish() must not be called after it.
  void abandon() { reconstructor_.reset(); }
  // The final stages and the mesh; `stop` (Ctrl-C) is checked between them and inside them (per
  // view, ICP iteration, block of the mesh: core::ReconstructionInterrupted naming the stage), a
  // stage out of memory is core::ReconstructionOutOfMemory. `log` (if any) is told when the mesh
  // stage begins.
  // `log` (if any) also shows which of the stages (reconstruction_stages) is under way.
  core::ScanResult finish(const std::atomic<bool>* stop = nullptr, const SessionLog* log = nullptr);
  // The headers of the frames added so far (timing events dropped), for what is missing.
  const std::vector<slproto::pb::FrameHeader>& received() const { return received_; }

 private:
  slproto::RigCalibration calibration_;
  core::ReconstructionOptions options_;
  std::optional<slproto::PatternPlan> plan_;
  std::vector<double> exposures_us_;  // the bracket; empty or one: a single exposure
  double reference_exposure_us_ = 0;
  std::unique_ptr<core::ScanReconstructor> reconstructor_;
  std::vector<slproto::pb::FrameHeader> received_;
};

// The stages after the last frame, in order (the keys of core::ScanResult::stage_ms).
const std::vector<std::string>& reconstruction_stages();

// "period_px 8 in the capture, 16 in the calibration; ..." for each field that differs.
std::string plan_differences(const slproto::PatternPlanConfig& capture, const slproto::PatternPlanConfig& calibration);
// "1140x912 columns P=16 N=8 +complementary", for messages.
std::string describe_plan(const slproto::PatternPlanConfig& config);

}  // namespace slscan::session
