// Pose maths and conversions shared by the calibration solvers (camera.cpp, projector.cpp,
// joint_refinement.cpp, turntable.cpp): rotation vectors, projection, OpenCV <-> slproto, the
// parameter-vector layout of the refinements, and the checks every target view goes through.
// Private to slscan_core.
#pragma once

#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <numbers>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "slscan/core/calibration_solve.hpp"

namespace slscan::core::calibration_detail {

using slproto::PinholeModel;
using slproto::RigidTransform;

constexpr double kDeg = 180.0 / std::numbers::pi;

// ---------------------------------------------------------------- conversions

inline Eigen::Matrix3d to_eigen(const slproto::Mat3& r) {
  Eigen::Matrix3d m;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) m(i, j) = r[static_cast<std::size_t>(i * 3 + j)];
  return m;
}

inline RigidTransform make_transform(const Eigen::Matrix3d& r, const Eigen::Vector3d& t) {
  RigidTransform out;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) out.R[static_cast<std::size_t>(i * 3 + j)] = r(i, j);
    out.t[static_cast<std::size_t>(i)] = t(i);
  }
  return out;
}

inline Eigen::Matrix3d rotation_from_vector(const Eigen::Vector3d& w) {
  const double angle = w.norm();
  if (angle < 1e-300) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
}

inline Eigen::Vector3d vector_from_rotation(const Eigen::Matrix3d& r) {
  const Eigen::AngleAxisd aa(r);
  return aa.axis() * aa.angle();
}

struct Pose {  // device_from_target as a rotation vector and translation
  Eigen::Vector3d w{0, 0, 0}, t{0, 0, 0};
  Eigen::Matrix3d R() const { return rotation_from_vector(w); }
  RigidTransform transform() const { return make_transform(R(), t); }
  static Pose from(const RigidTransform& p) {
    return {vector_from_rotation(to_eigen(p.R)), Eigen::Vector3d(p.t[0], p.t[1], p.t[2])};
  }
};

inline Eigen::Vector3d apply(const RigidTransform& p, const Eigen::Vector3d& x) {
  const slproto::Vec3 r = p.apply({x(0), x(1), x(2)});
  return {r[0], r[1], r[2]};
}

// Pixel of a device-frame point; a point behind the device gets a huge residual rather than a
// NaN so an optimiser step that goes there is simply rejected.
inline Eigen::Vector2d project(const PinholeModel& model, const Eigen::Vector3d& p) {
  double u = 0, v = 0;
  if (!model.project({p(0), p(1), p(2)}, u, v)) return {1e6, 1e6};
  return {u, v};
}

inline cv::Mat camera_matrix(const PinholeModel& m) {
  return (cv::Mat_<double>(3, 3) << m.fx, 0, m.cx, 0, m.fy, m.cy, 0, 0, 1);
}

inline cv::Mat distortion_vector(const PinholeModel& m) {
  const auto& d = m.distortion;
  return (cv::Mat_<double>(1, 5) << d.k1, d.k2, d.p1, d.p2, d.k3);
}

inline PinholeModel model_from_cv(const cv::Mat& k, const cv::Mat& d, int width, int height) {
  PinholeModel m;
  m.width = width;
  m.height = height;
  m.fx = k.at<double>(0, 0);
  m.fy = k.at<double>(1, 1);
  m.cx = k.at<double>(0, 2);
  m.cy = k.at<double>(1, 2);
  const auto* dd = d.ptr<double>();
  m.distortion = {dd[0], dd[1], dd[2], dd[3], d.total() > 4 ? dd[4] : 0.0};
  return m;
}

inline RigidTransform transform_from_cv(const cv::Mat& rvec, const cv::Mat& tvec) {
  Eigen::Vector3d w(rvec.at<double>(0), rvec.at<double>(1), rvec.at<double>(2));
  Eigen::Vector3d t(tvec.at<double>(0), tvec.at<double>(1), tvec.at<double>(2));
  return make_transform(rotation_from_vector(w), t);
}

inline int lens_flags(const LensModelOptions& lens) {
  int flags = 0;
  if (!lens.k3) flags |= cv::CALIB_FIX_K3;
  if (!lens.k2) flags |= cv::CALIB_FIX_K2;
  if (!lens.tangential) flags |= cv::CALIB_ZERO_TANGENT_DIST;
  return flags;
}

// ---------------------------------------------------------------- parameter vectors

// Parameter vector of the joint projector refinement:
//   [fx fy cx cy k1 k2 p1 p2 k3 | w t of proj_from_cam | w t of cam_from_target per view]
constexpr int kIntrinsics = 9;

inline PinholeModel intrinsics_from(const Eigen::VectorXd& x, int width, int height) {
  PinholeModel m;
  m.width = width;
  m.height = height;
  m.fx = x(0);
  m.fy = x(1);
  m.cx = x(2);
  m.cy = x(3);
  m.distortion = {x(4), x(5), x(6), x(7), x(8)};
  return m;
}

inline Pose pose_at(const Eigen::VectorXd& x, Eigen::Index offset) {
  return {x.segment<3>(offset), x.segment<3>(offset + 3)};
}

// ---------------------------------------------------------------- target views

// Throws std::invalid_argument unless `view` has at least `min` finite corners, all on `target`.
void check_view(const CheckerboardTarget& target, const TargetView& view, const std::string& what, std::size_t min);

// The view's corners as OpenCV's object (target frame) and image point lists.
void split_view(const CheckerboardTarget& target, const TargetView& view, std::vector<cv::Point3f>& object,
                std::vector<cv::Point2f>& image);

}  // namespace slscan::core::calibration_detail
