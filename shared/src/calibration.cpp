#include "slproto/calibration.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>
#include <numbers>
#include <sstream>

namespace slproto {

using json = nlohmann::json;

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

Status PinholeModel::check(std::string_view what) const {
  auto fail = [&](const std::string& msg) {
    return make_error(Errc::invalid_argument, std::string(what) + ": " + msg);
  };
  if (width <= 0 || height <= 0 || width > 65536 || height > 65536)
    return fail("image size " + std::to_string(width) + " x " + std::to_string(height) + " is impossible");
  for (double value : {fx, fy, cx, cy, distortion.k1, distortion.k2, distortion.p1, distortion.p2, distortion.k3})
    if (!std::isfinite(value)) return fail("a parameter is not a finite number");
  if (fx <= 0 || fy <= 0)
    return fail("focal lengths must be positive (fx " + std::to_string(fx) + ", fy " + std::to_string(fy) + ")");
  if (cx < -width || cx > 2.0 * width || cy < -height || cy > 2.0 * height)
    return fail("principal point (" + std::to_string(cx) + ", " + std::to_string(cy) + ") lies far outside the image");
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
  for (double value : R)
    if (!std::isfinite(value))
      return make_error(Errc::invalid_argument, std::string(what) + ": rotation is not finite");
  for (double value : t)
    if (!std::isfinite(value))
      return make_error(Errc::invalid_argument, std::string(what) + ": translation is not finite");
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
                                                  ": rotation is not orthonormal with determinant +1 (error " +
                                                  std::to_string(worst) + ", det " + std::to_string(det) + ")");
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
    if (auto s = projectors[i].intrinsics.check(name); !s) return s;
    if (auto s = projectors[i].cam_from_proj.check(name + ".cam_from_proj"); !s) return s;
  }
  if (auto s = turntable.cam_from_table.check("turntable.cam_from_table"); !s) return s;
  if (!(turntable.platform_radius_mm > 0) || !std::isfinite(turntable.platform_radius_mm))
    return make_error(Errc::invalid_argument, "turntable.platform_radius_mm must be positive");
  if (auto s = pattern_plan.check(); !s) return s;
  return Ok{};
}

// ---------------------------------------------------------------- JSON

namespace {

json to_json_model(const PinholeModel& m) {
  return {{"width", m.width},
          {"height", m.height},
          {"fx", m.fx},
          {"fy", m.fy},
          {"cx", m.cx},
          {"cy", m.cy},
          {"distortion",
           {{"k1", m.distortion.k1},
            {"k2", m.distortion.k2},
            {"p1", m.distortion.p1},
            {"p2", m.distortion.p2},
            {"k3", m.distortion.k3}}}};
}

json to_json_pose(const RigidTransform& p) { return {{"R", p.R}, {"t", p.t}}; }

json to_json_plan(const PatternPlanConfig& c) {
  return {{"projector_width", c.projector_width},
          {"projector_height", c.projector_height},
          {"axis", coding_axis_name(c.axis)},
          {"period_px", c.period_px},
          {"phase_steps", c.phase_steps},
          {"complementary_bit", c.complementary_bit},
          {"with_white_black", c.with_white_black},
          {"inverse_gray", c.inverse_gray},
          {"gray_low_bits", gray_low_bits_name(c.gray_low_bits)}};
}

// Reads fields with their full path in error messages ("camera.fx: missing").
struct Reader {
  std::string origin;
  const json& at(const json& obj, const std::string& path, const char* key) const {
    if (!obj.is_object()) throw std::runtime_error(path + ": expected an object");
    auto it = obj.find(key);
    if (it == obj.end()) throw std::runtime_error(path + "." + key + ": missing");
    return *it;
  }
  double number(const json& obj, const std::string& path, const char* key) const {
    const json& v = at(obj, path, key);
    if (!v.is_number()) throw std::runtime_error(path + "." + key + ": expected a number");
    return v.get<double>();
  }
  int integer(const json& obj, const std::string& path, const char* key) const {
    const json& v = at(obj, path, key);
    if (!v.is_number_integer()) throw std::runtime_error(path + "." + key + ": expected an integer");
    return v.get<int>();
  }
  bool boolean(const json& obj, const std::string& path, const char* key) const {
    const json& v = at(obj, path, key);
    if (!v.is_boolean()) throw std::runtime_error(path + "." + key + ": expected true or false");
    return v.get<bool>();
  }
  std::string text(const json& obj, const std::string& path, const char* key) const {
    const json& v = at(obj, path, key);
    if (!v.is_string()) throw std::runtime_error(path + "." + key + ": expected a string");
    return v.get<std::string>();
  }
  template <std::size_t N>
  std::array<double, N> array(const json& obj, const std::string& path, const char* key) const {
    const json& v = at(obj, path, key);
    if (!v.is_array() || v.size() != N)
      throw std::runtime_error(path + "." + key + ": expected an array of " + std::to_string(N) + " numbers");
    std::array<double, N> out{};
    for (std::size_t i = 0; i < N; ++i) {
      if (!v[i].is_number())
        throw std::runtime_error(path + "." + key + "[" + std::to_string(i) + "]: expected a number");
      out[i] = v[i].get<double>();
    }
    return out;
  }
  PinholeModel model(const json& obj, const std::string& path) const {
    PinholeModel m;
    m.width = integer(obj, path, "width");
    m.height = integer(obj, path, "height");
    m.fx = number(obj, path, "fx");
    m.fy = number(obj, path, "fy");
    m.cx = number(obj, path, "cx");
    m.cy = number(obj, path, "cy");
    const json& d = at(obj, path, "distortion");
    const std::string dp = path + ".distortion";
    m.distortion = {number(d, dp, "k1"), number(d, dp, "k2"), number(d, dp, "p1"), number(d, dp, "p2"),
                    number(d, dp, "k3")};
    return m;
  }
  RigidTransform pose(const json& obj, const std::string& path) const {
    RigidTransform p;
    p.R = array<9>(obj, path, "R");
    p.t = array<3>(obj, path, "t");
    return p;
  }
  PatternPlanConfig plan(const json& obj, const std::string& path) const {
    PatternPlanConfig c;
    c.projector_width = integer(obj, path, "projector_width");
    c.projector_height = integer(obj, path, "projector_height");
    const std::string axis = text(obj, path, "axis");
    if (axis == "columns")
      c.axis = CodingAxis::columns;
    else if (axis == "rows")
      c.axis = CodingAxis::rows;
    else
      throw std::runtime_error(path + ".axis: expected \"columns\" or \"rows\", got \"" + axis + "\"");
    c.period_px = integer(obj, path, "period_px");
    c.phase_steps = integer(obj, path, "phase_steps");
    c.complementary_bit = boolean(obj, path, "complementary_bit");
    c.with_white_black = boolean(obj, path, "with_white_black");
    // Later additions: optional, so files written before them still read (as false, centre).
    if (obj.contains("inverse_gray")) c.inverse_gray = boolean(obj, path, "inverse_gray");
    if (obj.contains("gray_low_bits")) {
      const std::string convention = text(obj, path, "gray_low_bits");
      if (convention == "centre")
        c.gray_low_bits = GrayLowBits::centre;
      else if (convention == "slstudio_parity")
        c.gray_low_bits = GrayLowBits::slstudio_parity;
      else
        throw std::runtime_error(path + ".gray_low_bits: expected \"centre\" or \"slstudio_parity\", got \"" +
                                 convention + "\"");
    }
    return c;
  }
};

}  // namespace

std::string format_calibration(const RigCalibration& cal) {
  json projectors = json::object();
  for (std::size_t i = 0; i < cal.projectors.size(); ++i) {
    const ProjectorCalibration& p = cal.projectors[i];
    projectors[projector_side_name(static_cast<ProjectorSide>(i))] = {{"intrinsics", to_json_model(p.intrinsics)},
                                                                      {"cam_from_proj", to_json_pose(p.cam_from_proj)},
                                                                      {"reprojection_rms_px", p.reprojection_rms_px}};
  }
  json doc = {
      {"format", "slscan-calibration"},
      {"format_version", cal.format_version},
      {"units", "mm"},
      {"camera", to_json_model(cal.camera)},
      {"camera_reprojection_rms_px", cal.camera_reprojection_rms_px},
      {"projectors", projectors},
      {"turntable",
       {{"cam_from_table", to_json_pose(cal.turntable.cam_from_table)},
        {"platform_radius_mm", cal.turntable.platform_radius_mm},
        {"pose_residual_mm", cal.turntable.pose_residual_mm}}},
      {"pattern_plan", to_json_plan(cal.pattern_plan)},
      {"source", cal.source},
      {"created_by", cal.created_by},
  };
  return doc.dump(2) + "\n";
}

Result<RigCalibration> parse_calibration(std::string_view text, std::string_view origin) {
  const std::string where(origin);
  json doc;
  try {
    doc = json::parse(text.begin(), text.end());
  } catch (const json::exception& e) {  // parse_error, and out_of_range for a number beyond double
    return make_error(Errc::malformed, where + ": not valid JSON (" + e.what() + ")");
  }
  Reader r{where};
  RigCalibration cal;
  try {
    if (!doc.is_object()) throw std::runtime_error("top level: expected an object");
    if (r.text(doc, "", "format") != "slscan-calibration")
      throw std::runtime_error("format: expected \"slscan-calibration\"");
    cal.format_version = r.integer(doc, "", "format_version");
    if (cal.format_version != RigCalibration::kFormatVersion)
      return make_error(Errc::wrong_version, where + ": format_version " + std::to_string(cal.format_version) +
                                                 " is not supported (this build reads version " +
                                                 std::to_string(RigCalibration::kFormatVersion) + ")");
    if (r.text(doc, "", "units") != "mm") throw std::runtime_error("units: only \"mm\" is supported");
    cal.camera = r.model(r.at(doc, "", "camera"), "camera");
    cal.camera_reprojection_rms_px = r.number(doc, "", "camera_reprojection_rms_px");
    const json& projectors = r.at(doc, "", "projectors");
    for (std::size_t i = 0; i < cal.projectors.size(); ++i) {
      const char* side = projector_side_name(static_cast<ProjectorSide>(i));
      const std::string path = std::string("projectors.") + side;
      const json& p = r.at(projectors, "projectors", side);
      cal.projectors[i].intrinsics = r.model(r.at(p, path, "intrinsics"), path + ".intrinsics");
      cal.projectors[i].cam_from_proj = r.pose(r.at(p, path, "cam_from_proj"), path + ".cam_from_proj");
      cal.projectors[i].reprojection_rms_px = r.number(p, path, "reprojection_rms_px");
    }
    const json& table = r.at(doc, "", "turntable");
    cal.turntable.cam_from_table = r.pose(r.at(table, "turntable", "cam_from_table"), "turntable.cam_from_table");
    cal.turntable.platform_radius_mm = r.number(table, "turntable", "platform_radius_mm");
    cal.turntable.pose_residual_mm = r.number(table, "turntable", "pose_residual_mm");
    cal.pattern_plan = r.plan(r.at(doc, "", "pattern_plan"), "pattern_plan");
    cal.source = r.text(doc, "", "source");
    cal.created_by = r.text(doc, "", "created_by");
  } catch (const std::exception& e) {
    std::string msg = e.what();
    if (!msg.empty() && msg[0] == '.') msg.erase(0, 1);
    return make_error(Errc::malformed, where + ": " + msg);
  }
  if (auto status = cal.check(); !status) return make_error(status.error().code, where + ": " + status.error().message);
  return cal;
}

std::string format_pattern_plan(const PatternPlanConfig& config) { return to_json_plan(config).dump(); }

Result<PatternPlanConfig> parse_pattern_plan(std::string_view json_text, std::string_view origin) {
  const std::string where(origin);
  PatternPlanConfig config;
  try {
    const json doc = json::parse(json_text);
    if (!doc.is_object()) return make_error(Errc::malformed, where + ": expected a JSON object");
    config = Reader{where}.plan(doc, "");
  } catch (const std::exception& e) {
    std::string msg = e.what();
    if (!msg.empty() && msg[0] == '.') msg.erase(0, 1);
    return make_error(Errc::malformed, where + ": " + msg);
  }
  if (auto status = config.check(); !status)
    return make_error(status.error().code, where + ": " + status.error().message);
  return config;
}

Result<RigCalibration> load_calibration(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return make_error(Errc::io_error, path + ": cannot open (" + std::strerror(errno) + ")");
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) return make_error(Errc::io_error, path + ": read failed");
  return parse_calibration(text.str(), path);
}

Status save_calibration(const std::string& path, const RigCalibration& calibration) {
  if (auto status = calibration.check(); !status) return status;
  return write_file_atomically(path, format_calibration(calibration));
}

Status write_file_atomically(const std::string& path, std::string_view bytes) {
  const std::string tmp = path + ".tmp." + std::to_string(::getpid());
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return make_error(Errc::io_error, tmp + ": cannot create (" + std::strerror(errno) + ")");
  std::size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const std::string why = std::strerror(errno);
      ::close(fd);
      ::unlink(tmp.c_str());
      return make_error(Errc::io_error, tmp + ": write failed (" + why + ")");
    }
    done += static_cast<std::size_t>(n);
  }
  if (::fsync(fd) != 0 || ::close(fd) != 0) {
    const std::string why = std::strerror(errno);
    ::unlink(tmp.c_str());
    return make_error(Errc::io_error, tmp + ": flush failed (" + why + ")");
  }
  if (::rename(tmp.c_str(), path.c_str()) != 0) {
    const std::string why = std::strerror(errno);
    ::unlink(tmp.c_str());
    return make_error(Errc::io_error, path + ": rename failed (" + why + ")");
  }
  return Ok{};
}

}  // namespace slproto
