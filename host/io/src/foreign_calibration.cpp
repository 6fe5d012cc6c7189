#include "slscan/io/foreign_calibration.hpp"

#include <cmath>
#include <fstream>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <sstream>
#include <vector>

#include "slscan/io/ply.hpp"

namespace slscan::io {

namespace {

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw IoError(path + ": cannot open the calibration file");
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

// The first of `names` present in the file, or an empty node.
cv::FileNode first_of(const cv::FileStorage& fs, std::initializer_list<const char*> names, std::string& found) {
  for (const char* name : names) {
    cv::FileNode node = fs[name];
    if (!node.empty()) {
      found = name;
      return node;
    }
  }
  return {};
}

std::string list_names(std::initializer_list<const char*> names) {
  std::string out;
  for (const char* name : names) out += (out.empty() ? "" : " or ") + std::string(name);
  return out;
}

cv::Mat read_matrix(const cv::FileStorage& fs, const std::string& path, std::initializer_list<const char*> names,
                    std::string& found) {
  cv::FileNode node = first_of(fs, names, found);
  if (node.empty()) throw IoError(path + ": no " + list_names(names) + " entry");
  cv::Mat m;
  try {
    node >> m;
  } catch (const cv::Exception& e) {
    throw IoError(path + ": " + found + " is not a matrix (" + e.what() + ")");
  }
  if (m.empty()) throw IoError(path + ": " + found + " is empty");
  cv::Mat d;
  m.convertTo(d, CV_64F);
  for (auto it = d.begin<double>(); it != d.end<double>(); ++it)
    if (!std::isfinite(*it)) throw IoError(path + ": " + found + " has a non-finite value");
  return d;
}

void read_intrinsics(const cv::Mat& k, const std::string& path, const std::string& name, slproto::PinholeModel& model) {
  if (k.rows != 3 || k.cols != 3)
    throw IoError(path + ": " + name + " is " + std::to_string(k.rows) + " x " + std::to_string(k.cols) +
                  ", expected a 3 x 3 camera matrix");
  if (k.at<double>(0, 1) != 0.0)
    throw IoError(path + ": " + name + " has a skew term (" + std::to_string(k.at<double>(0, 1)) +
                  "), which the pinhole model does not have");
  model.fx = k.at<double>(0, 0);
  model.fy = k.at<double>(1, 1);
  model.cx = k.at<double>(0, 2);
  model.cy = k.at<double>(1, 2);
}

void read_distortion(const cv::Mat& d, const std::string& path, const std::string& name, slproto::LensDistortion& out) {
  const int n = static_cast<int>(d.total());
  if (n != 4 && n != 5 && n != 8 && n != 12 && n != 14)
    throw IoError(path + ": " + name + " has " + std::to_string(n) +
                  " coefficients; OpenCV distortion vectors have 4, 5, 8, 12 or 14");
  const double* c = d.ptr<double>();
  out.k1 = c[0];
  out.k2 = c[1];
  out.p1 = c[2];
  out.p2 = c[3];
  out.k3 = n > 4 ? c[4] : 0.0;
  for (int i = 5; i < n; ++i)
    if (c[i] != 0.0)
      throw IoError(path + ": " + name + " coefficient " + std::to_string(i) + " is " + std::to_string(c[i]) +
                    "; only k1 k2 p1 p2 k3 are modelled");
}

int read_int(const cv::FileStorage& fs, std::initializer_list<const char*> names, int fallback) {
  std::string found;
  cv::FileNode node = first_of(fs, names, found);
  if (node.empty() || (!node.isReal() && !node.isInt())) return fallback;
  return static_cast<int>(std::lround(static_cast<double>(node)));
}

double read_real(const cv::FileStorage& fs, std::initializer_list<const char*> names) {
  std::string found;
  cv::FileNode node = first_of(fs, names, found);
  if (node.empty() || (!node.isReal() && !node.isInt())) return 0.0;
  return static_cast<double>(node);
}

int merge_size(int from_file, int from_options, const std::string& path, const std::string& what) {
  if (from_file > 0 && from_options > 0 && from_file != from_options)
    throw IoError(path + ": the file says " + what + " is " + std::to_string(from_file) + " but " +
                  std::to_string(from_options) + " was given");
  const int size = from_file > 0 ? from_file : from_options;
  if (size <= 0)
    throw IoError(path + ": the file does not give the " + what + "; pass it (e.g. the import description's " + what +
                  ")");
  return size;
}

}  // namespace

slproto::TurntableCalibration placeholder_turntable() {
  slproto::TurntableCalibration table;
  // Platform 100 m along the optical axis, its +z (up) towards the camera: every point in
  // front of the camera is "above the platform" and inside the radius.
  table.cam_from_table.R = {1, 0, 0, 0, -1, 0, 0, 0, -1};
  table.cam_from_table.t = {0, 0, 100000};
  table.platform_radius_mm = 1e6;
  return table;
}

slproto::RigCalibration read_foreign_calibration(const std::string& path, const ForeignCalibrationOptions& options) {
  const std::string text = read_text(path);
  const auto first = text.find_first_not_of(" \t\r\n");
  if (first != std::string::npos && text[first] == '{' && text.find("\"format_version\"") != std::string::npos) {
    auto ours = slproto::parse_calibration(text, path);
    if (!ours.ok()) throw IoError(ours.error().message);
    return *ours;
  }

  cv::FileStorage fs;
  try {
    fs.open(text, cv::FileStorage::READ | cv::FileStorage::MEMORY);
  } catch (const cv::Exception& e) {
    throw IoError(path + ": not an OpenCV FileStorage file nor our JSON calibration (" + e.what() + ")");
  }
  if (!fs.isOpened()) throw IoError(path + ": not an OpenCV FileStorage file nor our JSON calibration");

  slproto::RigCalibration rig;
  std::string name;
  read_intrinsics(read_matrix(fs, path, {"Kc", "K1", "K_cam", "camera_matrix", "K"}, name), path, name, rig.camera);
  read_distortion(read_matrix(fs, path, {"kc", "D1", "D_cam", "dist_coeffs", "D"}, name), path, name,
                  rig.camera.distortion);
  slproto::ProjectorCalibration projector;
  read_intrinsics(read_matrix(fs, path, {"Kp", "K2", "K_proj"}, name), path, name, projector.intrinsics);
  read_distortion(read_matrix(fs, path, {"kp", "D2", "D_proj"}, name), path, name, projector.intrinsics.distortion);
  cv::Mat r = read_matrix(fs, path, {"Rp", "R"}, name);
  if (r.total() == 3) {  // a rotation vector
    cv::Mat rotation;
    cv::Rodrigues(r.reshape(1, 3), rotation);
    r = rotation;
  }
  if (r.rows != 3 || r.cols != 3) throw IoError(path + ": " + name + " is neither a 3 x 3 rotation nor a 3-vector");
  std::string t_name;
  const cv::Mat t = read_matrix(fs, path, {"Tp", "T"}, t_name);
  if (t.total() != 3) throw IoError(path + ": " + t_name + " has " + std::to_string(t.total()) + " values, expected 3");
  slproto::RigidTransform pose;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) pose.R[static_cast<std::size_t>(3 * i + j)] = r.at<double>(i, j);
    pose.t[static_cast<std::size_t>(i)] = t.ptr<double>()[i];
  }
  if (auto status = pose.check(path + ": " + name + "/" + t_name); !status) throw IoError(status.error().message);
  projector.cam_from_proj = options.pose_direction == PoseDirection::proj_from_cam ? pose.inverse() : pose;

  rig.camera.width = merge_size(read_int(fs, {"frameWidth", "image_width", "camera_width"}, 0), options.camera_width,
                                path, "camera width");
  rig.camera.height = merge_size(read_int(fs, {"frameHeight", "image_height", "camera_height"}, 0),
                                 options.camera_height, path, "camera height");
  projector.intrinsics.width =
      merge_size(read_int(fs, {"screenResX", "projector_width"}, 0), options.projector_width, path, "projector width");
  projector.intrinsics.height = merge_size(read_int(fs, {"screenResY", "projector_height"}, 0),
                                           options.projector_height, path, "projector height");
  rig.camera_reprojection_rms_px = read_real(fs, {"cam_error", "camera_rms"});
  projector.reprojection_rms_px = read_real(fs, {"proj_error", "projector_rms"});
  rig.projectors = {projector, projector};
  rig.turntable = placeholder_turntable();
  rig.pattern_plan.projector_width = projector.intrinsics.width;
  rig.pattern_plan.projector_height = projector.intrinsics.height;
  rig.source = path;
  rig.created_by = "slscan import (one-projector rig: projector 0, copied into both slots)";
  if (auto status = rig.check(); !status) throw IoError(path + ": " + status.error().message);
  return rig;
}

}  // namespace slscan::io
