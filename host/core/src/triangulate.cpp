#include "slscan/core/triangulate.hpp"

#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/parallel_for.h>

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace slscan::core {

CameraRayTable CameraRayTable::build(const slproto::PinholeModel& camera) {
  if (auto status = camera.check("camera"); !status) throw std::invalid_argument(status.error().message);
  CameraRayTable table;
  table.width = camera.width;
  table.height = camera.height;
  const auto n = static_cast<std::size_t>(camera.width) * static_cast<std::size_t>(camera.height);
  table.x.resize(n);
  table.y.resize(n);
  tbb::parallel_for(tbb::blocked_range<int>(0, camera.height, 8), [&](const tbb::blocked_range<int>& rows) {
    const float nan = std::numeric_limits<float>::quiet_NaN();
    for (int v = rows.begin(); v < rows.end(); ++v)
      for (int u = 0; u < camera.width; ++u) {
        const std::size_t i =
            static_cast<std::size_t>(v) * static_cast<std::size_t>(camera.width) + static_cast<std::size_t>(u);
        double x = 0, y = 0;
        const bool ok = camera.pixel_to_ray(u, v, x, y);
        table.x[i] = ok ? static_cast<float>(x) : nan;
        table.y[i] = ok ? static_cast<float>(y) : nan;
      }
  });
  return table;
}

void TriangulateOptions::check() const {
  auto fail = [](const std::string& msg) { throw std::invalid_argument("triangulate options: " + msg); };
  if (newton_iterations < 1 || newton_iterations > 50)
    fail("newton_iterations " + std::to_string(newton_iterations) + " outside [1, 50]");
  if (!(max_residual_px > 0) || !std::isfinite(max_residual_px)) fail("max_residual_px must be positive and finite");
  if (!(frustum_margin_px >= 0) || !std::isfinite(frustum_margin_px)) fail("frustum_margin_px must be >= 0 and finite");
  if (!(min_depth_mm >= 0) || !(max_depth_mm > min_depth_mm) || !std::isfinite(max_depth_mm))
    fail("depth range [" + std::to_string(min_depth_mm) + ", " + std::to_string(max_depth_mm) + "] mm is empty");
}

ProjectorTriangulator::ProjectorTriangulator(std::shared_ptr<const CameraRayTable> rays,
                                             const slproto::ProjectorCalibration& projector, slproto::CodingAxis axis,
                                             const TriangulateOptions& options)
    : rays_(std::move(rays)), projector_(projector.intrinsics), axis_(axis), options_(options) {
  options_.check();
  if (!rays_ || rays_->width <= 0 || rays_->height <= 0 ||
      rays_->x.size() != static_cast<std::size_t>(rays_->width) * static_cast<std::size_t>(rays_->height) ||
      rays_->y.size() != rays_->x.size())
    throw std::invalid_argument("triangulator: camera ray table is missing or inconsistent");
  if (auto status = projector.intrinsics.check("projector"); !status)
    throw std::invalid_argument(status.error().message);
  if (auto status = projector.cam_from_proj.check("projector cam_from_proj"); !status)
    throw std::invalid_argument(status.error().message);
  const slproto::RigidTransform proj_from_cam = projector.cam_from_proj.inverse();
  for (int i = 0; i < 9; ++i) r_[i] = proj_from_cam.R[static_cast<std::size_t>(i)];
  for (int i = 0; i < 3; ++i) b_[i] = proj_from_cam.t[static_cast<std::size_t>(i)];
  const auto& d = projector_.distortion;
  k1_ = d.k1;
  k2_ = d.k2;
  k3_ = d.k3;
  p1_ = d.p1;
  p2_ = d.p2;
  fx_ = projector_.fx;
  fy_ = projector_.fy;
  cx_ = projector_.cx;
  cy_ = projector_.cy;
  distorted_ = !d.is_zero();
}

// The camera point t (rx, ry, 1) is Xp(t) = t a + b in the projector frame. The plane through
// the projector centre and the ray, normal l = a x b, cuts the projector's undistorted
// normalised image in the epipolar line l0 x + l1 y + l2 = 0. Along it, the coded coordinate
// s (x for columns, y for rows) fixes the other one, q = q0 + q1 s, and the distorted coded
// coordinate is a smooth 1D function of s: Newton solves it for the decoded value. Then the
// depth t follows linearly from s.
template <bool kColumns>
ProjectorTriangulator::Outcome ProjectorTriangulator::solve(float ray_x, float ray_y, float coord,
                                                            Eigen::Vector3f& point) const {
  const double ax = r_[0] * ray_x + r_[1] * ray_y + r_[2];
  const double ay = r_[3] * ray_x + r_[4] * ray_y + r_[5];
  const double az = r_[6] * ray_x + r_[7] * ray_y + r_[8];
  const double l0 = ay * b_[2] - az * b_[1];
  const double l1 = az * b_[0] - ax * b_[2];
  const double l2 = ax * b_[1] - ay * b_[0];
  const double l_along = kColumns ? l1 : l0;  // coefficient of the dependent coordinate
  const double l_coded = kColumns ? l0 : l1;
  const double l_norm = std::abs(l0) + std::abs(l1) + std::abs(l2);
  if (!(std::abs(l_along) > 1e-6f * l_norm)) return Outcome::no_intersection;
  const double q0 = -l2 / l_along, q1 = -l_coded / l_along;
  const double f_coded = kColumns ? fx_ : fy_, c_coded = kColumns ? cx_ : cy_;
  const double f_other = kColumns ? fy_ : fx_, c_other = kColumns ? cy_ : cx_;
  const double target = (coord - c_coded) / f_coded;
  // p_coded / p_other: the tangential coefficient that multiplies 2 x y in the coded / other
  // component (OpenCV: x gets 2 p1 x y + p2 (r2 + 2 x^2), y gets p1 (r2 + 2 y^2) + 2 p2 x y).
  const double p_coded = kColumns ? p1_ : p2_, p_other = kColumns ? p2_ : p1_;
  double s = target;
  double residual = 0.0;
  double other_distorted = 0.0;
  auto evaluate = [&](double sv, double& g, double& slope) {
    const double q = q0 + q1 * sv;
    const double r2 = sv * sv + q * q;
    const double radial = 1.0f + r2 * (k1_ + r2 * (k2_ + r2 * k3_));
    const double dradial = k1_ + r2 * (2.0f * k2_ + 3.0f * r2 * k3_);
    // Coded component: s radial + 2 p_coded s q + p_other (r2 + 2 s^2).
    g = sv * radial + 2.0f * p_coded * sv * q + p_other * (r2 + 2.0f * sv * sv) - target;
    const double d_ds = radial + 2.0f * sv * sv * dradial + 2.0f * p_coded * q + 6.0f * p_other * sv;
    const double d_dq = 2.0f * sv * q * dradial + 2.0f * p_coded * sv + 2.0f * p_other * q;
    slope = d_ds + d_dq * q1;
    other_distorted = q * radial + p_coded * (r2 + 2.0f * q * q) + 2.0f * p_other * sv * q;
  };
  if (distorted_) {
    double g = 0.0, slope = 1.0;
    // Stops once the step is below ~1e-7 projector px: two or three evaluations for a
    // DLP lens, since the start (the distorted target) is already within the distortion.
    for (int iter = 0; iter < options_.newton_iterations; ++iter) {
      evaluate(s, g, slope);
      const double step = g / slope;
      s -= step;
      if (std::abs(step) < 1e-10) break;
    }
    evaluate(s, g, slope);
    residual = std::abs(g) * f_coded;
  } else {
    const double q = q0 + q1 * s;
    other_distorted = q;
  }
  if (!(residual <= options_.max_residual_px)) return Outcome::not_converged;
  const double b_coded = kColumns ? b_[0] : b_[1];
  const double a_coded = kColumns ? ax : ay;
  const double denominator = a_coded - s * az;
  const double numerator = s * b_[2] - b_coded;
  if (!(std::abs(denominator) > 1e-12f)) return Outcome::no_intersection;
  const double t = numerator / denominator;
  if (!(t > 0.0f) || !(t * az + b_[2] > 0.0f)) return Outcome::no_intersection;
  const double other_px = f_other * other_distorted + c_other;
  const double other_extent = static_cast<double>(kColumns ? projector_.height : projector_.width);
  const double margin = options_.frustum_margin_px;
  if (!(other_px >= -0.5f - margin && other_px <= other_extent - 0.5f + margin)) return Outcome::outside_frustum;
  if (!(t >= options_.min_depth_mm && t <= options_.max_depth_mm)) return Outcome::outside_depth;
  point = Eigen::Vector3f(static_cast<float>(t * ray_x), static_cast<float>(t * ray_y), static_cast<float>(t));
  return Outcome::valid;
}

bool ProjectorTriangulator::intersect(float ray_x, float ray_y, float coord, Eigen::Vector3f& point) const {
  if (!std::isfinite(ray_x) || !std::isfinite(ray_y) || !std::isfinite(coord)) return false;
  const Outcome outcome = axis_ == slproto::CodingAxis::columns ? solve<true>(ray_x, ray_y, coord, point)
                                                                : solve<false>(ray_x, ray_y, coord, point);
  return outcome == Outcome::valid;
}

TriangulatedView ProjectorTriangulator::triangulate(const DecodedView& decoded) const {
  TriangulatedView out;
  out.counts = triangulate(decoded, out.cloud);
  return out;
}

TriangulateCounts ProjectorTriangulator::triangulate(const DecodedView& decoded, OrganizedCloud& out) const {
  if (decoded.width != rays_->width || decoded.height != rays_->height)
    throw std::invalid_argument("triangulator: decoded view is " + std::to_string(decoded.width) + " x " +
                                std::to_string(decoded.height) + " but the camera is " + std::to_string(rays_->width) +
                                " x " + std::to_string(rays_->height));
  if (decoded.axis != axis_)
    throw std::invalid_argument(std::string("triangulator: decoded view codes ") +
                                slproto::coding_axis_name(decoded.axis) + " but the triangulator expects " +
                                slproto::coding_axis_name(axis_));
  const std::size_t n = static_cast<std::size_t>(decoded.width) * static_cast<std::size_t>(decoded.height);
  if (decoded.coordinate.size() != n || decoded.quality.size() != n)
    throw std::invalid_argument("triangulator: decoded view buffers do not match its size");
  out.width = decoded.width;
  out.height = decoded.height;
  out.points.resize(n);
  out.quality.resize(n);
  out.valid.resize(n);
  tbb::combinable<TriangulateCounts> counts_by_thread;
  const int width = decoded.width;
  auto run = [&]<bool kColumns>(const tbb::blocked_range<int>& rows) {
    TriangulateCounts& counts = counts_by_thread.local();
    const float nan = std::numeric_limits<float>::quiet_NaN();
    for (int v = rows.begin(); v < rows.end(); ++v) {
      const std::size_t row = static_cast<std::size_t>(v) * static_cast<std::size_t>(width);
      for (std::size_t i = row; i < row + static_cast<std::size_t>(width); ++i) {
        const float coord = decoded.coordinate[i];
        Eigen::Vector3f point(nan, nan, nan);
        Outcome outcome = Outcome::no_intersection;
        if (!std::isfinite(coord)) {
          ++counts.not_decoded;
        } else if (!std::isfinite(rays_->x[i])) {
          ++counts.no_intersection;
        } else {
          outcome = solve<kColumns>(rays_->x[i], rays_->y[i], coord, point);
          switch (outcome) {
            case Outcome::valid:
              ++counts.valid;
              break;
            case Outcome::no_intersection:
              ++counts.no_intersection;
              break;
            case Outcome::not_converged:
              ++counts.not_converged;
              break;
            case Outcome::outside_frustum:
              ++counts.outside_frustum;
              break;
            case Outcome::outside_depth:
              ++counts.outside_depth;
              break;
          }
        }
        const bool ok = outcome == Outcome::valid && std::isfinite(coord);
        out.points[i] = ok ? point : Eigen::Vector3f(nan, nan, nan);
        out.quality[i] = ok ? decoded.quality[i] : 0.0f;
        out.valid[i] = ok ? 1 : 0;
      }
    }
  };
  tbb::parallel_for(tbb::blocked_range<int>(0, decoded.height, 8), [&](const tbb::blocked_range<int>& rows) {
    if (axis_ == slproto::CodingAxis::columns) {
      run.template operator()<true>(rows);
    } else {
      run.template operator()<false>(rows);
    }
  });
  TriangulateCounts total;
  counts_by_thread.combine_each([&](const TriangulateCounts& c) {
    total.valid += c.valid;
    total.not_decoded += c.not_decoded;
    total.no_intersection += c.no_intersection;
    total.not_converged += c.not_converged;
    total.outside_frustum += c.outside_frustum;
    total.outside_depth += c.outside_depth;
  });
  return total;
}

}  // namespace slscan::core
