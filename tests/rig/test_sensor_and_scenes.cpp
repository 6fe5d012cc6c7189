// Sensor noise, reproducibility, presets, scene files, meshes, calibration output and surface
// samples of the virtual rig.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "rig_test_util.hpp"
#include "slproto/calibration_file.hpp"

namespace slrig {
namespace {

using test::camera_frame_plane;
using test::small_rig_without_objects;

Scene noisy_plane_scene() {
  Scene scene = small_rig_without_objects();
  scene.sensor.noise = true;
  scene.objects.push_back(camera_frame_plane({0, -0.3, -std::sqrt(1 - 0.09)}, {0, 0, 540}));
  return scene;
}

TEST(Sensor, SameSeedSameFramesOtherSeedOtherFrames) {
  Scene scene = noisy_plane_scene();
  const ViewRenderer a(scene, 0, 0), b(scene, 0, 0);
  std::vector<std::uint8_t> fa(a.frame_bytes()), fb(b.frame_bytes()), fc(a.frame_bytes());
  a.render(ProjectorSide::left, 15, fa);
  b.render(ProjectorSide::left, 15, fb);
  EXPECT_EQ(fa, fb);
  scene.sensor.seed = 2;
  const ViewRenderer c(scene, 0, 0);
  c.render(ProjectorSide::left, 15, fc);
  EXPECT_NE(fa, fc);
  // Another view index or pattern draws other noise too.
  const ViewRenderer d(noisy_plane_scene(), 0, 1);
  d.render(ProjectorSide::left, 15, fc);
  EXPECT_NE(fa, fc);
  a.render(ProjectorSide::left, 0, fa);
  a.render(ProjectorSide::left, 0, fb);
  EXPECT_EQ(fa, fb) << "rendering is a pure function of its inputs";
}

TEST(Sensor, NoiseMatchesShotPlusReadModel) {
  for (int depth : {8, 12}) {
    Scene scene = noisy_plane_scene();
    scene.sensor.bit_depth = depth;
    const ViewRenderer noisy(scene, 0, 0);
    scene.sensor.noise = false;
    const ViewRenderer exact(scene, 0, 0);
    const std::size_t n = 640 * 512;
    std::vector<std::uint8_t> fn(noisy.frame_bytes()), fe(exact.frame_bytes());
    noisy.render(ProjectorSide::left, 0, fn);
    exact.render(ProjectorSide::left, 0, fe);
    auto at = [&](const std::vector<std::uint8_t>& f, std::size_t i) {
      return depth > 8 ? static_cast<double>(f[2 * i] | (f[2 * i + 1] << 8)) : static_cast<double>(f[i]);
    };
    const double scale = std::ldexp(1.0, depth - 8);
    const double electrons_per_dn = scene.sensor.full_well_electrons / (std::ldexp(1.0, depth) - 1);
    // Bins of the exact value: the spread must follow var = S / g + read^2 (+ rounding).
    for (double level : {40.0, 100.0, 160.0}) {
      double sum = 0, sum2 = 0, expected_var = 0;
      std::size_t count = 0;
      for (std::size_t i = 0; i < n; ++i) {
        const double s = at(fe, i);
        if (std::abs(s - level * scale) > 10 * scale) continue;
        const double diff = at(fn, i) - s;
        sum += diff;
        sum2 += diff * diff;
        expected_var += s / electrons_per_dn + std::pow(scene.sensor.read_noise_dn * scale, 2) + 1.0 / 12;
        ++count;
      }
      if (count < 5000) continue;  // this level is not on the plate
      const double mean = sum / static_cast<double>(count);
      const double sd = std::sqrt(sum2 / static_cast<double>(count) - mean * mean);
      const double expected_sd = std::sqrt(expected_var / static_cast<double>(count));
      EXPECT_NEAR(mean, 0, 0.05 * scale) << depth << "-bit, level " << level;
      EXPECT_NEAR(sd / expected_sd, 1.0, 0.05)
          << depth << "-bit, level " << level << ": sd " << sd << " vs " << expected_sd;
    }
  }
}

TEST(Sensor, ClipsAtFullScaleAndKeepsDarkLevel) {
  Scene scene = noisy_plane_scene();
  scene.sensor.noise = false;
  scene.sensor.white_level_dn = 2000;  // far beyond 8-bit full scale
  scene.sensor.dark_level_dn = 12;
  const ViewRenderer renderer(scene, 0, 0);
  std::vector<std::uint8_t> frame(renderer.frame_bytes());
  renderer.render(ProjectorSide::left, 0, frame);
  const auto& truth = renderer.ground_truth();
  std::size_t saturated = 0, lit = 0;
  for (std::size_t i = 0; i < frame.size(); ++i) {
    if (truth.lit[0][i] && truth.object_id[i] == 2) {  // the plate: lit at a moderate angle
      ++lit;
      saturated += frame[i] == 255;
    }
  }
  EXPECT_EQ(saturated, lit);
  renderer.render(ProjectorSide::left, 1, frame);  // all black: ambient + dark
  for (std::size_t i = 0; i < frame.size(); ++i) {
    if (truth.object_id[i] < 0) {
      ASSERT_EQ(frame[i], 12) << "nothing seen: the dark level only";
    }
  }
}

TEST(Presets, AllPresetsRenderWithTheirObjectsInViewAndLit) {
  for (const char* name :
       {"ballbar", "plane", "sphere", "blade", "teacup", "calibration", "shiny_blade", "dark_blade"}) {
    for (RigSize size : {RigSize::small, RigSize::full}) {
      auto scene = scene_preset(name, size);
      ASSERT_TRUE(scene.ok()) << name;
      ASSERT_TRUE(check_scene(*scene).ok()) << name << ": " << check_scene(*scene).error().message;
      EXPECT_EQ(scene->camera.width, size == RigSize::small ? 640 : 2464);
    }
    Scene scene = scene_preset(name, RigSize::small).value();
    const double angle = scene.view_angles_deg.at(0);
    const ViewRenderer renderer(scene, angle, 0);
    const auto& truth = renderer.ground_truth();
    std::size_t object = 0, lit_any = 0, lit_both = 0;
    for (std::size_t i = 0; i < truth.object_id.size(); ++i) {
      if (truth.object_id[i] < 2) continue;
      ++object;
      lit_any += truth.lit[0][i] || truth.lit[1][i];
      lit_both += truth.lit[0][i] && truth.lit[1][i];
    }
    EXPECT_GT(object, 2000u) << name << ": the object should fill part of the view";
    EXPECT_GT(static_cast<double>(lit_any), 0.9 * static_cast<double>(object)) << name;
    EXPECT_GT(static_cast<double>(lit_both), 0.5 * static_cast<double>(object)) << name;
  }
  EXPECT_FALSE(scene_preset("no-such-scene").ok());
  EXPECT_NE(scene_preset("no-such-scene").error().message.find("no-such-scene"), std::string::npos);
}

TEST(Presets, SmallRigHasTheSameHorizontalFieldOfView) {
  const Scene full = scene_preset("ballbar", RigSize::full).value();
  const Scene small = scene_preset("ballbar", RigSize::small).value();
  EXPECT_NEAR(full.camera.width / full.camera.fx, small.camera.width / small.camera.fx, 1e-12);
  EXPECT_EQ(full.turntable.cam_from_table, small.turntable.cam_from_table);
}

TEST(Calibration, GroundTruthRoundTripsThroughTheHostFormat) {
  const Scene scene = scene_preset("ballbar", RigSize::full).value();
  const slproto::RigCalibration cal = ground_truth_calibration(scene);
  ASSERT_TRUE(cal.check().ok()) << cal.check().error().message;
  EXPECT_EQ(cal.camera, scene.camera);
  EXPECT_EQ(cal.projectors[1].cam_from_proj, scene.projectors[1].cam_from_proj);
  EXPECT_EQ(cal.turntable.cam_from_table, scene.turntable.cam_from_table);
  auto parsed = slproto::parse_calibration(slproto::format_calibration(cal));
  ASSERT_TRUE(parsed.ok()) << parsed.error().message;
  EXPECT_EQ(*parsed, cal);
  // The default geometry as documented: camera 27 deg above the table plane, left projector on
  // the left (negative camera x), both projectors converging in front of the camera.
  const auto& R = scene.turntable.cam_from_table.R;
  const double axis_dot_optical = R[8];  // table z in camera coordinates, z component
  EXPECT_NEAR(std::asin(-axis_dot_optical) * 180 / std::numbers::pi, 27.0, 1e-9);
  EXPECT_LT(scene.projectors[0].cam_from_proj.t[0], -100);
  EXPECT_GT(scene.projectors[1].cam_from_proj.t[0], 100);
}

TEST(SceneFile, FormatThenParseIsIdentity) {
  for (const char* name : {"ballbar", "calibration", "teacup"}) {
    const Scene scene = scene_preset(name, RigSize::small).value();
    const std::string text = format_scene(scene);
    auto parsed = parse_scene(text, "test");
    ASSERT_TRUE(parsed.ok()) << parsed.error().message;
    EXPECT_EQ(format_scene(*parsed), text);
  }
}

// The camera in a scene file is spelled as in a calibration file (slproto's writer), and the
// older array form of the distortion still reads as the same model.
TEST(SceneFile, CamerasUseTheCalibrationFilesSpellingAndTheOlderArrayReads) {
  const Scene scene = scene_preset("ballbar", RigSize::small).value();
  const nlohmann::json written = nlohmann::json::parse(format_scene(scene));
  EXPECT_EQ(written["camera"], slproto::pinhole_to_json(scene.camera));
  EXPECT_EQ(written["turntable"]["cam_from_table"], slproto::pose_to_json(scene.turntable.cam_from_table));
  auto as_object = parse_scene(R"({"preset": "ballbar", "size": "small",
                                   "camera": {"distortion": {"k1": -0.1, "k2": 0.02, "p1": 0.001, "p2": -0.002, "k3": 0}}})");
  auto as_array = parse_scene(R"({"preset": "ballbar", "size": "small",
                                  "camera": {"distortion": [-0.1, 0.02, 0.001, -0.002, 0]}})");
  ASSERT_TRUE(as_object.ok()) << as_object.error().message;
  ASSERT_TRUE(as_array.ok()) << as_array.error().message;
  EXPECT_EQ(as_object->camera.distortion.k1, -0.1);
  EXPECT_EQ(as_object->camera.distortion.p2, -0.002);
  EXPECT_EQ(as_object->camera, as_array->camera);
  auto typo = parse_scene(R"({"camera": {"distortion": {"k4": 0.1}}})", "scene.json");
  ASSERT_FALSE(typo.ok());
  EXPECT_NE(typo.error().message.find("camera.distortion.k4: unknown field"), std::string::npos)
      << typo.error().message;
}

TEST(SceneFile, PresetWithOverridesAndErrorsNamingTheField) {
  auto scene = parse_scene(R"({"preset": "sphere", "size": "small", "sensor": {"noise": false, "seed": 7},
                               "objects": [{"kind": "sphere", "radius": 12, "pose": {"rotation_deg": [0, 0, 90], "t": [10, 0, 12]}}]})");
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  EXPECT_EQ(scene->camera.width, 640);
  EXPECT_FALSE(scene->sensor.noise);
  EXPECT_EQ(scene->sensor.seed, 7u);
  ASSERT_EQ(scene->objects.size(), 1u);
  EXPECT_EQ(scene->objects[0].radius, 12);
  EXPECT_NEAR(scene->objects[0].table_from_object.R[1], -1, 1e-12);  // Rz(90): x -> y

  auto expect_error = [](const char* text, const char* field) {
    auto bad = parse_scene(text, "bad.json");
    ASSERT_FALSE(bad.ok()) << text;
    EXPECT_NE(bad.error().message.find(field), std::string::npos) << bad.error().message;
    EXPECT_NE(bad.error().message.find("bad.json"), std::string::npos) << bad.error().message;
  };
  expect_error(R"({"objects": [{"kind": "sphere", "radius": -1}]})", "objects[0].radius");
  expect_error(R"({"objects": [{"kind": "sphere", "radus": 3}]})", "objects[0].radus");
  expect_error(R"({"objects": [{"kind": "cube"}]})", "objects[0].kind");
  expect_error(R"({"sensor": {"bit_depth": 9}})", "sensor.bit_depth");
  expect_error(R"({"sensor": {"read_noise_dn": "high"}})", "sensor.read_noise_dn");
  expect_error(R"({"projectors": [{}]})", "projectors");
  expect_error(R"({"turntable": {"cam_from_table": {"R": [1, 0, 0, 0, 1, 0, 0, 0, 2]}}})", "turntable.cam_from_table");
  expect_error(R"({"preset": "nothing"})", "preset");
  expect_error(R"({"view_angles_deg": [0, "x"]})", "view_angles_deg");
  expect_error(R"({"objects": [)", "bad.json");
  expect_error(R"({"format_version": 2})", "format_version");
  // 2^64 - 1 and 2^63 were read as -1 and INT64_MIN (wrapped), then passed the range check.
  expect_error(R"({"sensor": {"bit_depth": 18446744073709551615}})",
               "sensor.bit_depth: 18446744073709551615 is out of range");
  expect_error(R"({"camera": {"width": 9223372036854775808}})", "camera.width: 9223372036854775808 is out of range");
  expect_error(R"({"interreflection_samples": -9223372036854775808})", "interreflection_samples");
  auto missing = load_scene("/nonexistent/scene.json");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find("/nonexistent/scene.json"), std::string::npos);
}

TEST(SceneFile, ShippedScenesLoad) {
  const std::filesystem::path dir = std::filesystem::path(SLSCAN_SOURCE_DIR) / "firmware/rig/scenes";
  std::size_t count = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    if (entry.path().extension() != ".json") continue;
    auto scene = load_scene(entry.path().string());
    ASSERT_TRUE(scene.ok()) << scene.error().message;
    ++count;
  }
  EXPECT_GE(count, 2u);
}

class MeshFile : public ::testing::Test {
 protected:
  std::filesystem::path dir_;
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() / ("slrig_mesh_" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  std::string write(const std::string& name, const std::string& bytes) {
    const auto path = (dir_ / name).string();
    std::ofstream(path, std::ios::binary) << bytes;
    return path;
  }
};

// A 40 mm cube centred on the origin, as OBJ text.
std::string cube_obj() {
  return "v -20 -20 -20\nv 20 -20 -20\nv 20 20 -20\nv -20 20 -20\n"
         "v -20 -20 20\nv 20 -20 20\nv 20 20 20\nv -20 20 20\n"
         "f 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7\nf 4 1 5\nf 4 5 8\n";
}

std::string cube_binary_stl() {
  const float v[8][3] = {{-20, -20, -20}, {20, -20, -20}, {20, 20, -20}, {-20, 20, -20},
                         {-20, -20, 20},  {20, -20, 20},  {20, 20, 20},  {-20, 20, 20}};
  const int f[12][3] = {{0, 2, 1}, {0, 3, 2}, {4, 5, 6}, {4, 6, 7}, {0, 1, 5}, {0, 5, 4},
                        {1, 2, 6}, {1, 6, 5}, {2, 3, 7}, {2, 7, 6}, {3, 0, 4}, {3, 4, 7}};
  std::string out(80, ' ');
  const std::uint32_t count = 12;
  out.append(reinterpret_cast<const char*>(&count), 4);
  for (const auto& tri : f) {
    const float normal[3] = {0, 0, 0};
    out.append(reinterpret_cast<const char*>(normal), 12);
    for (int k : tri) out.append(reinterpret_cast<const char*>(v[k]), 12);
    out.append(2, '\0');
  }
  return out;
}

std::string cube_ascii_ply() {
  return "ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\nproperty float z\n"
         "element face 6\nproperty list uchar int vertex_indices\nend_header\n"
         "-20 -20 -20\n20 -20 -20\n20 20 -20\n-20 20 -20\n-20 -20 20\n20 -20 20\n20 20 20\n-20 20 20\n"
         "4 0 3 2 1\n4 4 5 6 7\n4 0 1 5 4\n4 1 2 6 5\n4 2 3 7 6\n4 3 0 4 7\n";
}

TEST_F(MeshFile, CubeFromEachFormatGivesTheAnalyticDepth) {
  for (const auto& [name, bytes] : {std::pair<std::string, std::string>{"cube.obj", cube_obj()},
                                    {"cube.stl", cube_binary_stl()},
                                    {"cube.ply", cube_ascii_ply()}}) {
    Scene scene = small_rig_without_objects();
    SceneObject cube;
    cube.kind = ObjectKind::mesh;
    cube.mesh_path = write(name, bytes);
    cube.on_turntable = false;
    cube.table_from_object.t = {0, 0, 400};  // front face at z = 380, facing the camera
    scene.objects.push_back(cube);
    auto renderer = ViewRenderer::make(scene, 0, 0);
    ASSERT_TRUE(renderer.ok()) << renderer.error().message;
    const auto& truth = renderer->ground_truth();
    double u, v;
    ASSERT_TRUE(scene.camera.project({0, 0, 380}, u, v));
    const std::size_t i = static_cast<std::size_t>(std::lround(v)) * 640 + static_cast<std::size_t>(std::lround(u));
    ASSERT_EQ(truth.object_id[i], 2) << name;
    EXPECT_NEAR(truth.points[3 * i + 2], 380.0, 1e-4) << name;
    EXPECT_NEAR(truth.normals[3 * i + 2], -1.0, 1e-6) << name;
    const SurfaceSample sample = sample_object_surfaces(scene, 1.0);
    EXPECT_NEAR(static_cast<double>(sample.object_id.size()), 6 * 40 * 40, 6 * 40 * 40 * 0.05) << name;
  }
}

TEST_F(MeshFile, BadFilesAreClearErrors) {
  Scene scene = small_rig_without_objects();
  SceneObject mesh;
  mesh.kind = ObjectKind::mesh;
  mesh.on_turntable = false;
  for (const auto& [name, bytes, expected] :
       {std::tuple<std::string, std::string, std::string>{"bad.obj", "v 0 0 0\nf 1 2 3\n", "out of range"},
        {"short.stl", "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n", "multiple of 3"},
        {"big.ply", "ply\nformat binary_big_endian 1.0\nelement vertex 0\nend_header\n", "binary_big_endian"},
        {"cut.ply", cube_ascii_ply().substr(0, 200), "truncated"},
        {"cube.xyz", "1 2 3\n", "extension"}}) {
    mesh.mesh_path = write(name, bytes);
    scene.objects = {mesh};
    auto renderer = ViewRenderer::make(scene, 0, 0);
    ASSERT_FALSE(renderer.ok()) << name;
    EXPECT_NE(renderer.error().message.find(expected), std::string::npos) << renderer.error().message;
    EXPECT_NE(renderer.error().message.find("objects[0]"), std::string::npos) << renderer.error().message;
  }
  mesh.mesh_path = (dir_ / "missing.stl").string();
  scene.objects = {mesh};
  EXPECT_FALSE(ViewRenderer::make(scene, 0, 0).ok());
}

// The blade's samples face out of the solid: by the divergence theorem the sum of p . n dA over
// a closed surface is 3 V, positive only with outward normals. The blade is wound by hand
// (scene_build.cpp) and was inside out until 2026-12-05: bench_mesh then counted every face of a
// good mesh as flipped. V for a NACA xx12 section (area ~0.0822 c^2) tapering from 60 to 45 mm
// over 120 mm: ~27,400 mm^3.
TEST(Surfaces, TheBladesSamplesFaceOutOfTheSolid) {
  const Scene scene = scene_preset("blade", RigSize::small).value();
  const double spacing = 0.5;
  const SurfaceSample s = sample_object_surfaces(scene, spacing);
  ASSERT_FALSE(s.object_id.empty());
  double flux = 0;
  for (std::size_t i = 0; i < s.object_id.size(); ++i)
    for (std::size_t k = 0; k < 3; ++k)
      flux += static_cast<double>(s.points[3 * i + k]) * static_cast<double>(s.normals[3 * i + k]);
  const double volume = flux * spacing * spacing / 3;
  EXPECT_NEAR(volume, 27400, 27400 * 0.15);
}

TEST(Surfaces, SamplesLieOnTheTrueSurfaces) {
  const Scene scene = scene_preset("ballbar", RigSize::small).value();
  const SurfaceSample s = sample_object_surfaces(scene, 0.5);
  const SceneObject& bar = scene.objects[0];
  const Vec3 a = bar.table_from_object.apply({-bar.centre_distance / 2, 0, 0});
  const Vec3 b = bar.table_from_object.apply({bar.centre_distance / 2, 0, 0});
  std::size_t on_a = 0, on_b = 0;
  for (std::size_t i = 0; i < s.object_id.size(); ++i) {
    const Vec3 p{s.points[3 * i], s.points[3 * i + 1], s.points[3 * i + 2]};
    auto dist = [&](const Vec3& c) {
      return std::sqrt((p[0] - c[0]) * (p[0] - c[0]) + (p[1] - c[1]) * (p[1] - c[1]) + (p[2] - c[2]) * (p[2] - c[2]));
    };
    if (s.part_id[i] == 0) {
      ASSERT_NEAR(dist(a), bar.radius_a, 1e-4);
      ++on_a;
    } else if (s.part_id[i] == 1) {
      ASSERT_NEAR(dist(b), bar.radius_b, 1e-4);
      ++on_b;
    } else {
      // The rod and the post are only sampled outside the spheres.
      ASSERT_GT(dist(a), bar.radius_a - 1e-3);
      ASSERT_GT(dist(b), bar.radius_b - 1e-3);
    }
  }
  // The sphere minus the cap the rod hides: 4 pi r^2 - 2 pi r h, h = r - sqrt(r^2 - rod^2).
  const double r = 15, cap = r - std::sqrt(r * r - bar.bar_radius * bar.bar_radius);
  const double expected = (4 * std::numbers::pi * r * r - 2 * std::numbers::pi * r * cap) / 0.25;
  EXPECT_NEAR(static_cast<double>(on_a), expected, expected * 0.01);
  EXPECT_NEAR(static_cast<double>(on_b), expected, expected * 0.01);
}

TEST(Renderer, BadArgumentsAreErrorsNotCrashes) {
  const Scene scene = test::small_rig_without_objects();
  const ViewRenderer renderer(scene, 0, 0);
  std::vector<std::uint8_t> small(10);
  const slproto::PatternPlan plan(scene.pattern_plan);
  EXPECT_FALSE(renderer.try_render(ProjectorSide::left, plan, 0, small).ok());
  std::vector<std::uint8_t> frame(renderer.frame_bytes());
  EXPECT_FALSE(renderer.try_render(ProjectorSide::left, plan, plan.size(), frame).ok());
  EXPECT_THROW(renderer.render(ProjectorSide::left, plan.size(), frame), std::invalid_argument);
  Scene bad = scene;
  bad.sensor.bit_depth = 7;
  auto made = ViewRenderer::make(bad, 0, 0);
  ASSERT_FALSE(made.ok());
  EXPECT_NE(made.error().message.find("sensor.bit_depth"), std::string::npos);
  EXPECT_THROW(ViewRenderer(bad, 0, 0), std::invalid_argument);
}

}  // namespace
}  // namespace slrig

namespace slrig {
namespace {

TEST(Turntable, AngleErrorAndWobbleAreSeededAndMoveTheTable) {
  Scene scene = scene_preset("sphere", RigSize::small).value();
  scene.turntable.angle_error_sigma_deg = 0.05;
  scene.turntable.axis_wobble_deg = 0.1;
  const ViewRenderer a(scene, 120, 2), b(scene, 120, 2), c(scene, 120, 3);
  const auto& ta = a.ground_truth();
  EXPECT_EQ(ta.commanded_angle_deg, 120);
  EXPECT_NE(ta.actual_angle_deg, 120);
  EXPECT_LT(std::abs(ta.actual_angle_deg - 120), 0.05 * 6);
  EXPECT_EQ(ta.actual_angle_deg, b.ground_truth().actual_angle_deg) << "same seed and view: same error";
  EXPECT_NE(ta.actual_angle_deg, c.ground_truth().actual_angle_deg) << "another view: another error";
  // The platform normal is tilted by the wobble against the calibrated axis.
  const auto nominal = scene.turntable.cam_from_table;
  const double cos_tilt = ta.cam_from_table.R[2] * nominal.R[2] + ta.cam_from_table.R[5] * nominal.R[5] +
                          ta.cam_from_table.R[8] * nominal.R[8];
  EXPECT_NEAR(std::acos(std::min(1.0, cos_tilt)) * 180 / std::numbers::pi, 0.1, 1e-6);
  // The table points in the truth lie on the tilted platform plane.
  const auto table_from_cam = ta.cam_from_table.inverse();
  for (std::size_t i = 0; i < ta.object_id.size(); ++i) {
    if (ta.object_id[i] != 0 || ta.part_id[i] != 0) continue;
    const Vec3 p = table_from_cam.apply({ta.points[3 * i], ta.points[3 * i + 1], ta.points[3 * i + 2]});
    ASSERT_NEAR(p[2], 0, 1e-3);
  }
}

TEST(Specular, GlazedHighlightOverexposes) {
  Scene scene = test::small_rig_without_objects();
  SceneObject ball;
  ball.kind = ObjectKind::sphere;
  ball.radius = 30;
  ball.albedo = 0.5;
  ball.table_from_object.t = {0, 0, 30};
  scene.objects.push_back(ball);
  auto count_saturated = [&](const Scene& s) {
    const ViewRenderer r(s, 0, 0);
    std::vector<std::uint8_t> frame(r.frame_bytes());
    r.render(ProjectorSide::left, 0, frame);
    std::size_t n = 0;
    for (std::size_t i = 0; i < frame.size(); ++i) n += r.ground_truth().object_id[i] == 2 && frame[i] == 255;
    return n;
  };
  EXPECT_EQ(count_saturated(scene), 0u) << "matte: 0.5 albedo stays far below full scale";
  scene.objects[0].specular = 2.0;
  scene.objects[0].specular_power = 40;
  EXPECT_GT(count_saturated(scene), 20u) << "a specular lobe toward the camera clips";
}

}  // namespace
}  // namespace slrig
