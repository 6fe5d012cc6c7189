// The per-view glue of stages 1-4: frames of both projectors in, one fused, denoised organised
// cloud (camera frame) out, with the counts of every stage for the scan report. Construct once
// per calibration (it builds the camera ray table and the frame stores); then for each view
// feed frames as they stream in, finish each projector as soon as its last frame arrived (so
// its decode overlaps the other projector's capture), and finish the view.
#pragma once

#include <array>
#include <memory>
#include <optional>

#include "slproto/calibration.hpp"
#include "slscan/core/decode.hpp"
#include "slscan/core/fusion.hpp"
#include "slscan/core/triangulate.hpp"
#include "slscan/core/turntable_denoise.hpp"

namespace slscan::core {

struct ViewPipelineOptions {
  DecodeOptions decode;
  TriangulateOptions triangulate;
  bool remove_flying_pixels = true;
  FlyingPixelOptions flying_pixels;
  FusionOptions fusion;
  bool denoise_turntable = true;
  TurntableDenoiseOptions turntable;
  void check() const;  // every part's check()
};

struct ProjectorViewCounts {
  DecodeCounts decode;
  TriangulateCounts triangulate;
  FlyingPixelCounts flying_pixels;
};

struct ViewResult {
  OrganizedCloud cloud;                           // fused (and denoised), camera frame
  std::array<OrganizedCloud, 2> per_projector;    // after flying-pixel removal, before fusion
  std::array<ProjectorViewCounts, 2> projectors;  // indexed by ProjectorSide
  FusionCounts fusion;
  TurntableDenoiseCounts turntable;
};

class ViewPipeline {
 public:
  // Throws std::invalid_argument if the calibration or the options fail their checks.
  explicit ViewPipeline(const slproto::RigCalibration& calibration, const ViewPipelineOptions& options = {});

  const slproto::PatternPlan& plan() const { return plan_; }
  const std::shared_ptr<const CameraRayTable>& rays() const { return rays_; }

  void add_frame(slproto::ProjectorSide side, std::size_t pattern_index, const std::uint8_t* data, std::size_t stride);
  void add_frame(slproto::ProjectorSide side, std::size_t pattern_index, const std::uint16_t* data, std::size_t stride);
  // Decode, triangulate and clean one projector's cloud (throws if a frame is missing).
  void finish_projector(slproto::ProjectorSide side);
  // Finishes the projectors not finished yet, fuses and denoises; readies the next view.
  ViewResult finish_view();

 private:
  static std::size_t index(slproto::ProjectorSide side) { return static_cast<std::size_t>(side); }

  slproto::RigCalibration calibration_;
  ViewPipelineOptions options_;
  slproto::PatternPlan plan_;
  std::shared_ptr<const CameraRayTable> rays_;
  std::array<std::unique_ptr<ProjectorViewDecoder>, 2> decoders_;
  std::array<std::unique_ptr<ProjectorTriangulator>, 2> triangulators_;
  std::array<std::optional<OrganizedCloud>, 2> clouds_;
  std::array<ProjectorViewCounts, 2> counts_;
  DecodedView decoded_;  // scratch reused across projectors and views
};

}  // namespace slscan::core
