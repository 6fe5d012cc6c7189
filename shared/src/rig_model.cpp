#include "slproto/rig_model.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <string>
#include <utility>

namespace {
// Physical bounds of a calibration (docs/security.md); see PinholeModel::check.
constexpr double kMinFocalPerSide = 0.01, kMaxFocalPerSide = 100.0;
constexpr double kMaxRadialDistortion = 1000.0, kMaxTangentialDistortion = 1.0;
constexpr double kMaxTranslationMm = 1e6;  // 1 km: the placeholder turntable of a foreign calibration is 100 m off
}  // namespace

namespace slproto {

// ---------------------------------------------------------------- PinholeModel

void PinholeModel::distort(double x, double y, double& xd, double& yd) const {
  const LensDistortion& d = distortion;
  const double r2 = x * x + y * y;
  const double radial = 1.0 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3));
  xd = x * radial + 2.0 * d.p1 * x * y + d.p2 * (r2 + 2.0 * x * x);
  yd = y * radial + d.p1 * (r2 + 2.0 * y * y) + 2.0 * d.p2 * x * y;
}

bool PinholeModel::undistort(double xd, double yd, double& x, double& y) const {
  x = xd;
  y = yd;
  if (distortion.is_zero()) return true;
  // Newton's method on F(x, y) = distort(x, y) - (xd, yd) with a numeric Jacobian: converges
  // in a few steps where plain fixed-point iteration can crawl at the image corners.
  for (int iter = 0; iter < 50; ++iter) {
    double fx0, fy0;
    distort(x, y, fx0, fy0);
    const double ex = fx0 - xd, ey = fy0 - yd;
    if (std::abs(ex) < 1e-15 && std::abs(ey) < 1e-15) return true;
    const double h = 1e-7;
    double fxx, fyx, fxy, fyy;
    distort(x + h, y, fxx, fyx);
    distort(x, y + h, fxy, fyy);
    const double j00 = (fxx - fx0) / h, j10 = (fyx - fy0) / h;
    const double j01 = (fxy - fx0) / h, j11 = (fyy - fy0) / h;
    const double det = j00 * j11 - j01 * j10;
    if (!std::isfinite(det) || std::abs(det) < 1e-12) return false;
    const double dx = (j11 * ex - j01 * ey) / det;
    const double dy = (-j10 * ex + j00 * ey) / det;
    x -= dx;
    y -= dy;
    if (std::abs(dx) < 1e-15 && std::abs(dy) < 1e-15) return true;
  }
  double fx0, fy0;
  distort(x, y, fx0, fy0);
  return std::abs(fx0 - xd) < 1e-12 && std::abs(fy0 - yd) < 1e-12;
}

bool PinholeModel::project(const Vec3& p, double& u, double& v) const {
  if (!(p[2] > 0)) return false;
  double xd, yd;
  distort(p[0] / p[2], p[1] / p[2], xd, yd);
  u = fx * xd + cx;
  v = fy * yd + cy;
  return true;
}

bool PinholeModel::pixel_to_ray(double u, double v, double& x, double& y) const {
  return undistort((u - cx) / fx, (v - cy) / fy, x, y);
}

namespace {

// A number as a message shows it: 6 significant digits, scientific when huge or tiny (1e+308,
// not std::to_string's 309 digits).
std::string shown(double value) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.6g", value);
  return buffer;
}

}  // namespace

// The physical bounds of a pinhole model (docs/security.md): what a real camera or projector
// can have, wide enough for any lens we may meet, tight enough that no later stage meets a
// pixel coordinate beyond what a double or a long holds. `what` is the field path.
Status PinholeModel::check(std::string_view what) const {
  const std::string path(what);
  auto fail = [&](const std::string& field, const std::string& msg) {
    return make_error(Errc::invalid_argument, path + "." + field + ": " + msg);
  };
  if (width <= 0 || height <= 0 || width > 65536 || height > 65536)
    return make_error(Errc::invalid_argument, path + ": image size " + std::to_string(width) + " x " +
                                                  std::to_string(height) + " is impossible (1 to 65536 pixels a side)");
  const std::pair<const char*, double> values[] = {{"fx", fx},
                                                   {"fy", fy},
                                                   {"cx", cx},
                                                   {"cy", cy},
                                                   {"distortion.k1", distortion.k1},
                                                   {"distortion.k2", distortion.k2},
                                                   {"distortion.p1", distortion.p1},
                                                   {"distortion.p2", distortion.p2},
                                                   {"distortion.k3", distortion.k3}};
  for (const auto& [field, value] : values)
    if (!std::isfinite(value)) return fail(field, "not a finite number");
  // Focal length: from a 179 degree fisheye (0.01 x the image side) to a 0.6 degree telephoto
  // (100 x).
  const double side = std::max(width, height);
  for (const auto& [field, value] : {std::pair<const char*, double>{"fx", fx}, {"fy", fy}})
    if (!(value >= kMinFocalPerSide * side && value <= kMaxFocalPerSide * side))
      return fail(field, shown(value) + " px is not a focal length for a " + std::to_string(width) + " x " +
                             std::to_string(height) + " image (allowed " + shown(kMinFocalPerSide * side) + " to " +
                             shown(kMaxFocalPerSide * side) + ": 0.01 to 100 times its larger side)");
  if (cx < -width || cx > 2.0 * width)
    return fail(
        "cx", shown(cx) + " lies far outside the image (allowed " + shown(-width) + " to " + shown(2.0 * width) + ")");
  if (cy < -height || cy > 2.0 * height)
    return fail("cy", shown(cy) + " lies far outside the image (allowed " + shown(-height) + " to " +
                          shown(2.0 * height) + ")");
  // Distortion of normalised coordinates: a strong fisheye fit stays within units, rational fits
  // within hundreds; tangential terms are a decentring of a fraction of the focal length.
  const std::pair<const char*, double> radial[] = {
      {"distortion.k1", distortion.k1}, {"distortion.k2", distortion.k2}, {"distortion.k3", distortion.k3}};
  for (const auto& [field, value] : radial)
    if (std::abs(value) > kMaxRadialDistortion)
      return fail(field, shown(value) + " is out of range (allowed -" + shown(kMaxRadialDistortion) + " to " +
                             shown(kMaxRadialDistortion) + ")");
  for (const auto& [field, value] :
       {std::pair<const char*, double>{"distortion.p1", distortion.p1}, {"distortion.p2", distortion.p2}})
    if (std::abs(value) > kMaxTangentialDistortion)
      return fail(field, shown(value) + " is out of range (allowed -" + shown(kMaxTangentialDistortion) + " to " +
                             shown(kMaxTangentialDistortion) + ")");
  return Ok{};
}

// ---------------------------------------------------------------- RigidTransform

Vec3 RigidTransform::rotate(const Vec3& d) const {
  return {R[0] * d[0] + R[1] * d[1] + R[2] * d[2], R[3] * d[0] + R[4] * d[1] + R[5] * d[2],
          R[6] * d[0] + R[7] * d[1] + R[8] * d[2]};
}

Vec3 RigidTransform::apply(const Vec3& p) const {
  Vec3 r = rotate(p);
  return {r[0] + t[0], r[1] + t[1], r[2] + t[2]};
}

RigidTransform RigidTransform::inverse() const {
  RigidTransform out;
  out.R = {R[0], R[3], R[6], R[1], R[4], R[7], R[2], R[5], R[8]};
  const Vec3 rt = out.rotate(t);
  out.t = {-rt[0], -rt[1], -rt[2]};
  return out;
}

RigidTransform RigidTransform::operator*(const RigidTransform& other) const {
  RigidTransform out;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      out.R[r * 3 + c] =
          R[r * 3 + 0] * other.R[0 * 3 + c] + R[r * 3 + 1] * other.R[1 * 3 + c] + R[r * 3 + 2] * other.R[2 * 3 + c];
  out.t = apply(other.t);
  return out;
}

RigidTransform RigidTransform::rotation_about_axis(const Vec3& axis, const Vec3& centre, double angle_rad) {
  const double norm = std::sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]);
  const double nx = axis[0] / norm, ny = axis[1] / norm, nz = axis[2] / norm;
  const double c = std::cos(angle_rad), s = std::sin(angle_rad), v = 1.0 - c;
  RigidTransform out;
  // R = cos I + sin [n]x + (1 - cos) n n^T ; t = c - R c
  out.R = {c + v * nx * nx,      v * nx * ny - s * nz, v * nx * nz + s * ny, v * ny * nx + s * nz, c + v * ny * ny,
           v * ny * nz - s * nx, v * nz * nx - s * ny, v * nz * ny + s * nx, c + v * nz * nz};
  const Vec3 rc = out.rotate(centre);
  out.t = {centre[0] - rc[0], centre[1] - rc[1], centre[2] - rc[2]};
  return out;
}

Status RigidTransform::check(std::string_view what) const {
  for (std::size_t i = 0; i < R.size(); ++i)
    if (!std::isfinite(R[i]))
      return make_error(Errc::invalid_argument,
                        std::string(what) + ".R[" + std::to_string(i) + "]: not a finite number");
  for (std::size_t i = 0; i < t.size(); ++i)
    if (!std::isfinite(t[i]))
      return make_error(Errc::invalid_argument,
                        std::string(what) + ".t[" + std::to_string(i) + "]: not a finite number");
  const double length = std::hypot(t[0], t[1], t[2]);  // no overflow for 1e300
  if (length > kMaxTranslationMm)
    return make_error(Errc::invalid_argument, std::string(what) + ".t: " + shown(length) +
                                                  " mm from the camera is out of range (at most " +
                                                  shown(kMaxTranslationMm) + " mm)");
  double worst = 0;
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) {
      double dot = 0;
      for (int k = 0; k < 3; ++k) dot += R[k * 3 + a] * R[k * 3 + b];
      worst = std::max(worst, std::abs(dot - (a == b ? 1.0 : 0.0)));
    }
  const double det =
      R[0] * (R[4] * R[8] - R[5] * R[7]) - R[1] * (R[3] * R[8] - R[5] * R[6]) + R[2] * (R[3] * R[7] - R[4] * R[6]);
  if (worst > 1e-6 || det < 0)
    return make_error(Errc::invalid_argument, std::string(what) +
                                                  ".R: rotation is not orthonormal with determinant +1 (error " +
                                                  shown(worst) + ", det " + shown(det) + ")");
  return Ok{};
}

const char* projector_side_name(ProjectorSide side) noexcept { return side == ProjectorSide::left ? "left" : "right"; }

RigidTransform TurntableCalibration::rotation_in_camera(double angle_deg) const {
  return RigidTransform::rotation_about_axis(axis_direction(), axis_point(), angle_deg * std::numbers::pi / 180.0);
}

Status RigCalibration::check() const {
  if (format_version != kFormatVersion)
    return make_error(Errc::wrong_version, "calibration format_version " + std::to_string(format_version) +
                                               " is not the supported version " + std::to_string(kFormatVersion));
  if (auto s = camera.check("camera"); !s) return s;
  for (std::size_t i = 0; i < projectors.size(); ++i) {
    const std::string name = std::string("projectors.") + projector_side_name(static_cast<ProjectorSide>(i));
    if (auto s = projectors[i].intrinsics.check(name + ".intrinsics"); !s) return s;
    if (auto s = projectors[i].cam_from_proj.check(name + ".cam_from_proj"); !s) return s;
  }
  if (auto s = turntable.cam_from_table.check("turntable.cam_from_table"); !s) return s;
  if (!(turntable.platform_radius_mm > 0) || !(turntable.platform_radius_mm <= kMaxTranslationMm))
    return make_error(Errc::invalid_argument, "turntable.platform_radius_mm: " + shown(turntable.platform_radius_mm) +
                                                  " is out of range (above 0, at most " + shown(kMaxTranslationMm) +
                                                  " mm)");
  const std::pair<const char*, double> residuals[] = {
      {"camera_reprojection_rms_px", camera_reprojection_rms_px},
      {"projectors.left.reprojection_rms_px", projectors[0].reprojection_rms_px},
      {"projectors.right.reprojection_rms_px", projectors[1].reprojection_rms_px},
      {"turntable.pose_residual_mm", turntable.pose_residual_mm}};
  for (const auto& [field, value] : residuals)
    if (!(value >= 0 && value <= 1e6))
      return make_error(Errc::invalid_argument,
                        std::string(field) + ": " + shown(value) + " is out of range (allowed 0 to 1e+06)");
  if (auto s = pattern_plan.check(); !s) return s;
  return Ok{};
}

}  // namespace slproto
