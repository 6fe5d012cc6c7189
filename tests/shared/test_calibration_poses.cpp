// The shared calibration pose set (slproto::calibration_pose_guide): the words the user reads
// agree with the pose the sim board is sent, the ScanRequest field round-trips, and a malformed
// field is refused naming it.
#include <gtest/gtest.h>

#include <cmath>

#include "slproto/calibration_poses.hpp"
#include "slproto/messages.hpp"

namespace {

using slproto::CheckerboardSize;
using slproto::GuidedCalibrationPose;

slproto::pb::ScanRequest valid_request() {
  slproto::pb::ScanRequest request;
  request.set_scan_id(1);
  request.add_turntable_angles_deg(0);
  request.add_projectors(0);
  *request.mutable_plan() = slproto::to_proto(slproto::PatternPlanConfig{});
  request.set_exposure_us(2000);
  request.set_pattern_period_us(5000);
  request.set_pixel_format(slproto::pb::PIXEL_FORMAT_MONO8);
  return request;
}

TEST(CalibrationPoses, FourteenFreePosesThenTheSixScanAngles) {
  const auto& guide = slproto::calibration_pose_guide();
  ASSERT_EQ(guide.size(), 20u);
  for (std::size_t i = 0; i < 14; ++i) {
    EXPECT_EQ(guide[i].name, "free " + std::to_string(i));
    EXPECT_FALSE(guide[i].on_turntable);
    EXPECT_FALSE(guide[i].instruction().empty());
  }
  for (std::size_t k = 0; k < 6; ++k) {
    EXPECT_TRUE(guide[14 + k].on_turntable);
    EXPECT_EQ(guide[14 + k].table_angle_deg, 60.0 * static_cast<double>(k));
    // Only the first table pose needs the user: the board turns the table for the others.
    EXPECT_EQ(guide[14 + k].instruction().empty(), k != 0);
  }
}

// The instruction's "which edge toward you" is what the pose sent to the sim board does.
TEST(CalibrationPoses, InstructionsDescribeThePose) {
  const CheckerboardSize board;
  const double w = (board.squares_x - 2) * board.square_mm, h = (board.squares_y - 2) * board.square_mm;
  for (const GuidedCalibrationPose& pose : slproto::calibration_pose_guide()) {
    if (pose.on_turntable) continue;
    const slproto::RigidTransform cam_from_board = slproto::guided_board_pose(pose, board);
    const auto middle = cam_from_board.apply({w / 2, h / 2, 0});
    EXPECT_NEAR(middle[0], pose.offset_x_mm, 1e-9) << pose.name;
    EXPECT_NEAR(middle[1], pose.offset_y_mm, 1e-9) << pose.name;
    EXPECT_NEAR(middle[2], pose.distance_mm, 1e-9) << pose.name;
    const std::string text = pose.instruction();
    // Edge midpoints before the spin: undo the spin to find the board's own right / top edges.
    slproto::RigidTransform tilt =
        slproto::RigidTransform::rotation_about_axis({1, 0, 0}, {0, 0, 0}, pose.tilt_x_deg * M_PI / 180) *
        slproto::RigidTransform::rotation_about_axis({0, 1, 0}, {0, 0, 0}, pose.tilt_y_deg * M_PI / 180);
    const double right_z = tilt.rotate({1, 0, 0})[2], top_z = tilt.rotate({0, -1, 0})[2];
    if (pose.tilt_y_deg != 0) {
      EXPECT_NE(text.find(right_z < 0 ? "right edge toward you" : "left edge toward you"), std::string::npos)
          << pose.name << ": " << text;
    }
    if (pose.tilt_x_deg != 0) {
      EXPECT_NE(text.find(top_z < 0 ? "top edge toward you" : "bottom edge toward you"), std::string::npos)
          << pose.name << ": " << text;
    }
    EXPECT_NE(text.find(pose.offset_x_mm < 0 ? "to the left" : "to the right"), std::string::npos) << text;
  }
}

TEST(CalibrationPoses, TheScanRequestFieldRoundTrips) {
  const CheckerboardSize board{10, 7, 20, 4};
  for (const GuidedCalibrationPose& pose : slproto::calibration_pose_guide()) {
    slproto::pb::ScanRequest request = valid_request();
    *request.mutable_calibration_target() = slproto::to_proto(pose, board);
    ASSERT_TRUE(slproto::check_scan_request(request, 2).ok()) << pose.name;
    auto placed = slproto::from_proto(request.calibration_target());
    ASSERT_TRUE(placed.ok()) << placed.error().message;
    EXPECT_EQ(placed->pose_name, pose.name);
    EXPECT_EQ(placed->on_turntable, pose.on_turntable);
    EXPECT_EQ(placed->board.squares_x, 10);
    EXPECT_EQ(placed->board.thickness_mm, 4);
    EXPECT_EQ(placed->pose, slproto::guided_board_pose(pose, board)) << pose.name;
  }
}

TEST(CalibrationPoses, AMalformedTargetIsRefusedNamingIt) {
  const slproto::pb::CalibrationTarget good =
      slproto::to_proto(slproto::calibration_pose_guide().front(), CheckerboardSize{});
  auto refused = [&](auto&& spoil) {
    slproto::pb::ScanRequest request = valid_request();
    *request.mutable_calibration_target() = good;
    spoil(*request.mutable_calibration_target());
    const slproto::Status status = slproto::check_scan_request(request, 2);
    EXPECT_FALSE(status.ok());
    return status.ok() ? std::string() : status.error().message;
  };
  EXPECT_NE(refused([](auto& t) { t.mutable_rotation()->RemoveLast(); }).find("calibration_target: rotation needs 9"),
            std::string::npos);
  EXPECT_NE(refused([](auto& t) { t.set_rotation(0, 2.0); }).find("calibration_target"), std::string::npos);
  EXPECT_NE(refused([](auto& t) { t.set_squares_x(2); }).find("2 x 7 squares"), std::string::npos);
  EXPECT_NE(refused([](auto& t) { t.set_square_mm(-1); }).find("square_mm"), std::string::npos);
  EXPECT_NE(refused([](auto& t) { t.set_translation_mm(0, NAN); }).find("translation_mm"), std::string::npos);
}

}  // namespace
