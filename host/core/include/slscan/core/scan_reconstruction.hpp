// The whole reconstruction of one scan, fed frame by frame in stream order: each
// projector-view is decoded and triangulated on a worker while the next one streams in; each
// view is fused, cleaned and given normals as soon as both projectors are done; finish()
// registers the views, cleans the merged model and meshes it. No I/O: the live scan and
// reprocessing feed the same object the same frames and get the same result, bit for bit.
#pragma once

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "slproto/calibration.hpp"
#include "slproto/pattern_plan.hpp"
#include "slscan/core/cloud_filters.hpp"
#include "slscan/core/decode.hpp"
#include "slscan/core/depth_smoothing.hpp"
#include "slscan/core/exposure_merge.hpp"
#include "slscan/core/fusion.hpp"
#include "slscan/core/mesh.hpp"
#include "slscan/core/normals.hpp"
#include "slscan/core/point_cloud.hpp"
#include "slscan/core/registration.hpp"
#include "slscan/core/triangulate.hpp"
#include "slscan/core/turntable_denoise.hpp"
#include "slscan/core/view_overlap.hpp"

namespace slscan::core {

struct ReconstructionOptions {
  DecodeOptions decode;
  TriangulateOptions triangulate;
  FusionOptions fusion;
  bool remove_flying_pixels = true;  // on each projector's cloud, before fusion
  FlyingPixelOptions flying_pixels;
  // Noise-adaptive limits (docs/pipeline.md): each projector-view's depth noise is estimated
  // from its own grid (noise_estimate.hpp: the better-lit half of the view), and the
  // flying-pixel limit becomes at least noise_factor x its second-difference sigma, the fusion
  // agreement at least noise_factor x the difference of two points' noise. The fixed values
  // above stay the floor: the rig's own noise is far below them (small rig: 3 x 0.014 mm
  // against 0.1 mm), so its scans are those of the fixed limits. 0: the fixed values only; the
  // estimates are reported either way. decode.noise_factor is the decoder's gate (config
  // noise.factor sets both).
  double noise_factor = 3;
  bool denoise_turntable = true;  // false keeps the platform and background (accuracy studies)
  TurntableDenoiseOptions turntable_denoise;
  GridNormalOptions grid_normals;
  bool register_views = true;  // false: coarse turntable poses only
  RegistrationOptions registration;
  // Statistical outlier removal on each view's organised cloud, neighbours from the image grid
  // (cloud_filters.hpp), on the worker that fused it: it runs while the next view streams in.
  bool remove_outliers = true;
  StatisticalOutlierOptions outliers;
  // Depth smoothing of each view's cloud over its pixel grid (depth_smoothing.hpp), on the
  // worker, after outlier removal and before the normals: each point slides along its camera
  // ray to a local quadratic fit. Off: every point exactly as triangulated.
  bool smooth_depth = true;
  DepthSmoothingOptions depth_smoothing;
  // Where registered views overlap, a point seen steeper than overlap.max_incidence_deg gives
  // way to another view's measurement of the same spot within that limit (view_overlap.hpp).
  bool select_best_views = true;
  OverlapSelectionOptions overlap;
  double voxel_mm = 0;  // > 0: thin the merged model to one point per voxel
  // The model's normals: 0 keeps each view's grid normals (from its organised cloud, facing
  // its camera: outward), computed on the workers; >= 3 recomputes PCA normals over the merged
  // model with that many neighbours (slower, after the last frame; smoother where views overlap).
  int normal_neighbors = 0;
  // The mesh is built by the session layer (slscan_mesh, StreamReconstruction::finish()), not
  // by ScanReconstructor::finish(): core does not link OpenVDB.
  bool build_mesh = true;
  MeshOptions mesh;
  MeshFormats mesh_formats;  // which mesh files the app writes (not used by the reconstruction)
  // Decoders in flight, each holding one projector-view of frames (19 x 5 MP = 96 MB at full
  // resolution). 0: the threads the process may use + 1 (one receiving while every thread
  // decodes); more only holds more frames in memory. A live scan's frames come far slower than
  // they decode (docs/architecture.md, "Threads"), so only a reprocess ever fills the bound.
  int max_pending_projector_views = 0;
  // Keep each projector's cloud (after flying-pixel removal) in ViewProducts, and the fused
  // grid's intensity: for accuracy studies and the per-projector reports; off in scans (two
  // more clouds per view in memory; the albedo is in ViewProducts::points).
  bool keep_projector_clouds = false;

  void check() const;  // throws std::invalid_argument naming the field
};

// Where a fused pixel came from.
enum class FusionSource : std::uint8_t { none = 0, left = 1, right = 2, both = 3, rejected = 4 };

struct ProjectorViewReport {
  bool present = false;
  DecodeCounts decode;
  // The decoder's self-checks (decode_checks.hpp), plus a "geometry" finding when most decoded
  // pixels do not triangulate (the axis, the pose direction or the calibration does not fit).
  DecodeChecks checks;
  double coordinate_noise_px = 0;         // the decoder's estimate (unsmoothed coordinate)
  float smoothing_max_deviation_px = 0;   // the decoder's smoothing gate as used
  double depth_noise_mm = 0;              // per point, from the triangulated grid (before cleanup)
  double depth_second_difference_mm = 0;  // its second-difference sigma (what the flying-pixel test sees)
  // Modulation against the irradiance the geometry implies (cos incidence / distance^2, log
  // terms, Pearson): high where the pose is right (scan_reconstruction.cpp).
  double shading_correlation = 0;
  TriangulateCounts triangulate;
  FlyingPixelCounts flying_pixels;
  double decode_ms = 0, triangulate_ms = 0;  // decode: every exposure's, and their merge
  // HDR (a capture with an exposure bracket): what each exposure gave, in bracket order; empty
  // for a single exposure. A projector-view some exposures of which never arrived is merged from
  // the ones that did, with a finding ("exposures") saying which are missing.
  std::vector<ExposureShare> exposures;
};

struct ViewReport {
  int view_index = 0;
  double commanded_angle_deg = 0, reported_angle_deg = 0;
  std::array<ProjectorViewReport, 2> projectors;
  FusionCounts fusion;
  float flying_max_abs_mm = 0, fusion_agreement_mm = 0;  // the limits used (noise-adaptive)
  double noise_factor = 0;                               // ReconstructionOptions::noise_factor
  FlyingPixelCounts flying_pixels;                       // both projectors' together
  TurntableDenoiseCounts turntable_denoise;
  std::size_t points = 0;  // in the view's cloud after cleaning
  std::size_t outliers_removed = 0;
  DepthSmoothingCounts depth_smoothing;
  double fuse_ms = 0;  // all of the view's cleanup below, on its worker
  double flying_pixels_ms = 0, fusion_ms = 0, denoise_ms = 0, normals_ms = 0, outliers_ms = 0, smoothing_ms = 0;
};

// What a view leaves for reports and pictures (camera frame of that view).
struct ViewProducts {
  // Fused, flying pixels and turntable removed, valid slots only; intensity only with keep_projector_clouds.
  SparseOrganizedCloud cloud;
  std::vector<FusionSource> source;                // per pixel
  std::array<OrganizedCloud, 2> projector_clouds;  // only with keep_projector_clouds
  PointCloud points;                               // cloud's valid points with grid normals
  // HDR: per pixel, the bracket member each projector's merged decode took it from
  // (kNotDecoded where it did not decode); empty without a bracket.
  static constexpr std::uint8_t kNotDecoded = 255;
  std::array<std::vector<std::uint8_t>, 2> exposure_member;
};

struct ScanResult {
  std::vector<ViewReport> views;
  std::vector<ViewProducts> view_products;
  RegistrationResult registration;
  bool registered = false;         // false: coarse turntable poses only
  std::string registration_error;  // why fine registration was not applied, if it failed
  PointCloud model;                // turntable frame, normals outward, confidence and view id kept
  std::size_t merged_points = 0, outliers_removed = 0;
  OverlapSelectionCounts overlap;  // steep points replaced by a better view's
  // Filled by session::StreamReconstruction::finish() (slscan_mesh), not by core.
  bool meshed = false;
  MeshResult mesh;
  std::string mesh_error;                  // why the model was not meshed (bad cloud), when build_mesh was set
  std::map<std::string, double> stage_ms;  // wall time of each stage after the last frame
};

struct FrameInfo {
  int view_index = 0;
  double commanded_angle_deg = 0;
  double reported_angle_deg = 0;
  int projector = 0;               // 0 left, 1 right
  std::size_t pattern_index = 0;   // position in the pattern plan
  std::size_t exposure_index = 0;  // position in the exposure bracket (set_exposure_bracket), 0 without one
  std::size_t stride_bytes = 0;
  int bytes_per_pixel = 1;  // 1 (8-bit) or 2 (uint16)
};

// Thrown by finish() when its stop flag is set (Ctrl-C after the last frame), at a stage
// boundary or inside a stage; stage() names the stage it ended. Not a std::runtime_error: stages that catch those
// (registration) must not swallow it.
class ReconstructionInterrupted : public std::exception {
 public:
  explicit ReconstructionInterrupted(std::string stage) : stage_(std::move(stage)) {}
  const std::string& stage() const { return stage_; }
  const char* what() const noexcept override { return stage_.c_str(); }

 private:
  std::string stage_;
};

// A stage of the reconstruction ran out of memory (std::bad_alloc): which one. Not a
// std::runtime_error either, for the same reason.
class ReconstructionOutOfMemory : public std::exception {
 public:
  explicit ReconstructionOutOfMemory(std::string stage) : stage_(std::move(stage)) {}
  const std::string& stage() const { return stage_; }
  const char* what() const noexcept override { return stage_.c_str(); }

 private:
  std::string stage_;
};

class ScanReconstructor {
 public:
  // Throws std::invalid_argument on an impossible calibration, plan or size, or a camera size
  // that differs from the calibration's.
  ScanReconstructor(const slproto::RigCalibration& calibration, const slproto::PatternPlan& plan, int width, int height,
                    const ReconstructionOptions& options = {});
  ~ScanReconstructor();
  ScanReconstructor(const ScanReconstructor&) = delete;
  ScanReconstructor& operator=(const ScanReconstructor&) = delete;

  // HDR: every projector-view comes at each of these exposures (us, bracket order; the frames'
  // exposure_index), decoded one by one and merged per pixel (ExposureMerge), intensities
  // scaled to `reference_us`. Before the first frame; without it, one exposure. Throws
  // std::invalid_argument on an empty or oversized bracket, a non-positive exposure, or after
  // a frame.
  void set_exposure_bracket(const std::vector<double>& exposures_us, double reference_us);

  // One camera frame. Views and projectors may arrive in any order, but a view's frames must
  // all arrive before finish(). Throws std::invalid_argument naming what is wrong (projector id,
  // pattern index, size, a view whose angle changed between frames), and std::bad_alloc when
  // this frame, or a projector-view's job queued earlier, ran out of memory.
  void add_frame(const FrameInfo& info, std::span<const std::byte> pixels);

  // Number of projector-views completed so far (decoded and triangulated or queued).
  std::size_t completed_projector_views() const;

  // Waits for the workers, then fuses what is left, registers, cleans and meshes. Views that
  // lack a projector's frames are reconstructed from the projector that is complete; a view
  // with no complete projector is skipped and counted in `incomplete_views`. `stop` (Ctrl-C) is
  // checked between stages and inside them (per projector-view still to decode, per view, per
  // ICP iteration): set, finish() throws ReconstructionInterrupted naming the stage.
  // A stage that runs out of memory throws ReconstructionOutOfMemory naming it. `on_stage`, when
  // given, is told each stage's name (the keys of ScanResult::stage_ms) as it begins.
  ScanResult finish(const std::atomic<bool>* stop = nullptr, const std::function<void(const char*)>& on_stage = {});
  std::vector<int> incomplete_views() const;

 private:
  ScanResult final_stages(const std::function<void(const char*)>& begin_stage, const InterruptionPoint& interrupt,
                          const std::atomic<bool>* stop);
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace slscan::core
