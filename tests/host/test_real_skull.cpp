// The host pipeline on a real capture made by a scanner nobody here built (SLStudio's skull,
// /work/shared/data/slstudio-skull-gray, README there): imported, decoded, triangulated and
// compared pixel for pixel with that scanner's own reconstruction.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>

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

struct ImportedView {
  core::DecodedView decoded;
  slproto::RigCalibration calibration;
};

// Imports the capture, then decodes it as reprocessing does.
ImportedView import_and_decode(const fs::path& dir, const std::string& pose_direction) {
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

  ImportedView out;
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
  out.decoded = decoder->finish();
  return out;
}

// Exact camera-ray / projector-column triangulation (both lenses' distortion), keeping each
// point's camera pixel.
core::PixelTaggedCloud triangulate(const ImportedView& view) {
  const auto rays = std::make_shared<const core::CameraRayTable>(core::CameraRayTable::build(view.calibration.camera));
  const core::ProjectorTriangulator triangulator(rays, view.calibration.projector(slproto::ProjectorSide::left),
                                                 view.decoded.axis);
  const core::TriangulatedView triangulated = triangulator.triangulate(view.decoded);
  core::PixelTaggedCloud out;
  for (std::size_t i = 0; i < triangulated.cloud.size(); ++i) {
    if (!triangulated.cloud.valid[i]) continue;
    out.points.push_back(triangulated.cloud.points[i]);
    out.u.push_back(static_cast<float>(i % static_cast<std::size_t>(triangulated.cloud.width)));
    out.v.push_back(static_cast<float>(i / static_cast<std::size_t>(triangulated.cloud.width)));
  }
  return out;
}

// SLStudio resamples its decoded columns onto the undistorted camera image before
// triangulating, so the reference's stored (u, v) are pixels of that virtual image, not of the
// frames. The camera pixel a reference point came from is its projection through the camera
// model with distortion (what `slscan compare --calib` does for clouds without u/v).
core::PixelTaggedCloud with_projected_pixels(core::PixelTaggedCloud cloud, const slproto::PinholeModel& camera) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (std::size_t i = 0; i < cloud.points.size(); ++i) {
    const Eigen::Vector3f& p = cloud.points[i];
    double u = 0, v = 0;
    const bool inside = camera.project({p.x(), p.y(), p.z()}, u, v) && u >= -0.5 && v >= -0.5 &&
                        u <= camera.width - 0.5 && v <= camera.height - 0.5;
    cloud.u[i] = inside ? static_cast<float>(u) : nan;
    cloud.v[i] = inside ? static_cast<float>(v) : nan;
  }
  return cloud;
}

void print(const char* what, const core::PixelComparison& c) {
  std::cout << what << ": median " << c.distance.median << " mm, p90 " << c.distance.p90 << " mm, p99 "
            << c.distance.p99 << " mm, coverage " << c.coverage << " of " << c.reference_pixels << ", median dz "
            << c.median_signed_z << " mm\n";
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
  const ImportedView view = import_and_decode(dir_, "proj_from_cam");
  const core::PixelTaggedCloud ours = triangulate(view);
  ImportedView slstudio_columns = view;
  app::to_slstudio_gray_columns(slstudio_columns.decoded.coordinate, 1);
  const core::PixelTaggedCloud ours_in_slstudio_columns = triangulate(slstudio_columns);
  // SLStudio's Triangulator also ignores the projector's distortion kp (its column planes are
  // those of Kp, Rp, Tp alone): the full emulation of its reconstruction.
  ImportedView slstudio_model = slstudio_columns;
  slstudio_model.calibration.projectors[0].intrinsics.distortion = {};
  const core::PixelTaggedCloud ours_as_slstudio = triangulate(slstudio_model);

  const core::PixelTaggedCloud reference_as_stored =
      app::read_pixel_tagged_ply((kData / "reference_cloud.ply").string(), nullptr);
  ASSERT_EQ(reference_as_stored.points.size(), 93876u);
  ASSERT_TRUE(reference_as_stored.has_pixels());
  const core::PixelTaggedCloud reference = with_projected_pixels(reference_as_stored, view.calibration.camera);
  // White - black > 20 keeps ~400 k pixels (README); the reference filtered down to ~94 k.
  EXPECT_GT(view.decoded.counts.valid, 350000u);
  EXPECT_LT(view.decoded.counts.valid, 450000u);

  const core::PixelComparison stored_pixels = core::compare_by_pixel(ours, reference_as_stored);
  const core::PixelComparison c = core::compare_by_pixel(ours, reference);
  const core::PixelComparison like_for_like = core::compare_by_pixel(ours_in_slstudio_columns, reference);
  print("ours (column-pair centre) vs reference, stored u/v", stored_pixels);
  print("ours (column-pair centre) vs reference, projected pixels", c);
  const core::PixelComparison emulated = core::compare_by_pixel(ours_as_slstudio, reference);
  print("ours in SLStudio's column convention vs reference, projected pixels", like_for_like);
  print("ours in SLStudio's column convention, projector distortion ignored, vs reference", emulated);

  // Figures of docs/real-data.md; bounds a little above the measured values catch any
  // regression of the import, the decode or the triangulation.
  // 1. Like for like (the reference's own column convention): the issue's target, median <= 0.3.
  //    Measured: median 0.171, p90 0.437, p99 1.90 mm, coverage 0.9615, dz +0.050 mm.
  EXPECT_LE(like_for_like.distance.median, 0.20);
  EXPECT_LE(like_for_like.distance.p90, 0.50);
  EXPECT_LE(like_for_like.distance.p99, 2.1);
  EXPECT_GE(like_for_like.coverage, 0.955);
  EXPECT_LT(std::abs(like_for_like.median_signed_z), 0.08) << "a depth bias: wrong column offset or pose";
  //    With kp ignored as well the depth bias vanishes: median 0.134, p90 0.237 mm, dz +0.006.
  EXPECT_LE(emulated.distance.median, 0.16);
  EXPECT_LE(emulated.distance.p90, 0.28);
  EXPECT_LT(std::abs(emulated.median_signed_z), 0.03) << "SLStudio's reconstruction is no longer reproduced";
  // 2. Our own output (each decoded step at the centre of its two columns). The reference sits
  //    half a column either side of that centre, alternately per step, which is what remains.
  //    Measured: median 0.357, p90 0.652, p99 1.68 mm, coverage 0.9615, dz +0.146 mm.
  EXPECT_LE(c.distance.median, 0.40);
  EXPECT_LE(c.distance.p90, 0.72);
  EXPECT_LE(c.distance.p99, 1.9);
  EXPECT_GE(c.coverage, 0.955);
  EXPECT_LT(like_for_like.distance.median, c.distance.median - 0.1)
      << "the reference no longer looks decoded with SLStudio's column convention";
  // 3. The stored u/v are not the frames' pixels: pairing by them doubles the tail.
  EXPECT_GT(stored_pixels.distance.p99, 1.5 * c.distance.p99) << "the reference pixel finding no longer holds";

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
    picture(ours, "real_skull_ours.png");
    picture(reference, "real_skull_reference.png");
  }
}

TEST_F(RealSkull, TheOtherPoseDirectionMissesTheReference) {
  // Rp/Tp read as the projector's pose in the camera frame instead of proj_from_cam: the
  // surface lands elsewhere. This is how the direction was decided from the data.
  const core::PixelTaggedCloud wrong = triangulate(import_and_decode(dir_, "cam_from_proj"));
  const core::PixelTaggedCloud reference =
      app::read_pixel_tagged_ply((kData / "reference_cloud.ply").string(), nullptr);
  const core::PixelComparison c = core::compare_by_pixel(wrong, reference);
  std::cout << "cam_from_proj: median " << c.distance.median << " mm, coverage " << c.coverage << "\n";
  EXPECT_TRUE(c.common_pixels < 1000 || c.distance.median > 10.0) << c.distance.median;
}

}  // namespace

namespace {

// SLStudio's decoder, bit for bit: the shown Gray bits with the unshown ones read as 0, then
// Gray -> binary by prefix XOR.
int slstudio_decode(int column, int bits_not_projected) {
  int word = ((column >> 1) ^ column) & ~((1 << bits_not_projected) - 1);
  for (int shift = 1; shift < 16; shift <<= 1) word ^= word >> shift;
  return word;
}

TEST(SlstudioGrayColumns, MatchesSlstudiosDecoderForEveryColumn) {
  for (int s = 0; s <= 3; ++s) {
    const int group = 1 << s;
    std::vector<float> centres;  // what our decoder returns for each column's Gray prefix
    for (int x = 0; x < 1824; ++x) centres.push_back(static_cast<float>((x >> s) * group) + 0.5f * (group - 1));
    app::to_slstudio_gray_columns(centres, s);
    for (int x = 0; x < 1824; ++x)
      ASSERT_EQ(centres[static_cast<std::size_t>(x)], static_cast<float>(slstudio_decode(x, s)))
          << "column " << x << ", " << s << " bits not projected";
  }
  std::vector<float> masked{std::numeric_limits<float>::quiet_NaN(), 4.5f};
  app::to_slstudio_gray_columns(masked, 1);
  EXPECT_TRUE(std::isnan(masked[0]));
  EXPECT_EQ(masked[1], 4.0f);  // c = 2 (even): the first of columns 4, 5
  EXPECT_THROW(app::to_slstudio_gray_columns(masked, -1), std::invalid_argument);
}

}  // namespace
