// The renderer against closed-form cases: analytic depth of a plane, analytic projector
// coordinates (and what a decoder reads from the rendered frames), a sphere's silhouette, a
// point in a projector's shadow, the turntable and ball-bar geometry.
#include <gtest/gtest.h>

#include <cmath>

#include "rig_test_util.hpp"

namespace slrig {
namespace {

using test::camera_frame_plane;
using test::small_rig_without_objects;

constexpr std::int16_t kFirstObject = 2;

TEST(ClosedForm, PlaneGivesAnalyticDepthAtEveryPixel) {
  Scene scene = small_rig_without_objects();
  const double s = std::sqrt(1.0 / 3.0);
  const Vec3 n{0.2, -s, -std::sqrt(1 - 0.04 - s * s)};  // tilted, facing the camera
  const Vec3 p0{10, -5, 420};
  scene.objects.push_back(camera_frame_plane(n, p0));
  const ViewRenderer renderer(scene, 0, 0);
  const ViewGroundTruth& truth = renderer.ground_truth();
  ASSERT_EQ(truth.width, 640);
  ASSERT_EQ(truth.height, 512);
  double worst = 0;
  for (int v = 0; v < truth.height; ++v)
    for (int u = 0; u < truth.width; ++u) {
      const std::size_t i = static_cast<std::size_t>(v) * 640 + static_cast<std::size_t>(u);
      ASSERT_EQ(truth.object_id[i], kFirstObject) << "pixel " << u << "," << v << " misses the plane";
      double x, y;
      ASSERT_TRUE(scene.camera.pixel_to_ray(u, v, x, y));
      // Ray t (x, y, 1) meets n . (X - p0) = 0.
      const double t = (n[0] * p0[0] + n[1] * p0[1] + n[2] * p0[2]) / (n[0] * x + n[1] * y + n[2]);
      worst = std::max(worst, std::abs(truth.points[3 * i + 2] - t));
      worst = std::max(worst, std::abs(truth.points[3 * i] - t * x));
      worst = std::max(worst, std::abs(truth.points[3 * i + 1] - t * y));
      const double facing =
          truth.normals[3 * i] * n[0] + truth.normals[3 * i + 1] * n[1] + truth.normals[3 * i + 2] * n[2];
      ASSERT_NEAR(std::abs(facing), 1.0, 1e-5);
      ASSERT_LT(truth.normals[3 * i + 2], 0) << "normal does not face the camera";
    }
  EXPECT_LT(worst, 1e-3) << "mm";
}

TEST(ClosedForm, ProjectorCoordinateMatchesProjectionAndDecoding) {
  Scene scene = small_rig_without_objects();
  scene.sensor.bit_depth = 12;  // keeps quantisation far below the 0.01 px budget
  scene.objects.push_back(camera_frame_plane({0, -0.3, -std::sqrt(1 - 0.09)}, {0, 0, 540}));
  const ViewRenderer renderer(scene, 0, 0);
  const ViewGroundTruth& truth = renderer.ground_truth();
  const slproto::PatternPlan plan(scene.pattern_plan);
  for (int side = 0; side < 2; ++side) {
    const ProjectorModel& projector = scene.projectors[static_cast<std::size_t>(side)];
    const auto proj_from_cam = projector.cam_from_proj.inverse();
    const auto& coord = truth.projector_coord[static_cast<std::size_t>(side)];
    std::size_t lit = 0;
    double worst_geometry = 0;
    for (std::size_t i = 0; i < coord.size(); ++i) {
      if (!truth.lit[static_cast<std::size_t>(side)][i]) {
        EXPECT_TRUE(std::isnan(coord[i]));
        continue;
      }
      ++lit;
      const Vec3 p{truth.points[3 * i], truth.points[3 * i + 1], truth.points[3 * i + 2]};
      double up, vp;
      ASSERT_TRUE(projector.intrinsics.project(proj_from_cam.apply(p), up, vp));
      worst_geometry = std::max(worst_geometry, std::abs(up - coord[i]));
    }
    EXPECT_GT(lit, coord.size() / 2) << "the plane should be mostly lit by projector " << side;
    EXPECT_LT(worst_geometry, 2e-3) << "projector px (float storage of the point limits this)";

    // Decoding the rendered frames (gamma 2.2, defocus 0.7 px, 12-bit, no noise) returns the
    // truth: the blur is symmetric and the 8-step phase shift ignores the gamma harmonics.
    const auto frames = test::render_all(renderer, static_cast<ProjectorSide>(side), plan, 12);
    const auto decoded = test::reference_decode(frames, plan, 400);
    std::size_t compared = 0;
    double worst = 0, sum = 0;
    for (std::size_t i = 0; i < coord.size(); ++i) {
      if (!truth.lit[static_cast<std::size_t>(side)][i] || std::isnan(decoded[i])) continue;
      // Stay clear of the DMD's edges, where the blur has nothing to blend with.
      if (coord[i] < 3 || coord[i] > 1136) continue;
      ++compared;
      const double error = std::abs(decoded[i] - coord[i]);
      worst = std::max(worst, error);
      sum += error;
    }
    EXPECT_GT(compared, lit / 2);
    EXPECT_LT(worst, 0.01) << "projector px, side " << side;
    EXPECT_LT(sum / static_cast<double>(compared), 0.003) << "projector px, side " << side;
  }
}

TEST(ClosedForm, SphereSilhouetteRadius) {
  Scene scene = small_rig_without_objects();
  scene.camera.distortion = {};
  scene.background_wall = false;
  SceneObject sphere;
  sphere.kind = ObjectKind::sphere;
  sphere.radius = 30;
  sphere.on_turntable = false;
  const double d = 450;
  // On the optical axis through the principal point.
  sphere.table_from_object.t = {0, 0, d};
  scene.objects.push_back(sphere);
  const ViewRenderer renderer(scene, 0, 0);
  const ViewGroundTruth& truth = renderer.ground_truth();
  const double rho = scene.camera.fx * sphere.radius / std::sqrt(d * d - sphere.radius * sphere.radius);
  std::size_t inside = 0, checked = 0;
  for (int v = 0; v < truth.height; ++v)
    for (int u = 0; u < truth.width; ++u) {
      const double r = std::hypot(u - scene.camera.cx, v - scene.camera.cy);
      const bool hit = truth.object_id[static_cast<std::size_t>(v) * 640 + static_cast<std::size_t>(u)] == kFirstObject;
      inside += hit;
      if (std::abs(r - rho) < 0.05) continue;  // undecidable at the edge itself
      ++checked;
      ASSERT_EQ(hit, r < rho) << "pixel " << u << "," << v << " at radius " << r << " vs silhouette " << rho;
    }
  EXPECT_GT(checked, 300000u);
  // The pixel count estimates the silhouette area.
  EXPECT_NEAR(std::sqrt(static_cast<double>(inside) / std::numbers::pi), rho, 0.05 * 2);
}

TEST(ClosedForm, PointInProjectorShadowGetsOnlyAmbient) {
  Scene scene = small_rig_without_objects();
  const Vec3 n{0, 0, -1};
  scene.objects.push_back(camera_frame_plane(n, {0, 0, 500}));
  // A sphere on the segment from the left projector's centre to a plane point q.
  const Vec3 q{-20, 10, 500};
  const Vec3 c = scene.projectors[0].cam_from_proj.t;
  const double f = 0.35;
  SceneObject blocker;
  blocker.kind = ObjectKind::sphere;
  blocker.radius = 8;
  blocker.on_turntable = false;
  blocker.table_from_object.t = {q[0] + f * (c[0] - q[0]), q[1] + f * (c[1] - q[1]), q[2] + f * (c[2] - q[2])};
  scene.objects.push_back(blocker);
  const ViewRenderer renderer(scene, 0, 0);
  const ViewGroundTruth& truth = renderer.ground_truth();
  double u, v;
  ASSERT_TRUE(scene.camera.project(q, u, v));
  const std::size_t i = static_cast<std::size_t>(std::lround(v)) * 640 + static_cast<std::size_t>(std::lround(u));
  ASSERT_EQ(truth.object_id[i], kFirstObject) << "the camera must see the plane at q";
  EXPECT_EQ(truth.lit[0][i], 0) << "q is in the left projector's shadow";
  EXPECT_EQ(truth.lit[1][i], 1) << "the right projector lights q";
  EXPECT_TRUE(std::isnan(truth.projector_coord[0][i]));

  std::vector<std::uint8_t> frame(renderer.frame_bytes());
  const double ambient_dn = scene.sensor.white_level_dn * 0.8 * scene.ambient.level + scene.sensor.dark_level_dn;
  renderer.render(ProjectorSide::left, 0, frame);  // all-white pattern
  EXPECT_NEAR(frame[i], ambient_dn, 0.5 + 1e-9);
  renderer.render_ambient(frame);
  EXPECT_NEAR(frame[i], ambient_dn, 0.5 + 1e-9);
  renderer.render(ProjectorSide::right, 0, frame);
  EXPECT_GT(frame[i], ambient_dn + 50) << "lit by the right projector";
}

TEST(ClosedForm, FacingWhiteMatteReachesTheWhiteLevel) {
  Scene scene = small_rig_without_objects();
  scene.ambient.level = 0;
  scene.turntable.platform_radius_mm = 1e-3;  // out of the way of the plate
  // A white matte plane through the table centre facing the left projector.
  const auto& proj = scene.projectors[0].cam_from_proj;
  const Vec3 centre = scene.turntable.cam_from_table.t;
  Vec3 toward{proj.t[0] - centre[0], proj.t[1] - centre[1], proj.t[2] - centre[2]};
  const double len = std::sqrt(toward[0] * toward[0] + toward[1] * toward[1] + toward[2] * toward[2]);
  for (double& x : toward) x /= len;
  SceneObject plate = camera_frame_plane(toward, centre, 400);
  plate.albedo = 1.0;
  scene.objects.push_back(plate);
  const ViewRenderer renderer(scene, 0, 0);
  double u, v;
  ASSERT_TRUE(scene.camera.project(centre, u, v));
  const std::size_t i = static_cast<std::size_t>(std::lround(v)) * 640 + static_cast<std::size_t>(std::lround(u));
  std::vector<std::uint8_t> frame(renderer.frame_bytes());
  renderer.render(ProjectorSide::left, 0, frame);
  EXPECT_NEAR(frame[i], scene.sensor.white_level_dn, 1.0);
}

TEST(ClosedForm, TurntableAndBallbarGeometry) {
  Scene scene = scene_preset("ballbar", RigSize::small).value();
  scene.sensor.noise = false;
  const double angle = 60;
  const ViewRenderer renderer(scene, angle, 1);
  const ViewGroundTruth& truth = renderer.ground_truth();
  EXPECT_EQ(truth.actual_angle_deg, angle);
  const auto expected_pose = scene.turntable.cam_from_table * slproto::RigidTransform::rotation_about_axis(
                                                                  {0, 0, 1}, {0, 0, 0}, angle * std::numbers::pi / 180);
  for (std::size_t k = 0; k < 9; ++k) EXPECT_NEAR(truth.cam_from_table.R[k], expected_pose.R[k], 1e-12);
  const auto table_from_cam = truth.cam_from_table.inverse();
  const SceneObject& bar = scene.objects[0];
  const auto cam_from_bar = truth.cam_from_table * bar.table_from_object;
  const Vec3 centre_a = cam_from_bar.apply({-bar.centre_distance / 2, 0, 0});
  const Vec3 centre_b = cam_from_bar.apply({bar.centre_distance / 2, 0, 0});
  std::size_t on_table = 0, on_a = 0, on_b = 0;
  for (std::size_t i = 0; i < truth.object_id.size(); ++i) {
    const Vec3 p{truth.points[3 * i], truth.points[3 * i + 1], truth.points[3 * i + 2]};
    if (truth.object_id[i] == 0 && truth.part_id[i] == 0) {
      const Vec3 t = table_from_cam.apply(p);
      ASSERT_NEAR(t[2], 0, 1e-3);
      ASSERT_LE(std::hypot(t[0], t[1]), scene.turntable.platform_radius_mm + 1e-3);
      ++on_table;
    }
    if (truth.object_id[i] == kFirstObject && truth.part_id[i] <= 1) {
      const Vec3& c = truth.part_id[i] == 0 ? centre_a : centre_b;
      const double r =
          std::sqrt((p[0] - c[0]) * (p[0] - c[0]) + (p[1] - c[1]) * (p[1] - c[1]) + (p[2] - c[2]) * (p[2] - c[2]));
      ASSERT_NEAR(r, truth.part_id[i] == 0 ? bar.radius_a : bar.radius_b, 1e-3);
      (truth.part_id[i] == 0 ? on_a : on_b) += 1;
    }
  }
  EXPECT_GT(on_table, 20000u);
  EXPECT_GT(on_a, 300u) << "sphere a should be in view";
  EXPECT_GT(on_b, 300u) << "sphere b should be in view";
}

}  // namespace
}  // namespace slrig
