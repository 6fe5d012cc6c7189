// A calibration capture folder read pose by pose (io::CalibrationCaptureFolder): the manifest at
// once and each pose's images when asked, so `slscan calibrate FOLDER` holds one pose's images,
// and a broken image is reported with its file when its pose is read.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "slscan/io/calibration_capture_files.hpp"
#include "slscan/io/io_error.hpp"

namespace slscan::io {
namespace {

namespace fs = std::filesystem;

class CalibrationCaptureFolderTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("slscan_capture_folder_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    capture_.poses = {{"free 0", false, 0}, {"table 0", true, 0}};
    for (int pose = 0; pose < 2; ++pose)
      for (std::size_t pattern = 0; pattern < 3; ++pattern) {
        core::CalibrationFrame frame;
        frame.pose = pose;
        frame.pattern_index = pattern;
        frame.image = cv::Mat(12, 16, CV_8UC1, cv::Scalar(static_cast<double>(10 * pose + pattern)));
        capture_.frames.push_back(frame);
      }
    folder_ = (dir_ / "capture").string();
    write_calibration_capture(capture_, folder_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  fs::path dir_;
  std::string folder_;
  core::CalibrationCapture capture_;
};

TEST_F(CalibrationCaptureFolderTest, ReadsTheManifestAtOnceAndEachPoseWhenAsked) {
  const CalibrationCaptureFolder folder(folder_);
  ASSERT_EQ(folder.capture().poses.size(), 2u);
  ASSERT_EQ(folder.capture().frames.size(), 6u);
  for (const core::CalibrationFrame& frame : folder.capture().frames) EXPECT_TRUE(frame.image.empty());

  const core::CalibrationCapture pose1 = folder.read_pose(1);
  EXPECT_EQ(pose1.poses.size(), 2u);
  ASSERT_EQ(pose1.frames.size(), 3u);
  for (const core::CalibrationFrame& frame : pose1.frames) {
    EXPECT_EQ(frame.pose, 1);
    ASSERT_EQ(frame.image.size(), cv::Size(16, 12));
    EXPECT_EQ(frame.image.at<std::uint8_t>(0, 0), 10 + frame.pattern_index);
  }
  EXPECT_THROW(folder.read_pose(2), std::invalid_argument);
  EXPECT_THROW(folder.read_pose(-1), std::invalid_argument);
}

TEST_F(CalibrationCaptureFolderTest, ABrokenImageIsNamedWhenItsPoseIsRead) {
  const fs::path missing = fs::path(folder_) / "pose01" / "left_columns_01.png";
  ASSERT_TRUE(fs::remove(missing));
  const CalibrationCaptureFolder folder(folder_);  // the manifest alone is fine
  EXPECT_EQ(folder.read_pose(0).frames.size(), 3u);
  try {
    (void)folder.read_pose(1);
    ADD_FAILURE() << "a missing image was not reported";
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find(missing.string()), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("frames[4]"), std::string::npos) << e.what();
  }
  EXPECT_THROW(read_calibration_capture(folder_), IoError);
}

TEST_F(CalibrationCaptureFolderTest, AnImageOfAnotherSizeNamesTheImageItDiffersFrom) {
  const fs::path other = fs::path(folder_) / "pose01" / "left_columns_02.png";
  ASSERT_TRUE(cv::imwrite(other.string(), cv::Mat(12, 18, CV_8UC1, cv::Scalar(0))));
  const CalibrationCaptureFolder folder(folder_);
  (void)folder.read_pose(0);
  try {
    (void)folder.read_pose(1);
    ADD_FAILURE() << "an image of another size was not reported";
  } catch (const IoError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("18 x 12 differs from 16 x 12 of"), std::string::npos) << what;
    EXPECT_NE(what.find("pose00/left_columns_00.png"), std::string::npos) << what;
  }
}

}  // namespace
}  // namespace slscan::io
