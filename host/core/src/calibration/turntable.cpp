// The turntable axis and platform plane from views of the target on the turning table.
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

// 180-degree turn of the target about its normal through its centre: what a detector's
// reversed corner order amounts to on a point-symmetric board.
RigidTransform half_turn(const CheckerboardTarget& target) {
  const Eigen::Vector3d c = target.centre();
  Eigen::Matrix3d r = Eigen::Vector3d(-1, -1, 1).asDiagonal();
  return make_transform(r, Eigen::Vector3d(2 * c(0), 2 * c(1), 0));
}

TargetView reversed(const CheckerboardTarget& target, const TargetView& view) {
  TargetView out = view;
  for (CornerObservation& c : out.corners) c.id = target.corner_count() - 1 - c.id;
  return out;
}

// Signed angle of rotation r about the unit axis n (r is assumed to turn about n).
double angle_about(const Eigen::Matrix3d& r, const Eigen::Vector3d& n) {
  const Eigen::Vector3d sin_axis(r(2, 1) - r(1, 2), r(0, 2) - r(2, 0), r(1, 0) - r(0, 1));
  return std::atan2(0.5 * n.dot(sin_axis), 0.5 * (r.trace() - 1.0));
}

double wrap_deg(double a) {
  a = std::fmod(a, 360.0);
  if (a > 180) a -= 360;
  if (a <= -180) a += 360;
  return a;
}

// The rotation axis model: n = normalise(n0 + a e1 + b e2), c = c0 + p e1 + q e2.
struct AxisFrame {
  Eigen::Vector3d n0, c0, e1, e2;
  Eigen::Vector3d direction(const Eigen::VectorXd& x) const { return (n0 + x(0) * e1 + x(1) * e2).normalized(); }
  Eigen::Vector3d point(const Eigen::VectorXd& x) const { return c0 + x(2) * e1 + x(3) * e2; }
};

Eigen::Matrix3d rodrigues(const Eigen::Vector3d& n, double angle) {
  return Eigen::AngleAxisd(angle, n).toRotationMatrix();
}

}  // namespace

TurntableSolve calibrate_turntable(const CheckerboardTarget& target, const PinholeModel& camera,
                                   const std::vector<TurntableView>& views_in, double platform_radius_mm,
                                   const std::array<TurntableProjector, 2>& projectors) {
  target.check();
  if (views_in.size() < 3)
    throw std::invalid_argument("turntable calibration: " + std::to_string(views_in.size()) +
                                " views of the target on the platform, at least 3 needed (6 recommended)");
  if (!(platform_radius_mm > 0)) throw std::invalid_argument("turntable calibration: platform radius must be positive");
  const std::size_t n = views_in.size();
  std::vector<TargetView> views(n);
  std::vector<std::array<TargetView, 2>> projector_views(n);
  std::vector<RigidTransform> poses(n);
  TurntableSolve out;
  out.flipped.assign(n, false);
  for (std::size_t i = 0; i < n; ++i) {
    check_view(target, views_in[i].camera, "turntable view", 6);
    views[i] = views_in[i].camera;
    poses[i] = solve_target_pose(target, camera, views[i]);
    for (std::size_t s = 0; s < 2; ++s)
      if (projectors[s].use && !views_in[i].projectors[s].corners.empty()) {
        check_view(target, views_in[i].projectors[s], "turntable view (projector corners)", 1);
        projector_views[i][s] = views_in[i].projectors[s];
      }
  }
  // The grid of inner corners is point-symmetric, and a detector may list it from either end
  // (always possible on a board with odd x odd squares, and after large turns on others). The
  // target turns about (nearly) its own normal, so a reversed list looks like an extra half
  // turn: keep, for each view, the order whose turn from the first view is closest to what was
  // commanded.
  {
    const RigidTransform flip = half_turn(target);
    for (std::size_t i = 1; i < n; ++i) {
      const double expected = std::abs(wrap_deg(views_in[i].commanded_angle_deg - views_in[0].commanded_angle_deg));
      const RigidTransform flipped_pose = poses[i] * flip;
      const double as_is = std::abs(rotation_angle_between_deg(poses[0], poses[i]) - expected);
      const double as_flipped = std::abs(rotation_angle_between_deg(poses[0], flipped_pose) - expected);
      if (as_flipped < as_is) {
        poses[i] = flipped_pose;
        views[i] = reversed(target, views[i]);
        for (TargetView& v : projector_views[i]) v = reversed(target, v);
        out.flipped[i] = true;
      }
    }
  }

  // Initial axis: the common fixed direction of every relative rotation R_i R_0^T, i.e. the
  // null vector of the stacked (R_i - I); the point from (I - R_i) c = t_i.
  const Eigen::Matrix3d r0 = to_eigen(poses[0].R);
  const Eigen::Vector3d t0(poses[0].t[0], poses[0].t[1], poses[0].t[2]);
  Eigen::MatrixXd stacked(3 * static_cast<Eigen::Index>(n - 1), 3);
  std::vector<Eigen::Matrix3d> relative_r(n);
  std::vector<Eigen::Vector3d> relative_t(n);
  for (std::size_t i = 1; i < n; ++i) {
    const Eigen::Matrix3d ri = to_eigen(poses[i].R);
    const Eigen::Vector3d ti(poses[i].t[0], poses[i].t[1], poses[i].t[2]);
    relative_r[i] = ri * r0.transpose();
    relative_t[i] = ti - relative_r[i] * t0;
    stacked.block<3, 3>(3 * static_cast<Eigen::Index>(i - 1), 0) = relative_r[i] - Eigen::Matrix3d::Identity();
  }
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(stacked, Eigen::ComputeFullV);
  Eigen::Vector3d axis = svd.matrixV().col(2);
  const Eigen::Vector3d centre0 = r0 * target.centre() + t0;
  if (axis.dot(centre0) > 0) axis = -axis;  // up = towards the camera's side of the platform
  double max_turn = 0;
  for (std::size_t i = 1; i < n; ++i) max_turn = std::max(max_turn, std::abs(angle_about(relative_r[i], axis)));
  if (max_turn < 5.0 / kDeg)
    throw std::invalid_argument(
        "turntable calibration: the views span less than 5 degrees of table rotation; "
        "the axis cannot be found");
  Eigen::MatrixXd a(3 * static_cast<Eigen::Index>(n - 1) + 1, 3);
  Eigen::VectorXd b(a.rows());
  for (std::size_t i = 1; i < n; ++i) {
    a.block<3, 3>(3 * static_cast<Eigen::Index>(i - 1), 0) = Eigen::Matrix3d::Identity() - relative_r[i];
    b.segment<3>(3 * static_cast<Eigen::Index>(i - 1)) = relative_t[i];
  }
  a.row(a.rows() - 1) = axis.transpose();  // pin the point to the target's height on the axis
  b(b.rows() - 1) = axis.dot(centre0);
  const Eigen::Vector3d point = a.colPivHouseholderQr().solve(b);

  // Joint fit: axis (4), angles of views 1..n-1, target pose at view 0 (6); reprojection
  // error of every corner, the camera model fixed.
  AxisFrame frame;
  frame.n0 = axis;
  frame.c0 = point;
  frame.e1 = axis.unitOrthogonal();
  frame.e2 = axis.cross(frame.e1);
  const Eigen::Index angle_base = 4, pose_base = 4 + static_cast<Eigen::Index>(n - 1);
  Eigen::VectorXd x = Eigen::VectorXd::Zero(pose_base + 6);
  for (std::size_t i = 1; i < n; ++i)
    x(angle_base + static_cast<Eigen::Index>(i - 1)) = angle_about(relative_r[i], axis);
  const Pose p0 = Pose::from(poses[0]);
  x.segment<3>(pose_base) = p0.w;
  x.segment<3>(pose_base + 3) = p0.t;
  Eigen::Index residual_count = 0;
  for (const TargetView& v : views) residual_count += 2 * static_cast<Eigen::Index>(v.corners.size());
  std::array<Eigen::Matrix3d, 2> proj_r;
  std::array<Eigen::Vector3d, 2> proj_t;
  for (std::size_t s = 0; s < 2; ++s) {
    const RigidTransform proj_from_cam = projectors[s].calibration.cam_from_proj.inverse();
    proj_r[s] = to_eigen(proj_from_cam.R);
    proj_t[s] = {proj_from_cam.t[0], proj_from_cam.t[1], proj_from_cam.t[2]};
    for (const auto& pv : projector_views) residual_count += 2 * static_cast<Eigen::Index>(pv[s].corners.size());
  }
  auto view_pose = [&](const Eigen::VectorXd& params, std::size_t i) {
    const Pose base = pose_at(params, pose_base);
    if (i == 0) return std::pair<Eigen::Matrix3d, Eigen::Vector3d>(base.R(), base.t);
    const Eigen::Vector3d dir = frame.direction(params), c = frame.point(params);
    const Eigen::Matrix3d rot = rodrigues(dir, params(angle_base + static_cast<Eigen::Index>(i - 1)));
    return std::pair<Eigen::Matrix3d, Eigen::Vector3d>(rot * base.R(), rot * base.t + c - rot * c);
  };
  auto residuals = [&](const Eigen::VectorXd& params) {
    Eigen::VectorXd res(residual_count);
    Eigen::Index k = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const auto [r, t] = view_pose(params, i);
      for (const CornerObservation& c : views[i].corners) {
        res.segment<2>(k) = project(camera, r * target.corner(c.id) + t) - c.pixel;
        k += 2;
      }
      for (std::size_t s = 0; s < 2; ++s)
        for (const CornerObservation& c : projector_views[i][s].corners) {
          const Eigen::Vector3d in_camera = r * target.corner(c.id) + t;
          res.segment<2>(k) =
              projectors[s].weight *
              (project(projectors[s].calibration.intrinsics, proj_r[s] * in_camera + proj_t[s]) - c.pixel);
          k += 2;
        }
    }
    return res;
  };
  Eigen::VectorXd step = Eigen::VectorXd::Constant(x.size(), 1e-6);
  step.segment<2>(2).setConstant(1e-4);
  step.segment<3>(pose_base + 3).setConstant(1e-4);
  levenberg_marquardt(residuals, x, step, 100);

  const Eigen::Vector3d dir = frame.direction(x), c = frame.point(x);
  const Pose base = pose_at(x, pose_base);
  // Formula 7: the platform plane n . (p - p0) = 0 lies `thickness` below the target surface.
  const double target_height = dir.dot(base.R() * target.centre() + base.t);
  const Eigen::Vector3d origin = c + (target_height - target.thickness_mm - dir.dot(c)) * dir;
  Eigen::Vector3d x_axis = Eigen::Vector3d::UnitX() - dir.x() * dir;
  if (x_axis.norm() < 1e-6) x_axis = dir.unitOrthogonal();
  x_axis.normalize();
  Eigen::Matrix3d r_table;
  r_table.col(0) = x_axis;
  r_table.col(1) = dir.cross(x_axis);
  r_table.col(2) = dir;
  out.calibration.cam_from_table = make_transform(r_table, origin);
  out.calibration.platform_radius_mm = platform_radius_mm;
  out.target_tilt_deg = std::acos(std::clamp(std::abs(dir.dot(base.R().col(2))), 0.0, 1.0)) * kDeg;

  double sum_px = 0, sum_mm = 0;
  std::size_t count = 0;
  double previous = 0;
  for (std::size_t i = 0; i < n; ++i) {
    // Reported next to the commanded turn (the fit's angle is only known modulo 360).
    const double commanded = views_in[i].commanded_angle_deg - views_in[0].commanded_angle_deg;
    const double fitted = i == 0 ? 0.0 : x(angle_base + static_cast<Eigen::Index>(i - 1)) * kDeg;
    const double angle = commanded + wrap_deg(fitted - commanded);
    out.measured_angle_deg.push_back(angle);
    out.step_deg.push_back(i == 0 ? 0.0 : wrap_deg(angle - previous));
    previous = angle;
    const auto [r, t] = view_pose(x, i);
    const RigidTransform fitted_pose = make_transform(r, t);
    const double px = view_reprojection_rms(target, camera, fitted_pose, views[i]);
    out.reprojection_rms_px.push_back(px);
    double mm = 0;
    for (const CornerObservation& corner : views[i].corners)
      mm += (apply(fitted_pose, target.corner(corner.id)) - apply(poses[i], target.corner(corner.id))).squaredNorm();
    out.pose_residual_mm.push_back(std::sqrt(mm / static_cast<double>(views[i].corners.size())));
    const auto m = static_cast<double>(views[i].corners.size());
    sum_px += px * px * m;
    sum_mm += mm;
    count += views[i].corners.size();
  }
  out.rms_px = std::sqrt(sum_px / static_cast<double>(count));
  out.calibration.pose_residual_mm = std::sqrt(sum_mm / static_cast<double>(count));
  return out;
}

}  // namespace slscan::core
