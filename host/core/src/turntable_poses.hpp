#pragma once
// Registration's turntable mode (docs/registration.md): the poses a turntable can give, as
// functions of a few parameters. Private to slscan_core.

#include <Eigen/Geometry>
#include <cmath>
#include <cstddef>
#include <numbers>
#include <utility>
#include <vector>

#include "slproto/rig_model.hpp"
#include "slscan/core/registration.hpp"

namespace slscan::core::detail {

// The poses a turntable can give: every view turned about one axis, by its reported angle plus
// a correction of its own. The axis itself may be off the calibrated one by a small tilt and
// shift, shared by all views. Parameters: [tilt about x, tilt about y (rad), shift along x, y
// (mm), angle corrections of views 1..n-1 (rad)]; view 0 keeps its reported angle (turning every
// view alike turns the whole model, which the data cannot see).
//   pose_i = E^-1 Rz(-(angle_i - angle_0 + correction_i)) E Rz(-angle_0) table_from_cam
// with E the axis correction in the table frame (z along the calibrated axis). Rotations about z
// and shifts along z commute with the turn: they are no parameters.
class TurntablePoses {
 public:
  static constexpr double kDegPerRadian = 180.0 / std::numbers::pi;
  TurntablePoses(const slproto::TurntableCalibration& turntable, std::vector<double> angles_deg)
      : table_from_cam_(to_isometry(turntable.cam_from_table).inverse()),
        angles_rad_(std::move(angles_deg)),
        params_(Eigen::VectorXd::Zero(static_cast<Eigen::Index>(4 + angles_rad_.size() - 1))) {
    for (double& a : angles_rad_) a /= kDegPerRadian;
  }

  static constexpr int kAxisParams = 4;
  const Eigen::VectorXd& params() const { return params_; }
  void update(const Eigen::VectorXd& delta) { params_ += delta; }

  std::vector<Eigen::Isometry3d> poses(const Eigen::VectorXd& p) const {
    const Eigen::Vector3d tilt(p[0], p[1], 0);
    Eigen::Isometry3d axis = Eigen::Isometry3d::Identity();
    if (tilt.norm() > 0) axis.linear() = Eigen::AngleAxisd(tilt.norm(), tilt.normalized()).toRotationMatrix();
    axis.translation() = Eigen::Vector3d(p[2], p[3], 0);
    const Eigen::Isometry3d start = turn(-angles_rad_[0]) * table_from_cam_;
    std::vector<Eigen::Isometry3d> out(angles_rad_.size());
    for (std::size_t i = 0; i < angles_rad_.size(); ++i) {
      const double correction = i == 0 ? 0.0 : p[static_cast<Eigen::Index>(kAxisParams + i - 1)];
      out[i] = axis.inverse() * turn(-(angles_rad_[i] - angles_rad_[0] + correction)) * axis * start;
    }
    return out;
  }
  std::vector<Eigen::Isometry3d> poses() const { return poses(params_); }

  // d(pose_i) / d(params) as left-perturbation twists (rotation, translation): 6 rows per view.
  Eigen::MatrixXd jacobian() const {
    constexpr double step = 1e-6;
    Eigen::MatrixXd J(static_cast<Eigen::Index>(6 * angles_rad_.size()), params_.size());
    for (Eigen::Index k = 0; k < params_.size(); ++k) {
      Eigen::VectorXd plus = params_, minus = params_;
      plus[k] += step;
      minus[k] -= step;
      const auto a = poses(plus), b = poses(minus);
      for (std::size_t i = 0; i < a.size(); ++i) {
        const Eigen::Isometry3d d = a[i] * b[i].inverse();
        const Eigen::AngleAxisd rotation(d.linear());
        const auto row = static_cast<Eigen::Index>(6 * i);
        J.block<3, 1>(row, k) = rotation.angle() * rotation.axis() / (2 * step);
        J.block<3, 1>(row + 3, k) = d.translation() / (2 * step);
      }
    }
    return J;
  }

  double axis_tilt_deg() const { return std::hypot(params_[0], params_[1]) * kDegPerRadian; }
  double axis_shift_mm() const { return std::hypot(params_[2], params_[3]); }
  double angle_correction_deg(std::size_t view) const {
    return view == 0 ? 0.0 : params_[static_cast<Eigen::Index>(kAxisParams + view - 1)] * kDegPerRadian;
  }

 private:
  static Eigen::Isometry3d turn(double angle_rad) {
    Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
    t.linear() = Eigen::AngleAxisd(angle_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    return t;
  }

  Eigen::Isometry3d table_from_cam_;
  std::vector<double> angles_rad_;
  Eigen::VectorXd params_;
};

}  // namespace slscan::core::detail
