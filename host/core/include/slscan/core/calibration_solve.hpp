// Calibration from corner correspondences: the camera, each projector (an inverse camera
// whose "image" coordinates are the decoded projector coordinates of the target corners) and
// the turntable axis. No images here: calibration_corners.hpp turns images into the
// TargetViews these functions take, and calibration_rig.hpp runs the whole procedure.
//
// Errors: bad input (too few views or corners, sizes that do not match) throws
// std::invalid_argument naming what and where; a solve that cannot succeed throws
// std::runtime_error.
#pragma once

#include <array>
#include <string>
#include <vector>

#include "slproto/calibration.hpp"
#include "slscan/core/calibration_target.hpp"

namespace slscan::core {

struct LensModelOptions {
  bool tangential = true;  // estimate p1, p2
  bool k3 = false;         // estimate k3 (poorly conditioned with few poses; off by default)
  bool k2 = true;
};

struct DeviceCalibration {
  slproto::PinholeModel model;
  double rms_px = 0;                                 // over every corner of every view
  std::vector<double> view_rms_px;                   // one per input view
  std::vector<slproto::RigidTransform> from_target;  // device_from_target, one per input view
};

// Intrinsics and distortion of a camera from >= `min_views` views of the planar target
// (OpenCV calibrateCamera, then the poses re-solved with the final model).
DeviceCalibration calibrate_camera(const CheckerboardTarget& target, const std::vector<TargetView>& views, int width,
                                   int height, const LensModelOptions& lens = {}, int min_views = 3);

struct ProjectorSolve {
  slproto::ProjectorCalibration calibration;             // intrinsics, cam_from_proj, reprojection RMS
  double camera_rms_px = 0;                              // camera residual of the joint refinement
  std::vector<double> view_rms_px;                       // projector residual per view
  std::vector<slproto::RigidTransform> cam_from_target;  // refined target poses, one per view
};

// One projector: intrinsics from its own views (calibrateCamera on the projector coordinates
// of the corners), extrinsics by cv::stereoCalibrate with both intrinsics fixed, then a joint
// Levenberg-Marquardt refinement of the projector's intrinsics, cam_from_proj and the target
// poses against both devices' corners with the camera model held fixed (it was calibrated
// from more views). `camera_views[i]` and `projector_views[i]` are the same target pose.
ProjectorSolve calibrate_projector(const CheckerboardTarget& target, const slproto::PinholeModel& camera,
                                   const std::vector<TargetView>& camera_views,
                                   const std::vector<TargetView>& projector_views, int projector_width,
                                   int projector_height, const LensModelOptions& lens = {}, int min_views = 3);

// The final bundle adjustment of the whole rig: the camera's intrinsics, both projectors'
// intrinsics and extrinsics and every target pose against every corner of every device at once.
// The separate solves above hold the camera fixed while fitting the projectors; here the
// projectors' corners (many decoded pixels each, so several times more precise than the
// camera's) also pin the target poses, and through them the camera's principal point and focal
// length. Each device's residuals are weighted by the inverse of its RMS from the separate solve.
struct ProjectorObservations {
  std::vector<std::size_t> camera_view;  // index into the camera views of each projector view
  std::vector<TargetView> views;         // the corners' projector coordinates
  slproto::ProjectorCalibration start;   // from calibrate_projector
};
struct RigBundle {
  DeviceCalibration camera;                                 // refined model, RMS, per-view RMS and poses
  std::array<slproto::ProjectorCalibration, 2> projectors;  // refined intrinsics, cam_from_proj, RMS
  std::array<std::vector<double>, 2> projector_view_rms_px;
};
RigBundle refine_rig_jointly(const CheckerboardTarget& target, const DeviceCalibration& camera,
                             const std::vector<TargetView>& camera_views,
                             const std::array<ProjectorObservations, 2>& projectors,
                             const LensModelOptions& camera_lens, const LensModelOptions& projector_lens);

// The turntable: the target lies on the platform and is seen at several table angles.
struct TurntableView {
  TargetView camera;               // corners in the camera image
  double commanded_angle_deg = 0;  // what the table was told
  // The corners' projector coordinates, when the projectors showed their patterns at this pose
  // (empty: camera only). Same corner ids as `camera`.
  std::array<TargetView, 2> projectors;
};

// A calibrated projector the turntable fit may use: its corners pin each table pose's depth by
// triangulation, where the camera alone has only perspective (PnP) for it.
struct TurntableProjector {
  bool use = false;
  slproto::ProjectorCalibration calibration;
  double weight = 1;  // of its residuals against the camera's (camera RMS / projector RMS)
};

struct TurntableSolve {
  slproto::TurntableCalibration calibration;
  std::vector<double> measured_angle_deg;   // per view, relative to the first view
  std::vector<double> step_deg;             // per view, angle turned since the previous view (0 for the first)
  std::vector<double> pose_residual_mm;     // per view: RMS 3D distance, own pose vs fitted rotation
  std::vector<double> reprojection_rms_px;  // per view, of the fitted rotation
  double rms_px = 0;
  double target_tilt_deg = 0;  // angle between the target's normal and the axis (target not flat?)
  std::vector<bool> flipped;   // per view: corner order reversed (listed from the other end)
};

// Fits the rotation axis (direction and point), every view's actual angle and the target's
// pose at the first angle to all corners at once (reprojection error, camera fixed). The
// platform plane is perpendicular to the axis, `target.thickness_mm` below the target's
// surface; the table frame's origin is where the axis meets it (Formula 7), z points up
// (towards the camera's side of the platform), x is the camera's x projected onto the plane.
// Projectors with `use` add their corners' reprojection errors (weighted) to the same fit.
TurntableSolve calibrate_turntable(const CheckerboardTarget& target, const slproto::PinholeModel& camera,
                                   const std::vector<TurntableView>& views, double platform_radius_mm,
                                   const std::array<TurntableProjector, 2>& projectors = {});

// Pose of the target from one view with a known model (iterative PnP).
slproto::RigidTransform solve_target_pose(const CheckerboardTarget& target, const slproto::PinholeModel& model,
                                          const TargetView& view);

// RMS reprojection error (px) of a view given the model and the device_from_target pose.
double view_reprojection_rms(const CheckerboardTarget& target, const slproto::PinholeModel& model,
                             const slproto::RigidTransform& device_from_target, const TargetView& view);

// Angle (degrees) of the rotation R_a^T R_b.
double rotation_angle_between_deg(const slproto::RigidTransform& a, const slproto::RigidTransform& b);

}  // namespace slscan::core
