#include "slscan/session/stream_reconstruction.hpp"

#include <algorithm>
#include <chrono>
#include <new>
#include <string>

#include "slscan/io/capture_replay.hpp"
#include "slscan/io/io_error.hpp"
#include "slscan/mesh/mesher.hpp"

namespace slscan::session {

StreamReconstruction::StreamReconstruction(const slproto::RigCalibration& calibration,
                                           const core::ReconstructionOptions& options)
    : calibration_(calibration), options_(options) {}

void StreamReconstruction::set_plan(const slproto::PatternPlan& plan) {
  // The fringe period may differ (slscan scan --fringe-period-px): the calibration maps
  // projector coordinates, whatever period coded them. The rest must be the calibration's.
  slproto::PatternPlanConfig calibrated = calibration_.pattern_plan;
  calibrated.period_px = plan.config().period_px;
  if (!(plan.config() == calibrated))
    throw io::IoError("the capture's pattern plan differs from the plan the calibration was made with: " +
                      plan_differences(plan.config(), calibrated) + " (capture " + describe_plan(plan.config()) +
                      ", calibration " + describe_plan(calibration_.pattern_plan) + ")");
  plan_ = plan;
}

void StreamReconstruction::set_exposures(const slproto::pb::ScanRequest& request) {
  if (reconstructor_) throw io::IoError("the exposure bracket is set after the first frame");
  exposures_us_.clear();
  for (const std::uint32_t us : slproto::exposures_of(request)) exposures_us_.push_back(us);
  reference_exposure_us_ = request.exposure_us();
}

void StreamReconstruction::add(const slproto::pb::FrameHeader& header, std::span<const std::byte> payload) {
  if (!plan_) throw io::IoError("a frame arrived before the scan request: the capture does not say its pattern plan");
  try {
    if (!reconstructor_) {
      reconstructor_ = std::make_unique<core::ScanReconstructor>(calibration_, *plan_, static_cast<int>(header.width()),
                                                                 static_cast<int>(header.height()), options_);
      if (exposures_us_.size() > 1) reconstructor_->set_exposure_bracket(exposures_us_, reference_exposure_us_);
    }
    reconstructor_->add_frame(io::frame_info(header), payload);
  } catch (const std::bad_alloc&) {
    throw core::ReconstructionOutOfMemory("decode (the frame of view " + std::to_string(header.view_index()) +
                                          ", projector " + std::to_string(header.projector_id()) + ", pattern " +
                                          std::to_string(header.pattern_index()) + ")");
  }
  received_.push_back(header);
  received_.back().clear_timing_events();
}

const std::vector<std::string>& reconstruction_stages() {
  static const std::vector<std::string> stages{"wait_for_views", "fuse_remaining", "register", "select_views",
                                               "merge",          "voxel",          "normals",  "mesh"};
  return stages;
}

core::ScanResult StreamReconstruction::finish(const std::atomic<bool>* stop, const SessionLog* log) {
  if (!reconstructor_) throw io::IoError("the capture holds no frames");
  const std::vector<std::string>& stages = reconstruction_stages();
  auto show = [&](const char* stage) {
    if (log == nullptr) return;
    const auto at = std::find(stages.begin(), stages.end(), stage);
    log->progress({"reconstruction", static_cast<std::size_t>(at - stages.begin()), stages.size(), {}, stage});
  };
  core::ScanResult result;
  try {
    result = reconstructor_->finish(stop, show);
  } catch (...) {
    if (log != nullptr) log->end_progress();
    throw;
  }
  const core::InterruptionPoint interrupt = [stop, log] {
    if (stop == nullptr || !stop->load()) return;
    if (log != nullptr) log->end_progress();
    throw core::ReconstructionInterrupted("mesh");
  };
  interrupt();
  show("mesh");
  // The mesh step (slscan_mesh): here rather than in core, which does not link OpenVDB. A cloud
  // the mesher refuses leaves the model and the reports as they are, with the reason.
  const auto start = std::chrono::steady_clock::now();
  if (options_.build_mesh && result.model.has_normals() && result.model.size() >= 100) {
    if (log != nullptr) log->info("meshing " + std::to_string(result.model.size()) + " points");
    try {
      result.mesh = mesh::build_mesh(result.model, options_.mesh, interrupt);
      result.meshed = true;
    } catch (const std::invalid_argument& e) {
      result.mesh_error = e.what();
    } catch (const std::bad_alloc&) {
      if (log != nullptr) log->end_progress();
      throw core::ReconstructionOutOfMemory("mesh");
    }
  }
  result.stage_ms["mesh"] = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  if (log != nullptr) {
    log->progress({"reconstruction", stages.size(), stages.size(), {}, "done"});
    log->end_progress();
  }
  return result;
}

std::string plan_differences(const slproto::PatternPlanConfig& capture, const slproto::PatternPlanConfig& calib) {
  std::string out;
  auto field = [&](const char* name, const std::string& a, const std::string& b) {
    if (a == b) return;
    out += (out.empty() ? "" : "; ") + std::string(name) + " " + a + " in the capture, " + b + " in the calibration";
  };
  auto yes_no = [](bool v) { return std::string(v ? "true" : "false"); };
  field("projector_width", std::to_string(capture.projector_width), std::to_string(calib.projector_width));
  field("projector_height", std::to_string(capture.projector_height), std::to_string(calib.projector_height));
  field("axis", slproto::coding_axis_name(capture.axis), slproto::coding_axis_name(calib.axis));
  field("period_px", std::to_string(capture.period_px), std::to_string(calib.period_px));
  field("phase_steps", std::to_string(capture.phase_steps), std::to_string(calib.phase_steps));
  field("complementary_bit", yes_no(capture.complementary_bit), yes_no(calib.complementary_bit));
  field("with_white_black", yes_no(capture.with_white_black), yes_no(calib.with_white_black));
  field("inverse_gray", yes_no(capture.inverse_gray), yes_no(calib.inverse_gray));
  field("gray_low_bits", slproto::gray_low_bits_name(capture.gray_low_bits),
        slproto::gray_low_bits_name(calib.gray_low_bits));
  field("phase_offset_rad", std::to_string(capture.phase_offset_rad), std::to_string(calib.phase_offset_rad));
  field("phase_offset_steps", std::to_string(capture.phase_offset_steps), std::to_string(calib.phase_offset_steps));
  return out;
}

std::string describe_plan(const slproto::PatternPlanConfig& c) {
  return std::to_string(c.projector_width) + "x" + std::to_string(c.projector_height) + " " +
         slproto::coding_axis_name(c.axis) + " P=" + std::to_string(c.period_px) +
         " N=" + std::to_string(c.phase_steps) + (c.complementary_bit ? " +complementary" : "") +
         (c.with_white_black ? "" : " -white/black") + (c.inverse_gray ? " +inverse" : "") +
         (c.gray_low_bits == slproto::GrayLowBits::centre
              ? ""
              : std::string(" ") + slproto::gray_low_bits_name(c.gray_low_bits));
}

}  // namespace slscan::session
