#include "slscan/core/scan_reconstruction.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <tbb/task_group.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <exception>
#include <functional>
#include <mutex>
#include <new>
#include <optional>
#include <stdexcept>
#include <tuple>
#include <utility>

#include "slproto/number_text.hpp"
#include "slscan/core/noise_estimate.hpp"

namespace slscan::core {

namespace {

using Clock = std::chrono::steady_clock;

using slproto::short_number;

double ms_since(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

}  // namespace

void ReconstructionOptions::check() const {
  decode.check();
  triangulate.check();
  fusion.check();
  flying_pixels.check();
  turntable_denoise.check();
  depth_smoothing.check();
  overlap.check();
  mesh.check();
  if (!mesh_formats.any())
    throw std::invalid_argument(
        "reconstruction options: mesh.formats names no file format (ply, stl, obj, 3mf); to write no mesh, set "
        "mesh.enabled false");
  if (!(noise_factor >= 0) || !std::isfinite(noise_factor))
    throw std::invalid_argument("reconstruction options: noise_factor must be a finite value >= 0 (0: fixed limits)");
  // A voxel below a micron thins nothing and costs a hash entry per point; above a metre it
  // leaves a handful of points: both are typos, not requests.
  if (voxel_mm != 0 && !(voxel_mm >= 0.001 && voxel_mm <= 1000))
    throw std::invalid_argument("reconstruction options: model.voxel_mm " + short_number(voxel_mm) +
                                " outside [0.001, 1000] mm (0: no thinning)");
  if (normal_neighbors != 0 && normal_neighbors < 3)
    throw std::invalid_argument("reconstruction options: normal_neighbors must be 0 (the views' grid normals) or >= 3");
  if (outliers.k < 1 || !(outliers.std_ratio > 0))
    throw std::invalid_argument("reconstruction options: outliers need k >= 1 and std_ratio > 0");
  if (grid_normals.window_radius < 1 || grid_normals.window_radius > 8 ||
      !(grid_normals.max_neighbor_distance_mm > 0) || grid_normals.min_neighbors < 3)
    throw std::invalid_argument(
        "reconstruction options: normals need window_radius in [1, 8], max_neighbor_distance_mm > 0 and "
        "min_neighbors >= 3");
  if (max_pending_projector_views < 0)
    throw std::invalid_argument("reconstruction options: max_pending_projector_views must be >= 0 (0: automatic)");
}

namespace {

// Lambertian shading against the geometry: the decoded modulation is proportional to the
// projector's irradiance, albedo x cos(incidence) / distance^2, so over a surface of even albedo
// it correlates with that term computed from the triangulated points, their grid normals and the
// projector's centre. A wrong pose (its direction read the other way) gives a surface that is
// smooth and in front of both devices, but lit the wrong way. Pearson correlation of log terms
// over every 4th row; NaN with too few points.
double shading_correlation(const OrganizedCloud& cloud, const slproto::RigidTransform& cam_from_proj) {
  const Eigen::Vector3f centre(static_cast<float>(cam_from_proj.t[0]), static_cast<float>(cam_from_proj.t[1]),
                               static_cast<float>(cam_from_proj.t[2]));
  const int w = cloud.width, h = cloud.height;
  double n = 0, sx = 0, sy = 0, sxx = 0, syy = 0, sxy = 0;
  for (int v = 1; v + 1 < h; v += 4)
    for (int u = 1; u + 1 < w; u += 2) {
      auto at = [&](int du, int dv) {
        return static_cast<std::size_t>(v + dv) * static_cast<std::size_t>(w) + static_cast<std::size_t>(u + du);
      };
      const std::size_t c = at(0, 0), l = at(-1, 0), r = at(1, 0), a = at(0, -1), b = at(0, 1);
      if (!cloud.valid[c] || !cloud.valid[l] || !cloud.valid[r] || !cloud.valid[a] || !cloud.valid[b]) continue;
      if (!(cloud.quality[c] > 0)) continue;
      Eigen::Vector3f normal = (cloud.points[r] - cloud.points[l]).cross(cloud.points[b] - cloud.points[a]);
      if (!(normal.norm() > 0)) continue;
      normal.normalize();
      if (normal.dot(cloud.points[c]) > 0) normal = -normal;  // facing the camera
      const Eigen::Vector3f to_projector = centre - cloud.points[c];
      const float d2 = to_projector.squaredNorm();
      const float cosine = normal.dot(to_projector) / std::sqrt(d2);
      const double x = std::log(std::max(cosine, 0.02f) / d2), y = std::log(cloud.quality[c]);
      n += 1;
      sx += x;
      sy += y;
      sxx += x * x;
      syy += y * y;
      sxy += x * y;
    }
  if (n < 500) return std::nan("");
  const double cov = sxy / n - sx / n * sy / n, vx = sxx / n - sx / n * sx / n, vy = syy / n - sy / n * sy / n;
  return vx > 0 && vy > 0 ? cov / std::sqrt(vx * vy) : std::nan("");
}

// Decoded pixels that mostly fail to triangulate: the codes are right but the geometry they are
// put into is not (a wrong coding axis, pose direction or calibration).
void add_geometry_check(ProjectorViewReport& report) {
  constexpr double kMinShare = 0.5;
  // Measured on the virtual rig: 0.87 with the right pose, -0.67 read the other way.
  constexpr double kMinShading = 0.1;
  const std::size_t decoded = report.decode.valid;
  if (decoded < 1000) return;
  const double share = static_cast<double>(report.triangulate.valid) / static_cast<double>(decoded);
  if (share >= kMinShare) {
    if (std::isfinite(report.shading_correlation) && report.shading_correlation < kMinShading) {
      char value[32];
      std::snprintf(value, sizeof value, "%.2f", report.shading_correlation);
      report.checks.findings.push_back(
          {"geometry",
           std::string("the decoded modulation does not follow the light the geometry implies (shading correlation ") +
               value + ", a right pose gives ~0.9): the projector's pose is probably read the wrong way",
           "the other pose direction (--pose-direction cam_from_proj or proj_from_cam), or a calibration that "
           "belongs to this capture; slscan import --detect tries it"});
    }
    return;
  }
  const auto& t = report.triangulate;
  std::string why;
  auto add = [&](std::size_t count, const char* what) {
    if (count == 0) return;
    why += (why.empty() ? "" : ", ") + std::to_string(count) + " " + what;
  };
  add(t.outside_frustum, "outside the projector image");
  add(t.no_intersection, "without an intersection");
  add(t.outside_depth, "outside the depth range");
  add(t.not_converged, "not converged");
  char percent[32];
  std::snprintf(percent, sizeof percent, "%.1f %%", 100 * share);
  report.checks.findings.push_back(
      {"geometry",
       std::string("only ") + percent + " of the " + std::to_string(decoded) + " decoded pixels triangulate (" + why +
           ")",
       "the codes are consistent but the geometry is not: check the coding axis (axis), the calibration's pose "
       "direction (--pose-direction) and that the calibration belongs to this capture; slscan import --detect tries "
       "them"});
}

}  // namespace

struct ScanReconstructor::Impl {
  slproto::RigCalibration calibration;
  slproto::PatternPlan plan;
  int width = 0, height = 0;
  ReconstructionOptions options;
  std::array<std::unique_ptr<ProjectorTriangulator>, 2> triangulators;

  struct ViewState {
    double commanded_angle_deg = 0, reported_angle_deg = 0;
    // Bracket members whose frames are all in (bit e: exposure e), per projector.
    std::array<std::uint32_t, 2> exposures_queued{};
    std::array<std::optional<TriangulatedView>, 2> triangulated;
    std::array<std::vector<std::uint8_t>, 2> exposure_member;  // HDR: ViewProducts::exposure_member
    ViewReport report;
    ViewProducts products;
    bool fused = false;
  };

  // A complete projector-view waiting for a thread to decode and triangulate it.
  struct Job {
    int view_index = 0, projector = 0, exposure = 0;
    std::unique_ptr<ProjectorViewDecoder> decoder;
  };

  // A projector-view's exposures merging as they are decoded (HDR), one at a time.
  struct Merging {
    std::mutex mutex;
    std::unique_ptr<ExposureMerge> merge;
    double decode_ms = 0;
  };

  std::vector<double> exposures_us{0};  // the bracket; one entry (unused) without one
  double reference_exposure_us = 0;
  bool frames_seen = false;

  std::mutex mutex;                          // guards everything below
  std::condition_variable decoder_released;  // a decoder came back or a running job ended
  std::vector<std::unique_ptr<ProjectorViewDecoder>> free_decoders;
  int decoders_in_flight = 0;
  // (view, projector, exposure index)
  std::map<std::tuple<int, int, int>, std::unique_ptr<ProjectorViewDecoder>> receiving;
  std::map<std::pair<int, int>, Merging> merging;  // (view, projector) with a bracket
  std::deque<Job> queued;                          // complete projector-views not started yet, oldest first
  int jobs_running = 0;                            // jobs some thread is executing right now
  std::exception_ptr job_error;                    // the first job that threw; finish() rethrows it
  // Set by finish(): Ctrl-C while the last projector-views wait for a thread (one CPU) ends
  // each job before it decodes (ReconstructionInterrupted, rethrown by finish()).
  std::atomic<const std::atomic<bool>*> stop{nullptr};
  std::map<int, ViewState> views;
  // Grids the views are done with (the projector clouds once fused, the fused grid once listed
  // as slots), handed to the next projector-view's triangulation and the next view's fusion,
  // which write every slot: at full resolution each is 85-105 MB that the kernel would otherwise
  // zero again (docs/scale.md "Grids passed on"). Emptied when the views are done.
  std::vector<OrganizedCloud> spare_grids;
  static constexpr std::size_t kMaxSpareGrids = 3;  // what one view gives back and takes
  std::size_t completed = 0;
  std::vector<int> incomplete;
  tbb::task_group workers;

  // The scheduling rule (docs/architecture.md, "Threads"): a thread never blocks on work that
  // is only queued. Each job lives in `queued`, and every task given to `workers` runs whichever
  // job is first there (or nothing, if another thread took it). A thread that needs a decoder
  // while all are in flight runs queued jobs itself, and waits only while a job runs on
  // another thread, which will hand a decoder back. With one worker thread (taskset -c 0, a
  // one-CPU container) the tbb tasks run only when the producer waits in finish(), so waiting
  // for them in add_frame would wait for ever.
  std::unique_ptr<ProjectorViewDecoder> acquire_decoder(std::unique_lock<std::mutex>& lock) {
    for (;;) {
      if (!free_decoders.empty() || decoders_in_flight < options.max_pending_projector_views) break;
      if (!queued.empty()) {
        run_first_queued(lock);
        continue;
      }
      // Every decoder in flight holds a projector-view still receiving frames (the input
      // interleaves more projector-views than the bound): nothing would ever hand one back.
      if (jobs_running == 0) break;
      decoder_released.wait(lock);
    }
    ++decoders_in_flight;
    if (!free_decoders.empty()) {
      auto decoder = std::move(free_decoders.back());
      free_decoders.pop_back();
      decoder->reset();
      return decoder;
    }
    return std::make_unique<ProjectorViewDecoder>(plan, width, height, options.decode);
  }

  void release_decoder(std::unique_ptr<ProjectorViewDecoder> decoder) {
    {
      std::lock_guard lock(mutex);
      free_decoders.push_back(std::move(decoder));
      --decoders_in_flight;
    }
    decoder_released.notify_all();
  }

  // Runs the oldest queued job on this thread; `lock` is held on entry and on return, released
  // while the job runs. A job's exception is kept for finish(), so it surfaces in the same place
  // whichever thread ran the job.
  void run_first_queued(std::unique_lock<std::mutex>& lock) {
    Job job = std::move(queued.front());
    queued.pop_front();
    ++jobs_running;
    lock.unlock();
    std::exception_ptr error;
    try {
      process_projector_view(job.view_index, job.projector, job.exposure, std::move(job.decoder));
    } catch (...) {
      error = std::current_exception();
    }
    lock.lock();
    --jobs_running;
    if (error && !job_error) job_error = error;
    decoder_released.notify_all();
  }

  // A tbb task: one queued job, if a thread that needed a decoder has not run it already.
  void run_queued_task() {
    std::unique_lock lock(mutex);
    if (!queued.empty()) run_first_queued(lock);
  }

  // Decodes and triangulates one complete projector-view, on whichever thread runs its job.
  void process_projector_view(int view_index, int projector, int exposure,
                              std::unique_ptr<ProjectorViewDecoder> decoder) {
    struct Release {
      Impl* self;
      std::unique_ptr<ProjectorViewDecoder>* decoder;
      ~Release() { self->release_decoder(std::move(*decoder)); }
    };
    ProjectorViewReport report;
    report.present = true;
    DecodedView decoded;
    {
      // The decoder (its frames) goes back to the pool as soon as they are decoded, or on a
      // throw: the next projector-view can stream into it while this one is triangulated.
      const Release release{this, &decoder};
      if (const std::atomic<bool>* flag = stop.load(); flag != nullptr && flag->load())
        throw ReconstructionInterrupted("wait_for_views");
      const auto start = Clock::now();
      decoded = decoder->finish();
      report.decode_ms = ms_since(start);
    }
    if (exposures_us.size() > 1) {
      Merging* merging_view = nullptr;
      {
        std::lock_guard lock(mutex);
        merging_view = &merging[{view_index, projector}];  // std::map: stable address
      }
      std::unique_lock merge_lock(merging_view->mutex);
      if (!merging_view->merge)
        merging_view->merge = std::make_unique<ExposureMerge>(exposures_us, reference_exposure_us);
      const auto start = Clock::now();
      merging_view->merge->add(static_cast<std::size_t>(exposure), std::move(decoded));
      merging_view->decode_ms += report.decode_ms + ms_since(start);
      if (!merging_view->merge->complete()) return;
      merge_lock.unlock();  // the last exposure: nobody else touches this entry
      complete_merge(view_index, projector);
      return;
    }
    triangulate_projector_view(view_index, projector, std::move(decoded), std::move(report));
  }

  // Merges a projector-view's exposures (all of them, or in finish() the ones that came) and
  // triangulates the result.
  void complete_merge(int view_index, int projector) {
    std::unique_ptr<ExposureMerge> merge;
    ProjectorViewReport report;
    report.present = true;
    {
      std::lock_guard lock(mutex);
      auto it = merging.find({view_index, projector});
      merge = std::move(it->second.merge);
      report.decode_ms = it->second.decode_ms;
      merging.erase(it);
    }
    const auto start = Clock::now();
    DecodedView decoded = merge->finish();
    std::vector<std::uint8_t> member = merge->chosen();
    for (std::size_t i = 0; i < member.size(); ++i)
      if (decoded.mask[i] != DecodeMask::valid) member[i] = ViewProducts::kNotDecoded;
    report.decode_ms += ms_since(start);
    report.exposures = merge->shares();
    {
      std::lock_guard lock(mutex);
      views[view_index].exposure_member[static_cast<std::size_t>(projector)] = std::move(member);
    }
    if (!merge->complete()) {
      std::string missing;
      for (std::size_t e = 0; e < report.exposures.size(); ++e)
        if (!merge->has(e)) missing += (missing.empty() ? "" : ", ") + slproto::short_number(exposures_us[e]) + " us";
      decoded.checks.findings.push_back(
          {"exposures",
           "only " + std::to_string(merge->added()) + " of the bracket's " + std::to_string(exposures_us.size()) +
               " exposures arrived (missing or incomplete: " + missing + "); merged from those",
           "rescan this view, or check the capture for dropped frames"});
    }
    triangulate_projector_view(view_index, projector, std::move(decoded), std::move(report));
  }

  void triangulate_projector_view(int view_index, int projector, DecodedView&& decoded_in,
                                  ProjectorViewReport&& report_in) {
    ProjectorViewReport report = std::move(report_in);
    TriangulatedView triangulated;
    {
      DecodedView decoded = std::move(decoded_in);
      report.decode = decoded.counts;
      const auto start = Clock::now();
      triangulated.cloud = take_grid();
      triangulated.counts =
          triangulators[static_cast<std::size_t>(projector)]->triangulate(decoded, triangulated.cloud);
      report.triangulate_ms = ms_since(start);
      report.triangulate = triangulated.counts;
      report.checks = std::move(decoded.checks);
      report.coordinate_noise_px = decoded.coordinate_noise_px;
      report.smoothing_max_deviation_px = decoded.smoothing_max_deviation_px;
    }  // the decoded planes are freed before the view is fused
    const NoiseEstimate depth_noise = estimate_depth_noise(triangulated.cloud);
    report.depth_noise_mm = depth_noise.per_point;
    report.depth_second_difference_mm = depth_noise.second_difference;
    report.shading_correlation = shading_correlation(
        triangulated.cloud,
        calibration.projector(projector == 0 ? slproto::ProjectorSide::left : slproto::ProjectorSide::right)
            .cam_from_proj);
    add_geometry_check(report);

    bool both_done = false;
    {
      std::lock_guard lock(mutex);
      ViewState& view = views[view_index];
      view.triangulated[static_cast<std::size_t>(projector)] = std::move(triangulated);
      view.report.projectors[static_cast<std::size_t>(projector)] = report;
      ++completed;
      both_done = view.triangulated[0].has_value() && view.triangulated[1].has_value() && !view.fused;
      if (both_done) view.fused = true;  // claimed by this worker
    }
    if (both_done) fuse_view(view_index);
  }

  OrganizedCloud take_grid() {
    std::lock_guard lock(mutex);
    if (spare_grids.empty()) return {};
    OrganizedCloud grid = std::move(spare_grids.back());
    spare_grids.pop_back();
    return grid;
  }

  void give_back(OrganizedCloud&& grid) {
    OrganizedCloud spare = std::move(grid);
    if (spare.points.capacity() == 0) return;
    std::lock_guard lock(mutex);
    if (spare_grids.size() < kMaxSpareGrids) spare_grids.push_back(std::move(spare));
  }

  // Fuses a view whose projector clouds are final; the caller has claimed it (fused = true).
  void fuse_view(int view_index) {
    ViewState* view = nullptr;
    {
      std::lock_guard lock(mutex);
      view = &views.at(view_index);  // std::map: stable address
    }
    const auto start = Clock::now();
    auto lap = start;
    auto split = [&lap] {
      const double ms = ms_since(lap);
      lap = Clock::now();
      return ms;
    };
    std::array<OrganizedCloud, 2> clouds;
    std::array<FlyingPixelCounts, 2> flying{};
    // Noise-adaptive limits from the projectors' own noise (the fixed options are the floor).
    FlyingPixelOptions flying_options = options.flying_pixels;
    FusionOptions fusion_options = options.fusion;
    {
      double second = 0, variance = 0;
      for (std::size_t side = 0; side < 2; ++side) {
        if (!view->triangulated[side]) continue;
        const auto& p = view->report.projectors[side];
        second = std::max(second, p.depth_second_difference_mm);
        variance += p.depth_noise_mm * p.depth_noise_mm;
      }
      if (options.noise_factor > 0) {
        flying_options.max_abs_mm =
            std::max(flying_options.max_abs_mm, static_cast<float>(options.noise_factor * second));
        fusion_options.agreement_mm =
            std::max(fusion_options.agreement_mm, static_cast<float>(options.noise_factor * std::sqrt(variance)));
      }
    }
    for (std::size_t side = 0; side < 2; ++side) {
      if (!view->triangulated[side]) {
        clouds[side].resize(width, height);
        continue;
      }
      if (options.remove_flying_pixels) {
        FlyingPixelResult cleaned = remove_flying_pixels(std::move(view->triangulated[side]->cloud), flying_options);
        flying[side] = cleaned.counts;
        clouds[side] = std::move(cleaned.cloud);
      } else {
        clouds[side] = std::move(view->triangulated[side]->cloud);
        flying[side] = {clouds[side].count_valid(), 0};
      }
      view->triangulated[side].reset();  // free the projector's cloud early
    }
    const double flying_ms = split();
    const OrganizedCloud& left = clouds[0];
    const OrganizedCloud& right = clouds[1];
    FusionResult fused = fuse_left_right(left, right, fusion_options, take_grid());
    ViewProducts products;
    products.exposure_member = std::move(view->exposure_member);
    products.source.resize(left.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, left.size(), std::size_t{1} << 16),
                      [&](const tbb::blocked_range<std::size_t>& slots) {
                        for (std::size_t i = slots.begin(); i < slots.end(); ++i) {
                          const bool l = left.valid[i] != 0, r = right.valid[i] != 0;
                          products.source[i] = !l && !r                ? FusionSource::none
                                               : !fused.cloud.valid[i] ? FusionSource::rejected
                                               : l && r                ? FusionSource::both
                                               : l                     ? FusionSource::left
                                                                       : FusionSource::right;
                        }
                      });
    if (!options.keep_projector_clouds)
      for (OrganizedCloud& cloud : clouds) give_back(std::move(cloud));
    const double fusion_ms = split();
    TurntableDenoiseResult<OrganizedCloud> denoised;
    if (options.denoise_turntable) {
      denoised = denoise_by_turntable(std::move(fused.cloud), calibration.turntable, options.turntable_denoise);
    } else {
      denoised.cloud = std::move(fused.cloud);
      denoised.counts.input = denoised.counts.kept = denoised.cloud.count_valid();
    }
    const double denoise_ms = split();
    std::size_t outliers_removed = 0;
    if (options.remove_outliers) {
      OrganizedOutlierResult filtered =
          statistical_outlier_removal(std::move(denoised.cloud), calibration.camera.fx, options.outliers);
      outliers_removed = filtered.removed;
      denoised.cloud = std::move(filtered.cloud);
    }
    const double outliers_ms = split();
    DepthSmoothingCounts smoothing;
    if (options.smooth_depth) smoothing = smooth_depth(denoised.cloud, calibration.camera.fx, options.depth_smoothing);
    const double smoothing_ms = split();
    products.points = oriented_point_cloud(denoised.cloud, static_cast<std::uint16_t>(view_index),
                                           Eigen::Vector3f::Zero(), options.grid_normals);
    const double normals_ms = split();
    // The grid is kept for the pictures and the overlap selection, its valid slots only; the
    // albedo is in products.points, so it stays in the grid only for diagnostics.
    products.cloud = SparseOrganizedCloud::of(denoised.cloud, options.keep_projector_clouds);
    give_back(std::move(denoised.cloud));  // the whole grid (85-105 MB a view at full resolution)

    std::lock_guard lock(mutex);
    view->report.flying_max_abs_mm = flying_options.max_abs_mm;
    view->report.fusion_agreement_mm = fusion_options.agreement_mm;
    view->report.noise_factor = options.noise_factor;
    view->report.flying_pixels_ms = flying_ms;
    view->report.fusion_ms = fusion_ms;
    view->report.denoise_ms = denoise_ms;
    view->report.normals_ms = normals_ms;
    view->report.outliers_ms = outliers_ms;
    view->report.smoothing_ms = smoothing_ms;
    view->report.depth_smoothing = smoothing;
    view->report.fusion = fused.counts;
    view->report.flying_pixels = {flying[0].input + flying[1].input, flying[0].removed + flying[1].removed};
    for (std::size_t side = 0; side < 2; ++side) view->report.projectors[side].flying_pixels = flying[side];
    view->report.turntable_denoise = denoised.counts;
    view->report.points = products.points.size();
    view->report.outliers_removed = outliers_removed;
    view->report.fuse_ms = ms_since(start);
    if (options.keep_projector_clouds) products.projector_clouds = std::move(clouds);
    view->products = std::move(products);
  }
};

ScanReconstructor::ScanReconstructor(const slproto::RigCalibration& calibration, const slproto::PatternPlan& plan,
                                     int width, int height, const ReconstructionOptions& options)
    : impl_(std::make_unique<Impl>()) {
  options.check();
  if (auto status = calibration.check(); !status) throw std::invalid_argument(status.error().message);
  if (width != calibration.camera.width || height != calibration.camera.height)
    throw std::invalid_argument("frames are " + std::to_string(width) + " x " + std::to_string(height) +
                                " but the calibration's camera is " + std::to_string(calibration.camera.width) + " x " +
                                std::to_string(calibration.camera.height));
  if (plan.config().coded_extent() != (plan.config().axis == slproto::CodingAxis::columns
                                           ? calibration.projectors[0].intrinsics.width
                                           : calibration.projectors[0].intrinsics.height))
    throw std::invalid_argument("the pattern plan codes " + std::to_string(plan.config().coded_extent()) +
                                " projector pixels but the calibration's projector is " +
                                std::to_string(calibration.projectors[0].intrinsics.width) + " x " +
                                std::to_string(calibration.projectors[0].intrinsics.height));
  impl_->calibration = calibration;
  impl_->plan = plan;
  impl_->width = width;
  impl_->height = height;
  impl_->options = options;
  if (options.max_pending_projector_views == 0)
    impl_->options.max_pending_projector_views = tbb::this_task_arena::max_concurrency() + 1;
  auto rays = std::make_shared<const CameraRayTable>(CameraRayTable::build(calibration.camera));
  for (std::size_t side = 0; side < 2; ++side)
    impl_->triangulators[side] = std::make_unique<ProjectorTriangulator>(rays, calibration.projectors[side],
                                                                         plan.config().axis, options.triangulate);
}

ScanReconstructor::~ScanReconstructor() {
  try {
    // Without finish() (an aborted scan, an error): drop the jobs nobody started, so this
    // returns once the running ones end instead of decoding what nobody will read.
    std::deque<Impl::Job> dropped;
    {
      std::lock_guard lock(impl_->mutex);
      dropped.swap(impl_->queued);
    }
    impl_->workers.wait();
  } catch (...) {  // NOLINT(bugprone-empty-catch): a destructor must not throw; finish() reports errors
  }
}

void ScanReconstructor::set_exposure_bracket(const std::vector<double>& exposures_us, double reference_us) {
  Impl& s = *impl_;
  std::lock_guard lock(s.mutex);
  if (s.frames_seen) throw std::invalid_argument("set_exposure_bracket: frames have arrived already");
  if (exposures_us.empty() || exposures_us.size() > 16)
    throw std::invalid_argument("exposure bracket of " + std::to_string(exposures_us.size()) +
                                " exposures (1 to 16 can be merged)");
  (void)ExposureMerge(exposures_us, reference_us);  // its checks: positive, finite
  s.exposures_us = exposures_us;
  s.reference_exposure_us = reference_us;
}

void ScanReconstructor::add_frame(const FrameInfo& info, std::span<const std::byte> pixels) {
  Impl& s = *impl_;
  const std::string where = "frame (view " + std::to_string(info.view_index) + ", projector " +
                            std::to_string(info.projector) + ", pattern " + std::to_string(info.pattern_index) + ")";
  if (info.projector != 0 && info.projector != 1)
    throw std::invalid_argument(where + ": projector id must be 0 (left) or 1 (right)");
  if (info.view_index < 0) throw std::invalid_argument(where + ": negative view index");
  if (info.pattern_index >= s.plan.size())
    throw std::invalid_argument(where + ": the pattern plan has only " + std::to_string(s.plan.size()) + " patterns");
  if (info.exposure_index >= s.exposures_us.size())
    throw std::invalid_argument(where + ": exposure index " + std::to_string(info.exposure_index) +
                                (s.exposures_us.size() > 1
                                     ? " is beyond the bracket of " + std::to_string(s.exposures_us.size())
                                     : " but the scan has no exposure bracket"));
  const int expected_bpp = s.options.decode.bit_depth > 8 ? 2 : 1;
  if (info.bytes_per_pixel != expected_bpp)
    throw std::invalid_argument(where + ": " + std::to_string(info.bytes_per_pixel) + " bytes per pixel, expected " +
                                std::to_string(expected_bpp) + " for " + std::to_string(s.options.decode.bit_depth) +
                                "-bit decoding");
  const std::size_t row_bytes = static_cast<std::size_t>(s.width) * static_cast<std::size_t>(expected_bpp);
  if (info.stride_bytes < row_bytes || info.stride_bytes % static_cast<std::size_t>(expected_bpp) != 0)
    throw std::invalid_argument(where + ": stride " + std::to_string(info.stride_bytes) + " bytes is impossible for " +
                                std::to_string(s.width) + " pixels");
  if (pixels.size() < info.stride_bytes * static_cast<std::size_t>(s.height - 1) + row_bytes)
    throw std::invalid_argument(where + ": " + std::to_string(pixels.size()) + " bytes is short of a " +
                                std::to_string(s.width) + " x " + std::to_string(s.height) + " frame");

  std::unique_lock lock(s.mutex);
  // A job that ran out of memory on a worker thread is said at the next frame, while frames still
  // arrive (a live scan then stops reconstructing and records the rest), not only in finish().
  // Other job errors wait for finish(), which names them.
  if (s.job_error) {
    try {
      std::rethrow_exception(s.job_error);
    } catch (const std::bad_alloc&) {
      s.job_error = nullptr;
      throw;
    } catch (...) {  // NOLINT(bugprone-empty-catch): kept in job_error for finish()
    }
  }
  auto [view_it, inserted] = s.views.try_emplace(info.view_index);
  Impl::ViewState& view = view_it->second;
  if (inserted) {
    view.commanded_angle_deg = info.commanded_angle_deg;
    view.reported_angle_deg = info.reported_angle_deg;
    view.report.view_index = info.view_index;
    view.report.commanded_angle_deg = info.commanded_angle_deg;
    view.report.reported_angle_deg = info.reported_angle_deg;
  } else if (view.commanded_angle_deg != info.commanded_angle_deg) {
    throw std::invalid_argument(where + ": commanded angle " + slproto::short_number(info.commanded_angle_deg) +
                                " deg differs from the view's earlier frames (" +
                                slproto::short_number(view.commanded_angle_deg) + " deg)");
  }
  const auto side = static_cast<std::size_t>(info.projector);
  const std::uint32_t exposure_bit = 1u << info.exposure_index;
  if (view.triangulated[side].has_value() || view.report.projectors[side].present ||
      (view.exposures_queued[side] & exposure_bit) != 0)
    throw std::invalid_argument(where + ": this projector-view is already complete" +
                                (s.exposures_us.size() > 1 ? " at this exposure" : ""));
  s.frames_seen = true;
  const auto key = std::make_tuple(info.view_index, info.projector, static_cast<int>(info.exposure_index));
  auto it = s.receiving.find(key);
  if (it == s.receiving.end()) it = s.receiving.emplace(key, s.acquire_decoder(lock)).first;
  ProjectorViewDecoder& decoder = *it->second;
  lock.unlock();  // the copy into the decoder's store runs without the lock
  const std::size_t stride_pixels = info.stride_bytes / static_cast<std::size_t>(expected_bpp);
  if (expected_bpp == 1) {
    decoder.add_frame(info.pattern_index, reinterpret_cast<const std::uint8_t*>(pixels.data()), stride_pixels);
  } else {
    decoder.add_frame(info.pattern_index, reinterpret_cast<const std::uint16_t*>(pixels.data()), stride_pixels);
  }
  if (!decoder.complete()) return;
  lock.lock();
  auto owned = std::move(it->second);
  s.receiving.erase(it);
  view.exposures_queued[side] |= exposure_bit;
  if (view.exposures_queued[side] == (1u << s.exposures_us.size()) - 1) view.report.projectors[side].present = true;
  s.queued.push_back({info.view_index, info.projector, static_cast<int>(info.exposure_index), std::move(owned)});
  lock.unlock();
  Impl* impl = impl_.get();
  s.workers.run([impl] { impl->run_queued_task(); });
}

std::size_t ScanReconstructor::completed_projector_views() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->completed;
}

std::vector<int> ScanReconstructor::incomplete_views() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->incomplete;
}

ScanResult ScanReconstructor::finish(const std::atomic<bool>* stop, const std::function<void(const char*)>& on_stage) {
  // The stage running, for an out-of-memory report. A stop is honoured at each boundary and
  // inside the long stages (per projector-view, view, ICP iteration), through `interrupt`; the
  // stage is only changed on this thread, between stages, so the workers read it unchanged.
  const char* stage = "wait_for_views";
  const InterruptionPoint interrupt = [&stage, stop] {
    if (stop != nullptr && stop->load()) throw ReconstructionInterrupted(stage);
  };
  auto begin_stage = [&](const char* next) {
    stage = next;
    interrupt();
    if (on_stage) on_stage(next);
  };
  try {
    return final_stages(begin_stage, interrupt, stop);
  } catch (const std::bad_alloc&) {
    throw ReconstructionOutOfMemory(stage);
  }
}

ScanResult ScanReconstructor::final_stages(const std::function<void(const char*)>& begin_stage,
                                           const InterruptionPoint& interrupt, const std::atomic<bool>* stop) {
  Impl& s = *impl_;
  begin_stage("wait_for_views");
  auto start = Clock::now();
  s.stop.store(stop);  // the queued projector-views' jobs check it before they decode
  s.workers.wait();    // runs every queued job (on this thread too)
  {
    std::unique_lock lock(s.mutex);
    while (!s.queued.empty()) s.run_first_queued(lock);  // none left by the tasks; kept as the invariant
    if (s.job_error) std::rethrow_exception(std::exchange(s.job_error, nullptr));
  }
  ScanResult result;
  result.stage_ms["wait_for_views"] = ms_since(start);

  // A bracket some exposures of which never completed: merged from the ones that did.
  {
    std::vector<std::pair<int, int>> partial;
    {
      std::lock_guard lock(s.mutex);
      for (const auto& [key, entry] : s.merging)
        if (entry.merge) partial.push_back(key);
    }
    for (const auto& [view_index, projector] : partial) {
      interrupt();
      s.complete_merge(view_index, projector);
      std::lock_guard lock(s.mutex);
      s.views[view_index].report.projectors[static_cast<std::size_t>(projector)].present = true;
    }
  }
  // No frame comes after finish(): projector-views that never completed are dropped, and every
  // decoder's frame store (96 MB each at full resolution) is freed before the views are
  // registered and merged, the stages that hold every view's cloud at once.
  {
    std::lock_guard lock(s.mutex);
    s.decoders_in_flight -= static_cast<int>(s.receiving.size());
    s.receiving.clear();
    s.free_decoders.clear();
    s.free_decoders.shrink_to_fit();
  }
  begin_stage("fuse_remaining");
  start = Clock::now();
  std::vector<int> to_fuse;
  for (auto& [index, view] : s.views) {
    if (view.fused) continue;
    if (view.triangulated[0] || view.triangulated[1]) {
      view.fused = true;
      to_fuse.push_back(index);
    } else {
      s.incomplete.push_back(index);
    }
  }
  for (int index : to_fuse) {
    interrupt();
    s.fuse_view(index);
  }
  result.stage_ms["fuse_remaining"] = ms_since(start);
  s.spare_grids.clear();  // registration and merging hold every view's cloud at once
  s.spare_grids.shrink_to_fit();

  std::vector<PointCloud> clouds;
  std::vector<double> angles;
  for (auto& [index, view] : s.views) {
    if (std::find(s.incomplete.begin(), s.incomplete.end(), index) != s.incomplete.end()) continue;
    result.views.push_back(view.report);
    clouds.push_back(view.products.points);
    angles.push_back(view.reported_angle_deg);
    result.view_products.push_back(std::move(view.products));
  }
  if (clouds.empty()) return result;

  begin_stage("register");
  start = Clock::now();
  std::vector<Eigen::Isometry3d> table_from_view(clouds.size());
  for (std::size_t i = 0; i < clouds.size(); ++i)
    table_from_view[i] = coarse_table_from_view(s.calibration.turntable, angles[i]);
  if (s.options.register_views && clouds.size() >= 2) {
    try {
      std::vector<int> view_numbers;
      for (const ViewReport& view : result.views) view_numbers.push_back(view.view_index);
      RegistrationOptions options = s.options.registration;
      options.view_numbers = std::move(view_numbers);
      result.registration = register_views_with_points(clouds, angles, s.calibration.turntable, options, interrupt);
      for (std::size_t i = 0; i < clouds.size(); ++i) table_from_view[i] = result.registration.views[i].table_from_view;
      result.registered = true;
    } catch (const std::runtime_error& e) {
      result.registration_error = e.what();
    }
  }
  result.stage_ms["register"] = ms_since(start);

  begin_stage("select_views");
  start = Clock::now();
  if (s.options.select_best_views && clouds.size() >= 2) {
    std::vector<const SparseOrganizedCloud*> grids;
    for (const auto& products : result.view_products) grids.push_back(&products.cloud);
    const OverlapSelection selection =
        select_best_views(clouds, grids, table_from_view, s.calibration.camera, s.options.overlap);
    result.overlap = selection.counts;
    interrupt();
    tbb::parallel_for(std::size_t{0}, clouds.size(), [&](std::size_t i) {
      std::vector<std::size_t> kept;
      kept.reserve(clouds[i].size());
      for (std::size_t k = 0; k < clouds[i].size(); ++k)
        if (selection.keep[i][k]) kept.push_back(k);
      clouds[i] = clouds[i].select(kept);
    });
  }
  result.stage_ms["select_views"] = ms_since(start);

  begin_stage("merge");
  start = Clock::now();
  PointCloud merged;
  for (std::size_t i = 0; i < clouds.size(); ++i) {
    interrupt();
    merged.append(transform_cloud(clouds[i], table_from_view[i]));
    result.outliers_removed += result.views[i].outliers_removed;
  }
  result.merged_points = merged.size();
  result.stage_ms["merge"] = ms_since(start);
  begin_stage("voxel");
  start = Clock::now();
  if (s.options.voxel_mm > 0) merged = voxel_downsample(merged, s.options.voxel_mm);
  result.stage_ms["voxel"] = ms_since(start);
  begin_stage("normals");
  start = Clock::now();
  if (s.options.normal_neighbors >= 3 && merged.size() >= static_cast<std::size_t>(s.options.normal_neighbors)) {
    PcaNormalOptions normal_options;
    normal_options.k = s.options.normal_neighbors;
    normal_options.orientation = NormalOrientation::away_from_axis;  // turntable frame: axis = origin + z
    merged.normals = pca_normals(merged, normal_options);
  }
  result.stage_ms["normals"] = ms_since(start);
  result.model = std::move(merged);
  return result;
}

}  // namespace slscan::core
