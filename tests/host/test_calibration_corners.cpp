// The image side of calibration without the virtual rig: checkerboard corners in a synthetic
// image with known geometry, and projector coordinates at corners through local homographies
// fitted to synthetic decoded maps.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <random>

#include "slscan/core/calibration_corners.hpp"

namespace slscan::core {
namespace {

// Camera pixel -> target mm for a board seen under a known homography; the image is rendered
// by supersampling each pixel 8 x 8 (the board's edges are anti-aliased as a lens would).
struct SyntheticBoard {
  CheckerboardTarget target{10, 7, 12.0, 0.0};
  cv::Matx33d pixel_from_board;  // homography: board mm (x, y, 1) -> pixel
  cv::Mat image;

  SyntheticBoard() {
    // A perspective view of the board's middle at the image centre, about 2 px per mm.
    const cv::Matx33d k(2.0, 0.0, 176.0, 0.0, 2.0, 128.0, 0.0, 0.0, 1.0);
    const cv::Matx33d tilt(1.0, 0.05, -48.0, -0.03, 1.0, -30.0, 0.0006, -0.0008, 1.0);
    pixel_from_board = k * tilt;
    const cv::Matx33d board_from_pixel = pixel_from_board.inv();
    image.create(256, 352, CV_8UC1);
    std::mt19937 rng(4);
    std::normal_distribution<double> noise(0.0, 1.0);
    for (int v = 0; v < image.rows; ++v)
      for (int u = 0; u < image.cols; ++u) {
        double sum = 0;
        for (int sy = 0; sy < 8; ++sy)
          for (int sx = 0; sx < 8; ++sx) {
            const cv::Vec3d p = board_from_pixel * cv::Vec3d(u - 0.5 + (sx + 0.5) / 8, v - 0.5 + (sy + 0.5) / 8, 1.0);
            const double x = p[0] / p[2], y = p[1] / p[2];
            const double fx = std::floor(x / target.square_mm), fy = std::floor(y / target.square_mm);
            const bool on_board = fx >= -1 && fy >= -1 && fx <= target.squares_x - 2 && fy <= target.squares_y - 2;
            const bool dark = on_board && (static_cast<long>(fx + fy) % 2 == 0);
            sum += dark ? 20.0 : 200.0;
          }
        image.at<std::uint8_t>(v, u) = cv::saturate_cast<std::uint8_t>(sum / 64.0 + noise(rng));
      }
  }
  Eigen::Vector2d pixel(int id) const {
    const Eigen::Vector3d c = target.corner(id);
    const cv::Vec3d p = pixel_from_board * cv::Vec3d(c(0), c(1), 1.0);
    return {p[0] / p[2], p[1] / p[2]};
  }
};

TEST(CalibrationCorners, FindsEveryCornerToATenthOfAPixel) {
  const SyntheticBoard board;
  for (bool sector_based : {true, false}) {
    CornerDetectionOptions options;
    options.sector_based = sector_based;
    const CornerDetection found = detect_checkerboard(board.image, board.target, options);
    ASSERT_TRUE(found.found) << found.reason;
    ASSERT_EQ(static_cast<int>(found.view.corners.size()), board.target.corner_count());
    // The grid may be listed from either end (its inner corners are point-symmetric); compare
    // with whichever order matches.
    double forward = 0, backward = 0;
    const int n = board.target.corner_count();
    for (int i = 0; i < n; ++i) {
      forward += (found.view.corners[static_cast<std::size_t>(i)].pixel - board.pixel(i)).squaredNorm();
      backward += (found.view.corners[static_cast<std::size_t>(i)].pixel - board.pixel(n - 1 - i)).squaredNorm();
    }
    const double rms = std::sqrt(std::min(forward, backward) / n);
    EXPECT_LT(rms, 0.1) << (sector_based ? "sector based only" : "sector based, classic fallback");
  }
}

// A large image is searched at half size (the 352 x 256 board counts as large here): the
// corners, refined on the full image, are as close to the truth as a full-size search's and
// agree with them.
TEST(CalibrationCorners, ALargeImageIsSearchedAtHalfSizeAndRefinedAtFullSize) {
  const SyntheticBoard board;
  CornerDetectionOptions whole;
  whole.search_max_pixels = 0;
  CornerDetectionOptions halved;
  halved.search_max_pixels = 10'000;
  const CornerDetection at_full = detect_checkerboard(board.image, board.target, whole);
  const CornerDetection at_half = detect_checkerboard(board.image, board.target, halved);
  ASSERT_TRUE(at_full.found) << at_full.reason;
  ASSERT_TRUE(at_half.found) << at_half.reason;
  EXPECT_EQ(at_full.search_scale, 1);
  EXPECT_EQ(at_half.search_scale, 2);
  const int n = board.target.corner_count();
  ASSERT_EQ(static_cast<int>(at_half.view.corners.size()), n);
  double forward = 0, backward = 0, largest_difference = 0;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector2d p = at_half.view.corners[static_cast<std::size_t>(i)].pixel;
    forward += (p - board.pixel(i)).squaredNorm();
    backward += (p - board.pixel(n - 1 - i)).squaredNorm();
    largest_difference =
        std::max(largest_difference, (p - at_full.view.corners[static_cast<std::size_t>(i)].pixel).norm());
  }
  EXPECT_LT(std::sqrt(std::min(forward, backward) / n), 0.1);
  EXPECT_LT(largest_difference, 0.01) << "the half-size search's corners refine to other points";
}

TEST(CalibrationCorners, MissingBoardIsReportedNotThrown) {
  const CheckerboardTarget target{10, 7, 12.0, 0.0};
  const cv::Mat blank(240, 320, CV_8UC1, cv::Scalar(90));
  const CornerDetection found = detect_checkerboard(blank, target);
  EXPECT_FALSE(found.found);
  EXPECT_NE(found.reason.find("9 x 6"), std::string::npos) << found.reason;
  EXPECT_FALSE(detect_checkerboard(cv::Mat(), target).found);
  EXPECT_THROW(detect_checkerboard(cv::Mat(10, 10, CV_32FC1), target), std::invalid_argument);
}

// Decoded maps from a known camera -> projector homography, with decode noise, masked dark
// squares and a few wrong-order outliers.
struct SyntheticMaps {
  cv::Matx33d proj_from_pixel{1.9, 0.15, 210.0, -0.1, 2.1, 95.0, 1e-4, -2e-4, 1.0};
  DecodedView columns, rows;
  SyntheticMaps(int width, int height) {
    columns.width = rows.width = width;
    columns.height = rows.height = height;
    columns.axis = slproto::CodingAxis::columns;
    rows.axis = slproto::CodingAxis::rows;
    const std::size_t n = static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
    columns.coordinate.assign(n, NAN);
    rows.coordinate.assign(n, NAN);
    std::mt19937 rng(8);
    std::normal_distribution<double> noise(0.0, 0.1);
    std::uniform_real_distribution<double> uniform(0.0, 1.0);
    for (int v = 0; v < height; ++v)
      for (int u = 0; u < width; ++u) {
        if (((u / 10) + (v / 10)) % 2 == 0) continue;  // "dark squares" do not decode
        const cv::Vec3d p = proj_from_pixel * cv::Vec3d(u, v, 1.0);
        const std::size_t k =
            static_cast<std::size_t>(v) * static_cast<std::size_t>(width) + static_cast<std::size_t>(u);
        const double outlier = uniform(rng) < 0.02 ? 8.0 : 0.0;  // a fringe order off by one
        columns.coordinate[k] = static_cast<float>(p[0] / p[2] + noise(rng) + outlier);
        rows.coordinate[k] = static_cast<float>(p[1] / p[2] + noise(rng));
      }
  }
  Eigen::Vector2d truth(const Eigen::Vector2d& pixel) const {
    const cv::Vec3d p = proj_from_pixel * cv::Vec3d(pixel(0), pixel(1), 1.0);
    return {p[0] / p[2], p[1] / p[2]};
  }
};

TEST(CalibrationCorners, LocalHomographyGivesProjectorCoordinates) {
  const SyntheticMaps maps(200, 160);
  TargetView corners;
  corners.name = "synthetic";
  int id = 0;
  for (int v = 30; v <= 130; v += 20)
    for (int u = 30; u <= 170; u += 20) corners.corners.push_back({id++, {u + 0.37, v - 0.21}});
  const ProjectorCorners result = projector_corners(corners, maps.columns, maps.rows);
  ASSERT_EQ(result.view.corners.size(), corners.corners.size());
  double worst = 0;
  for (std::size_t i = 0; i < corners.corners.size(); ++i) {
    EXPECT_EQ(result.view.corners[i].id, corners.corners[i].id);
    worst = std::max(worst, (result.view.corners[i].pixel - maps.truth(corners.corners[i].pixel)).norm());
  }
  // 0.1 px decode noise averaged over ~200 pixels per window: a few hundredths of a pixel.
  EXPECT_LT(worst, 0.05);
  EXPECT_LT(result.mean_fit_rms_px, 0.2);
}

TEST(CalibrationCorners, CornersWithoutDecodedPixelsAreRejected) {
  SyntheticMaps maps(120, 100);
  // Wipe the decode around (60, 50): the projector does not reach there.
  for (int v = 28; v < 73; ++v)
    for (int u = 38; u < 83; ++u)
      maps.columns.coordinate[static_cast<std::size_t>(v) * 120 + static_cast<std::size_t>(u)] = NAN;
  TargetView corners;
  corners.corners = {{0, {30, 30}}, {1, {60, 50}}, {2, {90, 70}}};
  const ProjectorCorners result = projector_corners(corners, maps.columns, maps.rows);
  ASSERT_EQ(result.view.corners.size(), 2u);
  EXPECT_EQ(result.view.corners[0].id, 0);
  EXPECT_EQ(result.view.corners[1].id, 2);
  EXPECT_EQ(result.rejected_few_pixels, 1);

  DecodedView wrong = maps.rows;
  wrong.width = 60;
  EXPECT_THROW(projector_corners(corners, maps.columns, wrong), std::invalid_argument);
  EXPECT_THROW(projector_corners(corners, maps.columns, maps.columns), std::invalid_argument);
}

}  // namespace
}  // namespace slscan::core
