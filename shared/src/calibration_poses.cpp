#include "slproto/calibration_poses.hpp"

#include <array>
#include <cmath>
#include <cstdio>
#include <numbers>

namespace slproto {
namespace {

RigidTransform rotation(const Vec3& axis, double deg) {
  return RigidTransform::rotation_about_axis(axis, {0, 0, 0}, deg * std::numbers::pi / 180.0);
}

std::vector<GuidedCalibrationPose> make_guide() {
  // tilt x, tilt y, spin, offset x, offset y, distance
  const std::array<std::array<double, 6>, 14> free_poses{{{25, 0, 5, -20, -10, 440},
                                                          {-25, 0, -5, 15, -15, 460},
                                                          {0, 30, 10, 20, -5, 450},
                                                          {0, -30, -10, -15, -20, 470},
                                                          {20, 20, 0, 0, -10, 430},
                                                          {-20, -20, 15, 10, -5, 480},
                                                          {20, -25, -15, -25, -15, 460},
                                                          {-25, 20, 20, 25, -10, 445},
                                                          {10, 35, 0, 0, -20, 490},
                                                          {-35, -10, -20, 5, -5, 435},
                                                          {0, 45, 5, -50, -25, 480},
                                                          {0, -45, -5, 50, -25, 480},
                                                          {45, 0, 10, -35, -40, 470},
                                                          {-45, 10, -10, 35, -15, 470}}};
  std::vector<GuidedCalibrationPose> out;
  for (std::size_t p = 0; p < free_poses.size(); ++p) {
    const auto& a = free_poses[p];
    GuidedCalibrationPose pose;
    pose.name = "free " + std::to_string(p);
    pose.tilt_x_deg = a[0];
    pose.tilt_y_deg = a[1];
    pose.spin_deg = a[2];
    pose.offset_x_mm = a[3];
    pose.offset_y_mm = a[4];
    pose.distance_mm = a[5];
    out.push_back(pose);
  }
  // Lying face up on the platform, off the axis.
  for (int k = 0; k < 6; ++k) {
    GuidedCalibrationPose pose;
    pose.name = "table " + std::to_string(60 * k);
    pose.on_turntable = true;
    pose.table_angle_deg = 60.0 * k;
    pose.spin_deg = 15;
    pose.offset_x_mm = 25;
    pose.offset_y_mm = -10;
    out.push_back(pose);
  }
  return out;
}

}  // namespace

std::string GuidedCalibrationPose::instruction() const {
  char text[320];
  if (on_turntable) {
    if (table_angle_deg != 0) return {};
    std::snprintf(text, sizeof text,
                  "lay the board face up on the platform, off centre (its middle about %.0f mm right of and %.0f mm "
                  "%s the axis), wholly in view at every angle; do not touch it until the table poses are done",
                  offset_x_mm, std::abs(offset_y_mm), offset_y_mm < 0 ? "in front of" : "behind");
    return text;
  }
  std::snprintf(text, sizeof text,
                "hold the board facing the camera, %.0f mm away, its middle %.0f mm to the %s of and %.0f mm %s "
                "the camera's axis; tilt it %.0f deg about the horizontal (%s), %.0f deg about the vertical (%s), "
                "spun %.0f deg in its plane",
                distance_mm, std::abs(offset_x_mm), offset_x_mm < 0 ? "left" : "right", std::abs(offset_y_mm),
                offset_y_mm < 0 ? "above" : "below", std::abs(tilt_x_deg),
                // The camera frame: x right, y down, z forward (docs/conventions.md).
                tilt_x_deg == 0 ? "upright" : (tilt_x_deg > 0 ? "top edge toward you" : "bottom edge toward you"),
                std::abs(tilt_y_deg),
                tilt_y_deg == 0 ? "square" : (tilt_y_deg > 0 ? "right edge toward you" : "left edge toward you"),
                spin_deg);
  return text;
}

const std::vector<GuidedCalibrationPose>& calibration_pose_guide() {
  static const std::vector<GuidedCalibrationPose> guide = make_guide();
  return guide;
}

RigidTransform guided_board_pose(const GuidedCalibrationPose& pose, const CheckerboardSize& board) {
  // The board's middle (its squares' centre) in its own frame.
  const Vec3 middle{(board.squares_x - 2) * board.square_mm / 2, (board.squares_y - 2) * board.square_mm / 2, 0};
  if (!pose.on_turntable) {
    RigidTransform cam_from_board = rotation({1, 0, 0}, pose.tilt_x_deg) * rotation({0, 1, 0}, pose.tilt_y_deg) *
                                    rotation({0, 0, 1}, pose.spin_deg);
    const Vec3 m = cam_from_board.rotate(middle);
    cam_from_board.t = {pose.offset_x_mm - m[0], pose.offset_y_mm - m[1], pose.distance_mm - m[2]};
    return cam_from_board;
  }
  // Face up: the board's z (into it) points down.
  RigidTransform table_from_board = rotation({0, 0, 1}, pose.spin_deg) * rotation({1, 0, 0}, 180);
  const Vec3 m = table_from_board.rotate(middle);
  table_from_board.t = {pose.offset_x_mm - m[0], pose.offset_y_mm - m[1], board.thickness_mm - m[2]};
  return table_from_board;
}

pb::CalibrationTarget to_proto(const GuidedCalibrationPose& pose, const CheckerboardSize& board) {
  pb::CalibrationTarget out;
  out.set_pose_name(pose.name);
  out.set_squares_x(static_cast<std::uint32_t>(board.squares_x));
  out.set_squares_y(static_cast<std::uint32_t>(board.squares_y));
  out.set_square_mm(board.square_mm);
  out.set_thickness_mm(board.thickness_mm);
  out.set_on_turntable(pose.on_turntable);
  const RigidTransform placed = guided_board_pose(pose, board);
  for (double r : placed.R) out.add_rotation(r);
  for (double t : placed.t) out.add_translation_mm(t);
  return out;
}

Result<CalibrationTargetPlacement> from_proto(const pb::CalibrationTarget& target) {
  auto bad = [](const std::string& what) {
    return make_error(Errc::invalid_argument, "scan request: calibration_target: " + what);
  };
  CalibrationTargetPlacement out;
  out.pose_name = target.pose_name();
  if (target.squares_x() < 3 || target.squares_x() > 100 || target.squares_y() < 3 || target.squares_y() > 100)
    return bad(std::to_string(target.squares_x()) + " x " + std::to_string(target.squares_y()) +
               " squares (each 3 to 100)");
  if (!(target.square_mm() > 0 && target.square_mm() <= 1000) ||
      !(target.thickness_mm() >= 0 && target.thickness_mm() <= 1000))
    return bad("square_mm must be in (0, 1000] and thickness_mm in [0, 1000]");
  out.board = {static_cast<int>(target.squares_x()), static_cast<int>(target.squares_y()), target.square_mm(),
               target.thickness_mm()};
  out.on_turntable = target.on_turntable();
  if (target.rotation_size() != 9 || target.translation_mm_size() != 3)
    return bad("rotation needs 9 values and translation_mm 3 (have " + std::to_string(target.rotation_size()) +
               " and " + std::to_string(target.translation_mm_size()) + ")");
  for (int i = 0; i < 9; ++i) out.pose.R[static_cast<std::size_t>(i)] = target.rotation(i);
  for (int i = 0; i < 3; ++i) {
    out.pose.t[static_cast<std::size_t>(i)] = target.translation_mm(i);
    if (!(std::abs(target.translation_mm(i)) <= 1e5)) return bad("translation_mm is not a finite position");
  }
  if (auto status = out.pose.check("calibration_target"); !status) return bad(status.error().message);
  return out;
}

}  // namespace slproto
