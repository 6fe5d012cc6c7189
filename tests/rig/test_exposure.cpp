// The rig's exposure physics: signal from exposure time and LED current, electrons' noise,
// clipping and blooming, mains flicker, the finishes and the one-bounce interreflection.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numeric>

#include "rig_test_util.hpp"
#include "slrig/rig.hpp"

namespace slrig {
namespace {

constexpr int kWhite = 0, kBlack = 1;  // the default plan starts white, black

Scene plate_scene() {
  Scene scene = test::small_rig_without_objects();
  scene.objects.push_back(test::camera_frame_plane({0, 0, -1}, {0, 0, 560}));
  return scene;
}

std::vector<std::uint8_t> render(const ViewRenderer& r, int pattern, const Exposure& e = {}) {
  std::vector<std::uint8_t> frame(r.frame_bytes());
  r.render(ProjectorSide::left, slproto::PatternPlan(), static_cast<std::size_t>(pattern), frame, e);
  return frame;
}

// A pixel the left projector lights on the plate.
std::size_t lit_pixel(const ViewRenderer& r) {
  const auto& t = r.ground_truth();
  const std::size_t centre = static_cast<std::size_t>(r.height() / 2) * static_cast<std::size_t>(r.width()) +
                             static_cast<std::size_t>(r.width() / 2);
  EXPECT_TRUE(t.lit[0][centre]);
  return centre;
}

TEST(Exposure, SignalScalesWithExposureTimeAndLedCurrent) {
  const Scene scene = plate_scene();
  const ViewRenderer r(scene, 0, 0);
  const std::size_t i = lit_pixel(r);
  const double ref = scene.sensor.exposure_us;
  const auto white = render(r, kWhite), black = render(r, kBlack);
  const double projector = white[i] - black[i], ambient = black[i];
  ASSERT_GT(projector, 100);
  ASSERT_GT(ambient, 4);
  // Half the exposure: half of everything (rounding: +-1 DN).
  const auto half_white = render(r, kWhite, {.exposure_us = ref / 2}),
             half_black = render(r, kBlack, {.exposure_us = ref / 2});
  EXPECT_NEAR(half_white[i], 0.5 * white[i], 1.0);
  EXPECT_NEAR(half_black[i], 0.5 * black[i], 1.0);
  // A quarter of the LED current: the projector's part only; the room light is the same.
  const auto dim_white = render(r, kWhite, {.led_current = 0.25}), dim_black = render(r, kBlack, {.led_current = 0.25});
  EXPECT_EQ(dim_black[i], black[i]);
  EXPECT_NEAR(dim_white[i] - dim_black[i], 0.25 * projector, 1.0);
  // The projector lit for half the exposure: half its light, all of the ambient's.
  const auto short_lit = render(r, kWhite, {.exposure_us = ref, .projector_us = ref / 2});
  EXPECT_NEAR(short_lit[i] - black[i], 0.5 * projector, 1.0);
  // The explicit reference is the reference, bit for bit (noise included).
  Scene noisy = scene;
  noisy.sensor.noise = true;
  const ViewRenderer rn(noisy, 0, 0);
  EXPECT_EQ(render(rn, 7), render(rn, 7, {.exposure_us = ref, .led_current = 1, .projector_us = ref}));
  EXPECT_NE(render(rn, 7), render(rn, 7, {.exposure_us = ref * 1.0001})) << "another exposure, other noise";
}

TEST(Exposure, ImpossibleExposuresAreErrorsNamingTheValue) {
  const ViewRenderer r(plate_scene(), 0, 0);
  std::vector<std::uint8_t> frame(r.frame_bytes());
  const slproto::PatternPlan plan;
  for (const Exposure& e : {Exposure{.exposure_us = -1}, Exposure{.led_current = 0}, Exposure{.led_current = 1.5},
                            Exposure{.exposure_us = 100, .projector_us = 200}, Exposure{.start_s = NAN}}) {
    auto status = r.try_render(ProjectorSide::left, plan, 0, frame, e);
    ASSERT_FALSE(status.ok());
    EXPECT_NE(status.error().message.find("render: "), std::string::npos) << status.error().message;
  }
  EXPECT_THROW(r.render_ambient(frame, {.exposure_us = std::nan("")}), std::invalid_argument);
}

TEST(Exposure, NoiseFollowsTheElectrons) {
  // Over a patch of the plate, the variance of (noisy - exact) is signal / gain + read noise^2
  // at any exposure: four times the exposure, four times the electrons, twice the shot noise.
  Scene scene = plate_scene();
  scene.sensor.bit_depth = 12;  // no rounding floor, no clipping in range
  const ViewRenderer exact(scene, 0, 0);
  scene.sensor.noise = true;
  const ViewRenderer noisy(scene, 0, 0);
  const double ref = scene.sensor.exposure_us;
  const double gain = scene.sensor.full_well_electrons / 4095.0;  // e- per DN
  const double read = scene.sensor.read_noise_dn * 16;
  const int w = exact.width();
  for (const double factor : {0.25, 1.0, 1.2}) {
    const Exposure e{.exposure_us = ref * factor};
    std::vector<std::uint8_t> a(exact.frame_bytes()), b(noisy.frame_bytes());
    exact.render(ProjectorSide::left, slproto::PatternPlan(), kWhite, a, e);
    noisy.render(ProjectorSide::left, slproto::PatternPlan(), kWhite, b, e);
    double sum = 0, sum2 = 0, signal = 0;
    int count = 0;
    for (int v = exact.height() / 2 - 40; v < exact.height() / 2 + 40; ++v)
      for (int u = w / 2 - 40; u < w / 2 + 40; ++u) {
        const auto i = static_cast<std::size_t>(v * w + u);
        const double x = a[2 * i] | (a[2 * i + 1] << 8), y = b[2 * i] | (b[2 * i + 1] << 8);
        sum += y - x;
        sum2 += (y - x) * (y - x);
        signal += x;
        count++;
      }
    signal /= count;
    const double mean = sum / count, variance = sum2 / count - mean * mean;
    EXPECT_NEAR(mean, 0, 1.0);
    EXPECT_NEAR(variance / (signal / gain + read * read), 1.0, 0.1)
        << "exposure x" << factor << ": " << signal << " DN";
  }
}

TEST(Exposure, ClipsAtFullScaleAndBloomsIntoTheNeighbours) {
  // A bright strip on a dark plate: over-exposed, the strip clips and its charge above the
  // full well spills a quarter of `blooming` into each 4-neighbour.
  Scene scene = test::small_rig_without_objects();
  SceneObject dark = test::camera_frame_plane({0, 0, -1}, {0, 0, 400});  // in front of the platform
  dark.albedo = 0.05;
  scene.objects.push_back(dark);
  SceneObject strip = test::camera_frame_plane({0, 0, -1}, {0, 0, 399}, 40);  // 40 mm square in front
  strip.albedo = 0.9;
  scene.objects.push_back(strip);
  const double ref = scene.sensor.exposure_us;
  scene.sensor.blooming = 0;
  const ViewRenderer without(scene, 0, 0);
  scene.sensor.blooming = 0.4;
  const ViewRenderer with(scene, 0, 0);
  const Exposure bright{.exposure_us = 4 * ref};
  const auto a = render(without, kWhite, bright), b = render(with, kWhite, bright);
  const auto& ids = with.ground_truth().object_id;
  const int w = with.width();
  std::size_t edges = 0, inside_clipped = 0, inside = 0;
  for (int v = 1; v + 1 < with.height(); ++v)
    for (int u = 1; u + 1 < w; ++u) {
      const std::size_t i = static_cast<std::size_t>(v * w + u);
      if (ids[i] == 3) {
        inside++;
        inside_clipped += a[i] == 255 && b[i] == 255;
        continue;
      }
      if (ids[i] != 2) continue;
      const int neighbours_in_strip = (ids[i - 1] == 3) + (ids[i + 1] == 3) +
                                      (ids[i - static_cast<std::size_t>(w)] == 3) +
                                      (ids[i + static_cast<std::size_t>(w)] == 3);
      if (neighbours_in_strip == 0) {
        EXPECT_EQ(a[i], b[i]) << "blooming reaches one pixel only";
        continue;
      }
      edges++;
      // Each strip neighbour holds ~4 x 0.9 x ~200 DN of charge, ~470 DN above the full well.
      EXPECT_GT(b[i], a[i] + 20 * neighbours_in_strip) << "pixel " << u << "," << v;
    }
  EXPECT_GT(inside, 100u);
  EXPECT_EQ(inside_clipped, inside) << "the strip clips at full scale";
  EXPECT_GT(edges, 40u);
  // Where nothing reaches full scale, blooming changes nothing.
  EXPECT_EQ(render(without, kWhite, {.exposure_us = ref / 2}), render(with, kWhite, {.exposure_us = ref / 2}));
}

TEST(Exposure, MainsFlickerAveragesOutOverWholePeriods) {
  Scene scene = plate_scene();
  scene.ambient.level = 0.3;
  scene.ambient.flicker_depth = 0.8;
  scene.ambient.mains_hz = 50;  // 100 Hz flicker: 10 ms
  scene.sensor.bit_depth = 12;
  const ViewRenderer flickering(scene, 0, 0);
  scene.ambient.flicker_depth = 0;
  const ViewRenderer steady(scene, 0, 0);
  const std::size_t i = lit_pixel(steady);
  auto level = [&](const ViewRenderer& r, const Exposure& e) {
    std::vector<std::uint8_t> frame(r.frame_bytes());
    r.render_ambient(frame, e);
    return frame[2 * i] | (frame[2 * i + 1] << 8);
  };
  // 20 ms = two flicker periods, from any start: exactly the steady ambient.
  for (const double start : {0.0, 0.0013, 0.0071, 12345.678})
    EXPECT_EQ(level(flickering, {.exposure_us = 20000, .start_s = start}), level(steady, {.exposure_us = 20000}));
  // 2.5 ms (a quarter period): the ambient follows the lamps' phase, by up to ~+-70 %.
  const int steady_short = level(steady, {.exposure_us = 2500});
  const int crest = level(flickering, {.exposure_us = 2500, .start_s = -0.00125});
  const int trough = level(flickering, {.exposure_us = 2500, .start_s = 0.00375});
  EXPECT_GT(crest, steady_short * 1.5);
  EXPECT_LT(trough, steady_short * 0.5);
}

// Share of the object's lit pixels (left projector) that clip in the white frame, and of those
// whose white - black contrast is below 12 DN (the decoder's default minimum).
struct WhiteFrameStats {
  double clipped = 0, dark = 0;
};
std::vector<ViewRenderer> views_of(const Scene& scene, int views) {
  std::vector<ViewRenderer> out;
  for (int view = 0; view < views; ++view)
    out.emplace_back(scene, scene.view_angles_deg[static_cast<std::size_t>(view)], view);
  return out;
}

WhiteFrameStats white_frame_stats(const std::vector<ViewRenderer>& views, double exposure_factor) {
  std::size_t lit = 0, clipped = 0, dark = 0;
  for (const ViewRenderer& r : views) {
    const Exposure e{.exposure_us = 8333 * exposure_factor};
    const auto white = render(r, kWhite, e), black = render(r, kBlack, e);
    const auto& t = r.ground_truth();
    for (std::size_t i = 0; i < white.size(); ++i) {
      if (t.object_id[i] != 2 || !t.lit[0][i]) continue;
      lit++;
      clipped += white[i] == 255;
      dark += white[i] - black[i] < 12;
    }
  }
  EXPECT_GT(lit, 2000u);
  return {static_cast<double>(clipped) / static_cast<double>(lit),
          static_cast<double>(dark) / static_cast<double>(lit)};
}

TEST(Materials, TheShinyBladeClipsAtTheReferenceAndNotAtAShortExposure) {
  // Over the scan's six views (left projector), as the accuracy bench counts it.
  Scene scene = scene_preset("shiny_blade", RigSize::small).value();
  const auto views = views_of(scene, 6);
  EXPECT_GT(white_frame_stats(views, 1.0).clipped, 0.30) << "the lobe clips a large part of the lit blade";
  EXPECT_LT(white_frame_stats(views, 1.0 / 16).clipped, 0.005);
  // The same blade in matte paint clips nowhere.
  for (SceneObject& o : scene.objects) apply_material(o, Material::matte);
  EXPECT_EQ(white_frame_stats(views_of(scene, 1), 1.0).clipped, 0.0);
}

TEST(Materials, DarkPlasticDrownsAtTheReferenceAndReadsWhenExposedLonger) {
  const auto views = views_of(scene_preset("dark_blade", RigSize::small).value(), 1);
  EXPECT_GT(white_frame_stats(views, 1.0).dark, 0.5) << "albedo 0.05: most of it below the contrast floor";
  const WhiteFrameStats longer = white_frame_stats(views, 16.0);
  EXPECT_LT(longer.dark, 0.05);
  EXPECT_LT(longer.clipped, 0.01);
}

TEST(Materials, NamesRoundTripAndUnknownOnesAreNamed) {
  for (Material m :
       {Material::matte, Material::glazed, Material::polished_metal, Material::brushed_metal, Material::dark_plastic})
    EXPECT_EQ(parse_material(material_name(m)).value(), m);
  auto bad = parse_material("chrome");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("'chrome'"), std::string::npos);
  // In a scene file: the finish first, explicit fields over it; errors name the field.
  auto scene = parse_scene(R"({"preset": "sphere", "size": "small",
      "objects": [{"kind": "sphere", "radius": 20, "material": "polished_metal", "albedo": 0.3}],
      "ambient": {"level": 0.1, "flicker_depth": 0.5, "mains_hz": 60}, "interreflection": true})");
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  EXPECT_EQ(scene->objects[0].specular, 30);
  EXPECT_EQ(scene->objects[0].albedo, 0.3);
  EXPECT_EQ(scene->ambient.mains_hz, 60);
  EXPECT_TRUE(scene->interreflection);
  auto again = parse_scene(format_scene(*scene));
  ASSERT_TRUE(again.ok()) << again.error().message;
  EXPECT_EQ(format_scene(*again), format_scene(*scene));
  auto unknown = parse_scene(R"({"preset": "sphere", "objects": [{"kind": "sphere", "material": "chrome"}]})");
  ASSERT_FALSE(unknown.ok());
  EXPECT_NE(unknown.error().message.find("objects[0].material"), std::string::npos) << unknown.error().message;
  auto flicker = parse_scene(R"({"preset": "sphere", "ambient": {"flicker_depth": 2}})");
  ASSERT_FALSE(flicker.ok());
  EXPECT_NE(flicker.error().message.find("ambient.flicker_depth"), std::string::npos) << flicker.error().message;
  auto old_form = parse_scene(R"({"preset": "sphere", "ambient": 0.02})");
  ASSERT_TRUE(old_form.ok());
  EXPECT_EQ(old_form->ambient.level, 0.02);
}

TEST(Interreflection, OneBounceLightsTheInsideOfTheCupWithThePatternOfWhatLightsIt) {
  Scene scene = scene_preset("teacup", RigSize::small).value();
  scene.sensor.noise = false;
  scene.objects[0].specular = 0;
  const ViewRenderer direct(scene, 0, 0);
  scene.interreflection = true;
  scene.interreflection_samples = 16;
  const ViewRenderer bounced(scene, 0, 0);
  const auto& t = bounced.ground_truth();
  const auto white_direct = render(direct, kWhite), white_bounced = render(bounced, kWhite);
  double gain_inside = 0;
  std::size_t inside = 0;
  for (std::size_t i = 0; i < white_direct.size(); ++i) {
    EXPECT_GE(white_bounced[i], white_direct[i]) << "light only adds";
    // The cup's inner wall and floor: points within the cup's inner radius of its axis.
    if (t.object_id[i] != 2 || white_direct[i] >= 250) continue;
    const auto p = slproto::Vec3{t.points[3 * i], t.points[3 * i + 1], t.points[3 * i + 2]};
    const auto q = t.cam_from_table.inverse().apply(p);
    const double r = std::hypot(q[0] - 10, q[1] - 10);
    if (r > 37.5 || q[2] > 69) continue;  // inner radius 37 mm, rim at 70
    inside++;
    gain_inside += white_bounced[i] - white_direct[i];
  }
  ASSERT_GT(inside, 200u);
  // A white cup (albedo 0.85) lit from inside: the bounce adds a good share of the direct
  // light but, one bounce of 0.85, never more than it.
  EXPECT_GT(gain_inside / inside, 5.0);
  EXPECT_LT(gain_inside / inside, 120.0);
  // No projector light, no bounce.
  EXPECT_EQ(render(direct, kBlack), render(bounced, kBlack));
}

}  // namespace
}  // namespace slrig
