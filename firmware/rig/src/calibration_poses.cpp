#include "slrig/calibration_poses.hpp"

#include <stdexcept>

#include "slproto/calibration_poses.hpp"

namespace slrig {
using slproto::RigidTransform;

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

  // The poses everyone uses (slproto::calibration_pose_guide): held in front of the camera
  // above the platform's front half, then lying face up on the platform at the six scan angles.
  const slproto::CheckerboardSize size{board.squares_x, board.squares_y, board.square_mm, board.thickness};
  int free_index = 0, table_index = 0;
  for (const slproto::GuidedCalibrationPose& guided : slproto::calibration_pose_guide()) {
    CalibrationPoseSpec pose;
    pose.name = guided.name;
    pose.on_turntable = guided.on_turntable;
    pose.commanded_angle_deg = guided.table_angle_deg;
    pose.scene = empty;
    SceneObject placed = board;
    const RigidTransform board_pose = slproto::guided_board_pose(guided, size);
    placed.table_from_object = board_pose;
    if (!guided.on_turntable) {
      const RigidTransform& cam_from_board = board_pose;
      for (double sx : {-0.5, 0.5})
        for (double sy : {-0.5, 0.5}) {
          const Vec3 corner{middle[0] + sx * board.width, middle[1] + sy * board.height, 0};
          if (table_from_cam.apply(cam_from_board.apply(corner))[2] < 5.0)
            throw std::logic_error("calibration_poses: free pose " + std::to_string(free_index) +
                                   " puts the board into the platform");
        }
      placed.on_turntable = false;
      pose.cam_from_board = cam_from_board;
      pose.view_index = 2 * free_index++;
    } else {
      pose.table_from_board = board_pose;
      pose.view_index = 100 + table_index++;
    }
    pose.scene.objects.push_back(placed);
    poses.push_back(std::move(pose));
  }
  return poses;
}

}  // namespace slrig
