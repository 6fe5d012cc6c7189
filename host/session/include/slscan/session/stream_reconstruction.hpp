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

namespace slscan::session {

class StreamReconstruction {
 public:
  StreamReconstruction(const slproto::RigCalibration& calibration, const core::ReconstructionOptions& options);

  // Throws io::IoError naming every field where `plan` differs from the calibration's.
  void set_plan(const slproto::PatternPlan& plan);
  // A std::bad_alloc while decoding becomes core::ReconstructionOutOfMemory naming the frame.
  void add(const slproto::pb::FrameHeader& header, std::span<const std::byte> payload);
  // The final stages and the mesh; `stop` (Ctrl-C) is checked between them
  // (core::ReconstructionInterrupted), a stage out of memory is core::ReconstructionOutOfMemory.
  core::ScanResult finish(const std::atomic<bool>* stop = nullptr);
  // The headers of the frames added so far (timing events dropped), for what is missing.
  const std::vector<slproto::pb::FrameHeader>& received() const { return received_; }

 private:
  slproto::RigCalibration calibration_;
  core::ReconstructionOptions options_;
  std::optional<slproto::PatternPlan> plan_;
  std::unique_ptr<core::ScanReconstructor> reconstructor_;
  std::vector<slproto::pb::FrameHeader> received_;
};

// "period_px 8 in the capture, 16 in the calibration; ..." for each field that differs.
std::string plan_differences(const slproto::PatternPlanConfig& capture, const slproto::PatternPlanConfig& calibration);
// "1140x912 columns P=16 N=8 +complementary", for messages.
std::string describe_plan(const slproto::PatternPlanConfig& config);

}  // namespace slscan::session
