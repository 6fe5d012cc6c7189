// What `reprocess` / `scan` leave in their output folder and what `compare` concludes, on
// synthetic data: the output folder is replaced as a set (issue 17, fault 4), the depth and
// quality pictures scale over a percentile range with a colour bar (issue 20, item 7), and
// `compare` refuses empty clouds and warns (exit 8) when too few points match (issue 17,
// fault 10; issue 20, item 7).
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <set>

#include "config.hpp"
#include "outputs.hpp"
#include "real_data.hpp"
#include "slscan/io/ply.hpp"

namespace slscan::app {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

std::string read_bytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

class TempDir : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("slscan_outputs_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(dir_);
  }
  fs::path dir_;
};

// A view of `width` x `height`: a plane tilted in u (z = 400 + u * 0.1 mm), all measured.
core::OrganizedCloud ramp_cloud(int width, int height) {
  core::OrganizedCloud cloud;
  cloud.resize(width, height);
  for (int v = 0; v < height; ++v)
    for (int u = 0; u < width; ++u) {
      const auto i = static_cast<std::size_t>(v * width + u);
      cloud.points[i] = Eigen::Vector3f(static_cast<float>(u) * 0.1f, static_cast<float>(v) * 0.1f,
                                        400.0f + static_cast<float>(u) * 0.1f);
      cloud.quality[i] = 10.0f + static_cast<float>(u);
      cloud.valid[i] = 1;
    }
  return cloud;
}

cv::Mat decode(const std::vector<unsigned char>& png) { return cv::imdecode(png, cv::IMREAD_UNCHANGED); }

cv::Vec3b colour_of(cv::ColormapTypes map, int grey) {
  cv::Mat one(1, 1, CV_8UC1, cv::Scalar(grey)), out;
  cv::applyColorMap(one, out, map);
  return out.at<cv::Vec3b>(0, 0);
}

std::size_t distinct_colours(const cv::Mat& image, int row, int from, int to) {
  std::set<std::tuple<int, int, int>> colours;
  for (int u = from; u < to; ++u) {
    const auto c = image.at<cv::Vec3b>(row, u);
    colours.insert({c[0], c[1], c[2]});
  }
  return colours.size();
}

TEST(Pictures, DepthColoursSpanTheObjectNotAStraySpeck) {
  const int width = 320, height = 240;
  core::OrganizedCloud cloud = ramp_cloud(width, height);
  // One background speck 10 m away, one pixel not measured: min/max scaling would squeeze the
  // object (400-432 mm) into the first 0.3 % of the colours.
  cloud.points[0].z() = 10000.0f;
  cloud.valid[static_cast<std::size_t>(5 * width + 5)] = 0;
  const cv::Mat image = decode(depth_picture_png(core::SparseOrganizedCloud::of(cloud)));
  ASSERT_FALSE(image.empty());
  ASSERT_EQ(image.type(), CV_8UC3);
  EXPECT_EQ(image.cols, width);
  ASSERT_GT(image.rows, height) << "no colour bar below the picture";
  // The object spans the scale: the 1st and 99th percentile of z sit at the scale's ends.
  EXPECT_GT(distinct_colours(image, height / 2, 0, width), 150u);
  const cv::Vec3b low = colour_of(cv::COLORMAP_TURBO, 0), high = colour_of(cv::COLORMAP_TURBO, 255);
  EXPECT_EQ(image.at<cv::Vec3b>(height / 2, 0), low);
  EXPECT_EQ(image.at<cv::Vec3b>(height / 2, width - 1), high);
  EXPECT_EQ(image.at<cv::Vec3b>(0, 0), high) << "beyond the range: the end colour";
  EXPECT_EQ(image.at<cv::Vec3b>(5, 5), cv::Vec3b(0, 0, 0)) << "not measured: black";
  // The bar: the colour map from its low end (left) to its high end (right), with labels.
  int bar_row = -1;
  for (int v = height; v < image.rows && bar_row < 0; ++v)
    if (distinct_colours(image, v, 0, width) > 100) bar_row = v;
  ASSERT_GE(bar_row, 0) << "no colour scale in the panel below the picture";
  int left = 0;
  while (left < width && image.at<cv::Vec3b>(bar_row, left) == cv::Vec3b(0, 0, 0)) ++left;
  int right = width - 1;
  while (right > 0 && image.at<cv::Vec3b>(bar_row, right) == cv::Vec3b(0, 0, 0)) --right;
  EXPECT_EQ(image.at<cv::Vec3b>(bar_row, left), low);
  EXPECT_EQ(image.at<cv::Vec3b>(bar_row, right), high);
  std::size_t white = 0;  // the labels (range and "1st-99th percentile"), white (antialiased)
  for (int v = bar_row; v < image.rows; ++v)
    for (int u = 0; u < width; ++u) {
      const cv::Vec3b c = image.at<cv::Vec3b>(v, u);
      white += std::min({c[0], c[1], c[2]}) > 150 ? 1 : 0;
    }
  EXPECT_GT(white, 100u);
}

TEST(Pictures, QualityHasAPercentileScaleAndABar) {
  const int width = 320, height = 240;
  core::OrganizedCloud cloud = ramp_cloud(width, height);
  cloud.quality[0] = 1e6f;  // one saturated-looking pixel
  const cv::Mat image = decode(quality_picture_png(core::SparseOrganizedCloud::of(cloud)));
  ASSERT_FALSE(image.empty());
  ASSERT_GT(image.rows, height);
  EXPECT_GT(distinct_colours(image, height / 2, 0, width), 150u);
  EXPECT_EQ(image.at<cv::Vec3b>(height / 2, 0), colour_of(cv::COLORMAP_VIRIDIS, 0));
  // An empty view still gives a picture (black, the bar saying nothing was measured).
  core::OrganizedCloud empty;
  empty.resize(64, 48);
  const cv::Mat blank = decode(quality_picture_png(core::SparseOrganizedCloud::of(empty)));
  ASSERT_FALSE(blank.empty());
  EXPECT_EQ(blank.at<cv::Vec3b>(10, 10), cv::Vec3b(0, 0, 0));
}

// A synthetic reconstruction: `views` views (each a small ramp), a model of `model_points`
// points, and a tetrahedron as the mesh when `meshed`.
core::ScanResult synthetic_result(int views, std::size_t model_points, bool meshed) {
  core::ScanResult result;
  for (int i = 0; i < views; ++i) {
    core::ViewReport report;
    report.view_index = i;
    result.views.push_back(report);
    core::ViewProducts products;
    products.cloud = core::SparseOrganizedCloud::of(ramp_cloud(64, 48));
    products.source.assign(products.cloud.size(), core::FusionSource::both);
    for (std::size_t k = 0; k < products.cloud.size(); ++k) {
      products.points.points.push_back(products.cloud.points[k]);
      products.points.normals.emplace_back(0.0f, 0.0f, -1.0f);
    }
    result.view_products.push_back(std::move(products));
  }
  for (std::size_t k = 0; k < model_points; ++k) {
    result.model.points.emplace_back(static_cast<float>(k % 100), static_cast<float>(k / 100), 1.0f);
    result.model.normals.emplace_back(0.0f, 0.0f, 1.0f);
  }
  if (meshed) {
    result.meshed = true;
    result.mesh.mesh.vertices = {{0, 0, 0}, {10, 0, 0}, {0, 10, 0}, {0, 0, 10}};
    result.mesh.mesh.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  }
  return result;
}

std::map<std::string, std::string> snapshot(const fs::path& dir) {
  std::map<std::string, std::string> files;
  for (const auto& entry : fs::recursive_directory_iterator(dir))
    files[fs::relative(entry.path(), dir).generic_string()] =
        entry.is_regular_file() ? read_bytes(entry.path()) : std::string("<folder>");
  return files;
}

TEST_F(TempDir, ANewRunReplacesTheWholeSetAndKeepsTheCapture) {
  const fs::path out = dir_ / "out";
  const OutputFiles first = write_scan_outputs(out.string(), synthetic_result(3, 500, true), json{{"run", 1}});
  EXPECT_EQ(first.model_ply, (out / "model.ply").string());
  ASSERT_TRUE(fs::exists(out / "mesh.stl"));
  ASSERT_TRUE(fs::exists(out / "views" / "view_2.ply"));
  ASSERT_TRUE(fs::exists(out / "pictures" / "view_2_depth.png"));
  // What is not the set's own stays: the capture, and anything else the user put there.
  std::ofstream(out / "capture.slcap") << "the capture";
  std::ofstream(out / "notes.txt") << "mine";

  const OutputFiles second = write_scan_outputs(out.string(), synthetic_result(2, 300, false), json{{"run", 2}});
  EXPECT_EQ(second.report_json, (out / "report.json").string());
  const json report = json::parse(read_bytes(out / "report.json"));
  EXPECT_EQ(report["run"], 2);
  EXPECT_EQ(io::read_ply((out / "model.ply").string()).size(), 300u);
  // Nothing of the first run is left beside the second's.
  EXPECT_FALSE(fs::exists(out / "mesh.stl"));
  EXPECT_FALSE(fs::exists(out / "mesh.ply"));
  EXPECT_FALSE(fs::exists(out / "views" / "view_2.ply"));
  EXPECT_FALSE(fs::exists(out / "pictures" / "view_2_depth.png"));
  EXPECT_TRUE(fs::exists(out / "views" / "view_1.ply"));
  EXPECT_EQ(read_bytes(out / "capture.slcap"), "the capture");
  EXPECT_EQ(read_bytes(out / "notes.txt"), "mine");
  // No staging folder or temporary file is left, and report.json is the newest file (the
  // completion marker: docs/cli.md).
  const auto marker = fs::last_write_time(out / "report.json");
  for (const auto& entry : fs::recursive_directory_iterator(out)) {
    const std::string name = entry.path().filename().string();
    EXPECT_NE(name.rfind(".slscan-", 0), 0u) << entry.path();
    EXPECT_EQ(name.find(".tmp"), std::string::npos) << entry.path();
    if (entry.is_regular_file() && name != "capture.slcap" && name != "notes.txt") {
      EXPECT_LE(fs::last_write_time(entry.path()), marker) << entry.path();
    }
  }
}

TEST_F(TempDir, AFailedWriteLeavesThePreviousSetAsItWas) {
  const fs::path out = dir_ / "out";
  (void)write_scan_outputs(out.string(), synthetic_result(2, 500, true), json{{"run", 1}});
  const auto before = snapshot(out);
  // The second run fails after its model, views and pictures are written: its report cannot
  // be serialised (a string that is not UTF-8). The disk-full case, with the real slscan and a
  // file-size limit, is in tests/integration/test_faults.cpp.
  json bad = {{"run", 2}};
  bad["not utf-8"] = std::string("\xff\xfe");
  EXPECT_ANY_THROW((void)write_scan_outputs(out.string(), synthetic_result(1, 300, false), bad));
  EXPECT_EQ(snapshot(out), before) << "the failed run changed the previous set";
}

TEST_F(TempDir, CompareRefusesEmptyCloudsAndWarnsWhenTooFewPointsMatch) {
  core::PointCloud plane;
  for (int i = 0; i < 2000; ++i)
    plane.points.emplace_back(static_cast<float>(i % 50), static_cast<float>(i / 50),
                              0.01f * static_cast<float>(i % 7));
  core::PointCloud shifted = plane;
  for (auto& p : shifted.points) p.x() += 200.0f;  // the same surface in another frame
  io::write_ply((dir_ / "plane.ply").string(), plane, {});
  io::write_ply((dir_ / "shifted.ply").string(), shifted, {});
  io::write_ply((dir_ / "empty.ply").string(), core::PointCloud{}, {});
  const Console quiet{.quiet = true, .json_log = false};

  CompareCommand same;
  same.measured_path = (dir_ / "plane.ply").string();
  same.reference_path = (dir_ / "plane.ply").string();
  same.report_path = (dir_ / "same.json").string();
  EXPECT_EQ(run_compare(same, quiet), exit_ok);
  EXPECT_DOUBLE_EQ(json::parse(read_bytes(dir_ / "same.json"))["matched_share"].get<double>(), 1.0);

  // Different frames: nothing within 5 mm; a warning naming the likely cause, exit 8.
  CompareCommand apart = same;
  apart.measured_path = (dir_ / "shifted.ply").string();
  apart.report_path = (dir_ / "apart.json").string();
  ::testing::internal::CaptureStderr();
  EXPECT_EQ(run_compare(apart, quiet), exit_unmatched);
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(err.find("different frames"), std::string::npos) << err;
  EXPECT_NE(err.find("--min-matched"), std::string::npos) << err;
  const json report = json::parse(read_bytes(dir_ / "apart.json"));
  EXPECT_EQ(report["matched_share"].get<double>(), 0.0);
  EXPECT_NE(report["warning"].get<std::string>().find("align them first"), std::string::npos);
  // ...and with the share lowered to 0 it is the caller's call.
  apart.min_matched = 0;
  EXPECT_EQ(run_compare(apart, quiet), exit_ok);

  // An empty cloud is an error naming the file, with nothing written.
  for (const bool measured_empty : {true, false}) {
    CompareCommand empty = same;
    (measured_empty ? empty.measured_path : empty.reference_path) = (dir_ / "empty.ply").string();
    empty.report_path = (dir_ / "empty.json").string();
    try {
      (void)run_compare(empty, quiet);
      ADD_FAILURE() << "an empty cloud was compared";
    } catch (const io::IoError& e) {
      EXPECT_NE(std::string(e.what()).find("empty.ply"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("no points"), std::string::npos) << e.what();
    }
    EXPECT_FALSE(fs::exists(dir_ / "empty.json"));
  }
  // A negative or zero distance is refused.
  for (const double distance : {-1.0, 0.0}) {
    CompareCommand bad = same;
    bad.max_distance_mm = distance;
    bad.report_path = (dir_ / "bad.json").string();
    EXPECT_THROW((void)run_compare(bad, quiet), std::invalid_argument);
    EXPECT_FALSE(fs::exists(dir_ / "bad.json"));
  }
}

TEST(AppConfigBounds, VoxelSizeOutsideAMicronToAMetreIsRefused) {
  for (const double voxel : {1e-300, 1e-4, 5000.0, -1.0}) {
    core::ReconstructionOptions options;
    try {
      apply_config(json{{"model", {{"voxel_mm", voxel}}}}, options);
      ADD_FAILURE() << "voxel_mm " << voxel << " accepted";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("voxel_mm"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("[0.001, 1000]"), std::string::npos) << e.what();
    }
  }
  for (const double voxel : {0.0, 0.001, 0.5, 1000.0}) {
    core::ReconstructionOptions options;
    EXPECT_NO_THROW(apply_config(json{{"model", {{"voxel_mm", voxel}}}}, options)) << voxel;
  }
}

}  // namespace
}  // namespace slscan::app
