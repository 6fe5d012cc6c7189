#include "slscan/core/calibration_solve.hpp"

#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <stdexcept>

namespace slscan::core {

using slproto::PinholeModel;
using slproto::RigidTransform;

void CheckerboardTarget::check() const {
  if (squares_x < 3 || squares_y < 3 || squares_x > 200 || squares_y > 200)
    throw std::invalid_argument("checkerboard target: " + std::to_string(squares_x) + " x " +
                                std::to_string(squares_y) + " squares; each side needs 3..200");
  if (!(square_mm > 0) || !std::isfinite(square_mm))
    throw std::invalid_argument("checkerboard target: square_mm must be positive, got " + std::to_string(square_mm));
  if (!(thickness_mm >= 0) || !std::isfinite(thickness_mm))
    throw std::invalid_argument("checkerboard target: thickness_mm must be >= 0, got " + std::to_string(thickness_mm));
}

namespace {

constexpr double kDeg = 180.0 / std::numbers::pi;

// ---------------------------------------------------------------- conversions

Eigen::Matrix3d to_eigen(const slproto::Mat3& r) {
  Eigen::Matrix3d m;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) m(i, j) = r[static_cast<std::size_t>(i * 3 + j)];
  return m;
}

RigidTransform make_transform(const Eigen::Matrix3d& r, const Eigen::Vector3d& t) {
  RigidTransform out;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) out.R[static_cast<std::size_t>(i * 3 + j)] = r(i, j);
    out.t[static_cast<std::size_t>(i)] = t(i);
  }
  return out;
}

Eigen::Matrix3d rotation_from_vector(const Eigen::Vector3d& w) {
  const double angle = w.norm();
  if (angle < 1e-300) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
}

Eigen::Vector3d vector_from_rotation(const Eigen::Matrix3d& r) {
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

Eigen::Vector3d apply(const RigidTransform& p, const Eigen::Vector3d& x) {
  const slproto::Vec3 r = p.apply({x(0), x(1), x(2)});
  return {r[0], r[1], r[2]};
}

// Pixel of a device-frame point; a point behind the device gets a huge residual rather than a
// NaN so an optimiser step that goes there is simply rejected.
Eigen::Vector2d project(const PinholeModel& model, const Eigen::Vector3d& p) {
  double u = 0, v = 0;
  if (!model.project({p(0), p(1), p(2)}, u, v)) return {1e6, 1e6};
  return {u, v};
}

cv::Mat camera_matrix(const PinholeModel& m) {
  return (cv::Mat_<double>(3, 3) << m.fx, 0, m.cx, 0, m.fy, m.cy, 0, 0, 1);
}

cv::Mat distortion_vector(const PinholeModel& m) {
  const auto& d = m.distortion;
  return (cv::Mat_<double>(1, 5) << d.k1, d.k2, d.p1, d.p2, d.k3);
}

PinholeModel model_from_cv(const cv::Mat& k, const cv::Mat& d, int width, int height) {
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

RigidTransform transform_from_cv(const cv::Mat& rvec, const cv::Mat& tvec) {
  Eigen::Vector3d w(rvec.at<double>(0), rvec.at<double>(1), rvec.at<double>(2));
  Eigen::Vector3d t(tvec.at<double>(0), tvec.at<double>(1), tvec.at<double>(2));
  return make_transform(rotation_from_vector(w), t);
}

int lens_flags(const LensModelOptions& lens) {
  int flags = 0;
  if (!lens.k3) flags |= cv::CALIB_FIX_K3;
  if (!lens.k2) flags |= cv::CALIB_FIX_K2;
  if (!lens.tangential) flags |= cv::CALIB_ZERO_TANGENT_DIST;
  return flags;
}

void check_view(const CheckerboardTarget& target, const TargetView& view, const std::string& what, std::size_t min) {
  if (view.corners.size() < min)
    throw std::invalid_argument(what + " '" + view.name + "': " + std::to_string(view.corners.size()) +
                                " corners, at least " + std::to_string(min) + " needed");
  for (const CornerObservation& c : view.corners) {
    if (c.id < 0 || c.id >= target.corner_count())
      throw std::invalid_argument(what + " '" + view.name + "': corner id " + std::to_string(c.id) +
                                  " is not on a target with " + std::to_string(target.corner_count()) + " corners");
    if (!c.pixel.allFinite())
      throw std::invalid_argument(what + " '" + view.name + "': corner " + std::to_string(c.id) + " is not finite");
  }
}

void split_view(const CheckerboardTarget& target, const TargetView& view, std::vector<cv::Point3f>& object,
                std::vector<cv::Point2f>& image) {
  object.clear();
  image.clear();
  for (const CornerObservation& c : view.corners) {
    const Eigen::Vector3d x = target.corner(c.id);
    object.emplace_back(static_cast<float>(x(0)), static_cast<float>(x(1)), static_cast<float>(x(2)));
    image.emplace_back(static_cast<float>(c.pixel(0)), static_cast<float>(c.pixel(1)));
  }
}

// ---------------------------------------------------------------- Levenberg-Marquardt

// Minimises |residuals(x)|^2 with Levenberg-Marquardt on a central-difference Jacobian.
// The problems here have tens of parameters and a few thousand residuals, so a dense
// Jacobian is cheap next to the image work that produced the corners.
template <class Residuals>
void levenberg_marquardt(Residuals&& residuals, Eigen::VectorXd& x, const Eigen::VectorXd& step, int max_iterations) {
  Eigen::VectorXd r = residuals(x);
  double cost = r.squaredNorm();
  double lambda = 1e-3;
  Eigen::MatrixXd jacobian(r.size(), x.size());
  for (int iteration = 0; iteration < max_iterations; ++iteration) {
    for (Eigen::Index j = 0; j < x.size(); ++j) {
      Eigen::VectorXd xp = x, xm = x;
      xp(j) += step(j);
      xm(j) -= step(j);
      jacobian.col(j) = (residuals(xp) - residuals(xm)) / (2.0 * step(j));
    }
    const Eigen::MatrixXd jtj = jacobian.transpose() * jacobian;
    const Eigen::VectorXd jtr = jacobian.transpose() * r;
    bool improved = false;
    for (int attempt = 0; attempt < 12 && !improved; ++attempt) {
      Eigen::MatrixXd a = jtj;
      // A parameter the residuals ignore (a lens term held fixed) gets a unit diagonal, so its
      // step is exactly zero instead of a division by nothing.
      for (Eigen::Index j = 0; j < a.rows(); ++j) a(j, j) = jtj(j, j) > 0 ? jtj(j, j) * (1.0 + lambda) : 1.0;
      const Eigen::VectorXd dx = a.ldlt().solve(-jtr);
      const Eigen::VectorXd candidate = x + dx;
      const Eigen::VectorXd rc = residuals(candidate);
      const double candidate_cost = rc.squaredNorm();
      if (std::isfinite(candidate_cost) && candidate_cost < cost) {
        const double gain = (cost - candidate_cost) / std::max(cost, 1e-300);
        x = candidate;
        r = rc;
        cost = candidate_cost;
        lambda = std::max(lambda * 0.3, 1e-12);
        improved = true;
        if (gain < 1e-12 || dx.cwiseAbs().cwiseQuotient(step).maxCoeff() < 1e-6) return;
      } else {
        lambda *= 10;
      }
    }
    if (!improved) return;
  }
}

}  // namespace

// ---------------------------------------------------------------- single views

RigidTransform solve_target_pose(const CheckerboardTarget& target, const PinholeModel& model, const TargetView& view) {
  check_view(target, view, "view", 4);
  std::vector<cv::Point3f> object;
  std::vector<cv::Point2f> image;
  split_view(target, view, object, image);
  cv::Mat rvec, tvec;
  if (!cv::solvePnP(object, image, camera_matrix(model), distortion_vector(model), rvec, tvec, false,
                    cv::SOLVEPNP_ITERATIVE))
    throw std::runtime_error("view '" + view.name + "': no pose of the target fits its corners");
  // Refine with LM on the exact model (solvePnP's first guess for planar targets is good but
  // not always at the minimum).
  cv::solvePnPRefineLM(object, image, camera_matrix(model), distortion_vector(model), rvec, tvec,
                       cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 50, 1e-12));
  return transform_from_cv(rvec, tvec);
}

double view_reprojection_rms(const CheckerboardTarget& target, const PinholeModel& model,
                             const RigidTransform& device_from_target, const TargetView& view) {
  if (view.corners.empty()) return 0;
  double sum = 0;
  for (const CornerObservation& c : view.corners)
    sum += (project(model, apply(device_from_target, target.corner(c.id))) - c.pixel).squaredNorm();
  return std::sqrt(sum / static_cast<double>(view.corners.size()));
}

double rotation_angle_between_deg(const RigidTransform& a, const RigidTransform& b) {
  const Eigen::Matrix3d r = to_eigen(a.R).transpose() * to_eigen(b.R);
  return std::acos(std::clamp((r.trace() - 1.0) / 2.0, -1.0, 1.0)) * kDeg;
}

// ---------------------------------------------------------------- camera

DeviceCalibration calibrate_camera(const CheckerboardTarget& target, const std::vector<TargetView>& views, int width,
                                   int height, const LensModelOptions& lens, int min_views) {
  target.check();
  if (width <= 0 || height <= 0)
    throw std::invalid_argument("camera calibration: image size " + std::to_string(width) + " x " +
                                std::to_string(height) + " is impossible");
  if (static_cast<int>(views.size()) < min_views)
    throw std::invalid_argument("camera calibration: " + std::to_string(views.size()) +
                                " usable target views, at least " + std::to_string(min_views) + " needed");
  std::vector<std::vector<cv::Point3f>> object(views.size());
  std::vector<std::vector<cv::Point2f>> image(views.size());
  for (std::size_t i = 0; i < views.size(); ++i) {
    check_view(target, views[i], "camera view", 6);
    split_view(target, views[i], object[i], image[i]);
  }
  cv::Mat k, d;
  std::vector<cv::Mat> rvecs, tvecs;
  cv::calibrateCamera(object, image, cv::Size(width, height), k, d, rvecs, tvecs, lens_flags(lens),
                      cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 200, 1e-12));
  DeviceCalibration out;
  out.model = model_from_cv(k, d, width, height);
  if (auto status = out.model.check("camera calibration result"); !status)
    throw std::runtime_error(status.error().message + " (are the views varied enough?)");
  double sum = 0;
  std::size_t count = 0;
  for (std::size_t i = 0; i < views.size(); ++i) {
    out.from_target.push_back(transform_from_cv(rvecs[i], tvecs[i]));
    const double rms = view_reprojection_rms(target, out.model, out.from_target.back(), views[i]);
    out.view_rms_px.push_back(rms);
    sum += rms * rms * static_cast<double>(views[i].corners.size());
    count += views[i].corners.size();
  }
  out.rms_px = std::sqrt(sum / static_cast<double>(count));
  return out;
}

// ---------------------------------------------------------------- projector

namespace {

// Parameter vector of the joint projector refinement:
//   [fx fy cx cy k1 k2 p1 p2 k3 | w t of proj_from_cam | w t of cam_from_target per view]
constexpr int kIntrinsics = 9;

PinholeModel intrinsics_from(const Eigen::VectorXd& x, int width, int height) {
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

Pose pose_at(const Eigen::VectorXd& x, Eigen::Index offset) { return {x.segment<3>(offset), x.segment<3>(offset + 3)}; }

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

// ---------------------------------------------------------------- whole rig

RigBundle refine_rig_jointly(const CheckerboardTarget& target, const DeviceCalibration& camera,
                             const std::vector<TargetView>& camera_views,
                             const std::array<ProjectorObservations, 2>& projectors,
                             const LensModelOptions& camera_lens, const LensModelOptions& projector_lens) {
  target.check();
  const std::size_t n = camera_views.size();
  if (camera.from_target.size() != n)
    throw std::invalid_argument("rig refinement: " + std::to_string(n) + " camera views but " +
                                std::to_string(camera.from_target.size()) + " camera poses");
  for (std::size_t s = 0; s < 2; ++s) {
    if (projectors[s].views.size() != projectors[s].camera_view.size())
      throw std::invalid_argument("rig refinement: projector " + std::to_string(s) + " has " +
                                  std::to_string(projectors[s].views.size()) + " views but " +
                                  std::to_string(projectors[s].camera_view.size()) + " camera view indices");
    for (std::size_t v : projectors[s].camera_view)
      if (v >= n)
        throw std::invalid_argument("rig refinement: projector view refers to camera view " + std::to_string(v) +
                                    " of " + std::to_string(n));
  }
  // Layout: [camera 9 | per projector: 9 intrinsics + 6 proj_from_cam | 6 per target pose].
  const Eigen::Index projector_base = kIntrinsics;
  const Eigen::Index pose_base = kIntrinsics + 2 * (kIntrinsics + 6);
  Eigen::VectorXd x(pose_base + 6 * static_cast<Eigen::Index>(n));
  const auto put_intrinsics = [&](Eigen::Index at, const PinholeModel& m) {
    x.segment<kIntrinsics>(at) << m.fx, m.fy, m.cx, m.cy, m.distortion.k1, m.distortion.k2, m.distortion.p1,
        m.distortion.p2, m.distortion.k3;
  };
  const auto put_pose = [&](Eigen::Index at, const RigidTransform& t) {
    const Pose p = Pose::from(t);
    x.segment<3>(at) = p.w;
    x.segment<3>(at + 3) = p.t;
  };
  put_intrinsics(0, camera.model);
  for (std::size_t s = 0; s < 2; ++s) {
    const Eigen::Index at = projector_base + static_cast<Eigen::Index>(s) * (kIntrinsics + 6);
    put_intrinsics(at, projectors[s].start.intrinsics);
    put_pose(at + kIntrinsics, projectors[s].start.cam_from_proj.inverse());
  }
  for (std::size_t i = 0; i < n; ++i) put_pose(pose_base + 6 * static_cast<Eigen::Index>(i), camera.from_target[i]);
  const Eigen::VectorXd start = x;

  // Lens terms each device's options leave out stay at their start value.
  const auto free_terms = [](const LensModelOptions& lens) {
    return std::array<bool, kIntrinsics>{true,   true, true, true, true, lens.k2, lens.tangential, lens.tangential,
                                         lens.k3};
  };
  const std::array<bool, kIntrinsics> camera_free = free_terms(camera_lens);
  const std::array<bool, kIntrinsics> projector_free = free_terms(projector_lens);
  // Weights: each device's corner noise, as its separate solve measured it (floored so a
  // perfect synthetic device cannot take all the weight).
  const double camera_weight = 1.0 / std::max(camera.rms_px, 0.005);
  std::array<double, 2> projector_weight{};
  Eigen::Index residual_count = 0;
  for (const TargetView& v : camera_views) residual_count += 2 * static_cast<Eigen::Index>(v.corners.size());
  for (std::size_t s = 0; s < 2; ++s) {
    projector_weight[s] = 1.0 / std::max(projectors[s].start.reprojection_rms_px, 0.005);
    for (const TargetView& v : projectors[s].views) residual_count += 2 * static_cast<Eigen::Index>(v.corners.size());
  }

  const auto unpack = [&](const Eigen::VectorXd& params) {
    Eigen::VectorXd full = params;
    for (int j = 0; j < kIntrinsics; ++j) {
      if (!camera_free[static_cast<std::size_t>(j)]) full(j) = start(j);
      for (std::size_t s = 0; s < 2; ++s) {
        const Eigen::Index at = projector_base + static_cast<Eigen::Index>(s) * (kIntrinsics + 6) + j;
        if (!projector_free[static_cast<std::size_t>(j)]) full(at) = start(at);
      }
    }
    return full;
  };
  auto residuals = [&](const Eigen::VectorXd& params) {
    const Eigen::VectorXd full = unpack(params);
    const PinholeModel cam = intrinsics_from(full.head<kIntrinsics>(), camera.model.width, camera.model.height);
    std::array<PinholeModel, 2> proj;
    std::array<Pose, 2> proj_from_cam;
    std::array<Eigen::Matrix3d, 2> rpc;
    for (std::size_t s = 0; s < 2; ++s) {
      const Eigen::Index at = projector_base + static_cast<Eigen::Index>(s) * (kIntrinsics + 6);
      proj[s] = intrinsics_from(full.segment<kIntrinsics>(at), projectors[s].start.intrinsics.width,
                                projectors[s].start.intrinsics.height);
      proj_from_cam[s] = pose_at(full, at + kIntrinsics);
      rpc[s] = proj_from_cam[s].R();
    }
    std::vector<Pose> poses(n);
    std::vector<Eigen::Matrix3d> rotations(n);
    for (std::size_t i = 0; i < n; ++i) {
      poses[i] = pose_at(full, pose_base + 6 * static_cast<Eigen::Index>(i));
      rotations[i] = poses[i].R();
    }
    Eigen::VectorXd out(residual_count);
    Eigen::Index k = 0;
    for (std::size_t i = 0; i < n; ++i)
      for (const CornerObservation& c : camera_views[i].corners) {
        const Eigen::Vector3d pc = rotations[i] * target.corner(c.id) + poses[i].t;
        out.segment<2>(k) = camera_weight * (project(cam, pc) - c.pixel);
        k += 2;
      }
    for (std::size_t s = 0; s < 2; ++s)
      for (std::size_t v = 0; v < projectors[s].views.size(); ++v) {
        const std::size_t i = projectors[s].camera_view[v];
        for (const CornerObservation& c : projectors[s].views[v].corners) {
          const Eigen::Vector3d pc = rotations[i] * target.corner(c.id) + poses[i].t;
          out.segment<2>(k) = projector_weight[s] * (project(proj[s], rpc[s] * pc + proj_from_cam[s].t) - c.pixel);
          k += 2;
        }
      }
    return out;
  };
  Eigen::VectorXd step = Eigen::VectorXd::Constant(x.size(), 1e-6);
  step.head<4>().setConstant(1e-3);
  for (std::size_t s = 0; s < 2; ++s) {
    const Eigen::Index at = projector_base + static_cast<Eigen::Index>(s) * (kIntrinsics + 6);
    step.segment<4>(at).setConstant(1e-3);
    step.segment<3>(at + kIntrinsics + 3).setConstant(1e-5);
  }
  for (Eigen::Index i = pose_base + 3; i < x.size(); i += 6) step.segment<3>(i).setConstant(1e-5);
  levenberg_marquardt(residuals, x, step, 50);
  x = unpack(x);

  RigBundle out;
  out.camera.model = intrinsics_from(x.head<kIntrinsics>(), camera.model.width, camera.model.height);
  if (auto status = out.camera.model.check("rig refinement (camera)"); !status)
    throw std::runtime_error(status.error().message + " (are the views varied enough?)");
  double sum = 0;
  std::size_t count = 0;
  for (std::size_t i = 0; i < n; ++i) {
    out.camera.from_target.push_back(pose_at(x, pose_base + 6 * static_cast<Eigen::Index>(i)).transform());
    const double rms = view_reprojection_rms(target, out.camera.model, out.camera.from_target[i], camera_views[i]);
    out.camera.view_rms_px.push_back(rms);
    sum += rms * rms * static_cast<double>(camera_views[i].corners.size());
    count += camera_views[i].corners.size();
  }
  out.camera.rms_px = std::sqrt(sum / static_cast<double>(count));
  for (std::size_t s = 0; s < 2; ++s) {
    const Eigen::Index at = projector_base + static_cast<Eigen::Index>(s) * (kIntrinsics + 6);
    slproto::ProjectorCalibration& p = out.projectors[s];
    p.intrinsics = intrinsics_from(x.segment<kIntrinsics>(at), projectors[s].start.intrinsics.width,
                                   projectors[s].start.intrinsics.height);
    if (auto status = p.intrinsics.check("rig refinement (projector)"); !status)
      throw std::runtime_error(status.error().message + " (are the views varied enough?)");
    const RigidTransform proj_from_cam = pose_at(x, at + kIntrinsics).transform();
    p.cam_from_proj = proj_from_cam.inverse();
    double psum = 0;
    std::size_t pcount = 0;
    for (std::size_t v = 0; v < projectors[s].views.size(); ++v) {
      const double rms = view_reprojection_rms(target, p.intrinsics,
                                               proj_from_cam * out.camera.from_target[projectors[s].camera_view[v]],
                                               projectors[s].views[v]);
      out.projector_view_rms_px[s].push_back(rms);
      psum += rms * rms * static_cast<double>(projectors[s].views[v].corners.size());
      pcount += projectors[s].views[v].corners.size();
    }
    p.reprojection_rms_px = std::sqrt(psum / static_cast<double>(std::max<std::size_t>(pcount, 1)));
  }
  return out;
}

// ---------------------------------------------------------------- turntable

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
