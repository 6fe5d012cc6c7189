#include "slrig/calibration_poses.hpp"

#include <array>
#include <numbers>
#include <stdexcept>

namespace slrig {
namespace {

using slproto::RigidTransform;

RigidTransform rotation(const Vec3& axis, double deg) {
  return RigidTransform::rotation_about_axis(axis, {0, 0, 0}, deg * std::numbers::pi / 180.0);
}

}  // namespace

std::vector<CalibrationPoseSpec> calibration_poses(const Scene& calibration_scene) {
  if (calibration_scene.objects.empty() || calibration_scene.objects.front().kind != ObjectKind::checkerboard)
    throw std::logic_error("calibration_poses: the scene's first object must be the checkerboard");
  Scene empty = calibration_scene;
  const SceneObject board = empty.objects.front();
  empty.objects.clear();
  // The board's middle (its squares' centre) in its own frame.
  const Vec3 middle{(board.squares_x - 2) * board.square_mm / 2, (board.squares_y - 2) * board.square_mm / 2, 0};
  const RigidTransform table_from_cam = empty.turntable.cam_from_table.inverse();
  std::vector<CalibrationPoseSpec> poses;

  // Free poses: held above the platform's front half, facing the camera (the board's z into it
  // along the view), tilted up to 35 degrees about varied axes, filling about half the image
  // width, 430-490 mm from the camera.
  // The last four are steeper and off to the image's sides: perspective across a steep board is
  // what separates the principal point from a small turn of the whole rig.
  const std::array<std::array<double, 6>, 14> free_poses{{// tilt x, tilt y, spin, offset x, offset y, distance
                                                          {25, 0, 5, -20, -10, 440},
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
  for (std::size_t p = 0; p < free_poses.size(); ++p) {
    const auto& a = free_poses[p];
    RigidTransform cam_from_board = rotation({1, 0, 0}, a[0]) * rotation({0, 1, 0}, a[1]) * rotation({0, 0, 1}, a[2]);
    const Vec3 m = cam_from_board.rotate(middle);
    cam_from_board.t = {a[3] - m[0], a[4] - m[1], a[5] - m[2]};
    for (double sx : {-0.5, 0.5})
      for (double sy : {-0.5, 0.5}) {
        const Vec3 corner{middle[0] + sx * board.width, middle[1] + sy * board.height, 0};
        if (table_from_cam.apply(cam_from_board.apply(corner))[2] < 5.0)
          throw std::logic_error("calibration_poses: free pose " + std::to_string(p) +
                                 " puts the board into the platform");
      }
    CalibrationPoseSpec pose;
    pose.name = "free " + std::to_string(p);
    pose.scene = empty;
    SceneObject held = board;
    held.on_turntable = false;
    held.table_from_object = cam_from_board;
    pose.scene.objects.push_back(held);
    pose.cam_from_board = cam_from_board;
    pose.view_index = static_cast<int>(2 * p);
    poses.push_back(std::move(pose));
  }

  // Turntable poses: lying face up on the platform (its z into the board points down), off
  // the axis, at the six scan angles.
  RigidTransform table_from_board = rotation({0, 0, 1}, 15) * rotation({1, 0, 0}, 180);
  const Vec3 m = table_from_board.rotate(middle);
  table_from_board.t = {25 - m[0], -10 - m[1], board.thickness - m[2]};
  for (int k = 0; k < 6; ++k) {
    CalibrationPoseSpec pose;
    pose.on_turntable = true;
    pose.commanded_angle_deg = 60.0 * k;
    pose.name = "table " + std::to_string(60 * k);
    pose.scene = empty;
    SceneObject lying = board;
    lying.table_from_object = table_from_board;
    pose.scene.objects.push_back(lying);
    pose.table_from_board = table_from_board;
    pose.view_index = 100 + k;
    poses.push_back(std::move(pose));
  }
  return poses;
}

}  // namespace slrig
