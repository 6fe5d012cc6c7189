// Accuracy of the whole reconstruction against the virtual rig's ground truth (issue 4's
// accuracy section), through ScanReconstructor: the code path of a scan.
//
//   bench_accuracy [--size full|small] [--scenes ballbar,blade,teacup] [--views N] [--mesh]
//                  [--no-noise] [--no-registration] [--registration-mode M] [--decode-smoothing R]
//                  [--decode-quadratic-radius Q] [--json FILE]
//                  [--outliers CSV] [--frame-period-ms P] [--turntable-deg-per-s S] [--prerender]
//                  [--exposure-bracket F,F,... | --exposure-auto] [--material NAME]
//                  [--interreflection SAMPLES] [--fringe-period-px P]
//
// --exposure-bracket 1,0.25,0.125 captures every view at each of these fractions of the scene's
// reference exposure and merges them per pixel (HDR, docs/hdr.md); --material NAME gives every
// object that finish (e.g. the shiny blade in matte paint: the same shape, for comparison).
// --exposure-auto meters as `slscan scan --exposure auto` does (white and black of both
// projectors at the first view, at 1/8 .. 16 x the reference; core::choose_exposures with the
// decoder's floors) and scans with the exposure or bracket it picks.
// --interreflection SAMPLES turns on the rig's one-bounce term (docs/virtual-rig.md; SAMPLES rays
// per pixel, e.g. 16 or 64: minutes per view at full resolution); --fringe-period-px P scans with
// fringes of P projector pixels instead of the preset's 8 (docs/hdr.md, "Interreflection").
//
// Frames reach the reconstructor at a camera's pace: one every P ms (default 8.333, a DLP4500's
// 8-bit pattern period), and between views the turntable's move (60 deg at S = 360 deg/s plus
// 50 ms settle, the sim board's measured 217 ms). --frame-period-ms 0 feeds them as fast as the
// renderer draws (~150 a second at full resolution): then the time after the last frame holds a
// backlog of views that no camera would leave. The renderer itself takes ~6.5 ms of a core per
// frame, which a camera does not: --prerender draws every frame before the scan starts (~2.3 GB
// at full resolution), so the scan has the machine to itself, as behind a real camera.
//
// Per view: each projector's cloud and the fused cloud (object and platform: the working
// volume) against the per-pixel truth: median, RMS, fraction beyond 0.2 mm; points a projector
// gave inside its own true shadow; coverage of what the projectors light and the camera sees;
// the shadow-hole area that left/right fusion filled; the final object-only cloud. Per scene:
// the registered 6-view model in the truth's table frame: the ball bar's spheres and centre
// distance, stray points above the platform away from the object, the fraction of the true
// surface within 0.1 mm of a model point (360-degree coverage). Then the stage times after the
// last frame and the peak memory. Full resolution takes ~1-2 min per scene on 2 cores.
#include <sys/resource.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <numbers>
#include <optional>
#include <span>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "slproto/calibration.hpp"
#include "slrig/rig.hpp"
#include "slscan/core/auto_exposure.hpp"
#include "slscan/core/fusion.hpp"
#include "slscan/core/huge_pages.hpp"
#include "slscan/core/measure.hpp"
#include "slscan/core/point_index.hpp"
#include "slscan/core/registration.hpp"
#include "slscan/core/scan_reconstruction.hpp"

namespace {

using slscan::core::OrganizedCloud;
using Json = nlohmann::ordered_json;
using Clock = std::chrono::steady_clock;

constexpr std::int16_t kTurntable = 0, kWall = 1;

// What a view's truth keeps after its renderer is gone (the renderer holds ~10 buffers).
struct ViewTruth {
  int width = 0, height = 0;
  std::vector<float> points, normals;
  std::vector<std::int16_t> object_id;
  std::array<std::vector<std::uint8_t>, 2> lit;
  slproto::RigidTransform cam_from_table;
  std::size_t at(int u, int v) const {
    return static_cast<std::size_t>(v) * static_cast<std::size_t>(width) + static_cast<std::size_t>(u);
  }
  Eigen::Vector3f point(std::size_t i) const { return {points[3 * i], points[3 * i + 1], points[3 * i + 2]}; }
  bool working_volume(std::size_t i) const { return std::isfinite(points[3 * i]) && object_id[i] != kWall; }
};

// Incidence bins (degrees between the true normal and the line of sight) of the signed error.
constexpr std::array<double, 6> kIncidenceEdgesDeg{0, 30, 50, 60, 70, 80};

struct ErrorStats {
  std::size_t points = 0, beyond_0_2mm = 0;
  double median_um = 0, rms_um = 0;
  // Signed distance along the true outward normal (+ = outside the surface), over the points
  // within 0.2 mm of their truth: a bias here is a size error of every fitted feature (a sphere
  // measured with its points 5 um inside reads 10 um small), which the unsigned figures hide.
  double signed_mean_um = 0;
  std::array<double, kIncidenceEdgesDeg.size()> signed_sum_um{}, signed_count{};
  double fraction_beyond_percent() const {
    return points ? 100.0 * static_cast<double>(beyond_0_2mm) / static_cast<double>(points) : 0;
  }
  Json json() const {
    Json by_incidence = Json::array();
    for (std::size_t b = 0; b < kIncidenceEdgesDeg.size(); ++b) {
      if (signed_count[b] == 0) continue;
      const double upper = b + 1 < kIncidenceEdgesDeg.size() ? kIncidenceEdgesDeg[b + 1] : 90.0;
      by_incidence.push_back({{"incidence_deg", {kIncidenceEdgesDeg[b], upper}},
                              {"points", signed_count[b]},
                              {"signed_mean_um", signed_sum_um[b] / signed_count[b]}});
    }
    return {{"points", points},
            {"median_um", median_um},
            {"rms_um", rms_um},
            {"beyond_0_2mm_percent", fraction_beyond_percent()},
            {"signed_mean_um", signed_mean_um},
            {"signed_by_incidence", by_incidence}};
  }
};

// Points of the working volume (object and platform: the wall is 2x the working distance away
// and the turntable denoise removes it) against the truth of their own pixel.
ErrorStats error_stats(const OrganizedCloud& cloud, const ViewTruth& truth, bool object_only = false) {
  ErrorStats stats;
  std::vector<double> errors;
  double sum2 = 0;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!cloud.valid[i] || truth.object_id[i] == kWall) continue;
    if (object_only && truth.object_id[i] < 2) continue;
    ++stats.points;
    const Eigen::Vector3f g = truth.point(i);
    if (!g.allFinite()) {  // a point where the camera sees nothing
      ++stats.beyond_0_2mm;
      continue;
    }
    const double e = (cloud.points[i] - g).norm();
    errors.push_back(e);
    sum2 += e * e;
    if (e > 0.2) {
      ++stats.beyond_0_2mm;
      continue;
    }
    const Eigen::Vector3f n(truth.normals[3 * i], truth.normals[3 * i + 1], truth.normals[3 * i + 2]);
    const double signed_um = 1e3 * static_cast<double>((cloud.points[i] - g).dot(n));
    const double incidence_deg = std::acos(std::min(1.0f, std::fabs(n.dot(g.normalized())))) * 180.0 / std::numbers::pi;
    const auto bin =
        static_cast<std::size_t>(std::upper_bound(kIncidenceEdgesDeg.begin(), kIncidenceEdgesDeg.end(), incidence_deg) -
                                 kIncidenceEdgesDeg.begin() - 1);
    stats.signed_sum_um[bin] += signed_um;
    stats.signed_count[bin] += 1;
  }
  double signed_total = 0, signed_points = 0;
  for (std::size_t b = 0; b < kIncidenceEdgesDeg.size(); ++b) {
    signed_total += stats.signed_sum_um[b];
    signed_points += stats.signed_count[b];
  }
  if (signed_points > 0) stats.signed_mean_um = signed_total / signed_points;
  if (!errors.empty()) {
    std::nth_element(errors.begin(), errors.begin() + static_cast<long>(errors.size() / 2), errors.end());
    stats.median_um = 1e3 * errors[errors.size() / 2];
    stats.rms_um = 1e3 * std::sqrt(sum2 / static_cast<double>(errors.size()));
  }
  return stats;
}

// A point counts as in projector s's shadow only if no pixel of its 3 x 3 neighbourhood is lit
// (a pixel whose centre is shadowed can still be partly lit at the shadow's border).
std::size_t points_in_true_shadow(const OrganizedCloud& cloud, const ViewTruth& truth, std::size_t s) {
  std::size_t count = 0;
  for (int v = 0; v < truth.height; ++v)
    for (int u = 0; u < truth.width; ++u) {
      const std::size_t i = truth.at(u, v);
      if (!cloud.valid[i] || truth.lit[s][i]) continue;
      bool near_lit = false;
      for (int dv = -1; dv <= 1; ++dv)
        for (int du = -1; du <= 1; ++du) {
          const int uu = u + du, vv = v + dv;
          if (uu >= 0 && vv >= 0 && uu < truth.width && vv < truth.height && truth.lit[s][truth.at(uu, vv)])
            near_lit = true;
        }
      count += near_lit ? 0 : 1;
    }
  return count;
}

// Coverage of the working-volume pixels that a projector lights and the camera sees: all of
// them (raw), and those whose 5 x 5 neighbourhood is lit by the same projector and shows the
// same object (the reach of the flying-pixel filter: edge pixels are legitimately dropped).
Json coverage(const OrganizedCloud& fused, const ViewTruth& truth) {
  std::size_t lit_seen = 0, lit_seen_covered = 0, interior = 0, interior_covered = 0;
  for (int v = 0; v < truth.height; ++v)
    for (int u = 0; u < truth.width; ++u) {
      const std::size_t i = truth.at(u, v);
      if (!truth.working_volume(i) || !(truth.lit[0][i] || truth.lit[1][i])) continue;
      ++lit_seen;
      lit_seen_covered += fused.valid[i] != 0;
      bool inside = false;
      for (std::size_t s = 0; s < 2 && !inside; ++s) {
        bool ok = truth.lit[s][i] && u >= 2 && v >= 2 && u < truth.width - 2 && v < truth.height - 2;
        for (int dv = -2; dv <= 2 && ok; ++dv)
          for (int du = -2; du <= 2 && ok; ++du) {
            const std::size_t j = truth.at(u + du, v + dv);
            ok = truth.lit[s][j] && truth.object_id[j] == truth.object_id[i];
          }
        inside = ok;
      }
      if (!inside) continue;
      ++interior;
      interior_covered += fused.valid[i] != 0;
    }
  auto percent = [](std::size_t a, std::size_t b) {
    return b ? 100.0 * static_cast<double>(a) / static_cast<double>(b) : 100.0;
  };
  return {{"lit_and_seen_pixels", lit_seen},
          {"raw_percent", percent(lit_seen_covered, lit_seen)},
          {"interior_pixels", interior},
          {"interior_percent", percent(interior_covered, interior)}};
}

// Object surface (mm^2) measured by one projector only where the other's light does not reach:
// the shadow holes that left/right fusion filled. A pixel's footprint is (z / f)^2 / cos(incidence).
double filled_shadow_area_mm2(const std::vector<slscan::core::FusionSource>& source, const ViewTruth& truth,
                              const slproto::PinholeModel& camera) {
  double area = 0;
  for (std::size_t i = 0; i < source.size(); ++i) {
    const bool left_only = source[i] == slscan::core::FusionSource::left;
    const bool right_only = source[i] == slscan::core::FusionSource::right;
    if (!(left_only || right_only) || truth.object_id[i] < 2) continue;
    if (truth.lit[left_only ? 1 : 0][i]) continue;  // the other projector lights it: not a shadow
    const Eigen::Vector3f p = truth.point(i);
    const Eigen::Vector3f n(truth.normals[3 * i], truth.normals[3 * i + 1], truth.normals[3 * i + 2]);
    const float cos_incidence = std::max(0.05f, std::fabs(n.dot(p.normalized())));
    area += static_cast<double>(p.z() * p.z()) / (camera.fx * camera.fy) / cos_incidence;
  }
  return area;
}

// One line per fused working-volume point farther than 0.2 mm from its truth, with what is
// around it: to find where the outliers sit (silhouettes, shadow borders, grazing surfaces).
void append_outliers(std::FILE* csv, const std::string& scene, int view, const OrganizedCloud& fused,
                     const std::vector<slscan::core::FusionSource>& source, const ViewTruth& truth) {
  const int reach = 4;
  for (int v = 0; v < truth.height; ++v)
    for (int u = 0; u < truth.width; ++u) {
      const std::size_t i = truth.at(u, v);
      if (!fused.valid[i] || truth.object_id[i] == kWall) continue;
      const Eigen::Vector3f g = truth.point(i);
      const double error = g.allFinite() ? (fused.points[i] - g).norm() : -1;
      if (error >= 0 && error <= 0.2) continue;
      // Chebyshev distance (px) to the nearest pixel of another object or of nothing, and to
      // the nearest pixel unlit by each projector; reach + 1 when none is that close.
      int to_edge = reach + 1;
      std::array<int, 2> to_shadow{reach + 1, reach + 1};
      for (int dv = -reach; dv <= reach; ++dv)
        for (int du = -reach; du <= reach; ++du) {
          const int uu = u + du, vv = v + dv;
          if (uu < 0 || vv < 0 || uu >= truth.width || vv >= truth.height) continue;
          const std::size_t j = truth.at(uu, vv);
          const int d = std::max(std::abs(du), std::abs(dv));
          if (truth.object_id[j] != truth.object_id[i] || !std::isfinite(truth.points[3 * j]))
            to_edge = std::min(to_edge, d);
          for (std::size_t s = 0; s < 2; ++s)
            if (!truth.lit[s][j]) to_shadow[s] = std::min(to_shadow[s], d);
        }
      const Eigen::Vector3f n(truth.normals[3 * i], truth.normals[3 * i + 1], truth.normals[3 * i + 2]);
      const double view_angle_deg =
          std::acos(std::min(1.0f, std::fabs(n.dot(g.normalized())))) * 180.0 / std::numbers::pi;
      std::fprintf(csv, "%s,%d,%d,%d,%.4f,%d,%d,%.1f,%d,%d,%d\n", scene.c_str(), view, u, v, error, truth.object_id[i],
                   static_cast<int>(source[i]), view_angle_deg, to_edge, to_shadow[0], to_shadow[1]);
    }
}

Eigen::Isometry3d to_isometry(const slproto::RigidTransform& t) {
  Eigen::Isometry3d m = Eigen::Isometry3d::Identity();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) m.linear()(r, c) = t.R[(3 * static_cast<std::size_t>(r)) + static_cast<std::size_t>(c)];
    m.translation()(r) = t.t[static_cast<std::size_t>(r)];
  }
  return m;
}

long peak_rss_mb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024;
}

// How frames reach the reconstructor (0: as fast as they are rendered).
struct Pacing {
  double frame_period_ms = 1000.0 / 120.0;
  double turntable_deg_per_s = 360;
  double settle_ms = 50;
  bool prerender = false;
};

// How the scene is exposed (docs/hdr.md): one exposure or a bracket, as fractions of the
// scene's reference exposure; a finish for every object instead of the preset's.
struct Exposing {
  std::vector<double> bracket{1.0};
  bool automatic = false;
  std::optional<slrig::Material> material;
  int interreflection_samples = 0;  // 0: the one-bounce term off
  int fringe_period_px = 0;         // 0: the preset's
};

// The metering pass of `slscan scan --exposure auto` on the rendered scene: the bracket as
// fractions of the reference, and the choice for the report.
std::vector<double> meter_scene(const slrig::Scene& scene, const slscan::core::DecodeOptions& decode, Json& report) {
  const double reference_us = scene.sensor.exposure_us;
  const std::vector<double> ladder = slscan::core::metering_ladder(reference_us, 1, 1e9, 0);
  const slrig::ViewRenderer renderer(scene, scene.view_angles_deg.at(0), 0);
  const slproto::PatternPlan plan(scene.pattern_plan);
  std::vector<std::uint8_t> frame(renderer.frame_bytes());
  const bool wide = scene.sensor.bit_depth > 8;
  std::vector<slscan::core::MeteringFrames> frames;
  for (const int side : {0, 1})
    for (const double exposure_us : ladder) {
      slscan::core::MeteringFrames f;
      f.exposure_us = exposure_us;
      f.projector = side;
      for (const auto kind : {slproto::PatternKind::white, slproto::PatternKind::black}) {
        renderer.render(static_cast<slproto::ProjectorSide>(side), plan, static_cast<std::size_t>(plan.index_of(kind)),
                        frame, slrig::Exposure{.exposure_us = exposure_us});
        auto& image = kind == slproto::PatternKind::white ? f.white : f.black;
        image.resize(frame.size() / (wide ? 2 : 1));
        if (wide)
          std::memcpy(image.data(), frame.data(), frame.size());
        else
          std::copy(frame.begin(), frame.end(), image.begin());
      }
      frames.push_back(std::move(f));
    }
  slscan::core::AutoExposureOptions choose;
  choose.min_contrast_dn = std::max<double>(decode.min_contrast_dn, 2.0 * decode.min_modulation_dn);
  choose.saturation_dn = decode.saturation_level();
  choose.reference_us = reference_us;
  const slscan::core::AutoExposureChoice choice = slscan::core::choose_exposures(frames, choose);
  std::vector<double> fractions;
  for (const double e : choice.exposures_us) fractions.push_back(e / reference_us);
  report = {{"fractions_of_reference", fractions},
            {"usable_share", choice.usable_share},
            {"saturated_share", choice.saturated_share},
            {"dark_share", choice.dark_share},
            {"unreachable_share", choice.unreachable_share},
            {"met", choice.met},
            {"reason", choice.reason}};
  return fractions;
}

Json run_scene(const std::string& name, slrig::RigSize size, int max_views, bool mesh, bool noise, int decode_smoothing,
               int quadratic_radius, bool registration, slscan::core::RefinementMode registration_mode,
               std::FILE* outliers_csv, const Pacing& pacing, Exposing exposing) {
  auto scene_or = slrig::scene_preset(name, size);
  if (!scene_or) throw std::runtime_error(scene_or.error().message);
  scene_or->sensor.noise = noise;
  if (exposing.material)
    for (slrig::SceneObject& object : scene_or->objects) slrig::apply_material(object, *exposing.material);
  scene_or->interreflection = exposing.interreflection_samples > 0;
  if (scene_or->interreflection) scene_or->interreflection_samples = exposing.interreflection_samples;
  if (exposing.fringe_period_px > 0) scene_or->pattern_plan.period_px = exposing.fringe_period_px;
  const slrig::Scene scene = *scene_or;
  Json auto_exposure;
  if (exposing.automatic) {
    slscan::core::DecodeOptions decode;
    decode.bit_depth = scene.sensor.bit_depth;
    exposing.bracket = meter_scene(scene, decode, auto_exposure);
  }
  const double reference_us = scene.sensor.exposure_us;
  const std::size_t exposures = exposing.bracket.size();
  std::vector<double> bracket_us;
  for (const double f : exposing.bracket) bracket_us.push_back(f * reference_us);
  auto exposure_of = [&](std::size_t e) {
    slrig::Exposure x;
    if (exposing.bracket[e] != 1.0) x.exposure_us = bracket_us[e];
    return x;
  };
  const slproto::RigCalibration calibration = slrig::ground_truth_calibration(scene);
  const slproto::PatternPlan plan(calibration.pattern_plan);
  slscan::core::ReconstructionOptions options;
  options.decode.bit_depth = scene.sensor.bit_depth;
  if (decode_smoothing >= 0) options.decode.smoothing_radius = decode_smoothing;
  if (quadratic_radius >= 0) options.decode.quadratic_radius = quadratic_radius;
  options.register_views = registration;
  options.registration.mode = registration_mode;
  options.keep_projector_clouds = true;
  options.build_mesh = mesh;
  const int width = scene.camera.width, height = scene.camera.height;
  slscan::core::ScanReconstructor reconstructor(calibration, plan, width, height, options);
  if (exposures > 1) reconstructor.set_exposure_bracket(bracket_us, reference_us);

  const std::size_t views = std::min(scene.view_angles_deg.size(), static_cast<std::size_t>(std::max(1, max_views)));
  std::vector<ViewTruth> truths;
  double render_s = 0;
  std::vector<std::uint8_t> frame;
  const int bytes_per_pixel = scene.sensor.bit_depth > 8 ? 2 : 1;
  auto keep_truth = [&](const slrig::ViewRenderer& renderer) {
    const auto& t = renderer.ground_truth();
    truths.push_back(ViewTruth{t.width, t.height, t.points, t.normals, t.object_id, t.lit, t.cam_from_table});
  };
  // --prerender: every frame drawn before the scan starts, so the renderer takes no CPU from it.
  std::vector<std::vector<std::vector<std::uint8_t>>> rendered(views);  // [view][frame]
  if (pacing.prerender)
    for (std::size_t view = 0; view < views; ++view) {
      const slrig::ViewRenderer renderer(scene, scene.view_angles_deg[view], static_cast<int>(view));
      for (std::size_t e = 0; e < exposures; ++e)
        for (int side = 0; side < 2; ++side)
          for (std::size_t p = 0; p < plan.size(); ++p) {
            const auto t0 = Clock::now();
            rendered[view].emplace_back(renderer.frame_bytes());
            renderer.render(static_cast<slproto::ProjectorSide>(side), plan, p, rendered[view].back(), exposure_of(e));
            render_s += std::chrono::duration<double>(Clock::now() - t0).count();
          }
      keep_truth(renderer);
    }
  const bool paced = pacing.frame_period_ms > 0;
  const auto period = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double, std::milli>(paced ? pacing.frame_period_ms : 0.0));
  auto due = Clock::now();
  int late_frames = 0;  // rendered after their due time (the renderer shares the CPU with the scan)
  for (std::size_t view = 0; view < views; ++view) {
    const double angle = scene.view_angles_deg[view];
    if (paced && view > 0)
      due += std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double, std::milli>(
          std::abs(angle - scene.view_angles_deg[view - 1]) / pacing.turntable_deg_per_s * 1000 + pacing.settle_ms));
    std::optional<slrig::ViewRenderer> renderer;
    if (!pacing.prerender) {
      renderer.emplace(scene, angle, static_cast<int>(view));
      frame.resize(renderer->frame_bytes());
    }
    for (std::size_t e = 0; e < exposures; ++e)
      for (int side = 0; side < 2; ++side)
        for (std::size_t p = 0; p < plan.size(); ++p) {
          std::span<const std::uint8_t> bytes;
          if (pacing.prerender) {
            bytes = rendered[view][(e * 2 + static_cast<std::size_t>(side)) * plan.size() + p];
          } else {
            const auto t0 = Clock::now();
            renderer->render(static_cast<slproto::ProjectorSide>(side), plan, p, frame, exposure_of(e));
            render_s += std::chrono::duration<double>(Clock::now() - t0).count();
            bytes = frame;
          }
          slscan::core::FrameInfo info;
          info.view_index = static_cast<int>(view);
          info.commanded_angle_deg = info.reported_angle_deg = angle;
          info.projector = side;
          info.pattern_index = p;
          info.exposure_index = e;
          info.bytes_per_pixel = bytes_per_pixel;
          info.stride_bytes = static_cast<std::size_t>(width) * static_cast<std::size_t>(bytes_per_pixel);
          if (paced) {
            if (Clock::now() > due) {
              ++late_frames;
              due = Clock::now();
            }
            std::this_thread::sleep_until(due);
            due += period;
          }
          reconstructor.add_frame(info, std::as_bytes(bytes));
        }
    if (renderer) keep_truth(*renderer);
    rendered[view] = {};
  }
  const auto finish_start = Clock::now();
  slscan::core::ScanResult result = reconstructor.finish();
  const double finish_ms = std::chrono::duration<double, std::milli>(Clock::now() - finish_start).count();

  Json out;
  out["scene"] = name;
  out["size"] = std::to_string(width) + " x " + std::to_string(height);
  if (exposing.automatic) out["auto_exposure"] = auto_exposure;
  out["fringe_period_px"] = scene.pattern_plan.period_px;
  out["interreflection_samples"] = exposing.interreflection_samples;
  Json view_reports = Json::array();
  double filled_area_total = 0;
  for (std::size_t v = 0; v < result.views.size(); ++v) {
    const auto& report = result.views[v];
    const auto& products = result.view_products[v];
    const ViewTruth& truth = truths.at(static_cast<std::size_t>(report.view_index));
    Json j;
    j["view"] = report.view_index;
    j["fuse_clean_ms"] = {{"total", report.fuse_ms},
                          {"flying_pixels", report.flying_pixels_ms},
                          {"fusion", report.fusion_ms},
                          {"denoise", report.denoise_ms},
                          {"normals", report.normals_ms},
                          {"outliers", report.outliers_ms},
                          {"depth_smoothing", report.smoothing_ms}};
    j["depth_smoothing"] = {{"window_radius_px", report.depth_smoothing.window_radius_px},
                            {"full", report.depth_smoothing.full},
                            {"partial", report.depth_smoothing.partial},
                            {"kept", report.depth_smoothing.kept},
                            {"mean_shift_um", report.depth_smoothing.mean_shift_um}};
    for (std::size_t s = 0; s < 2; ++s) {
      const OrganizedCloud& cloud = products.projector_clouds[s];
      Json pj = error_stats(cloud, truth).json();
      pj["points_in_own_true_shadow"] = points_in_true_shadow(cloud, truth, s);
      pj["decode_ms"] = report.projectors[s].decode_ms;
      pj["triangulate_ms"] = report.projectors[s].triangulate_ms;
      pj["decoded"] = report.projectors[s].decode.valid;
      pj["saturated"] = report.projectors[s].decode.saturated;
      for (const auto& share : report.projectors[s].exposures)
        pj["exposures"].push_back({{"exposure_us", share.exposure_us},
                                   {"decoded", share.decoded},
                                   {"chosen", share.chosen},
                                   {"clipped", share.clipped}});
      j[s == 0 ? "left" : "right"] = pj;
    }
    const auto fused =
        slscan::core::fuse_left_right(products.projector_clouds[0], products.projector_clouds[1], options.fusion);
    j["fused"] = error_stats(fused.cloud, truth).json();
    if (outliers_csv) append_outliers(outliers_csv, name, report.view_index, fused.cloud, products.source, truth);
    j["fused"]["coverage"] = coverage(fused.cloud, truth);
    j["fusion"] = {{"both", report.fusion.both},
                   {"left_only", report.fusion.left_only},
                   {"right_only", report.fusion.right_only},
                   {"rejected", report.fusion.rejected}};
    const double filled = filled_shadow_area_mm2(products.source, truth, calibration.camera);
    filled_area_total += filled;
    j["shadow_area_filled_mm2"] = filled;
    j["final_object_cloud"] = error_stats(products.cloud.to_organized(), truth, true).json();
    view_reports.push_back(j);
  }
  out["views"] = view_reports;
  out["shadow_area_filled_mm2"] = filled_area_total;

  // The model, from the host's table frame to the rig's: view 0 is held at its coarse pose.
  const Eigen::Isometry3d host_table_from_cam0 =
      slscan::core::coarse_table_from_view(calibration.turntable, scene.view_angles_deg[0]);
  const Eigen::Isometry3d rig_table_from_host_table =
      to_isometry(truths[0].cam_from_table).inverse() * host_table_from_cam0.inverse();
  std::vector<Eigen::Vector3f> model(result.model.points.size());
  const Eigen::Isometry3f to_rig = rig_table_from_host_table.cast<float>();
  for (std::size_t i = 0; i < model.size(); ++i) model[i] = to_rig * result.model.points[i];

  const slrig::SurfaceSample surface = slrig::sample_object_surfaces(scene, 0.05);
  std::vector<Eigen::Vector3f> truth_points(surface.points.size() / 3);
  for (std::size_t i = 0; i < truth_points.size(); ++i)
    truth_points[i] = {surface.points[3 * i], surface.points[3 * i + 1], surface.points[3 * i + 2]};
  Json model_json;
  model_json["points"] = model.size();
  model_json["registered"] = result.registered;
  if (!result.registration_error.empty()) model_json["registration_error"] = result.registration_error;
  model_json["registration_iterations"] = result.registration.iterations;
  double max_correction_deg = 0, max_correction_mm = 0;
  for (const auto& r : result.registration.views) {
    max_correction_deg = std::max(max_correction_deg, r.correction_deg);
    max_correction_mm = std::max(max_correction_mm, r.correction_mm);
  }
  Json angle_corrections = Json::array();
  for (const auto& r : result.registration.views) angle_corrections.push_back(r.angle_correction_deg);
  model_json["registration_angle_corrections_deg"] = angle_corrections;
  model_json["registration_axis_tilt_deg"] = result.registration.axis_tilt_deg;
  model_json["registration_axis_shift_mm"] = result.registration.axis_shift_mm;
  model_json["max_registration_correction_deg"] = max_correction_deg;
  model_json["max_registration_correction_mm"] = max_correction_mm;
  if (!truth_points.empty() && !model.empty()) {
    const slscan::core::PointIndex truth_tree(truth_points);
    const slscan::core::PointIndex model_tree(model);
    // Stray points: above the platform by more than 0.5 mm and more than 0.5 mm from the object.
    std::size_t stray = 0, near_object = 0;
    std::vector<double> distances;
    distances.reserve(model.size());
    for (const auto& p : model) {
      float d2 = 0;
      const std::int64_t nearest = truth_tree.nearest_within(p, 0.5f, d2);
      if (nearest >= 0) {
        ++near_object;
        // Point to surface: along the true normal at the nearest sample (samples are 0.05 mm
        // apart, so the distance to the sample itself would read ~20 um on a perfect point).
        const auto k = static_cast<std::size_t>(nearest);
        const Eigen::Vector3f n(surface.normals[3 * k], surface.normals[3 * k + 1], surface.normals[3 * k + 2]);
        distances.push_back(std::fabs(static_cast<double>(n.dot(p - truth_points[k]))));
      } else if (p.z() > 0.5f) {
        ++stray;
      }
    }
    std::sort(distances.begin(), distances.end());
    model_json["stray_points_above_0_5mm"] = stray;
    model_json["points_within_0_5mm_of_object"] = near_object;
    if (!distances.empty()) {
      model_json["distance_to_true_surface_median_um"] = 1e3 * distances[distances.size() / 2];
      model_json["distance_to_true_surface_p99_um"] = 1e3 * distances[distances.size() * 99 / 100];
    }
    // 360-degree coverage: true surface samples with a model point within 0.1 mm, per object.
    std::map<int, std::pair<std::size_t, std::size_t>> by_object;
    for (std::size_t i = 0; i < truth_points.size(); ++i) {
      float d2 = 0;
      auto& [covered, total] = by_object[surface.object_id[i]];
      ++total;
      covered += model_tree.nearest_within(truth_points[i], 0.1f, d2) >= 0 ? 1 : 0;
    }
    Json cov = Json::object();
    for (const auto& [id, counts] : by_object)
      cov[scene.objects.at(static_cast<std::size_t>(id - 2)).name] =
          100.0 * static_cast<double>(counts.first) / static_cast<double>(counts.second);
    model_json["surface_within_0_1mm_percent"] = cov;
  }
  if (name == "ballbar") {
    const slrig::SceneObject* bar = nullptr;
    for (const auto& o : scene.objects)
      if (o.kind == slrig::ObjectKind::ballbar) bar = &o;
    slscan::core::PointCloud cloud;
    cloud.points = model;
    slscan::core::BallBarOptions bar_options;
    bar_options.nominal_radii_mm = {bar->radius_a, bar->radius_b};
    try {
      const auto m = slscan::core::measure_ball_bar(cloud, bar_options);
      model_json["ball_bar"] = {{"centre_distance_mm", m.centre_distance_mm},
                                {"centre_distance_error_um", 1e3 * (m.centre_distance_mm - bar->centre_distance)},
                                {"radius_a_error_um", 1e3 * (m.spheres[0].radius_mm - bar->radius_a)},
                                {"radius_b_error_um", 1e3 * (m.spheres[1].radius_mm - bar->radius_b)},
                                {"form_error_a_um", 1e3 * m.spheres[0].form_error_mm},
                                {"form_error_b_um", 1e3 * m.spheres[1].form_error_mm},
                                {"sphere_rms_a_um", 1e3 * m.spheres[0].rms_mm},
                                {"sphere_rms_b_um", 1e3 * m.spheres[1].rms_mm}};
    } catch (const std::exception& e) {
      model_json["ball_bar"] = {{"error", e.what()}};
    }
  }
  out["model"] = model_json;
  Json stages = Json::object();
  for (const auto& [stage, ms] : result.stage_ms) stages[stage] = ms;
  out["after_last_frame_ms"] = {{"total", finish_ms}, {"stages", stages}};
  out["render_s"] = render_s;
  out["pacing"] = {{"frame_period_ms", pacing.frame_period_ms},
                   {"turntable_deg_per_s", pacing.turntable_deg_per_s},
                   {"settle_ms", paced ? pacing.settle_ms : 0.0},
                   {"late_frames", late_frames},
                   {"prerendered", pacing.prerender}};
  out["peak_rss_mb"] = peak_rss_mb();
  return out;
}

}  // namespace

int main(int argc, char** argv) try {
  slscan::core::run_with_huge_pages(argv);  // as slscan does: the same allocator behind the same code
  std::string size_name = "full", json_path, outliers_path;
  std::vector<std::string> scenes{"ballbar", "blade", "teacup"};
  int max_views = 6;
  bool mesh = false, noise = true, registration = true;
  auto registration_mode = slscan::core::RefinementMode::turntable;
  int decode_smoothing = -1, quadratic_radius = -1;  // -1: the decoder's defaults
  Pacing pacing;
  Exposing exposing;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw std::invalid_argument(arg + " needs a value");
      return argv[++i];
    };
    try {
      if (arg == "--size") {
        size_name = value();
      } else if (arg == "--scenes") {
        scenes.clear();
        std::stringstream list(value());
        for (std::string s; std::getline(list, s, ',');) scenes.push_back(s);
      } else if (arg == "--views") {
        max_views = std::stoi(value());
      } else if (arg == "--mesh") {
        mesh = true;
      } else if (arg == "--no-noise") {
        noise = false;
      } else if (arg == "--no-registration") {
        registration = false;
      } else if (arg == "--registration-mode") {
        const std::string mode = value();
        if (mode == "turntable")
          registration_mode = slscan::core::RefinementMode::turntable;
        else if (mode == "joint")
          registration_mode = slscan::core::RefinementMode::joint;
        else if (mode == "sequential")
          registration_mode = slscan::core::RefinementMode::sequential;
        else
          throw std::invalid_argument("--registration-mode: turntable, joint or sequential, not '" + mode + "'");
      } else if (arg == "--decode-smoothing") {
        decode_smoothing = std::stoi(value());
      } else if (arg == "--decode-quadratic-radius") {
        quadratic_radius = std::stoi(value());
      } else if (arg == "--outliers") {
        outliers_path = value();
      } else if (arg == "--json") {
        json_path = value();
      } else if (arg == "--frame-period-ms") {
        pacing.frame_period_ms = std::stod(value());
        if (!(pacing.frame_period_ms >= 0 && pacing.frame_period_ms <= 10000))
          throw std::invalid_argument("--frame-period-ms must be in [0, 10000]");
      } else if (arg == "--exposure-bracket") {
        exposing.bracket.clear();
        std::stringstream list(value());
        for (std::string f; std::getline(list, f, ',');) {
          exposing.bracket.push_back(std::stod(f));
          if (!(exposing.bracket.back() > 0 && exposing.bracket.back() <= 100))
            throw std::invalid_argument("--exposure-bracket: each fraction of the reference must be in (0, 100]");
        }
        if (exposing.bracket.empty() || exposing.bracket.size() > 8)
          throw std::invalid_argument("--exposure-bracket: 1 to 8 fractions of the reference exposure");
      } else if (arg == "--exposure-auto") {
        exposing.automatic = true;
      } else if (arg == "--material") {
        auto material = slrig::parse_material(value());
        if (!material) throw std::invalid_argument("--material: " + material.error().message);
        exposing.material = *material;
      } else if (arg == "--interreflection") {
        exposing.interreflection_samples = std::stoi(value());
        if (exposing.interreflection_samples < 1 || exposing.interreflection_samples > 1024)
          throw std::invalid_argument("--interreflection: 1 to 1024 rays per pixel");
      } else if (arg == "--fringe-period-px") {
        exposing.fringe_period_px = std::stoi(value());
        if (exposing.fringe_period_px < 2 || exposing.fringe_period_px > 1140)
          throw std::invalid_argument("--fringe-period-px: 2 to 1140 projector pixels");
      } else if (arg == "--prerender") {
        pacing.prerender = true;
      } else if (arg == "--turntable-deg-per-s") {
        pacing.turntable_deg_per_s = std::stod(value());
        if (!(pacing.turntable_deg_per_s > 0 && pacing.turntable_deg_per_s <= 1e6))
          throw std::invalid_argument("--turntable-deg-per-s must be in (0, 1e6]");
      } else {
        std::fprintf(stderr,
                     "usage: bench_accuracy [--size full|small] [--scenes a,b] [--views N] [--mesh] [--no-noise] "
                     "[--no-registration] [--registration-mode turntable|joint|sequential] "
                     "[--decode-smoothing R] [--decode-quadratic-radius Q] [--json FILE] [--outliers CSV] "
                     "[--frame-period-ms P] [--turntable-deg-per-s S] [--prerender] [--exposure-bracket F,F,...] "
                     "[--exposure-auto] [--material NAME] [--interreflection SAMPLES] [--fringe-period-px P]\n");
        return 2;
      }
    } catch (const std::exception& e) {
      std::fprintf(stderr, "bench_accuracy: %s\n", e.what());
      return 2;
    }
  }
  if (size_name != "full" && size_name != "small") {
    std::fprintf(stderr, "bench_accuracy: --size must be full or small, not '%s'\n", size_name.c_str());
    return 2;
  }
  const auto size = size_name == "full" ? slrig::RigSize::full : slrig::RigSize::small;
  std::FILE* outliers = nullptr;
  if (!outliers_path.empty()) {
    outliers = std::fopen(outliers_path.c_str(), "w");
    if (!outliers) {
      std::fprintf(stderr, "bench_accuracy: cannot write %s\n", outliers_path.c_str());
      return 1;
    }
    std::fprintf(outliers,
                 "scene,view,u,v,error_mm,object_id,fusion_source,view_angle_deg,px_to_edge,"
                 "px_to_left_shadow,px_to_right_shadow\n");
  }
  Json report = Json::array();
  for (const auto& name : scenes) {
    try {
      Json scene = run_scene(name, size, max_views, mesh, noise, decode_smoothing, quadratic_radius, registration,
                             registration_mode, outliers, pacing, exposing);
      std::printf("%s\n", scene.dump(1).c_str());
      std::fflush(stdout);
      report.push_back(std::move(scene));
    } catch (const std::exception& e) {
      std::fprintf(stderr, "bench_accuracy: scene '%s': %s\n", name.c_str(), e.what());
      if (outliers) std::fclose(outliers);
      return 1;
    }
  }
  if (outliers) std::fclose(outliers);
  if (!json_path.empty()) {
    const std::string text = report.dump(2) + "\n";
    if (auto status = slproto::write_file_atomically(json_path, text); !status) {
      std::fprintf(stderr, "bench_accuracy: %s\n", status.error().message.c_str());
      return 1;
    }
  }
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "bench_accuracy: %s\n", e.what());
  return 1;
}
