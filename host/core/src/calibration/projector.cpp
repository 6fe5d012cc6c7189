// One projector against the calibrated camera: DLT start, stereo extrinsics, joint refinement.
#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>

#include "levenberg_marquardt.hpp"
#include "pose_maths.hpp"
#include "slscan/core/calibration_solve.hpp"

namespace slscan::core {

using namespace calibration_detail;

namespace {

// Intrinsics (3x3, CV_64F) of a device from the DLT of its 3x4 projection matrix on corners
// whose camera-frame positions are known.
cv::Mat projection_matrix_intrinsics(const CheckerboardTarget& target,
                                     const std::vector<RigidTransform>& cam_from_target,
                                     const std::vector<TargetView>& views) {
  std::vector<Eigen::Vector3d> points;
  std::vector<Eigen::Vector2d> pixels;
  for (std::size_t i = 0; i < views.size(); ++i)
    for (const CornerObservation& c : views[i].corners) {
      points.push_back(apply(cam_from_target[i], target.corner(c.id)));
      pixels.push_back(c.pixel);
    }
  // Hartley normalisation of both sides keeps the DLT well conditioned.
  Eigen::Vector3d mean3 = Eigen::Vector3d::Zero();
  Eigen::Vector2d mean2 = Eigen::Vector2d::Zero();
  for (std::size_t i = 0; i < points.size(); ++i) {
    mean3 += points[i];
    mean2 += pixels[i];
  }
  mean3 /= static_cast<double>(points.size());
  mean2 /= static_cast<double>(points.size());
  double spread3 = 0, spread2 = 0;
  for (std::size_t i = 0; i < points.size(); ++i) {
    spread3 += (points[i] - mean3).norm();
    spread2 += (pixels[i] - mean2).norm();
  }
  const double s3 = std::sqrt(3.0) * static_cast<double>(points.size()) / spread3;
  const double s2 = std::sqrt(2.0) * static_cast<double>(points.size()) / spread2;
  Eigen::MatrixXd a(2 * static_cast<Eigen::Index>(points.size()), 12);
  for (std::size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3d p = (points[i] - mean3) * s3;
    const Eigen::Vector2d q = (pixels[i] - mean2) * s2;
    Eigen::Matrix<double, 1, 4> ph(p(0), p(1), p(2), 1.0);
    const auto row = 2 * static_cast<Eigen::Index>(i);
    a.row(row) << ph, Eigen::Matrix<double, 1, 4>::Zero(), -q(0) * ph;
    a.row(row + 1) << Eigen::Matrix<double, 1, 4>::Zero(), ph, -q(1) * ph;
  }
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(a, Eigen::ComputeFullV);
  const Eigen::VectorXd h = svd.matrixV().col(11);
  Eigen::Matrix<double, 3, 4> p_norm;
  p_norm << h.segment<4>(0).transpose(), h.segment<4>(4).transpose(), h.segment<4>(8).transpose();
  Eigen::Matrix3d t2;
  t2 << s2, 0, -s2 * mean2(0), 0, s2, -s2 * mean2(1), 0, 0, 1;
  Eigen::Matrix4d t3 = Eigen::Matrix4d::Identity();
  t3.topLeftCorner<3, 3>() *= s3;
  t3.topRightCorner<3, 1>() = -s3 * mean3;
  const Eigen::Matrix<double, 3, 4> projection = t2.inverse() * p_norm * t3;
  cv::Mat pm(3, 4, CV_64F);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 4; ++j) pm.at<double>(i, j) = projection(i, j);
  cv::Mat k, rot, centre;
  cv::decomposeProjectionMatrix(pm, k, rot, centre);
  k /= k.at<double>(2, 2);
  if (k.at<double>(0, 0) < 0 || k.at<double>(1, 1) < 0)
    throw std::runtime_error(
        "projector calibration: the corners' projector coordinates fit no projector in front of "
        "the target (are the decoded axes swapped or mirrored?)");
  k.at<double>(0, 1) = 0;  // no skew in the model
  return k;
}

}  // namespace

ProjectorSolve calibrate_projector(const CheckerboardTarget& target, const PinholeModel& camera,
                                   const std::vector<TargetView>& camera_views,
                                   const std::vector<TargetView>& projector_views, int projector_width,
                                   int projector_height, const LensModelOptions& lens, int min_views) {
  target.check();
  if (camera_views.size() != projector_views.size())
    throw std::invalid_argument("projector calibration: " + std::to_string(camera_views.size()) + " camera views but " +
                                std::to_string(projector_views.size()) + " projector views");
  if (static_cast<int>(camera_views.size()) < min_views)
    throw std::invalid_argument("projector calibration: " + std::to_string(camera_views.size()) +
                                " usable target views, at least " + std::to_string(min_views) + " needed");
  const std::size_t n = camera_views.size();
  // Stereo calibration wants the same corners in both devices: keep the corners both saw.
  std::vector<TargetView> cam(n), proj(n);
  for (std::size_t i = 0; i < n; ++i) {
    check_view(target, camera_views[i], "camera view", 6);
    check_view(target, projector_views[i], "projector view", 6);
    std::vector<const CornerObservation*> by_id(static_cast<std::size_t>(target.corner_count()), nullptr);
    for (const CornerObservation& c : camera_views[i].corners) by_id[static_cast<std::size_t>(c.id)] = &c;
    cam[i].name = camera_views[i].name;
    proj[i].name = projector_views[i].name;
    for (const CornerObservation& c : projector_views[i].corners) {
      if (const CornerObservation* in_camera = by_id[static_cast<std::size_t>(c.id)]) {
        cam[i].corners.push_back(*in_camera);
        proj[i].corners.push_back(c);
      }
    }
    check_view(target, proj[i], "projector view (corners seen by both devices)", 6);
  }

  // 1. Projector intrinsics. OpenCV's planar initialisation assumes the principal point near
  // the image centre, which a DLP projector's offset optics break (cy near the bottom edge),
  // so start from a DLP fit instead: with the target poses from the camera every corner is a
  // known 3D point in the camera frame, and those points (not coplanar across poses) give the
  // projector's 3x4 projection matrix, hence K, R and t.
  std::vector<std::vector<cv::Point3f>> object(n);
  std::vector<std::vector<cv::Point2f>> cam_points(n), proj_points(n);
  std::vector<RigidTransform> cam_from_target(n);
  for (std::size_t i = 0; i < n; ++i) {
    split_view(target, cam[i], object[i], cam_points[i]);
    split_view(target, proj[i], object[i], proj_points[i]);
    cam_from_target[i] = solve_target_pose(target, camera, cam[i]);
  }
  cv::Mat kp = projection_matrix_intrinsics(target, cam_from_target, proj);
  cv::Mat dp = cv::Mat::zeros(1, 5, CV_64F);
  std::vector<cv::Mat> rvecs, tvecs;
  const cv::Size proj_size(projector_width, projector_height);
  const auto criteria = cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 200, 1e-12);
  cv::calibrateCamera(object, proj_points, proj_size, kp, dp, rvecs, tvecs,
                      lens_flags(lens) | cv::CALIB_USE_INTRINSIC_GUESS, criteria);

  // 2. Extrinsics with both intrinsics fixed.
  cv::Mat kc = camera_matrix(camera), dc = distortion_vector(camera);
  cv::Mat r, t, e, f;
  cv::stereoCalibrate(object, cam_points, proj_points, kc, dc, kp, dp, proj_size, r, t, e, f, cv::CALIB_FIX_INTRINSIC,
                      criteria);

  // 3. Joint refinement: projector intrinsics, proj_from_cam and the target poses against
  // both devices' corners, the camera model fixed. stereoCalibrate above could only refine
  // both intrinsics or neither.
  const Eigen::Index pose_base = kIntrinsics + 6;
  Eigen::VectorXd x(pose_base + 6 * static_cast<Eigen::Index>(n));
  const PinholeModel proj0 = model_from_cv(kp, dp, projector_width, projector_height);
  x.head<kIntrinsics>() << proj0.fx, proj0.fy, proj0.cx, proj0.cy, proj0.distortion.k1, proj0.distortion.k2,
      proj0.distortion.p1, proj0.distortion.p2, proj0.distortion.k3;
  {
    cv::Mat rvec;
    cv::Rodrigues(r, rvec);
    const Pose p = Pose::from(transform_from_cv(rvec, t));
    x.segment<3>(kIntrinsics) = p.w;
    x.segment<3>(kIntrinsics + 3) = p.t;
  }
  for (std::size_t i = 0; i < n; ++i) {
    const Pose p = Pose::from(cam_from_target[i]);
    x.segment<3>(pose_base + 6 * static_cast<Eigen::Index>(i)) = p.w;
    x.segment<3>(pose_base + 6 * static_cast<Eigen::Index>(i) + 3) = p.t;
  }
  const Eigen::VectorXd start = x;
  Eigen::Index residual_count = 0;
  for (std::size_t i = 0; i < n; ++i) residual_count += 4 * static_cast<Eigen::Index>(cam[i].corners.size());
  // Parameters the lens options leave out stay at their start value (0 for k3 by default).
  const std::array<bool, kIntrinsics> free{true,   true, true, true, true, lens.k2, lens.tangential, lens.tangential,
                                           lens.k3};
  auto residuals = [&](const Eigen::VectorXd& params) {
    Eigen::VectorXd full = params;
    for (int j = 0; j < kIntrinsics; ++j)
      if (!free[static_cast<std::size_t>(j)]) full(j) = start(j);
    const PinholeModel projector = intrinsics_from(full, projector_width, projector_height);
    const Pose proj_from_cam = pose_at(full, kIntrinsics);
    const Eigen::Matrix3d rpc = proj_from_cam.R();
    Eigen::VectorXd out(residual_count);
    Eigen::Index k = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const Pose target_pose = pose_at(full, pose_base + 6 * static_cast<Eigen::Index>(i));
      const Eigen::Matrix3d rct = target_pose.R();
      for (std::size_t c = 0; c < cam[i].corners.size(); ++c) {
        const Eigen::Vector3d pc = rct * target.corner(cam[i].corners[c].id) + target_pose.t;
        out.segment<2>(k) = project(camera, pc) - cam[i].corners[c].pixel;
        out.segment<2>(k + 2) = project(projector, rpc * pc + proj_from_cam.t) - proj[i].corners[c].pixel;
        k += 4;
      }
    }
    return out;
  };
  Eigen::VectorXd step = Eigen::VectorXd::Constant(x.size(), 1e-6);
  step.head<4>().setConstant(1e-3);
  for (Eigen::Index i = kIntrinsics + 3; i < x.size(); i += 6) step.segment<3>(i).setConstant(1e-5);
  levenberg_marquardt(residuals, x, step, 100);
  for (int j = 0; j < kIntrinsics; ++j)
    if (!free[static_cast<std::size_t>(j)]) x(j) = start(j);

  ProjectorSolve out;
  out.calibration.intrinsics = intrinsics_from(x, projector_width, projector_height);
  if (auto status = out.calibration.intrinsics.check("projector calibration result"); !status)
    throw std::runtime_error(status.error().message + " (are the views varied enough?)");
  const RigidTransform proj_from_cam = pose_at(x, kIntrinsics).transform();
  out.calibration.cam_from_proj = proj_from_cam.inverse();
  double proj_sum = 0, cam_sum = 0;
  std::size_t count = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const RigidTransform refined = pose_at(x, pose_base + 6 * static_cast<Eigen::Index>(i)).transform();
    out.cam_from_target.push_back(refined);
    const double pr = view_reprojection_rms(target, out.calibration.intrinsics, proj_from_cam * refined, proj[i]);
    const double cr = view_reprojection_rms(target, camera, refined, cam[i]);
    out.view_rms_px.push_back(pr);
    const auto m = static_cast<double>(cam[i].corners.size());
    proj_sum += pr * pr * m;
    cam_sum += cr * cr * m;
    count += cam[i].corners.size();
  }
  out.calibration.reprojection_rms_px = std::sqrt(proj_sum / static_cast<double>(count));
  out.camera_rms_px = std::sqrt(cam_sum / static_cast<double>(count));
  return out;
}

}  // namespace slscan::core
