#include "slscan/io/foreign_calibration.hpp"

#include <fcntl.h>
#include <poll.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "slscan/io/io_error.hpp"

namespace slscan::io {

namespace {

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw IoError(path + ": cannot open the calibration file");
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
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

const std::vector<CalibrationKeys>& calibration_key_sets() {
  static const std::vector<CalibrationKeys> sets = {
      {"SLStudio", "Kc", "kc", "Kp", "kp", "Rp", "Tp", "frameWidth", "frameHeight", "screenResX", "screenResY",
       "cam_error", "proj_error", 1},
      {"OpenCV stereo sample", "M1", "D1", "M2", "D2", "R", "T", "image_width", "image_height", "projector_width",
       "projector_height", "", "", 1},
      {"OpenCV stereo (K1/D1/K2/D2)", "K1", "D1", "K2", "D2", "R", "T", "image_width", "image_height",
       "projector_width", "projector_height", "camera_rms", "projector_rms", 1},
      {"OpenCV stereoCalibrate (cameraMatrix1/distCoeffs1)", "cameraMatrix1", "distCoeffs1", "cameraMatrix2",
       "distCoeffs2", "R", "T", "image_width", "image_height", "projector_width", "projector_height", "", "", 1},
      {"camera/projector (K_cam/K_proj)", "K_cam", "D_cam", "K_proj", "D_proj", "R", "T", "camera_width",
       "camera_height", "projector_width", "projector_height", "camera_rms", "projector_rms", 1},
      {"MATLAB stereoParametersToOpenCV", "intrinsicMatrix1", "distortionCoefficients1", "intrinsicMatrix2",
       "distortionCoefficients2", "rotationMatrix", "translationVector", "", "", "", "", "", "", 1},
  };
  return sets;
}

CalibrationKeys calibration_keys_from(const std::map<std::string, std::string>& mapping, const std::string& origin) {
  CalibrationKeys keys;
  keys.name = "calibration_keys";
  std::map<std::string, std::string*> fields = {{"camera_matrix", &keys.camera_matrix},
                                                {"camera_distortion", &keys.camera_distortion},
                                                {"projector_matrix", &keys.projector_matrix},
                                                {"projector_distortion", &keys.projector_distortion},
                                                {"rotation", &keys.rotation},
                                                {"translation", &keys.translation},
                                                {"camera_width", &keys.camera_width},
                                                {"camera_height", &keys.camera_height},
                                                {"projector_width", &keys.projector_width},
                                                {"projector_height", &keys.projector_height},
                                                {"camera_error", &keys.camera_error},
                                                {"projector_error", &keys.projector_error}};
  for (const auto& [field, key] : mapping) {
    if (field == "translation_unit") {
      if (key == "mm")
        keys.translation_to_mm = 1;
      else if (key == "m")
        keys.translation_to_mm = 1000;
      else
        throw IoError(origin + ": calibration_keys.translation_unit must be \"mm\" or \"m\", got \"" + key + "\"");
      continue;
    }
    auto it = fields.find(field);
    if (it == fields.end()) {
      std::string known;
      for (const auto& f : fields) known += (known.empty() ? "" : ", ") + f.first;
      throw IoError(origin + ": calibration_keys." + field + ": unknown field (known: " + known +
                    ", translation_unit)");
    }
    *it->second = key;
  }
  for (const auto& [field, target] :
       {std::pair{"camera_matrix", &keys.camera_matrix}, std::pair{"camera_distortion", &keys.camera_distortion},
        std::pair{"projector_matrix", &keys.projector_matrix},
        std::pair{"projector_distortion", &keys.projector_distortion}, std::pair{"rotation", &keys.rotation},
        std::pair{"translation", &keys.translation}})
    if (target->empty()) throw IoError(origin + ": calibration_keys." + field + " is missing");
  return keys;
}

namespace {

// Plain YAML as PyYAML writes it (Kalibr) puts a block sequence's "- " items at the indentation
// of their key; OpenCV's parser wants them deeper: indent such items by two spaces.
std::string indent_block_sequences(const std::string& text) {
  std::istringstream in(text);
  std::string out, line;
  int key_indent = -1;  // indentation of the last "key:" line without a value
  while (std::getline(in, line)) {
    const auto first = line.find_first_not_of(' ');
    const int indent = first == std::string::npos ? -1 : static_cast<int>(first);
    if (indent >= 0 && line.compare(first, 2, "- ") == 0 && indent == key_indent) {
      line.insert(0, "  ");
    } else if (indent >= 0) {
      const auto end = line.find_last_not_of(" \t\r");
      // A line of spaces and tabs only has no last character (found by fuzz_foreign_calibration).
      key_indent =
          end != std::string::npos && line[end] == ':' ? indent : (line.compare(first, 2, "- ") == 0 ? key_indent : -1);
    }
    out += line + "\n";
  }
  return out;
}

// The files of one calibration, opened as cv::FileStorage; a key is looked up in each in turn.
class Files {
 public:
  explicit Files(const std::vector<std::string>& paths) : paths_(paths) {
    for (const auto& path : paths) {
      std::string text = read_text(path);
      // Calibration files are text. OpenCV 4.6's FileStorage parsers crash (a null read, a
      // std::length_error) on some inputs with control bytes (found by fuzz_foreign_calibration),
      // so those never reach it.
      for (std::size_t i = 0; i < text.size(); ++i) {
        const auto c = static_cast<unsigned char>(text[i]);
        if (c < 0x20 && c != '\n' && c != '\r' && c != '\t')
          throw IoError(path + ": byte " + std::to_string(i) + " is a control character (" + std::to_string(c) +
                        "): not a text calibration file");
      }
      cv::FileStorage fs;
      auto open = [&](const std::string& content) {
        try {
          fs.open(content, cv::FileStorage::READ | cv::FileStorage::MEMORY | cv::FileStorage::FORMAT_AUTO);
        } catch (const cv::Exception&) {
        }
        return fs.isOpened();
      };
      // Plain YAML (ROS, Kalibr) lacks OpenCV's %YAML:1.0 line.
      if (!open(text) && !open("%YAML:1.0\n" + indent_block_sequences(text)))
        throw IoError(path +
                      ": not an OpenCV FileStorage, ROS camera_info or Kalibr YAML file, nor our JSON calibration");
      files_.push_back(std::move(fs));
      texts_.push_back(std::move(text));
    }
  }
  // The number as the file spells it after `key` ("key: 4294967936", "\"key\": ...",
  // "<key>...</key>"), read as a double; NaN when not found. OpenCV keeps integers in 32 bits and
  // wraps a larger one (4294967936 reads as 640): comparing with the text catches that.
  double spelt_number(const std::string& key) const {
    for (std::size_t i = 0; i < files_.size(); ++i) {
      if (files_[i][key].empty()) continue;
      const std::string& text = texts_[i];
      for (std::size_t at = text.find(key); at != std::string::npos; at = text.find(key, at + 1)) {
        if (at > 0 && (std::isalnum(static_cast<unsigned char>(text[at - 1])) || text[at - 1] == '_')) continue;
        std::size_t p = at + key.size();
        if (p < text.size() && (text[p] == '"' || text[p] == '\'')) ++p;
        while (p < text.size() && (text[p] == ' ' || text[p] == '\t')) ++p;
        if (p >= text.size() || (text[p] != ':' && text[p] != '>' && text[p] != '=')) continue;
        ++p;
        while (p < text.size() && (text[p] == ' ' || text[p] == '\t' || text[p] == '"')) ++p;
        const char* begin = text.c_str() + p;
        char* end = nullptr;
        const double value = std::strtod(begin, &end);
        if (end != begin) return value;
      }
      return std::numeric_limits<double>::quiet_NaN();
    }
    return std::numeric_limits<double>::quiet_NaN();
  }
  cv::FileNode find(const std::string& key, std::string* where = nullptr) const {
    if (key.empty()) return {};
    for (std::size_t i = 0; i < files_.size(); ++i) {
      cv::FileNode node = files_[i][key];
      if (!node.empty()) {
        if (where) *where = paths_[i];
        return node;
      }
    }
    return {};
  }
  bool has(const std::string& key) const { return !find(key).empty(); }
  std::vector<std::string> keys() const {
    std::vector<std::string> out;
    for (const auto& fs : files_)
      for (const auto& k : fs.root().keys()) out.push_back(k);
    return out;
  }
  const std::string& name() const { return paths_.front(); }
  std::string names() const {
    std::string out;
    for (const auto& p : paths_) out += (out.empty() ? "" : " + ") + p;
    return out;
  }

 private:
  std::vector<std::string> paths_;
  std::vector<cv::FileStorage> files_;
  std::vector<std::string> texts_;
};

// A matrix given as an OpenCV matrix, a list of numbers, a list of lists, or ROS's
// {rows, cols, data}.
cv::Mat matrix_of(const cv::FileNode& node, const std::string& what) {
  cv::Mat m;
  try {
    // OpenCV allocates rows x cols before reading the data: a calibration's matrices are at most
    // 4 x 4 or 1 x 14, so a declared size beyond 64 x 64 is refused before it costs gigabytes
    // (found by fuzz_foreign_calibration: rows 10^9, malloc of 8 GB).
    if (node.isMap())
      for (const char* dimension : {"rows", "cols"})
        if (const cv::FileNode n = node[dimension]; !n.empty()) {
          const double value = n.isInt() || n.isReal() ? static_cast<double>(n) : -1;
          if (!(value >= 0 && value <= 64))
            throw IoError(what + ": " + dimension + " is not a calibration matrix's size (0-64)");
        }
    if (node.isMap() && !node["data"].empty() && node["dt"].empty()) {
      std::vector<double> data;
      for (const auto& v : node["data"]) data.push_back(static_cast<double>(v));
      const int rows = node["rows"].empty() ? 1 : static_cast<int>(node["rows"]);
      m = cv::Mat(data, true);
      if (rows > 0 && static_cast<int>(data.size()) % rows == 0) m = m.reshape(1, rows);
    } else if (node.isSeq()) {
      std::vector<std::vector<double>> rows;
      for (const auto& row : node) {
        std::vector<double> r;
        if (row.isSeq())
          for (const auto& v : row) r.push_back(static_cast<double>(v));
        else
          r.push_back(static_cast<double>(row));
        rows.push_back(r);
      }
      const bool nested = !rows.empty() && rows.front().size() > 1;
      if (nested) {
        m = cv::Mat(static_cast<int>(rows.size()), static_cast<int>(rows.front().size()), CV_64F);
        for (int r = 0; r < m.rows; ++r) {
          if (rows[static_cast<std::size_t>(r)].size() != static_cast<std::size_t>(m.cols))
            throw IoError(what + " has rows of different lengths");
          for (int c = 0; c < m.cols; ++c)
            m.at<double>(r, c) = rows[static_cast<std::size_t>(r)][static_cast<std::size_t>(c)];
        }
      } else {
        std::vector<double> flat;
        for (const auto& r : rows) flat.insert(flat.end(), r.begin(), r.end());
        m = cv::Mat(flat, true).reshape(1, 1);
      }
    } else {
      node >> m;
    }
  } catch (const cv::Exception& e) {
    throw IoError(what + " is not a matrix (" + e.what() + ")");
  }
  if (m.empty()) throw IoError(what + " is empty");
  cv::Mat d;
  m.convertTo(d, CV_64F);
  for (auto it = d.begin<double>(); it != d.end<double>(); ++it)
    if (!std::isfinite(*it)) throw IoError(what + " has a non-finite value");
  return d;
}

cv::Mat required(const Files& files, const std::string& key) {
  std::string where;
  cv::FileNode node = files.find(key, &where);
  if (node.empty()) throw IoError(files.names() + ": no " + key + " entry");
  return matrix_of(node, where + ": " + key);
}

// An image side as the file gives it: a whole number of pixels in [1, 65536], refused (never
// wrapped or rounded into range) otherwise. `where` names the entry.
int image_side(double value, const std::string& where) {
  if (!(value >= 1 && value <= 65536) || value != std::floor(value))
    throw IoError(where + ": " + cv::format("%.6g", value) +
                  " is not an image size (a whole number of pixels, 1 to 65536)");
  return static_cast<int>(value);
}

int optional_int(const Files& files, const std::string& key) {
  cv::FileNode node = files.find(key);
  if (node.empty() || (!node.isReal() && !node.isInt())) return 0;
  const double spelt = files.spelt_number(key);
  return image_side(std::isnan(spelt) ? static_cast<double>(node) : spelt, files.names() + ": " + key);
}

double optional_real(const Files& files, const std::string& key) {
  cv::FileNode node = files.find(key);
  if (node.empty() || (!node.isReal() && !node.isInt())) return 0.0;
  return static_cast<double>(node);
}

// A camera matrix stored transposed (MATLAB's IntrinsicMatrix: [fx 0 0; s fy 0; cx cy 1],
// principal point 1-based) becomes OpenCV's.
cv::Mat opencv_camera_matrix(cv::Mat k, const std::string& what, bool& transposed) {
  transposed = false;
  if (k.rows == 3 && k.cols == 3 && k.at<double>(0, 2) == 0 && k.at<double>(1, 2) == 0 &&
      (k.at<double>(2, 0) != 0 || k.at<double>(2, 1) != 0)) {
    k = k.t();
    k.at<double>(0, 2) -= 1;
    k.at<double>(1, 2) -= 1;
    transposed = true;
  }
  (void)what;
  return k;
}

struct Pose {
  cv::Mat r, t;  // proj_from_cam as the file states it (before --pose-direction)
  std::string names;
};

slproto::RigCalibration assemble(const std::string& origin, const cv::Mat& kc, const cv::Mat& dc, const cv::Mat& kp,
                                 const cv::Mat& dp, Pose pose, double translation_to_mm,
                                 const ForeignCalibrationOptions& options, int camera_width, int camera_height,
                                 int projector_width, int projector_height, double camera_error, double projector_error,
                                 const std::string& names) {
  slproto::RigCalibration rig;
  read_intrinsics(kc, origin, names + " camera matrix", rig.camera);
  read_distortion(dc, origin, names + " camera distortion", rig.camera.distortion);
  slproto::ProjectorCalibration projector;
  read_intrinsics(kp, origin, names + " projector matrix", projector.intrinsics);
  read_distortion(dp, origin, names + " projector distortion", projector.intrinsics.distortion);
  cv::Mat r = pose.r;
  if (r.total() == 3) {  // a rotation vector
    cv::Mat rotation;
    cv::Rodrigues(r.reshape(1, 3), rotation);
    r = rotation;
  }
  if (r.rows != 3 || r.cols != 3)
    throw IoError(origin + ": " + pose.names + ": the rotation is neither a 3 x 3 matrix nor a 3-vector");
  if (pose.t.total() != 3)
    throw IoError(origin + ": " + pose.names + ": the translation has " + std::to_string(pose.t.total()) +
                  " values, expected 3");
  slproto::RigidTransform transform;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) transform.R[static_cast<std::size_t>(3 * i + j)] = r.at<double>(i, j);
    transform.t[static_cast<std::size_t>(i)] = pose.t.ptr<double>()[i] * translation_to_mm;
  }
  if (auto status = transform.check(origin + ": " + pose.names); !status) throw IoError(status.error().message);
  projector.cam_from_proj = options.pose_direction == PoseDirection::proj_from_cam ? transform.inverse() : transform;
  rig.camera.width = merge_size(camera_width, options.camera_width, origin, "camera width");
  rig.camera.height = merge_size(camera_height, options.camera_height, origin, "camera height");
  projector.intrinsics.width = merge_size(projector_width, options.projector_width, origin, "projector width");
  projector.intrinsics.height = merge_size(projector_height, options.projector_height, origin, "projector height");
  rig.camera_reprojection_rms_px = camera_error;
  projector.reprojection_rms_px = projector_error;
  rig.projectors = {projector, projector};
  rig.turntable = placeholder_turntable();
  rig.pattern_plan.projector_width = projector.intrinsics.width;
  rig.pattern_plan.projector_height = projector.intrinsics.height;
  rig.source = origin;
  rig.created_by = "slscan import (" + names + "; one-projector rig: projector 0, copied into both slots)";
  if (auto status = rig.check(); !status) throw IoError(origin + ": " + status.error().message);
  return rig;
}

slproto::RigCalibration read_with_keys(const Files& files, const CalibrationKeys& k,
                                       const ForeignCalibrationOptions& options) {
  const std::string origin = files.names();
  bool transposed_c = false, transposed_p = false;
  const cv::Mat kc = opencv_camera_matrix(required(files, k.camera_matrix), k.camera_matrix, transposed_c);
  const cv::Mat kp = opencv_camera_matrix(required(files, k.projector_matrix), k.projector_matrix, transposed_p);
  Pose pose{required(files, k.rotation), required(files, k.translation), k.rotation + "/" + k.translation};
  if (transposed_c || transposed_p)
    pose.r = pose.r.total() == 9 ? cv::Mat(pose.r.t()) : pose.r;  // MATLAB's row-vector R
  return assemble(origin, kc, required(files, k.camera_distortion), kp, required(files, k.projector_distortion), pose,
                  k.translation_to_mm, options, optional_int(files, k.camera_width),
                  optional_int(files, k.camera_height), optional_int(files, k.projector_width),
                  optional_int(files, k.projector_height), optional_real(files, k.camera_error),
                  optional_real(files, k.projector_error),
                  k.name + " keys " + k.camera_matrix + " " + k.camera_distortion + " " + k.projector_matrix + " " +
                      k.projector_distortion + " " + k.rotation + " " + k.translation);
}

// Kalibr camchain: cam0 the camera, cam1 the projector (T_cn_cnm1 = cam1_from_cam0, metres).
slproto::RigCalibration read_kalibr(const Files& files, const ForeignCalibrationOptions& options) {
  const std::string origin = files.names();
  auto device = [&](const char* name, cv::Mat& k, cv::Mat& d, int& w, int& h) {
    const cv::FileNode cam = files.find(name);
    const std::string model = cam["camera_model"].empty() ? "pinhole" : static_cast<std::string>(cam["camera_model"]);
    const std::string dist =
        cam["distortion_model"].empty() ? "radtan" : static_cast<std::string>(cam["distortion_model"]);
    if (model != "pinhole" || dist != "radtan")
      throw IoError(origin + ": " + name + " is a " + model + "/" + dist +
                    " camera; only Kalibr's pinhole/radtan model (OpenCV's) is read");
    const cv::Mat in = matrix_of(cam["intrinsics"], origin + ": " + name + ".intrinsics");
    if (in.total() != 4) throw IoError(origin + ": " + name + ".intrinsics must be [fu, fv, pu, pv]");
    const double* v = in.ptr<double>();
    k = (cv::Mat_<double>(3, 3) << v[0], 0, v[2], 0, v[1], v[3], 0, 0, 1);
    d = matrix_of(cam["distortion_coeffs"], origin + ": " + name + ".distortion_coeffs");
    const cv::Mat res = cam["resolution"].empty() ? cv::Mat() : matrix_of(cam["resolution"], origin + ": resolution");
    w = res.total() == 2 ? image_side(res.ptr<double>()[0], origin + ": " + name + ".resolution[0]") : 0;
    h = res.total() == 2 ? image_side(res.ptr<double>()[1], origin + ": " + name + ".resolution[1]") : 0;
  };
  cv::Mat kc, dc, kp, dp;
  int cw, ch, pw, ph;
  device("cam0", kc, dc, cw, ch);
  device("cam1", kp, dp, pw, ph);
  const cv::Mat t = matrix_of(files.find("cam1")["T_cn_cnm1"], origin + ": cam1.T_cn_cnm1");
  if (t.rows != 4 || t.cols != 4) throw IoError(origin + ": cam1.T_cn_cnm1 must be a 4 x 4 matrix");
  Pose pose{t(cv::Rect(0, 0, 3, 3)).clone(), t(cv::Rect(3, 0, 1, 3)).clone(), "cam1.T_cn_cnm1"};
  return assemble(origin, kc, dc, kp, dp, pose, 1000.0, options, cw, ch, pw, ph, 0, 0,
                  "Kalibr camchain cam0 (camera), cam1 (projector), metres");
}

// ROS camera_info, two files: the camera's, then the projector's. The pose comes from the
// rectification matrices R1, R2 and the projector's P (its Tx = -fx' B): X_rect = R1 X_cam,
// X_rect' = X_rect + (Tx / fx', 0, 0), X_proj = R2^T X_rect'.
slproto::RigCalibration read_ros(const std::vector<std::string>& paths, const ForeignCalibrationOptions& options) {
  if (paths.size() != 2)
    throw IoError(paths.front() +
                  ": a ROS camera_info file describes one device: give the camera's and the projector's (--calib "
                  "camera.yaml --calib projector.yaml)");
  const Files camera({paths[0]}), projector({paths[1]});
  auto k_of = [](const Files& f) { return matrix_of(f.find("camera_matrix"), f.name() + ": camera_matrix"); };
  auto d_of = [](const Files& f) {
    return matrix_of(f.find("distortion_coefficients"), f.name() + ": distortion_coefficients");
  };
  auto rect_of = [](const Files& f) {
    return f.has("rectification_matrix") ? matrix_of(f.find("rectification_matrix"), f.name()).reshape(1, 3)
                                         : cv::Mat(cv::Mat::eye(3, 3, CV_64F));
  };
  for (const Files* f : {&camera, &projector}) {
    const cv::FileNode model = f->find("distortion_model");
    if (!model.empty() && static_cast<std::string>(model) != "plumb_bob" &&
        static_cast<std::string>(model) != "rational_polynomial")
      throw IoError(f->name() + ": distortion_model " + static_cast<std::string>(model) +
                    " is not OpenCV's (plumb_bob)");
  }
  if (!projector.has("projection_matrix"))
    throw IoError(paths[1] + ": no projection_matrix: the projector's pose cannot be found");
  const cv::Mat p2 = matrix_of(projector.find("projection_matrix"), paths[1] + ": projection_matrix").reshape(1, 3);
  const cv::Mat r1 = rect_of(camera), r2 = rect_of(projector);
  const double fx2 = p2.at<double>(0, 0);
  if (!(std::abs(fx2) > 0)) throw IoError(paths[1] + ": projection_matrix has fx 0");
  const cv::Mat offset = (cv::Mat_<double>(3, 1) << p2.at<double>(0, 3) / fx2, p2.at<double>(1, 3) / fx2, 0.0);
  Pose pose{cv::Mat(r2.t() * r1), cv::Mat(r2.t() * offset), "rectification_matrix/projection_matrix"};
  return assemble(paths[0] + " + " + paths[1], k_of(camera).reshape(1, 3), d_of(camera), k_of(projector).reshape(1, 3),
                  d_of(projector), pose, 1000.0, options, optional_int(camera, "image_width"),
                  optional_int(camera, "image_height"), optional_int(projector, "image_width"),
                  optional_int(projector, "image_height"), 0, 0, "ROS camera_info (camera, projector), metres");
}

}  // namespace

namespace {

slproto::RigCalibration read_any(const std::string& path, const ForeignCalibrationOptions& options) {
  const std::string text = read_text(path);
  const auto first = text.find_first_not_of(" \t\r\n");
  if (options.more_paths.empty() && first != std::string::npos && text[first] == '{' &&
      text.find("\"format_version\"") != std::string::npos) {
    auto ours = slproto::parse_calibration(text, path);
    if (!ours.ok()) throw IoError(ours.error().message);
    return *ours;
  }
  std::vector<std::string> paths{path};
  paths.insert(paths.end(), options.more_paths.begin(), options.more_paths.end());
  const Files files(paths);
  if (options.keys) return read_with_keys(files, *options.keys, options);
  if (files.has("cam0") && files.has("cam1")) return read_kalibr(files, options);
  if (files.has("camera_matrix") && files.has("distortion_coefficients")) return read_ros(paths, options);
  const CalibrationKeys* closest = nullptr;
  int closest_found = 0;
  for (const auto& set : calibration_key_sets()) {
    int found = 0;
    for (const auto* key : {&set.camera_matrix, &set.camera_distortion, &set.projector_matrix,
                            &set.projector_distortion, &set.rotation, &set.translation})
      found += files.has(*key) ? 1 : 0;
    if (found == 6) return read_with_keys(files, set, options);
    if (found > closest_found) {
      closest_found = found;
      closest = &set;
    }
  }
  std::string found_keys;
  for (const auto& k : files.keys()) found_keys += (found_keys.empty() ? "" : ", ") + k;
  std::string known;
  for (const auto& set : calibration_key_sets())
    known += "; " + set.name + " (" + set.camera_matrix + " " + set.camera_distortion + " " + set.projector_matrix +
             " " + set.projector_distortion + " " + set.rotation + " " + set.translation + ")";
  std::string near;
  if (closest != nullptr && closest_found >= 2) {
    std::string missing;
    for (const auto* key : {&closest->camera_matrix, &closest->camera_distortion, &closest->projector_matrix,
                            &closest->projector_distortion, &closest->rotation, &closest->translation})
      if (!files.has(*key)) missing += (missing.empty() ? "" : ", ") + *key;
    near = " The nearest set, " + closest->name + ", lacks " + missing + " (a second file? --calib A --calib B).";
  }
  throw IoError(files.names() + ": no known calibration key set fits; the file has the keys " +
                (found_keys.empty() ? std::string("(none)") : found_keys) + "." + near +
                " Known: Kalibr camchain (cam0, cam1), ROS camera_info (camera_matrix, distortion_coefficients)" +
                known +
                ". For other names, map them in the description: \"calibration_keys\": {\"camera_matrix\": ..., "
                "\"camera_distortion\": ..., \"projector_matrix\": ..., \"projector_distortion\": ..., "
                "\"rotation\": ..., \"translation\": ...} (docs/real-data.md)");
}

}  // namespace

slproto::RigCalibration read_foreign_calibration_in_process(const std::string& path,
                                                            const ForeignCalibrationOptions& options) {
  // OpenCV's FileNode asserts (cv::Exception) when an entry has another shape than asked for (a
  // scalar where a map or matrix must be: "cam0: 1"): bad input, named with the file (found by
  // fuzz_foreign_calibration), not an internal error.
  try {
    return read_any(path, options);
  } catch (const cv::Exception& e) {
    if (e.code == cv::Error::StsNoMem) throw std::bad_alloc();
    throw IoError(path + ": an entry does not have the shape a calibration needs (OpenCV: " + e.err + " in " + e.func +
                  ")");
  } catch (const std::length_error&) {
    // OpenCV's YAML parser computes a string length from some malformed inputs and lets the
    // resulting std::length_error through (found by fuzz_foreign_calibration in CI).
    throw IoError(path + ": OpenCV could not parse the file (malformed YAML/XML structure)");
  }
}

namespace {

// The child's reply on the pipe: one tag byte, then the calibration as our JSON or the message.
enum Reply : char {
  reply_calibration = 'C',
  reply_bad_input = 'E',
  reply_invalid_argument = 'A',
  reply_out_of_memory = 'M',
  reply_internal = 'X'
};

// ASan reserves terabytes of address space up front and maps its shadow lazily; an address-space
// limit there ends the sanitizer, not the parser. Sanitizer builds keep the CPU limit only.
#if defined(__SANITIZE_ADDRESS__)
constexpr bool kAddressSpaceLimit = false;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
constexpr bool kAddressSpaceLimit = false;
#else
constexpr bool kAddressSpaceLimit = true;
#endif
#else
constexpr bool kAddressSpaceLimit = true;
#endif

// This process's address space in bytes (the first field of /proc/self/statm, in pages); 0 if
// unknown.
std::uint64_t address_space_bytes() {
  std::ifstream statm("/proc/self/statm");
  std::uint64_t pages = 0;
  if (!(statm >> pages)) return 0;
  return pages * static_cast<std::uint64_t>(sysconf(_SC_PAGESIZE));
}

void write_all(int fd, const std::string& bytes) {
  std::size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return;  // the parent is gone: nobody to tell
    done += static_cast<std::size_t>(n);
  }
}

// The child: limits, parse, reply, _exit (never the parent's atexit handlers, static destructors
// or stdio buffers).
[[noreturn]] void run_parser_child(int fd, const std::string& path, const ForeignCalibrationOptions& options) {
  std::signal(SIGINT, SIG_DFL);  // Ctrl-C ends the parse at once; the parent reports it
  std::signal(SIGTERM, SIG_DFL);
  const rlimit no_core{0, 0};
  setrlimit(RLIMIT_CORE, &no_core);
  const auto cpu = static_cast<rlim_t>(options.parser_cpu_seconds);
  const rlimit cpu_limit{cpu, cpu + 1};  // SIGXCPU at the soft limit, SIGKILL a second later
  setrlimit(RLIMIT_CPU, &cpu_limit);
  if (kAddressSpaceLimit) {
    const std::uint64_t now = address_space_bytes();
    if (now > 0) {
      const auto limit = static_cast<rlim_t>(now + static_cast<std::uint64_t>(options.parser_memory_mb) * 1024 * 1024);
      const rlimit memory{limit, limit};
      setrlimit(RLIMIT_AS, &memory);
    }
  }
  try {
    std::string reply;
    try {
      reply = static_cast<char>(reply_calibration) +
              slproto::format_calibration(read_foreign_calibration_in_process(path, options));
    } catch (const IoError& e) {
      reply = static_cast<char>(reply_bad_input) + std::string(e.what());
    } catch (const std::invalid_argument& e) {
      reply = static_cast<char>(reply_invalid_argument) + std::string(e.what());
    } catch (const std::bad_alloc&) {
      reply = static_cast<char>(reply_out_of_memory);
    } catch (const std::exception& e) {
      reply = static_cast<char>(reply_internal) + std::string(e.what());
    }
    write_all(fd, reply);
  } catch (...) {
    _exit(3);
  }
  _exit(0);
}

// Reads `fd` to its end, or until `deadline`; true when the end was reached.
bool read_to_end(int fd, std::string& out, std::chrono::steady_clock::time_point deadline) {
  char buffer[65536];
  for (;;) {
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) return false;
    pollfd p{fd, POLLIN, 0};
    const int ready = ::poll(&p, 1, static_cast<int>(std::min<std::int64_t>(left.count(), 1000)));
    if (ready < 0 && errno != EINTR) return false;
    if (ready <= 0) continue;
    const ssize_t n = ::read(fd, buffer, sizeof buffer);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return true;
    out.append(buffer, static_cast<std::size_t>(n));
  }
}

}  // namespace

slproto::RigCalibration read_foreign_calibration(const std::string& path, const ForeignCalibrationOptions& options) {
  const std::string what = "foreign calibration " + path;
  if (options.parser_cpu_seconds < 1 || options.parser_memory_mb < 1)
    throw std::invalid_argument(what + ": the parser's CPU and memory budgets must be positive");
  int fds[2];
  if (::pipe2(fds, O_CLOEXEC) != 0)
    throw IoError(what + ": cannot start the parser process (pipe: " + std::strerror(errno) + ")");
  const pid_t pid = ::fork();
  if (pid < 0) {
    const int error = errno;
    ::close(fds[0]);
    ::close(fds[1]);
    throw IoError(what + ": cannot start the parser process (fork: " + std::strerror(error) + ")");
  }
  if (pid == 0) {
    ::close(fds[0]);
    run_parser_child(fds[1], path, options);
  }
  ::close(fds[1]);
  // A CPU-bound hang ends at the CPU limit; the wall-clock deadline covers a child that sleeps
  // (it cannot in the parser, but a lock held by another thread at fork could) and a busy machine.
  const int wall_seconds = 4 * options.parser_cpu_seconds + 10;
  std::string reply;
  const bool finished =
      read_to_end(fds[0], reply, std::chrono::steady_clock::now() + std::chrono::seconds(wall_seconds));
  ::close(fds[0]);
  if (!finished) ::kill(pid, SIGKILL);
  int status = 0;
  rusage usage{};
  while (::wait4(pid, &status, 0, &usage) < 0 && errno == EINTR) {
  }
  const double cpu_s = static_cast<double>(usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) +
                       1e-6 * static_cast<double>(usage.ru_utime.tv_usec + usage.ru_stime.tv_usec);
  const std::string cpu_limit = std::to_string(options.parser_cpu_seconds);
  if (!finished)
    throw IoError(what + ": the parser did not finish within " + std::to_string(wall_seconds) +
                  " s (wall clock; it used " + cv::format("%.1f", cpu_s) + " s of CPU): not a file it can read");
  if (WIFSIGNALED(status)) {
    const int signal_number = WTERMSIG(status);
    if (signal_number == SIGXCPU || (signal_number == SIGKILL && cpu_s >= options.parser_cpu_seconds))
      throw IoError(what + ": the parser did not finish within " + cpu_limit +
                    " s of CPU time (OpenCV's FileStorage hangs on some malformed YAML; docs/security.md): not a file "
                    "it can read");
    if (signal_number == SIGINT) throw IoError(what + ": the parser was interrupted (SIGINT)");
    throw IoError(what + ": the parser crashed on this file (signal " + std::to_string(signal_number) + ", " +
                  strsignal(signal_number) + "): malformed input OpenCV's FileStorage cannot read");
  }
  if (reply.empty())
    throw IoError(what + ": the parser ended without a result (exit status " +
                  std::to_string(WIFEXITED(status) ? WEXITSTATUS(status) : -1) + ")");
  const std::string message = reply.substr(1);
  switch (reply.front()) {
    case reply_calibration: {
      auto calibration = slproto::parse_calibration(message, path);
      if (!calibration.ok())
        throw std::runtime_error(what + ": the parser's result does not read back: " + calibration.error().message);
      return *calibration;
    }
    case reply_bad_input:
      throw IoError(message);
    case reply_invalid_argument:
      throw std::invalid_argument(message);
    case reply_out_of_memory:
      throw IoError(what + ": the parser needed more than " + std::to_string(options.parser_memory_mb) +
                    " MB of memory (its limit): a file declaring huge sizes, not a calibration");
    default:
      throw std::runtime_error(what + ": " + message);
  }
}

}  // namespace slscan::io
