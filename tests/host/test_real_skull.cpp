// The host pipeline on a real capture made by a scanner nobody here built (SLStudio's skull,
// /work/shared/data/slstudio-skull-gray, README there): imported, decoded, triangulated and
// compared pixel for pixel with that scanner's own reconstruction.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "outputs.hpp"
#include "real_data.hpp"
#include "slproto/calibration.hpp"
#include "slscan/core/cloud_compare.hpp"
#include "slscan/core/decode.hpp"
#include "slscan/core/normals.hpp"
#include "slscan/core/triangulate.hpp"
#include "slscan/io/capture_replay.hpp"
#include "slscan/io/ply.hpp"

namespace fs = std::filesystem;
using namespace slscan;

namespace {

const fs::path kData = fs::path(SLSCAN_SOURCE_DIR "/../shared/data/slstudio-skull-gray");

struct Reconstruction {
  core::PixelTaggedCloud cloud;
  core::DecodeCounts decode;
  slproto::RigCalibration calibration;
};

// Imports the capture, then decodes and triangulates it as reprocessing does, keeping each
// point's camera pixel.
Reconstruction import_and_reconstruct(const fs::path& dir, const std::string& pose_direction) {
  {
    std::ofstream description(dir / "sequence.json");
    description << R"({"projector": {"width": 1824, "height": 1140}, "axis": "columns",
      "camera": {"width": 1688, "height": 1352, "bit_depth": 8},
      "white": ")"
                << (kData / "frameSeq_00.bmp").string() << R"(", "black": ")" << (kData / "frameSeq_01.bmp").string()
                << R"(",
      "gray": {"files": {"pattern": ")"
                << (kData / "frameSeq_%02d.bmp").string()
                << R"(", "first": 2, "count": 10}, "bit_order": "msb_first", "bits_not_projected": 1}})";
  }
  app::ImportCommand command;
  command.description_path = (dir / "sequence.json").string();
  command.calibration_path = (kData / "calibration.xml").string();
  command.output_dir = (dir / "imported").string();
  command.pose_direction = pose_direction;
  const app::Console quiet{.quiet = true, .json_log = false};
  EXPECT_EQ(app::run_import(command, quiet), app::exit_ok);

  Reconstruction out;
  auto calibration = slproto::load_calibration((dir / "imported" / "calibration.json").string());
  EXPECT_TRUE(calibration.ok());
  out.calibration = *calibration;
  // SLStudio's mask: white - black > 20. The code has 2-pixel steps and no phase: smoothing
  // would only blur the steps, so the decode is plain, as in the reference.
  core::DecodeOptions decode_options;
  decode_options.min_contrast_dn = 21;
  decode_options.smoothing_radius = 0;
  std::unique_ptr<core::ProjectorViewDecoder> decoder;
  io::replay_capture((dir / "imported" / "capture.slcap").string(),
                     [&](const slproto::pb::ScanRequest& request) {
                       decoder = std::make_unique<core::ProjectorViewDecoder>(
                           io::plan_of(request), out.calibration.camera.width, out.calibration.camera.height,
                           decode_options);
                     },
                     [&](const slproto::pb::FrameHeader& header, std::span<const std::byte> payload) {
                       decoder->add_frame(header.pattern_index(), reinterpret_cast<const std::uint8_t*>(payload.data()),
                                          header.stride_bytes());
                     });
  const core::DecodedView decoded = decoder->finish();
  out.decode = decoded.counts;
  const auto rays = std::make_shared<const core::CameraRayTable>(core::CameraRayTable::build(out.calibration.camera));
  const core::ProjectorTriangulator triangulator(rays, out.calibration.projector(slproto::ProjectorSide::left),
                                                 decoded.axis);
  const core::TriangulatedView view = triangulator.triangulate(decoded);
  for (std::size_t i = 0; i < view.cloud.size(); ++i) {
    if (!view.cloud.valid[i]) continue;
    out.cloud.points.push_back(view.cloud.points[i]);
    out.cloud.u.push_back(static_cast<float>(i % static_cast<std::size_t>(view.cloud.width)));
    out.cloud.v.push_back(static_cast<float>(i / static_cast<std::size_t>(view.cloud.width)));
  }
  return out;
}

class RealSkull : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!fs::exists(kData / "frameSeq_11.bmp") || !fs::exists(kData / "reference_cloud.ply"))
      GTEST_SKIP() << "the real capture is not at " << kData.string() << " (it lives in ../shared/data; CI has it)";
    dir_ = fs::temp_directory_path() / ("slscan_real_skull_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (!dir_.empty()) fs::remove_all(dir_);
  }
  fs::path dir_;
};

TEST_F(RealSkull, ReconstructsOntoTheReferencePixelForPixel) {
  const Reconstruction ours = import_and_reconstruct(dir_, "proj_from_cam");
  const core::PixelTaggedCloud reference =
      app::read_pixel_tagged_ply((kData / "reference_cloud.ply").string(), nullptr);
  ASSERT_EQ(reference.points.size(), 93876u);
  ASSERT_TRUE(reference.has_pixels());
  // White - black > 20 keeps ~400 k pixels (README); the reference filtered down to ~94 k.
  EXPECT_GT(ours.decode.valid, 350000u);
  EXPECT_LT(ours.decode.valid, 450000u);

  // The reference's u is one more than the pixel its point came from (a 1-based column from
  // the .mat conversion, it seems): shifting it by -1 fits better whatever the column offset
  // or projector distortion model (docs/real-data.md); v needs no shift.
  core::PixelTaggedCloud reference_0based = reference;
  for (auto& u : reference_0based.u) u -= 1.0f;
  const core::PixelComparison as_given = core::compare_by_pixel(ours.cloud, reference);
  const core::PixelComparison c = core::compare_by_pixel(ours.cloud, reference_0based);
  EXPECT_LT(c.distance.median, as_given.distance.median - 0.03) << "the u convention finding no longer holds";
  std::cout << "per pixel vs SLStudio (u as given): median " << as_given.distance.median << " mm, p90 "
            << as_given.distance.p90 << " mm, p99 " << as_given.distance.p99 << " mm, coverage " << as_given.coverage
            << ", median dz " << as_given.median_signed_z << " mm\n";
  std::cout << "per pixel vs SLStudio (u - 1): median " << c.distance.median << " mm, p90 " << c.distance.p90
            << " mm, p99 " << c.distance.p99 << " mm, coverage " << c.coverage << ", median dz " << c.median_signed_z
            << " mm\n";
  // Measured figures (docs/real-data.md): median 0.314, p90 0.92, p99 3.52 mm, coverage 0.956.
  // The issue's target is a median <= 0.30 mm; we are at 0.314 (open: see the doc). These
  // bounds catch any regression of the decode, the triangulation or the import.
  EXPECT_LE(c.distance.median, 0.33);
  EXPECT_LE(c.distance.p90, 1.0);
  EXPECT_LE(c.distance.p99, 3.7);
  EXPECT_GE(c.coverage, 0.95);
  EXPECT_LT(std::abs(c.median_signed_z), 0.08) << "a depth bias: wrong column offset or pose";

  // SLSCAN_REAL_DATA_OUT=DIR: also write our cloud (with u, v) and the pictures of
  // docs/real-data.md (docs/images/real_skull_{ours,reference}.png).
  if (const char* out = std::getenv("SLSCAN_REAL_DATA_OUT")) {
    auto picture = [&](const core::PixelTaggedCloud& tagged, const std::string& name) {
      core::PointCloud cloud;
      cloud.points = tagged.points;
      cloud.normals = core::pca_normals(cloud);
      // Normals towards the camera (at the origin) for the shading.
      for (std::size_t i = 0; i < cloud.size(); ++i)
        if (cloud.normals[i].dot(cloud.points[i]) > 0) cloud.normals[i] = -cloud.normals[i];
      const auto png = app::render_preview_png(cloud, 90.0, -90.0, 640);
      io::write_file_atomically((fs::path(out) / name).string(),
                                std::string_view(reinterpret_cast<const char*>(png.data()), png.size()));
    };
    picture(ours.cloud, "real_skull_ours.png");
    picture(reference, "real_skull_reference.png");
  }
}

TEST_F(RealSkull, TheOtherPoseDirectionMissesTheReference) {
  // Rp/Tp read as the projector's pose in the camera frame instead of proj_from_cam: the
  // surface lands elsewhere. This is how the direction was decided from the data.
  const Reconstruction wrong = import_and_reconstruct(dir_, "cam_from_proj");
  const core::PixelTaggedCloud reference =
      app::read_pixel_tagged_ply((kData / "reference_cloud.ply").string(), nullptr);
  const core::PixelComparison c = core::compare_by_pixel(wrong.cloud, reference);
  std::cout << "cam_from_proj: median " << c.distance.median << " mm, coverage " << c.coverage << "\n";
  EXPECT_TRUE(c.common_pixels < 1000 || c.distance.median > 10.0) << c.distance.median;
}

}  // namespace
