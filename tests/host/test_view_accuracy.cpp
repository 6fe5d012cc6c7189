// Stages 1-4 end to end on the virtual rig's small (640 x 512) presets, against the rig's
// per-pixel ground truth, with the true calibration.
//
// What is measured: every point of each projector's cloud and of the fused cloud that lies in
// the scanner's working volume: the object and the platform. The background wall (object id 1)
// is excluded: it stands 400 mm behind the axis, ~2x the working distance, where depth noise
// is ~4x larger, and turntable denoise removes it anyway. The final per-view cloud (fused and
// denoised: the object only) is checked too.
//
// Tolerances. Issue 4 states them for the full 2464 x 2056 rig: median <= 10 um, RMS <= 25 um,
// < 0.1 % beyond 0.2 mm. On the small rig a camera pixel covers 3.85x the surface, so curvature
// inside one pixel and inside the decoder's 5 x 5 smoothing window weighs ~3.85x more, while the
// per-pixel sensor noise is the same. Scaled bounds asserted here: median <= 20 um,
// RMS <= 50 um, <= 0.6 % beyond 0.2 mm (measured: 0.15-0.45 %, at silhouettes and on the
// teacup's handle and rim: see docs/pipeline.md, "Known gaps"). The final object-only cloud
// is mostly silhouette, where the outliers sit: <= 2 % there (measured ~0.9 %).
//
// Coverage: of the working-volume pixels that at least one projector lights and the camera sees, we count
// those whose whole 5 x 5 neighbourhood (the reach of the flying-pixel filter) is lit by the
// same projector and shows the same object, and that this projector's decoder did not have to
// mask (saturated, too little contrast or modulation: dark or grazing surfaces, a legitimate
// mask). At least 99 % of them must end up in the fused cloud. The raw fraction is printed too.
#include <gtest/gtest.h>

#if __has_include("slrig/rig.hpp")
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <vector>

#include "slrig/rig.hpp"
#include "slscan/core/scan_reconstruction.hpp"

namespace {

using slproto::ProjectorSide;
using slscan::core::DecodeMask;
using slscan::core::OrganizedCloud;
using slscan::core::ReconstructionOptions;
using slscan::core::ScanReconstructor;

struct ErrorStats {
  std::size_t points = 0, beyond_0_2mm = 0, without_truth = 0;
  double median_mm = 0, rms_mm = 0;
  double fraction_beyond() const {
    return points ? static_cast<double>(beyond_0_2mm) / static_cast<double>(points) : 0;
  }
};

constexpr std::int16_t kWall = 1;

ErrorStats error_stats(const OrganizedCloud& cloud, const slrig::ViewGroundTruth& truth) {
  ErrorStats stats;
  std::vector<double> errors;
  double sum2 = 0;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!cloud.valid[i] || truth.object_id[i] == kWall) continue;
    ++stats.points;
    const Eigen::Vector3f g(truth.points[3 * i], truth.points[3 * i + 1], truth.points[3 * i + 2]);
    if (!g.allFinite()) {
      ++stats.without_truth;
      ++stats.beyond_0_2mm;
      continue;
    }
    const double e = (cloud.points[i] - g).norm();
    errors.push_back(e);
    sum2 += e * e;
    if (e > 0.2) ++stats.beyond_0_2mm;
  }
  if (!errors.empty()) {
    std::nth_element(errors.begin(), errors.begin() + static_cast<long>(errors.size() / 2), errors.end());
    stats.median_mm = errors[errors.size() / 2];
    stats.rms_mm = std::sqrt(sum2 / static_cast<double>(errors.size()));
  }
  return stats;
}

// What one view leaves, as the scan's reconstruction produces it.
struct ViewResult {
  std::array<OrganizedCloud, 2> per_projector;  // after flying-pixel removal, before fusion
  OrganizedCloud cloud;                         // fused (and denoised unless turned off)
  slscan::core::FusionCounts fusion;
  slscan::core::TurntableDenoiseCounts turntable;
};

struct ViewRun {
  slrig::Scene scene;
  slproto::RigCalibration calibration;
  std::unique_ptr<slrig::ViewRenderer> renderer;
  ViewResult result;
  std::array<std::vector<DecodeMask>, 2> masks;
};

// One view through ScanReconstructor (the code path of a scan), registration and the
// model's cleanup off: stages 1-4 only.
// `edit`, when given, changes the preset's scene before rendering.
ViewRun run_view(const std::string& preset, int view_index, ReconstructionOptions options = {},
                 const std::function<void(slrig::Scene&)>& edit = {}) {
  ViewRun run;
  auto scene = slrig::scene_preset(preset, slrig::RigSize::small);
  if (!scene) throw std::runtime_error(scene.error().message);
  run.scene = *scene;
  if (edit) edit(run.scene);
  run.calibration = slrig::ground_truth_calibration(run.scene);
  const double angle = run.scene.view_angles_deg.at(static_cast<std::size_t>(view_index));
  run.renderer = std::make_unique<slrig::ViewRenderer>(run.scene, angle, view_index);
  options.decode.bit_depth = run.scene.sensor.bit_depth;
  options.register_views = false;
  options.remove_outliers = false;
  options.build_mesh = false;
  options.keep_projector_clouds = true;
  const slproto::PatternPlan plan(run.calibration.pattern_plan);
  const int width = run.renderer->width(), height = run.renderer->height();
  ScanReconstructor reconstructor(run.calibration, plan, width, height, options);
  std::vector<std::uint8_t> frame(run.renderer->frame_bytes());
  const int bytes_per_pixel = run.scene.sensor.bit_depth > 8 ? 2 : 1;
  for (ProjectorSide side : {ProjectorSide::left, ProjectorSide::right}) {
    for (std::size_t p = 0; p < plan.size(); ++p) {
      run.renderer->render(side, p, frame);
      slscan::core::FrameInfo info;
      info.view_index = view_index;
      info.commanded_angle_deg = info.reported_angle_deg = angle;
      info.projector = static_cast<int>(side);
      info.pattern_index = p;
      info.bytes_per_pixel = bytes_per_pixel;
      info.stride_bytes = static_cast<std::size_t>(width * bytes_per_pixel);
      reconstructor.add_frame(info, std::as_bytes(std::span(frame)));
    }
  }
  slscan::core::ScanResult scan = reconstructor.finish();
  if (scan.view_products.size() != 1) throw std::runtime_error("the view was not reconstructed");
  auto& products = scan.view_products.front();
  run.result.per_projector = std::move(products.projector_clouds);
  run.result.cloud = products.cloud.to_organized();
  run.result.fusion = scan.views.front().fusion;
  run.result.turntable = scan.views.front().turntable_denoise;
  // The decoder's masks, for the coverage count: decode the frames once more, standalone.
  for (ProjectorSide side : {ProjectorSide::left, ProjectorSide::right}) {
    slscan::core::ProjectorViewDecoder decoder(plan, run.renderer->width(), run.renderer->height(), options.decode);
    for (std::size_t p = 0; p < plan.size(); ++p) {
      run.renderer->render(side, p, frame);
      if (run.scene.sensor.bit_depth > 8) {
        decoder.add_frame(p, reinterpret_cast<const std::uint16_t*>(frame.data()), static_cast<std::size_t>(width));
      } else {
        decoder.add_frame(p, frame.data(), static_cast<std::size_t>(width));
      }
    }
    run.masks[static_cast<std::size_t>(side)] = decoder.finish().mask;
  }
  return run;
}

struct Coverage {
  std::size_t lit_seen = 0, expected = 0, expected_covered = 0, lit_seen_covered = 0;
  double fraction() const {
    return expected ? static_cast<double>(expected_covered) / static_cast<double>(expected) : 1;
  }
};

Coverage coverage(const ViewRun& run, const OrganizedCloud& fused) {
  const auto& truth = run.renderer->ground_truth();
  const int w = truth.width, h = truth.height;
  Coverage c;
  auto at = [w](int u, int v) {
    return static_cast<std::size_t>(v) * static_cast<std::size_t>(w) + static_cast<std::size_t>(u);
  };
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const std::size_t i = at(u, v);
      if (!std::isfinite(truth.points[3 * i]) || !(truth.lit[0][i] || truth.lit[1][i])) continue;
      if (truth.object_id[i] == kWall) continue;  // outside the working volume, as for accuracy
      ++c.lit_seen;
      c.lit_seen_covered += fused.valid[i] != 0;
      bool expected = false;
      for (std::size_t s = 0; s < 2 && !expected; ++s) {
        const DecodeMask m = run.masks[s][i];
        if (m != DecodeMask::valid) continue;
        bool interior = u >= 2 && v >= 2 && u < w - 2 && v < h - 2;
        for (int dv = -2; dv <= 2 && interior; ++dv)
          for (int du = -2; du <= 2 && interior; ++du) {
            const std::size_t j = at(u + du, v + dv);
            interior = truth.lit[s][j] && truth.object_id[j] == truth.object_id[i];
          }
        expected = interior;
      }
      if (!expected) continue;
      ++c.expected;
      c.expected_covered += fused.valid[i] != 0;
    }
  return c;
}

// Points that projector `s` gave where it does not light the surface. A camera pixel whose
// centre is in shadow can still be partly lit at a shadow border, so a point is only counted
// when no pixel of its 3 x 3 neighbourhood is lit.
std::size_t points_in_true_shadow(const OrganizedCloud& cloud, const slrig::ViewGroundTruth& truth, std::size_t s) {
  const int w = truth.width, h = truth.height;
  std::size_t count = 0;
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const auto i = static_cast<std::size_t>(v * w + u);
      if (!cloud.valid[i] || truth.lit[s][i]) continue;
      bool near_lit = false;
      for (int dv = -1; dv <= 1; ++dv)
        for (int du = -1; du <= 1; ++du) {
          const int uu = u + du, vv = v + dv;
          if (uu >= 0 && vv >= 0 && uu < w && vv < h && truth.lit[s][static_cast<std::size_t>(vv * w + uu)])
            near_lit = true;
        }
      count += near_lit ? 0 : 1;
    }
  return count;
}

void check_view(const std::string& preset, int view_index) {
  SCOPED_TRACE(preset + " view " + std::to_string(view_index));
  ReconstructionOptions options;
  options.denoise_turntable = false;  // accuracy of everything the camera sees, table included
  const ViewRun run = run_view(preset, view_index, options);
  const auto& truth = run.renderer->ground_truth();
  for (std::size_t s = 0; s < 2; ++s) {
    const ErrorStats e = error_stats(run.result.per_projector[s], truth);
    std::printf("%s view %d %s: %zu points, median %.1f um, RMS %.1f um, beyond 0.2 mm %.4f %% (%zu without truth)\n",
                preset.c_str(), view_index, s ? "right" : "left", e.points, 1e3 * e.median_mm, 1e3 * e.rms_mm,
                100 * e.fraction_beyond(), e.without_truth);
    EXPECT_GT(e.points, 20000u);
    EXPECT_LT(e.median_mm, 0.020);
    EXPECT_LT(e.rms_mm, 0.050);
    EXPECT_LT(e.fraction_beyond(), 0.006);
    EXPECT_EQ(points_in_true_shadow(run.result.per_projector[s], truth, s), 0u);
  }
  const ErrorStats fused = error_stats(run.result.cloud, truth);
  const Coverage c = coverage(run, run.result.cloud);
  const auto& f = run.result.fusion;
  std::printf(
      "%s view %d fused: %zu points, median %.1f um, RMS %.1f um, beyond 0.2 mm %.4f %%; both %zu, left only %zu, "
      "right only %zu, rejected %zu; coverage %.3f %% of %zu expected (raw %.3f %% of %zu lit and seen)\n",
      preset.c_str(), view_index, fused.points, 1e3 * fused.median_mm, 1e3 * fused.rms_mm,
      100 * fused.fraction_beyond(), f.both, f.left_only, f.right_only, f.rejected, 100 * c.fraction(), c.expected,
      100.0 * static_cast<double>(c.lit_seen_covered) / static_cast<double>(std::max<std::size_t>(c.lit_seen, 1)),
      c.lit_seen);
  EXPECT_LT(fused.median_mm, 0.020);
  EXPECT_LT(fused.rms_mm, 0.050);
  EXPECT_LT(fused.fraction_beyond(), 0.006);
  EXPECT_GT(c.expected, 50000u);
  EXPECT_GE(c.fraction(), 0.99);
  // Both projectors light most of what the camera sees; each fills the other's shadow.
  EXPECT_GT(f.both, f.left_only + f.right_only);
  EXPECT_GT(f.left_only, 0u);
  EXPECT_GT(f.right_only, 0u);
}

TEST(ViewAccuracy, Sphere) { check_view("sphere", 0); }
TEST(ViewAccuracy, TeacupTwoViews) {
  check_view("teacup", 0);
  check_view("teacup", 1);
}

TEST(ViewAccuracy, TurntableDenoiseLeavesOnlyTheObject) {
  const ViewRun run = run_view("teacup", 0);
  const auto& truth = run.renderer->ground_truth();
  const OrganizedCloud& cloud = run.result.cloud;
  std::size_t object_points = 0, other_points = 0;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!cloud.valid[i]) continue;
    (truth.object_id[i] >= 2 ? object_points : other_points) += 1;
  }
  const auto& t = run.result.turntable;
  std::printf(
      "teacup view 0 denoise: %zu in, %zu kept, %zu at/below the platform, %zu beyond the radius; "
      "%zu non-object points left\n",
      t.input, t.kept, t.below_min_height, t.outside_radius, other_points);
  EXPECT_GT(t.below_min_height, 10000u) << "the platform is in view and must go";
  EXPECT_GT(t.outside_radius, 10000u) << "the background wall is in view and must go";
  EXPECT_EQ(other_points, 0u);
  // The object itself survives (points within min_height of the platform go with it).
  std::size_t object_before = 0;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const auto& fused = run.result.per_projector;
    if ((fused[0].valid[i] || fused[1].valid[i]) && truth.object_id[i] >= 2) ++object_before;
  }
  EXPECT_GT(static_cast<double>(object_points), 0.98 * static_cast<double>(object_before));
  const ErrorStats e = error_stats(cloud, truth);
  std::printf("teacup view 0 final cloud: %zu points, median %.1f um, RMS %.1f um, beyond 0.2 mm %.4f %%\n", e.points,
              1e3 * e.median_mm, 1e3 * e.rms_mm, 100 * e.fraction_beyond());
  EXPECT_LT(e.median_mm, 0.020);
  EXPECT_LT(e.rms_mm, 0.050);
  EXPECT_LT(e.fraction_beyond(), 0.02);
}

// The albedo channel (DecodedView::intensity) per pixel: each projector's cloud holds, at every
// point, exactly what the rig rendered there in the white frame minus the black frame (as a
// fraction of full scale): a channel read from the wrong pixel or plane, or dropped on the way
// through triangulation and flying-pixel removal, fails here. The fused cloud holds the
// quality-weighted mean, so it lies between the two projectors' values.
TEST(ViewAccuracy, IntensityIsTheRenderedWhiteMinusBlackAtEachPoint) {
  ReconstructionOptions options;
  options.denoise_turntable = false;  // the sphere, the platform and the wall: three materials
  const ViewRun run = run_view("sphere", 0, options);
  const slproto::PatternPlan plan(run.calibration.pattern_plan);
  const int white = plan.index_of(slproto::PatternKind::white), black = plan.index_of(slproto::PatternKind::black);
  ASSERT_GE(white, 0);
  ASSERT_GE(black, 0);
  ASSERT_EQ(run.scene.sensor.bit_depth, 8);
  std::vector<std::uint8_t> w(run.renderer->frame_bytes()), b(run.renderer->frame_bytes());
  std::array<std::vector<float>, 2> expected;
  for (ProjectorSide side : {ProjectorSide::left, ProjectorSide::right}) {
    const auto s = static_cast<std::size_t>(side);
    run.renderer->render(side, static_cast<std::size_t>(white), w);
    run.renderer->render(side, static_cast<std::size_t>(black), b);
    const OrganizedCloud& cloud = run.result.per_projector[s];
    ASSERT_EQ(cloud.intensity.size(), cloud.size());
    expected[s].resize(cloud.size());
    std::size_t checked = 0, ambient = 0;
    for (std::size_t i = 0; i < cloud.size(); ++i) {
      expected[s][i] = std::max(0.0f, (static_cast<float>(w[i]) - static_cast<float>(b[i])) / 255.0f);
      if (!cloud.valid[i]) continue;
      ++checked;
      ambient += b[i] > 2 ? 1 : 0;
      ASSERT_NEAR(cloud.intensity[i], expected[s][i], 1e-6f) << (s ? "right" : "left") << " pixel " << i;
    }
    EXPECT_GT(checked, 20000u);
    // The room light shows in the black frame: the white frame alone would not be the albedo.
    EXPECT_GT(ambient, checked / 2) << "ambient light in the black frame at most points";
  }
  const OrganizedCloud& fused = run.result.cloud;
  ASSERT_EQ(fused.intensity.size(), fused.size());
  std::size_t both = 0;
  for (std::size_t i = 0; i < fused.size(); ++i) {
    if (!fused.valid[i]) continue;
    const bool l = run.result.per_projector[0].valid[i] != 0, r = run.result.per_projector[1].valid[i] != 0;
    ASSERT_TRUE(l || r) << "pixel " << i;
    if (l && r) {
      ++both;
      const auto [lo, hi] = std::minmax(expected[0][i], expected[1][i]);
      ASSERT_GE(fused.intensity[i], lo - 1e-6f) << "pixel " << i;
      ASSERT_LE(fused.intensity[i], hi + 1e-6f) << "pixel " << i;
    } else {
      ASSERT_NEAR(fused.intensity[i], expected[l ? 0 : 1][i], 1e-6f) << "pixel " << i;
    }
  }
  EXPECT_GT(both, 10000u);
}

// Proportional to the albedo: the same sphere at half the albedo, same pose and light, reads half
// the intensity at each of its points; the platform, unchanged, reads the same. Asserted on the
// points measured in both runs: median ratio 0.5 within 2 %, 90 % of the sphere's points within
// 10 % of it (sensor noise).
TEST(ViewAccuracy, IntensityIsProportionalToTheAlbedo) {
  ReconstructionOptions options;
  options.denoise_turntable = false;
  const ViewRun bright = run_view("sphere", 0, options);
  const ViewRun dark = run_view("sphere", 0, options, [](slrig::Scene& scene) { scene.objects.at(0).albedo *= 0.5; });
  const auto& truth = bright.renderer->ground_truth();
  std::vector<double> ratios, platform;
  for (std::size_t i = 0; i < truth.object_id.size(); ++i) {
    if (!bright.result.cloud.valid[i] || !dark.result.cloud.valid[i]) continue;
    const double a = bright.result.cloud.intensity[i], d = dark.result.cloud.intensity[i];
    if (!(a > 0.05)) continue;
    if (truth.object_id[i] == 2) ratios.push_back(d / a);
    if (truth.object_id[i] == 0) platform.push_back(d / a);
  }
  ASSERT_GT(ratios.size(), 3000u);
  ASSERT_GT(platform.size(), 1000u);
  auto quantile = [](std::vector<double> v, double q) {
    const auto k = static_cast<std::size_t>(q * static_cast<double>(v.size() - 1));
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
    return v[k];
  };
  const double median = quantile(ratios, 0.5), p05 = quantile(ratios, 0.05), p95 = quantile(ratios, 0.95);
  std::printf("sphere at half albedo: intensity ratio median %.4f, 5-95 %% %.4f..%.4f over %zu points; platform %.4f\n",
              median, p05, p95, ratios.size(), quantile(platform, 0.5));
  EXPECT_NEAR(median, 0.5, 0.01);
  EXPECT_GT(p05, 0.45);
  EXPECT_LT(p95, 0.55);
  EXPECT_NEAR(quantile(platform, 0.5), 1.0, 0.02) << "the platform's albedo did not change";
}

}  // namespace

#else
TEST(ViewAccuracy, NeedsTheVirtualRig) { GTEST_SKIP() << "built without slrig (firmware/rig)"; }
#endif
