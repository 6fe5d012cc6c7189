// The target, view checks, one view's pose and reprojection error, the angle between poses.
#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "pose_maths.hpp"
#include "slproto/number_text.hpp"
#include "slscan/core/calibration_solve.hpp"

namespace slscan::core {

using namespace calibration_detail;

void CheckerboardTarget::check() const {
  if (squares_x < 3 || squares_y < 3 || squares_x > 200 || squares_y > 200)
    throw std::invalid_argument("checkerboard target: " + std::to_string(squares_x) + " x " +
                                std::to_string(squares_y) + " squares; each side needs 3..200");
  if (!(square_mm > 0) || !std::isfinite(square_mm))
    throw std::invalid_argument("checkerboard target: square_mm must be positive, got " +
                                slproto::short_number(square_mm));
  if (!(thickness_mm >= 0) || !std::isfinite(thickness_mm))
    throw std::invalid_argument("checkerboard target: thickness_mm must be >= 0, got " +
                                slproto::short_number(thickness_mm));
}

namespace calibration_detail {

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

}  // namespace calibration_detail

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

}  // namespace slscan::core
