// Geometric model of the rig: lenses, poses, projectors, turntable, and the calibration that
// holds them. Shared by the virtual rig (its ground truth), calibration (which estimates it) and
// the host pipeline. The file format is calibration_file.hpp.
//
// Conventions (docs/conventions.md): millimetres; camera and projector frames are OpenCV's
// (x right, y down, z forward); pixel centres at integer coordinates; poses are named
// target_from_source and map a point in `source` coordinates to `target` coordinates.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <string_view>

#include "slproto/pattern_plan.hpp"
#include "slproto/result.hpp"

namespace slproto {

using Vec3 = std::array<double, 3>;
using Mat3 = std::array<double, 9>;  // row-major

// Brown-Conrady distortion, OpenCV order and meaning.
struct LensDistortion {
  double k1 = 0, k2 = 0, p1 = 0, p2 = 0, k3 = 0;
  bool operator==(const LensDistortion&) const = default;
  bool is_zero() const { return k1 == 0 && k2 == 0 && p1 == 0 && p2 == 0 && k3 == 0; }
};

// A pinhole camera (or an inverse one: a projector) with lens distortion.
struct PinholeModel {
  int width = 0, height = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0;
  LensDistortion distortion;
  bool operator==(const PinholeModel&) const = default;

  // Normalised undistorted (x, y) -> normalised distorted.
  void distort(double x, double y, double& xd, double& yd) const;
  // Normalised distorted -> undistorted, by fixed-point iteration to ~1e-14 (exact inverse
  // within the image, not a small-distortion approximation). False if it does not converge.
  bool undistort(double xd, double yd, double& x, double& y) const;
  // Point in the device frame -> pixel. False behind the device (z <= 0).
  bool project(const Vec3& p, double& u, double& v) const;
  // Pixel -> undistorted normalised coordinates (ray direction (x, y, 1)).
  bool pixel_to_ray(double u, double v, double& x, double& y) const;
  Status check(std::string_view what) const;
};

struct RigidTransform {
  Mat3 R{1, 0, 0, 0, 1, 0, 0, 0, 1};
  Vec3 t{0, 0, 0};
  bool operator==(const RigidTransform&) const = default;

  Vec3 apply(const Vec3& p) const;
  Vec3 rotate(const Vec3& d) const;
  RigidTransform inverse() const;
  // (this * other)(p) = this(other(p)): a_from_c = a_from_b * b_from_c.
  RigidTransform operator*(const RigidTransform& other) const;
  // Rotation about the unit axis `axis` through point `centre` by `angle_rad` (Rodrigues).
  static RigidTransform rotation_about_axis(const Vec3& axis, const Vec3& centre, double angle_rad);
  Status check(std::string_view what) const;  // R orthonormal with det +1, finite values
};

enum class ProjectorSide : std::uint8_t { left = 0, right = 1 };
const char* projector_side_name(ProjectorSide side) noexcept;

struct ProjectorCalibration {
  PinholeModel intrinsics;         // width x height = the DMD's resolution
  RigidTransform cam_from_proj;    // projector frame -> camera frame
  double reprojection_rms_px = 0;  // of the calibration that made it (0 for ground truth)
  bool operator==(const ProjectorCalibration&) const = default;
};

// The turntable frame: origin at the platform centre on its top surface, z along the rotation
// axis pointing away from the platform, angles counter-clockwise seen from above (+z).
struct TurntableCalibration {
  RigidTransform cam_from_table;  // the table frame at angle 0
  double platform_radius_mm = 150;
  double pose_residual_mm = 0;  // of the calibration that made it (0 for ground truth)
  bool operator==(const TurntableCalibration&) const = default;

  Vec3 axis_point() const { return cam_from_table.t; }
  Vec3 axis_direction() const { return {cam_from_table.R[2], cam_from_table.R[5], cam_from_table.R[8]}; }
  // Camera-frame transform that turns a point by `angle_deg` about the axis (Formula 8
  // computed directly for the angle, not as a power of a one-step transform).
  RigidTransform rotation_in_camera(double angle_deg) const;
};

struct RigCalibration {
  static constexpr int kFormatVersion = 1;
  int format_version = kFormatVersion;
  PinholeModel camera;
  double camera_reprojection_rms_px = 0;
  std::array<ProjectorCalibration, 2> projectors;  // indexed by ProjectorSide
  TurntableCalibration turntable;
  PatternPlanConfig pattern_plan;
  std::string source;      // the capture it came from, or "virtual rig ground truth"
  std::string created_by;  // program and version

  const ProjectorCalibration& projector(ProjectorSide side) const { return projectors[static_cast<std::size_t>(side)]; }
  Status check() const;
  bool operator==(const RigCalibration&) const = default;
};

}  // namespace slproto
