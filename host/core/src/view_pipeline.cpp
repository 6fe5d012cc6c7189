#include "slscan/core/view_pipeline.hpp"

#include <stdexcept>
#include <string>

namespace slscan::core {

void ViewPipelineOptions::check() const {
  decode.check();
  triangulate.check();
  flying_pixels.check();
  fusion.check();
  turntable.check();
}

ViewPipeline::ViewPipeline(const slproto::RigCalibration& calibration, const ViewPipelineOptions& options)
    : calibration_(calibration), options_(options), plan_(slproto::PatternPlan()) {
  if (auto status = calibration.check(); !status)
    throw std::invalid_argument("view pipeline: " + status.error().message);
  options_.check();
  plan_ = slproto::PatternPlan(calibration.pattern_plan);
  rays_ = std::make_shared<const CameraRayTable>(CameraRayTable::build(calibration.camera));
  for (std::size_t side = 0; side < 2; ++side) {
    decoders_[side] = std::make_unique<ProjectorViewDecoder>(plan_, calibration.camera.width, calibration.camera.height,
                                                             options_.decode);
    triangulators_[side] = std::make_unique<ProjectorTriangulator>(rays_, calibration.projectors[side],
                                                                   calibration.pattern_plan.axis, options_.triangulate);
  }
}

void ViewPipeline::add_frame(slproto::ProjectorSide side, std::size_t pattern_index, const std::uint8_t* data,
                             std::size_t stride) {
  decoders_.at(index(side))->add_frame(pattern_index, data, stride);
}

void ViewPipeline::add_frame(slproto::ProjectorSide side, std::size_t pattern_index, const std::uint16_t* data,
                             std::size_t stride) {
  decoders_.at(index(side))->add_frame(pattern_index, data, stride);
}

void ViewPipeline::finish_projector(slproto::ProjectorSide side) {
  const std::size_t i = index(side);
  ProjectorViewCounts& counts = counts_[i];
  decoders_[i]->finish(decoded_);
  counts.decode = decoded_.counts;
  OrganizedCloud cloud;
  counts.triangulate = triangulators_[i]->triangulate(decoded_, cloud);
  if (options_.remove_flying_pixels) {
    FlyingPixelResult cleaned = remove_flying_pixels(cloud, options_.flying_pixels);
    counts.flying_pixels = cleaned.counts;
    cloud = std::move(cleaned.cloud);
  } else {
    counts.flying_pixels = {cloud.count_valid(), 0};
  }
  clouds_[i] = std::move(cloud);
}

ViewResult ViewPipeline::finish_view() {
  for (std::size_t i = 0; i < 2; ++i)
    if (!clouds_[i]) finish_projector(static_cast<slproto::ProjectorSide>(i));
  ViewResult result;
  FusionResult fused = fuse_left_right(*clouds_[0], *clouds_[1], options_.fusion);
  result.fusion = fused.counts;
  if (options_.denoise_turntable) {
    auto denoised = denoise_by_turntable(fused.cloud, calibration_.turntable, options_.turntable);
    result.turntable = denoised.counts;
    result.cloud = std::move(denoised.cloud);
  } else {
    result.cloud = std::move(fused.cloud);
  }
  for (std::size_t i = 0; i < 2; ++i) {
    result.per_projector[i] = std::move(*clouds_[i]);
    clouds_[i].reset();
    result.projectors[i] = counts_[i];
    counts_[i] = {};
  }
  return result;
}

}  // namespace slscan::core
