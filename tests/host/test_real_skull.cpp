// The host pipeline on a real capture made by a scanner nobody here built (SLStudio's skull,
// ../shared/data/slstudio-skull-gray, README there), through the commands docs/real-data.md
// gives a user: `slscan import` with docs/examples/slstudio-skull-gray.json, `slscan
// reprocess` with docs/examples/slstudio-skull-gray.config.json, and `slscan compare
// --project-pixels` against that scanner's own reconstruction, pixel for pixel.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>

#include "outputs.hpp"
#include "real_data.hpp"
#include "run.hpp"
#include "slproto/calibration.hpp"
#include "slscan/core/cloud_compare.hpp"
#include "slscan/core/normals.hpp"
#include "slscan/io/ply.hpp"

namespace fs = std::filesystem;
using json = nlohmann::json;
using namespace slscan;

namespace {

const fs::path kData = fs::path(SLSCAN_SOURCE_DIR "/../shared/data/slstudio-skull-gray");
const fs::path kExamples = fs::path(SLSCAN_SOURCE_DIR "/docs/examples");
const app::Console kQuiet{.quiet = true, .json_log = false};

json read_json(const fs::path& path) {
  std::ifstream in(path);
  return json::parse(in);
}

struct Pipeline {
  fs::path calibration;  // our calibration.json, written by import
  fs::path cloud;        // views/view_0.ply, written by reprocess (camera frame, no u/v)
  json report;           // reprocess's report.json
};

// `slscan import DESCRIPTION --calib calibration.xml --out DIR/imported [--pose-direction]`,
// then `slscan reprocess DIR/imported/capture.slcap --calib CALIB --out DIR/result --config
// slstudio-skull-gray.config.json`, CALIB being the imported calibration or, with
// `without_projector_distortion`, a copy of it whose projector has no distortion.
Pipeline import_and_reprocess(const fs::path& dir, const fs::path& description, const std::string& pose_direction,
                              bool without_projector_distortion = false) {
  app::ImportCommand import;
  import.description_path = description.string();
  import.calibration_path = (kData / "calibration.xml").string();
  import.output_dir = (dir / "imported").string();
  import.pose_direction = pose_direction;
  // The other pose direction is caught by the import's self-checks (exit 6, "only 22 % of the
  // decoded pixels triangulate"); --force writes it anyway, to measure how far off it is.
  import.force = pose_direction != "proj_from_cam";
  EXPECT_EQ(app::run_import(import, kQuiet), app::exit_ok);
  Pipeline run;
  run.calibration = dir / "imported" / "calibration.json";
  if (without_projector_distortion) {
    auto calibration = slproto::load_calibration(run.calibration.string());
    EXPECT_TRUE(calibration.ok());
    for (auto& projector : calibration->projectors) projector.intrinsics.distortion = {};
    run.calibration = dir / "calibration_without_kp.json";
    EXPECT_TRUE(slproto::save_calibration(run.calibration.string(), *calibration).ok());
  }
  app::ReprocessRequest reprocess;
  reprocess.capture_path = (dir / "imported" / "capture.slcap").string();
  reprocess.calibration_path = run.calibration.string();
  reprocess.output_dir = (dir / "result").string();
  reprocess.config_path = (kExamples / "slstudio-skull-gray.config.json").string();
  // reprocess runs the same checks and writes its outputs either way; a flagged view exits 6.
  EXPECT_EQ(app::run_reprocess(reprocess, kQuiet), import.force ? app::exit_inconsistent : app::exit_ok);
  run.cloud = dir / "result" / "views" / "view_0.ply";
  run.report = read_json(dir / "result" / "report.json");
  return run;
}

// The example description with its image folder made absolute and `convention` set: what a
// user gets by editing that one field.
fs::path description_with_convention(const fs::path& dir, const std::string& convention) {
  json description = read_json(kExamples / "slstudio-skull-gray.json");
  description["image_dir"] = kData.string();
  description["gray"]["convention"] = convention;
  const fs::path path = dir / ("sequence_" + convention + ".json");
  std::ofstream(path) << description.dump(2);
  return path;
}

struct Figures {
  double median = 0, p90 = 0, p99 = 0, coverage = 0, dz = 0;
  std::size_t reference_pixels = 0;
};

// `slscan compare CLOUD reference_cloud.ply --calib CALIB --project-pixels --report FILE`:
// SLStudio's stored u/v are pixels of its undistorted image, so the reference's pixels are its
// points projected through the camera model with distortion (as are ours).
Figures compare_with_reference(const fs::path& dir, const Pipeline& run, const char* what) {
  app::CompareCommand compare;
  compare.measured_path = run.cloud.string();
  compare.reference_path = (kData / "reference_cloud.ply").string();
  compare.calibration_path = run.calibration.string();
  compare.project_pixels = true;
  compare.report_path = (dir / "compare.json").string();
  EXPECT_EQ(app::run_compare(compare, kQuiet), app::exit_ok);
  const json report = read_json(dir / "compare.json");
  EXPECT_EQ(report["reference"]["points"], 93876);
  const json& p = report.at("per_pixel");
  Figures f{p["distance"]["median_mm"], p["distance"]["p90_mm"], p["distance"]["p99_mm"], p["coverage"],
            p["median_signed_z_mm"],    p["reference_pixels"]};
  std::cout << what << ": median " << f.median << " mm, p90 " << f.p90 << " mm, p99 " << f.p99 << " mm, coverage "
            << f.coverage << " of " << f.reference_pixels << ", median dz " << f.dz << " mm\n";
  return f;
}

std::size_t decoded_pixels(const Pipeline& run) {
  return run.report["scan"]["views"][0]["projectors"][0]["decode"]["valid"].get<std::size_t>();
}

class RealSkull : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!fs::exists(kData / "frameSeq_11.bmp") || !fs::exists(kData / "reference_cloud.ply"))
      GTEST_SKIP() << "the real capture is not at " << kData.string() << " (it lives in ../shared/data; CI has it)";
    dir_ = fs::temp_directory_path() / ("slscan_real_skull_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (!dir_.empty()) fs::remove_all(dir_);
  }
  fs::path sub(const std::string& name) const {
    fs::create_directories(dir_ / name);
    return dir_ / name;
  }
  fs::path dir_;
};

TEST_F(RealSkull, ReconstructsOntoTheReferencePixelForPixel) {
  // 1. The documented commands as they stand: the example description asks for SLStudio's
  //    column convention, the one its calibration and reference were made with. The issue's
  //    target, median <= 0.3 mm. Measured: median 0.170, p90 0.434, p99 1.83 mm, coverage
  //    0.959, dz +0.050 mm. Bounds a little above catch any regression of the import, the
  //    decode or the triangulation.
  ASSERT_EQ(read_json(kExamples / "slstudio-skull-gray.json")["gray"]["convention"], "slstudio");
  const Pipeline slstudio =
      import_and_reprocess(sub("slstudio"), kExamples / "slstudio-skull-gray.json", "proj_from_cam");
  const Figures like_for_like = compare_with_reference(dir_, slstudio, "SLStudio's column convention");
  EXPECT_LE(like_for_like.median, 0.20);
  EXPECT_LE(like_for_like.p90, 0.50);
  EXPECT_LE(like_for_like.p99, 2.1);
  EXPECT_GE(like_for_like.coverage, 0.955);
  EXPECT_LT(std::abs(like_for_like.dz), 0.08) << "a depth bias: wrong column offset or pose";
  EXPECT_EQ(like_for_like.reference_pixels, 93058u) << "distinct camera pixels the reference projects to";
  // White - black > 20 keeps ~400 k pixels (README); the reference filtered down to ~94 k.
  EXPECT_GT(decoded_pixels(slstudio), 350000u);
  EXPECT_LT(decoded_pixels(slstudio), 450000u);

  // 2. Our own convention (each decoded step at the centre of its two columns). The reference
  //    sits half a column either side of that centre, alternately per step, which is what
  //    remains. Measured: median 0.356, p90 0.648, p99 1.60 mm, coverage 0.959, dz +0.146 mm.
  const Pipeline centre =
      import_and_reprocess(sub("centre"), description_with_convention(dir_, "centre"), "proj_from_cam");
  const Figures ours = compare_with_reference(dir_, centre, "our column convention (step centre)");
  EXPECT_LE(ours.median, 0.40);
  EXPECT_LE(ours.p90, 0.72);
  EXPECT_LE(ours.p99, 1.9);
  EXPECT_GE(ours.coverage, 0.955);
  EXPECT_EQ(decoded_pixels(centre), decoded_pixels(slstudio)) << "the convention moves columns, not the mask";
  EXPECT_LT(like_for_like.median, ours.median - 0.1)
      << "the reference no longer looks decoded with SLStudio's column convention";

  // 3. SLStudio's Triangulator also ignores the projector's distortion kp (its column planes
  //    are those of Kp, Rp, Tp alone): the full emulation of its reconstruction leaves no depth
  //    bias. Measured: median 0.134, p90 0.236 mm, dz +0.006 mm.
  const Pipeline emulated =
      import_and_reprocess(sub("emulated"), kExamples / "slstudio-skull-gray.json", "proj_from_cam",
                           /*without_projector_distortion=*/true);
  const Figures full_emulation = compare_with_reference(dir_, emulated, "the same, projector distortion ignored");
  EXPECT_LE(full_emulation.median, 0.16);
  EXPECT_LE(full_emulation.p90, 0.28);
  EXPECT_LT(std::abs(full_emulation.dz), 0.03) << "SLStudio's reconstruction is no longer reproduced";

  // 4. The stored u/v are not the frames' pixels: pairing by them doubles the tail.
  const slproto::RigCalibration calibration = *slproto::load_calibration(centre.calibration.string());
  const core::PixelTaggedCloud ours_tagged = app::read_pixel_tagged_ply(centre.cloud.string(), &calibration.camera);
  const core::PixelTaggedCloud reference_as_stored =
      app::read_pixel_tagged_ply((kData / "reference_cloud.ply").string(), nullptr);
  ASSERT_TRUE(reference_as_stored.has_pixels());
  const core::PixelComparison stored_pixels = core::compare_by_pixel(ours_tagged, reference_as_stored);
  std::cout << "our column convention, reference paired by its stored u/v: median " << stored_pixels.distance.median
            << " mm, p99 " << stored_pixels.distance.p99 << " mm\n";
  EXPECT_GT(stored_pixels.distance.p99, 1.5 * ours.p99) << "the reference pixel finding no longer holds";

  // SLSCAN_REAL_DATA_OUT=DIR: also write the pictures of docs/real-data.md
  // (docs/images/real_skull_{ours,reference}.png).
  if (const char* out = std::getenv("SLSCAN_REAL_DATA_OUT")) {
    auto picture = [&](const fs::path& ply, const std::string& name) {
      core::PointCloud cloud = io::read_ply(ply.string());
      cloud.normals = core::pca_normals(cloud);
      // Normals towards the camera (at the origin) for the shading.
      for (std::size_t i = 0; i < cloud.size(); ++i)
        if (cloud.normals[i].dot(cloud.points[i]) > 0) cloud.normals[i] = -cloud.normals[i];
      const auto png = app::render_preview_png(cloud, 90.0, -90.0, 640);
      io::write_file_atomically((fs::path(out) / name).string(),
                                std::string_view(reinterpret_cast<const char*>(png.data()), png.size()));
    };
    picture(slstudio.cloud, "real_skull_ours.png");
    picture(kData / "reference_cloud.ply", "real_skull_reference.png");
  }
}

TEST_F(RealSkull, TheOtherPoseDirectionMissesTheReference) {
  // Rp/Tp read as the projector's pose in the camera frame instead of proj_from_cam: the
  // surface lands elsewhere. This is how the direction was decided from the data.
  const Pipeline wrong = import_and_reprocess(dir_, kExamples / "slstudio-skull-gray.json", "cam_from_proj");
  const core::PixelTaggedCloud ours =
      app::read_pixel_tagged_ply(wrong.cloud.string(), &slproto::load_calibration(wrong.calibration.string())->camera);
  const core::PixelTaggedCloud reference =
      app::read_pixel_tagged_ply((kData / "reference_cloud.ply").string(), nullptr);
  const core::PixelComparison c = core::compare_by_pixel(ours, reference);
  std::cout << "cam_from_proj: median " << c.distance.median << " mm, coverage " << c.coverage << "\n";
  EXPECT_TRUE(c.common_pixels < 1000 || c.distance.median > 10.0) << c.distance.median;
}

}  // namespace
