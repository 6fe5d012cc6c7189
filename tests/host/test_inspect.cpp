// slscan inspect (core/inspect.hpp, app/inspect.hpp; docs/inspection.md "Deviation from a
// nominal"): exact signed distances with the sign right at faces, edges and corners; the unit
// detection; the coarse alignment of a part placed anywhere; a 50 um bump in the nominal found
// where it is with its height; a small-rig scan of the sphere preset inspected against the
// preset's own shape, against the rig's truth; and bad input refused with nothing written.
#include <gtest/gtest.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <numbers>
#include <random>
#include <span>

#include "inspect.hpp"
#include "slrig/rig.hpp"
#include "slscan/core/inspect.hpp"
#include "slscan/core/registration.hpp"
#include "slscan/core/scan_reconstruction.hpp"
#include "slscan/io/mesh_file.hpp"
#include "slscan/io/ply.hpp"
#include "slscan/io/stl.hpp"

namespace slscan::core {
namespace {

namespace fs = std::filesystem;
constexpr double kPi = std::numbers::pi;

// An icosphere (radius r about c, `levels` subdivisions), counter-clockwise from outside.
TriangleMesh icosphere(double r, const Eigen::Vector3d& c, int levels) {
  const double t = (1 + std::sqrt(5.0)) / 2;
  std::vector<Eigen::Vector3d> v = {{-1, t, 0},  {1, t, 0},  {-1, -t, 0}, {1, -t, 0}, {0, -1, t},  {0, 1, t},
                                    {0, -1, -t}, {0, 1, -t}, {t, 0, -1},  {t, 0, 1},  {-t, 0, -1}, {-t, 0, 1}};
  for (auto& p : v) p.normalize();
  std::vector<std::array<std::uint32_t, 3>> f = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                                 {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                                 {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                                 {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
  for (int level = 0; level < levels; ++level) {
    std::map<std::pair<std::uint32_t, std::uint32_t>, std::uint32_t> mid;
    auto midpoint = [&](std::uint32_t a, std::uint32_t b) {
      const auto key = std::minmax(a, b);
      if (auto it = mid.find(key); it != mid.end()) return it->second;
      v.push_back((v[a] + v[b]).normalized());
      return mid[key] = static_cast<std::uint32_t>(v.size() - 1);
    };
    std::vector<std::array<std::uint32_t, 3>> next;
    for (const auto& tri : f) {
      const std::uint32_t ab = midpoint(tri[0], tri[1]), bc = midpoint(tri[1], tri[2]), ca = midpoint(tri[2], tri[0]);
      next.push_back({tri[0], ab, ca});
      next.push_back({tri[1], bc, ab});
      next.push_back({tri[2], ca, bc});
      next.push_back({ab, bc, ca});
    }
    f = std::move(next);
  }
  TriangleMesh mesh;
  for (const auto& p : v) mesh.vertices.push_back((c + r * p).cast<float>());
  mesh.triangles = f;
  return mesh;
}

// The axis-aligned box [lo, hi], 12 triangles, outward.
TriangleMesh box_mesh(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  TriangleMesh m;
  for (int i = 0; i < 8; ++i)
    m.vertices.emplace_back(static_cast<float>(i & 1 ? hi.x() : lo.x()), static_cast<float>(i & 2 ? hi.y() : lo.y()),
                            static_cast<float>(i & 4 ? hi.z() : lo.z()));
  m.triangles = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                 {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
  return m;
}

// Raises the mesh by `height` * 0.5 (1 + cos(pi r / radius)) along each vertex's radial
// direction from `sphere_centre` within `radius` of `at` (a 50 um x 5 mm bump: radius 2.5 mm).
void add_bump(TriangleMesh& mesh, const Eigen::Vector3d& sphere_centre, const Eigen::Vector3d& at, double radius,
              double height) {
  for (auto& v : mesh.vertices) {
    const Eigen::Vector3d p = v.cast<double>();
    const double r = (p - at).norm();
    if (r >= radius) continue;
    const Eigen::Vector3d n = (p - sphere_centre).normalized();
    v = (p + height * 0.5 * (1 + std::cos(kPi * r / radius)) * n).cast<float>();
  }
}

TEST(InspectMesh, RefusesBrokenNominals) {
  TriangleMesh empty;
  EXPECT_THROW(check_nominal_mesh(empty), std::invalid_argument);
  TriangleMesh nan_vertex = box_mesh({0, 0, 0}, {1, 1, 1});
  nan_vertex.vertices[3].y() = NAN;
  try {
    check_nominal_mesh(nan_vertex);
    FAIL() << "a NaN vertex was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("vertex 3"), std::string::npos) << e.what();
  }
  // Three triangles on one edge.
  TriangleMesh fin = box_mesh({0, 0, 0}, {1, 1, 1});
  fin.vertices.emplace_back(0.5f, 2.0f, 0.5f);
  fin.triangles.push_back({0, 2, 8});
  try {
    check_nominal_mesh(fin);
    FAIL() << "a non-manifold edge was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("not manifold"), std::string::npos) << e.what();
  }
  // One triangle wound against its neighbours: check_nominal_mesh names it; NominalSurface
  // turns it back (and the distances are those of the box).
  TriangleMesh flipped = box_mesh({0, 0, 0}, {1, 1, 1});
  std::swap(flipped.triangles[4][1], flipped.triangles[4][2]);
  try {
    check_nominal_mesh(flipped);
    FAIL() << "an inconsistently oriented mesh was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("oriented"), std::string::npos) << e.what();
  }
  for (int seed_face : {0, 4}) {  // the flood keeps the first triangle's winding: both ways end outward
    TriangleMesh m = flipped;
    std::rotate(m.triangles.begin(), m.triangles.begin() + seed_face, m.triangles.end());
    const NominalSurface repaired(m);
    EXPECT_EQ(repaired.reoriented_triangles(), seed_face == 0 ? 1u : 11u);
    EXPECT_NEAR(repaired.closest({0.5, 0.5, 1.5}).signed_distance_mm, 0.5, 1e-9);
    EXPECT_NEAR(repaired.closest({0.5, 0.5, 0.9}).signed_distance_mm, -0.1, 1e-9);
    EXPECT_NEAR(repaired.closest({0.5, 0.1, 0.5}).signed_distance_mm, -0.1, 1e-9);
  }
  TriangleMesh out_of_range = box_mesh({0, 0, 0}, {1, 1, 1});
  out_of_range.triangles[0][2] = 99;
  EXPECT_THROW(check_nominal_mesh(out_of_range), std::invalid_argument);
}

// Faces, edges and corners of a cube: the pseudo-normal gets the sign right everywhere, the
// distance is exact; an inside-out closed mesh is turned outward.
TEST(InspectMesh, SignedDistanceIsExactWithTheRightSignAtFacesEdgesAndCorners) {
  for (bool inside_out : {false, true}) {
    TriangleMesh cube = box_mesh({-1, -1, -1}, {1, 1, 1});
    if (inside_out)
      for (auto& t : cube.triangles) std::swap(t[1], t[2]);
    const NominalSurface surface(cube);
    struct Case {
      Eigen::Vector3d p;
      double d;
    };
    const Case cases[] = {{{0.2, 0.1, 1.5}, 0.5},                   // above a face
                          {{0.3, 1.3, 1.4}, std::hypot(0.3, 0.4)},  // beyond an edge
                          {{1.5, 1.5, 1.5}, std::sqrt(0.75)},       // beyond a corner
                          {{0.9, 0.9, 0.9}, -0.1},                  // inside near a corner
                          {{0.0, 0.95, 0.0}, -0.05},                // inside near a face
                          {{0.95, 0.95, 0.0}, -0.05}};              // inside near an edge
    for (const Case& c : cases) {
      const auto closest = surface.closest(c.p);
      EXPECT_NEAR(closest.signed_distance_mm, c.d, 1e-6) << c.p.transpose() << (inside_out ? " inside-out" : "");
    }
  }
  // A sphere: the chord error of a level-5 icosphere of radius 10 is < 5 um.
  const NominalSurface sphere(icosphere(10, Eigen::Vector3d::Zero(), 5));
  EXPECT_NEAR(sphere.closest({0, 0, 12}).signed_distance_mm, 2, 5e-3);
  EXPECT_NEAR(sphere.closest({3, -4, 0}).signed_distance_mm, -5, 5e-3);
}

TEST(InspectUnits, DetectsMetresAndInchesAndRefusesWhatFitsNone) {
  EXPECT_EQ(decide_nominal_units(86.6, 86.6, NominalUnits::auto_detect).units, "mm");
  EXPECT_EQ(decide_nominal_units(300, 86.6, NominalUnits::auto_detect).units, "mm");  // scan with its platform
  EXPECT_EQ(decide_nominal_units(86.6, 0.0866, NominalUnits::auto_detect).units, "m");
  EXPECT_DOUBLE_EQ(decide_nominal_units(86.6, 0.0866, NominalUnits::auto_detect).scale_to_mm, 1000);
  EXPECT_EQ(decide_nominal_units(86.6, 86.6 / 25.4, NominalUnits::auto_detect).units, "in");
  EXPECT_EQ(decide_nominal_units(86.6, 1e6, NominalUnits::in).units, "in");  // given: not second-guessed
  for (double nominal : {86.6 / 7.0, 86.6 / 1e6, 86.6 * 100}) {              // between mm and in; nothing; far too big
    try {
      (void)decide_nominal_units(86.6, nominal, NominalUnits::auto_detect);
      FAIL() << "ratio " << 86.6 / nominal << " accepted";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("--nominal-units"), std::string::npos) << e.what();
    }
  }
}

PointCloud sample_cloud(const NominalSurface& surface, std::size_t n, double sigma, std::uint64_t seed,
                        double min_z = -1e9) {
  const std::vector<Eigen::Vector3d> s = surface.sample(n, seed);
  std::mt19937_64 rng(seed + 1);
  std::normal_distribution<double> noise(0, sigma > 0 ? sigma : 1);
  PointCloud cloud;
  for (const auto& p : s) {
    if (p.z() < min_z) continue;
    const auto c = surface.closest(p);
    cloud.points.push_back((p + (sigma > 0 ? noise(rng) : 0.0) * c.face_normal).cast<float>());
  }
  return cloud;
}

// A box seen from above and the sides (no bottom), turned 70 deg and moved 120 mm: the scan
// frame does not fit, the coarse search does, and the deviation is the noise alone.
TEST(InspectAlignment, FindsAPartPlacedAnywhere) {
  const NominalSurface nominal(box_mesh({0, 0, 0}, {60, 30, 12}));
  PointCloud cloud = sample_cloud(nominal, 30000, 0.005, 3, 0.5);
  Eigen::Isometry3d moved = Eigen::Isometry3d::Identity();
  moved.linear() = Eigen::AngleAxisd(70 * kPi / 180, Eigen::Vector3d(0.3, -0.2, 1).normalized()).toRotationMatrix();
  moved.translation() = Eigen::Vector3d(120, -40, 35);
  for (auto& p : cloud.points) p = (moved * p.cast<double>()).cast<float>();
  InspectOptions options;
  options.tolerance_mm = 0.02;
  const InspectionResult r = inspect(cloud, nominal, options);
  std::printf("box placed anywhere: %s (%d tried), RMS %.2f um, %zu of %zu matched\n", r.alignment.method.c_str(),
              r.alignment.candidates_tried, 1e3 * r.stats.rms_mm, r.stats.matched, r.stats.points);
  EXPECT_NE(r.alignment.method, "scan frame");
  EXPECT_NEAR(r.stats.rms_mm, 0.005, 0.001);
  EXPECT_GT(static_cast<double>(r.stats.matched), 0.999 * static_cast<double>(r.stats.points));
  ASSERT_TRUE(r.stats.pass.has_value());
  EXPECT_TRUE(*r.stats.pass);
  // Without the coarse search the same scan does not overlap its nominal: a clear error.
  options.coarse_search = false;
  try {
    (void)inspect(cloud, nominal, options);
    FAIL() << "a scan 120 mm away was inspected";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("does not overlap"), std::string::npos) << e.what();
  }
  // A different part (a sphere against the box) does not overlap either, coarse search or not.
  options.coarse_search = true;
  const NominalSurface other(icosphere(25, Eigen::Vector3d::Zero(), 4));
  const PointCloud sphere_cloud = sample_cloud(other, 5000, 0.005, 4);
  EXPECT_THROW((void)inspect(sphere_cloud, nominal, options), std::runtime_error);
  EXPECT_THROW((void)inspect(PointCloud{}, nominal, options), std::invalid_argument);
  PointCloud nan_cloud = cloud;
  nan_cloud.points[17].x() = NAN;
  EXPECT_THROW((void)inspect(nan_cloud, nominal, options), std::invalid_argument);
}

// A 50 um bump, 5 mm across (raised cosine, radius 2.5 mm), put into a 50 mm sphere's nominal
// (level 6: 0.4 mm edges, 12 across the bump; the linear pieces miss the raised cosine by < 1
// um). The scan: a dense synthetic cloud of the sphere without the bump (150 000 points, 19 per
// mm2, 5 um noise: the small rig's 15-30 um per point would need a larger bump). The bump shows
// as the region below -25 um (half height): its centre within 0.3 mm of where it was put, its
// height (minus the median deviation within 0.3 mm of the centre) within 10 um of 50 um.
TEST(InspectDeviation, FindsABumpInTheNominalWhereItIsWithItsHeight) {
  const Eigen::Vector3d centre(40, 0, 25);
  const double radius = 25;
  const NominalSurface plain(icosphere(radius, centre, 6));
  const PointCloud cloud = sample_cloud(plain, 150000, 0.005, 7);
  TriangleMesh bumped = plain.mesh();
  const Eigen::Vector3d dir = Eigen::Vector3d(0.6, -0.5, 0.62).normalized();
  const Eigen::Vector3d bump_at = centre + radius * dir;
  add_bump(bumped, centre, bump_at, 2.5, 0.050);
  const NominalSurface nominal(std::move(bumped));
  InspectOptions options;
  options.tolerance_mm = 0.03;
  const InspectionResult r = inspect(cloud, nominal, options);
  EXPECT_EQ(r.alignment.method, "scan frame");
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  std::size_t in_bump = 0;
  for (std::size_t i = 0; i < cloud.size(); ++i)
    if (r.deviation_mm[i] < -0.025) sum += r.aligned_points[i].cast<double>(), ++in_bump;
  ASSERT_GT(in_bump, 20u);
  const Eigen::Vector3d found = sum / static_cast<double>(in_bump);
  // The centroid of a cap region lies slightly inside the sphere: compare on the surface.
  const Eigen::Vector3d found_on_surface = centre + radius * (found - centre).normalized();
  std::vector<double> near;
  for (std::size_t i = 0; i < cloud.size(); ++i)
    if ((r.aligned_points[i].cast<double>() - found_on_surface).norm() < 0.3) near.push_back(r.deviation_mm[i]);
  ASSERT_GT(near.size(), 5u);
  std::nth_element(near.begin(), near.begin() + static_cast<std::ptrdiff_t>(near.size() / 2), near.end());
  const double height = -near[near.size() / 2];
  std::printf(
      "bump: found %.3f mm from where it was put, height %.1f um (%zu points below -25 um, %zu near its "
      "centre); alignment moved %.4f deg / %.4f mm; RMS %.1f um; %.2f %% within +-30 um\n",
      (found_on_surface - bump_at).norm(), 1e3 * height, in_bump, near.size(), r.alignment.rotation_deg,
      r.alignment.translation_mm, 1e3 * r.stats.rms_mm, 100 * r.stats.share_within.value());
  EXPECT_LT((found_on_surface - bump_at).norm(), 0.3);
  EXPECT_NEAR(height, 0.050, 0.010);
  // The robust fit is not pulled by the bump: the sphere's centre stays (its rotations about the
  // centre are free and move nothing).
  EXPECT_LT((r.alignment.nominal_from_scan * centre - centre).norm(), 0.002);
  // The bump's points are the ones out of tolerance.
  EXPECT_LT(r.stats.min_mm, -0.045);
  EXPECT_GT(*r.stats.share_within, 0.99);
}

Eigen::Isometry3d to_isometry_rows(const slproto::RigidTransform& t) {
  Eigen::Isometry3d m = Eigen::Isometry3d::Identity();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) m.linear()(r, c) = t.R[static_cast<std::size_t>(3 * r + c)];
    m.translation()(r) = t.t[static_cast<std::size_t>(r)];
  }
  return m;
}

// A preset of the small rig scanned (6 views x 2 projectors) with the rig's calibration, as in
// test_feature_metrology: the model and the map from its table frame into the rig's.
struct RigScan {
  PointCloud model;
  Eigen::Isometry3d to_rig = Eigen::Isometry3d::Identity();
};
RigScan scan_small(const slrig::Scene& scene) {
  const slproto::RigCalibration calibration = slrig::ground_truth_calibration(scene);
  const slproto::PatternPlan plan(calibration.pattern_plan);
  ReconstructionOptions options;
  options.decode.bit_depth = scene.sensor.bit_depth;
  options.build_mesh = false;
  ScanReconstructor reconstructor(calibration, plan, scene.camera.width, scene.camera.height, options);
  std::vector<std::uint8_t> frame;
  slproto::RigidTransform cam0_from_table;
  const int bytes_per_pixel = scene.sensor.bit_depth > 8 ? 2 : 1;
  for (std::size_t view = 0; view < scene.view_angles_deg.size(); ++view) {
    const double angle = scene.view_angles_deg[view];
    const slrig::ViewRenderer renderer(scene, angle, static_cast<int>(view));
    if (view == 0) cam0_from_table = renderer.ground_truth().cam_from_table;
    frame.resize(renderer.frame_bytes());
    for (int side = 0; side < 2; ++side)
      for (std::size_t p = 0; p < plan.size(); ++p) {
        renderer.render(static_cast<slproto::ProjectorSide>(side), p, frame);
        FrameInfo info;
        info.view_index = static_cast<int>(view);
        info.commanded_angle_deg = info.reported_angle_deg = angle;
        info.projector = side;
        info.pattern_index = p;
        info.bytes_per_pixel = bytes_per_pixel;
        info.stride_bytes = static_cast<std::size_t>(scene.camera.width * bytes_per_pixel);
        reconstructor.add_frame(info, std::as_bytes(std::span(frame)));
      }
  }
  RigScan out;
  out.model = reconstructor.finish().model;
  out.to_rig = to_isometry_rows(cam0_from_table).inverse() *
               coarse_table_from_view(calibration.turntable, scene.view_angles_deg[0]).inverse();
  return out;
}

class InspectFiles : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("slscan_inspect_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  // SLSCAN_KEEP_TEST_FILES=1 keeps the folder (to look at the pictures and reports).
  void TearDown() override {
    if (std::getenv("SLSCAN_KEEP_TEST_FILES") == nullptr) fs::remove_all(dir_);
  }
  std::string path(const std::string& name) const { return (dir_ / name).string(); }
  fs::path dir_;
};

void write_stl_mesh(const std::string& path, const TriangleMesh& mesh, double scale = 1) {
  std::vector<Eigen::Vector3f> v = mesh.vertices;
  for (auto& p : v) p *= static_cast<float>(scale);
  std::vector<Eigen::Vector3i> t;
  for (const auto& tri : mesh.triangles)
    t.emplace_back(static_cast<int>(tri[0]), static_cast<int>(tri[1]), static_cast<int>(tri[2]));
  io::write_stl(path, v, t);
}

// The small rig's sphere preset scanned, then inspected against the preset's own shape (a level-6
// icosphere of the true radius where the rig puts it, written as STL): the deviation RMS within
// 10 % of the truth-based point-to-surface RMS (model points within 0.5 mm of the true sphere,
// distance to the exact sphere, docs/accuracy.md's selection), through `slscan inspect`'s code
// with its files; the same nominal in metres and in inches detected, with the same figures.
TEST_F(InspectFiles, SmallRigSpherePresetAgainstItsOwnShape) {
  const slrig::Scene scene = slrig::scene_preset("sphere", slrig::RigSize::small).value();
  const RigScan scan = scan_small(scene);
  ASSERT_GT(scan.model.size(), 10000u);
  const slrig::SceneObject& truth = scene.objects.at(0);
  const Eigen::Vector3d true_centre(truth.table_from_object.t[0], truth.table_from_object.t[1],
                                    truth.table_from_object.t[2]);
  // Truth-based: in the rig's frame.
  double sum_sq = 0, sum = 0;
  std::size_t n = 0;
  for (const auto& p : scan.model.points) {
    const double d = (scan.to_rig * p.cast<double>() - true_centre).norm() - truth.radius;
    if (std::abs(d) > 0.5) continue;
    sum_sq += d * d, sum += d, ++n;
  }
  const double truth_rms = std::sqrt(sum_sq / static_cast<double>(n)), truth_mean = sum / static_cast<double>(n);
  // The nominal where the part is, in the model's frame (the scan frame the user's CAD shares).
  TriangleMesh nominal = icosphere(truth.radius, Eigen::Vector3d::Zero(), 6);
  const Eigen::Isometry3d model_from_object = scan.to_rig.inverse() * Eigen::Translation3d(true_centre);
  for (auto& v : nominal.vertices) v = (model_from_object * v.cast<double>()).cast<float>();
  io::write_ply(path("model.ply"), scan.model);
  write_stl_mesh(path("sphere.stl"), nominal);
  write_stl_mesh(path("sphere_m.stl"), nominal, 1e-3);
  write_stl_mesh(path("sphere_in.stl"), nominal, 1 / 25.4);

  app::Console quiet;
  quiet.quiet = true;
  app::InspectCommand command;
  command.model_path = path("model.ply");
  command.nominal_path = path("sphere.stl");
  command.output_dir = path("out");
  command.tolerance_mm = 0.1;
  command.part_id = "sphere-1";
  EXPECT_EQ(app::run_inspect(command, quiet), app::exit_ok);
  for (const char* f : {"deviation.ply", "deviation.png", "report.json", "report.html"})
    EXPECT_TRUE(fs::exists(dir_ / "out" / f)) << f;
  std::ifstream in(dir_ / "out" / "report.json");
  const nlohmann::json report = nlohmann::json::parse(in);
  const auto& ins = report.at("inspection");
  const double rms = 1e-3 * ins.at("rms_um").get<double>();
  std::printf(
      "small-rig sphere: inspect RMS %.1f um, mean %+.1f um over %zu points (%s, moved %.4f deg / %.4f mm); "
      "truth-based RMS %.1f um, mean %+.1f um over %zu points; %.2f %% within +-100 um\n",
      1e3 * rms, ins.at("mean_um").get<double>(), ins.at("matched").get<std::size_t>(),
      ins.at("alignment").at("method").get<std::string>().c_str(), ins.at("alignment").at("rotation_deg").get<double>(),
      ins.at("alignment").at("translation_mm").get<double>(), 1e3 * truth_rms, 1e3 * truth_mean, n,
      ins.at("within_tolerance_percent").get<double>());
  EXPECT_EQ(ins.at("alignment").at("method"), "scan frame");
  EXPECT_NEAR(rms, truth_rms, 0.10 * truth_rms);
  EXPECT_NEAR(static_cast<double>(ins.at("matched").get<std::size_t>()), static_cast<double>(n),
              0.01 * static_cast<double>(n));
  EXPECT_EQ(ins.at("verdict"), "PASS");
  EXPECT_EQ(report.at("provenance").at("part_id"), "sphere-1");
  // deviation.ply: one vertex per model point, with the deviation property.
  const io::PlyTable table = io::read_ply_table((dir_ / "out" / "deviation.ply").string());
  EXPECT_EQ(table.vertex_count, scan.model.size());
  EXPECT_GE(table.find("deviation"), 0);
  EXPECT_GE(table.find("red"), 0);

  for (const auto& [file, unit] : {std::pair{"sphere_m.stl", "m"}, std::pair{"sphere_in.stl", "in"}}) {
    command.nominal_path = path(file);
    command.output_dir = path(std::string("out_") + unit);
    EXPECT_EQ(app::run_inspect(command, quiet), app::exit_ok) << file;
    std::ifstream in2(dir_ / command.output_dir / "report.json");
    const nlohmann::json r2 = nlohmann::json::parse(in2);
    EXPECT_EQ(r2.at("inspection").at("nominal").at("units"), unit);
    EXPECT_NEAR(1e-3 * r2.at("inspection").at("rms_um").get<double>(), rms, 0.5e-3) << file;  // float rounding
  }
  // A tolerance tighter than the small rig's noise: FAIL, exit 7.
  command.nominal_path = path("sphere.stl");
  command.output_dir = path("out_tight");
  command.tolerance_mm = 0.005;
  EXPECT_EQ(app::run_inspect(command, quiet), app::exit_out_of_tolerance);
}

// Bad input through `slscan inspect`'s code: a clear error, and no output folder.
TEST_F(InspectFiles, BadInputIsRefusedWithNothingWritten) {
  const NominalSurface sphere(icosphere(25, Eigen::Vector3d(0, 0, 25), 4));
  io::write_ply(path("scan.ply"), sample_cloud(sphere, 20000, 0.005, 9));
  write_stl_mesh(path("sphere.stl"), sphere.mesh());
  io::write_ply(path("empty.ply"), PointCloud{});
  {
    std::ofstream obj(path("nan.obj"));
    obj << "v 0 0 0\nv 1 0 0\nv nan 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n";
  }
  {
    std::ofstream obj(path("fin.obj"));  // a tetrahedron with a fin on edge 1-2
    obj << "v 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 0 10\nv 5 -5 -5\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\nf 1 2 5\n";
  }
  {
    std::ofstream obj(path("points.ply"));
    obj << "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
           "end_header\n0 0 0\n";
  }
  write_stl_mesh(path("huge.stl"), sphere.mesh(), 1e5);
  TriangleMesh far = sphere.mesh();
  for (auto& v : far.vertices) v += Eigen::Vector3f(400, 0, 0);
  write_stl_mesh(path("far.stl"), far);

  app::Console quiet;
  quiet.quiet = true;
  struct Case {
    std::string model, nominal, expect;
    std::string units = "auto";
    bool coarse = true;
  };
  const Case cases[] = {
      {"empty.ply", "sphere.stl", "no points"},    {"scan.ply", "nan.obj", "not finite"},
      {"scan.ply", "fin.obj", "not manifold"},     {"scan.ply", "points.ply", "no triangles"},
      {"scan.ply", "huge.stl", "--nominal-units"}, {"scan.ply", "far.stl", "does not overlap", "auto", false},
  };
  for (const Case& c : cases) {
    app::InspectCommand command;
    command.model_path = path(c.model);
    command.nominal_path = path(c.nominal);
    command.output_dir = path("out");
    command.nominal_units = c.units;
    command.scan_frame_only = !c.coarse;
    testing::internal::CaptureStderr();
    std::string message;
    try {
      const int code = app::run_inspect(command, quiet);
      EXPECT_EQ(code, app::exit_measurement) << c.nominal;
    } catch (const std::exception& e) {
      message = e.what();
    }
    message += testing::internal::GetCapturedStderr();
    EXPECT_NE(message.find(c.expect), std::string::npos) << c.model << " / " << c.nominal << ": " << message;
    EXPECT_FALSE(fs::exists(dir_ / "out")) << c.nominal << ": something was written";
  }
}

}  // namespace
}  // namespace slscan::core
