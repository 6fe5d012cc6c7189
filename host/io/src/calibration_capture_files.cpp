#include "slscan/io/calibration_capture_files.hpp"

#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

#include "slproto/calibration.hpp"
#include "slscan/io/ply.hpp"

namespace slscan::io {

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

constexpr const char* kFormat = "slscan-calibration-capture";
constexpr int kFormatVersion = 1;

[[noreturn]] void fail(const std::string& origin, const std::string& what) { throw IoError(origin + ": " + what); }

const json& field(const json& obj, const std::string& origin, const std::string& path, const char* key) {
  if (!obj.is_object()) fail(origin, (path.empty() ? std::string("the manifest") : path) + " must be an object");
  const auto it = obj.find(key);
  if (it == obj.end()) fail(origin, (path.empty() ? "" : path + ".") + key + ": missing");
  return *it;
}

template <typename T>
T typed(const json& obj, const std::string& origin, const std::string& path, const char* key) {
  const json& v = field(obj, origin, path, key);
  const std::string name = (path.empty() ? "" : path + ".") + key;
  if constexpr (std::is_same_v<T, bool>) {
    if (!v.is_boolean()) fail(origin, name + ": expected true or false");
  } else if constexpr (std::is_same_v<T, int>) {
    if (!v.is_number_integer()) fail(origin, name + ": expected an integer");
  } else if constexpr (std::is_same_v<T, double>) {
    if (!v.is_number()) fail(origin, name + ": expected a number");
  } else {
    if (!v.is_string()) fail(origin, name + ": expected a string");
  }
  return v.get<T>();
}

const char* kind_name(core::CalibrationFrame::Kind kind) {
  return kind == core::CalibrationFrame::Kind::camera ? "camera" : "pattern";
}

std::string frame_file(const core::CalibrationFrame& frame) {
  char name[96];
  if (frame.kind == core::CalibrationFrame::Kind::camera)
    std::snprintf(name, sizeof name, "pose%02d/camera.png", frame.pose);
  else
    std::snprintf(name, sizeof name, "pose%02d/%s_%s_%02zu.png", frame.pose, slproto::projector_side_name(frame.side),
                  slproto::coding_axis_name(frame.axis), frame.pattern_index);
  return name;
}

}  // namespace

core::CalibrationCapture read_calibration_capture(const std::string& folder) {
  const std::string origin = (fs::path(folder) / "manifest.json").string();
  std::ifstream in(origin, std::ios::binary);
  if (!in) fail(origin, "cannot open (is '" + folder + "' a calibration capture folder?)");
  json doc;
  try {
    doc = json::parse(in);
  } catch (const std::exception& e) {
    fail(origin, std::string("not valid JSON: ") + e.what());
  }
  if (typed<std::string>(doc, origin, "", "format") != kFormat)
    fail(origin, std::string("format: expected \"") + kFormat + "\"");
  if (const int version = typed<int>(doc, origin, "", "format_version"); version != kFormatVersion)
    fail(origin, "format_version " + std::to_string(version) + " is not supported (this build reads version " +
                     std::to_string(kFormatVersion) + ")");

  core::CalibrationCapture capture;
  const json& target = field(doc, origin, "", "target");
  capture.target.squares_x = typed<int>(target, origin, "target", "squares_x");
  capture.target.squares_y = typed<int>(target, origin, "target", "squares_y");
  capture.target.square_mm = typed<double>(target, origin, "target", "square_mm");
  capture.target.thickness_mm = typed<double>(target, origin, "target", "thickness_mm");
  if (capture.target.squares_x < 3 || capture.target.squares_y < 3 || capture.target.squares_x > 100 ||
      capture.target.squares_y > 100)
    fail(origin, "target: squares_x and squares_y must be in [3, 100]");
  if (!(capture.target.square_mm > 0) || !(capture.target.thickness_mm >= 0))
    fail(origin, "target: square_mm must be > 0 and thickness_mm >= 0");
  auto plan = slproto::parse_pattern_plan(field(doc, origin, "", "pattern_plan").dump(), origin + ": pattern_plan");
  if (!plan) throw IoError(plan.error().message);
  capture.pattern_plan = *plan;
  capture.bit_depth = typed<int>(doc, origin, "", "bit_depth");
  if (capture.bit_depth != 8 && capture.bit_depth != 10 && capture.bit_depth != 12 && capture.bit_depth != 16)
    fail(origin, "bit_depth " + std::to_string(capture.bit_depth) + ": expected 8, 10, 12 or 16");
  capture.platform_radius_mm = typed<double>(doc, origin, "", "platform_radius_mm");
  if (!(capture.platform_radius_mm > 0)) fail(origin, "platform_radius_mm must be > 0");
  capture.source = doc.contains("source") ? typed<std::string>(doc, origin, "", "source") : folder;

  const json& poses = field(doc, origin, "", "poses");
  if (!poses.is_array() || poses.empty()) fail(origin, "poses: expected a non-empty list");
  for (std::size_t i = 0; i < poses.size(); ++i) {
    const std::string path = "poses[" + std::to_string(i) + "]";
    capture.poses.push_back({typed<std::string>(poses[i], origin, path, "name"),
                             typed<bool>(poses[i], origin, path, "on_turntable"),
                             typed<double>(poses[i], origin, path, "table_angle_deg")});
  }
  const std::array<slproto::PatternPlan, 2> plans{capture.plan(slproto::CodingAxis::columns),
                                                  capture.plan(slproto::CodingAxis::rows)};
  const json& frames = field(doc, origin, "", "frames");
  if (!frames.is_array() || frames.empty()) fail(origin, "frames: expected a non-empty list");
  cv::Size size;
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const std::string path = "frames[" + std::to_string(i) + "]";
    const json& f = frames[i];
    core::CalibrationFrame frame;
    frame.pose = typed<int>(f, origin, path, "pose");
    if (frame.pose < 0 || frame.pose >= static_cast<int>(capture.poses.size()))
      fail(origin, path + ".pose " + std::to_string(frame.pose) + ": the manifest lists " +
                       std::to_string(capture.poses.size()) + " poses");
    const std::string kind = typed<std::string>(f, origin, path, "kind");
    if (kind == "camera") {
      frame.kind = core::CalibrationFrame::Kind::camera;
    } else if (kind == "pattern") {
      frame.kind = core::CalibrationFrame::Kind::pattern;
      const std::string side = typed<std::string>(f, origin, path, "projector");
      if (side != "left" && side != "right") fail(origin, path + ".projector: expected \"left\" or \"right\"");
      frame.side = side == "left" ? slproto::ProjectorSide::left : slproto::ProjectorSide::right;
      const std::string axis = typed<std::string>(f, origin, path, "axis");
      if (axis != "columns" && axis != "rows") fail(origin, path + ".axis: expected \"columns\" or \"rows\"");
      frame.axis = axis == "columns" ? slproto::CodingAxis::columns : slproto::CodingAxis::rows;
      const int index = typed<int>(f, origin, path, "pattern");
      const std::size_t count = plans[static_cast<std::size_t>(frame.axis)].size();
      if (index < 0 || static_cast<std::size_t>(index) >= count)
        fail(origin, path + ".pattern " + std::to_string(index) + ": the plan along " + axis + " has " +
                         std::to_string(count) + " patterns");
      frame.pattern_index = static_cast<std::size_t>(index);
    } else {
      fail(origin, path + ".kind \"" + kind + "\": expected \"camera\" or \"pattern\"");
    }
    const std::string name = typed<std::string>(f, origin, path, "file");
    const std::string file = (fs::path(folder) / name).string();
    frame.image = cv::imread(file, cv::IMREAD_UNCHANGED);
    if (frame.image.empty()) fail(file, "missing or not a readable image (" + path + ")");
    if (frame.image.channels() != 1) fail(file, "expected a single-channel (grey) image");
    const int expected_depth = capture.bit_depth > 8 ? CV_16U : CV_8U;
    if (frame.image.depth() != expected_depth)
      fail(file, std::string("the image is ") + (frame.image.depth() == CV_16U ? "16" : "8") +
                     "-bit, the manifest's bit_depth is " + std::to_string(capture.bit_depth));
    if (i == 0) size = frame.image.size();
    if (frame.image.size() != size)
      fail(file, std::to_string(frame.image.cols) + " x " + std::to_string(frame.image.rows) + " differs from " +
                     std::to_string(size.width) + " x " + std::to_string(size.height) + " of the first frame");
    capture.frames.push_back(std::move(frame));
  }
  return capture;
}

void write_calibration_capture(const core::CalibrationCapture& capture, const std::string& folder) {
  if (fs::exists(folder)) throw IoError(folder + ": already exists (not overwritten)");
  const fs::path tmp = folder + ".tmp." + std::to_string(::getpid());
  std::error_code ec;
  fs::remove_all(tmp, ec);
  try {
    json poses = json::array();
    for (const core::CalibrationPose& pose : capture.poses)
      poses.push_back(
          {{"name", pose.name}, {"on_turntable", pose.on_turntable}, {"table_angle_deg", pose.table_angle_deg}});
    json frames = json::array();
    for (const core::CalibrationFrame& frame : capture.frames) {
      const std::string name = frame_file(frame);
      fs::create_directories((tmp / name).parent_path());
      // Fast compression: sensor noise barely compresses, and a full-resolution capture is 766 frames.
      if (!cv::imwrite((tmp / name).string(), frame.image, {cv::IMWRITE_PNG_COMPRESSION, 1}))
        throw IoError((tmp / name).string() + ": cannot write");
      json entry = {{"pose", frame.pose}, {"kind", kind_name(frame.kind)}, {"file", name}};
      if (frame.kind == core::CalibrationFrame::Kind::pattern) {
        entry["projector"] = slproto::projector_side_name(frame.side);
        entry["axis"] = slproto::coding_axis_name(frame.axis);
        entry["pattern"] = frame.pattern_index;
      }
      frames.push_back(std::move(entry));
    }
    const json doc = {{"format", kFormat},
                      {"format_version", kFormatVersion},
                      {"target",
                       {{"squares_x", capture.target.squares_x},
                        {"squares_y", capture.target.squares_y},
                        {"square_mm", capture.target.square_mm},
                        {"thickness_mm", capture.target.thickness_mm}}},
                      {"pattern_plan", json::parse(slproto::format_pattern_plan(capture.pattern_plan))},
                      {"bit_depth", capture.bit_depth},
                      {"platform_radius_mm", capture.platform_radius_mm},
                      {"source", capture.source},
                      {"poses", poses},
                      {"frames", frames}};
    if (auto status = slproto::write_file_atomically((tmp / "manifest.json").string(), doc.dump(1)); !status)
      throw IoError(status.error().message);
    fs::rename(tmp, folder);
  } catch (...) {
    fs::remove_all(tmp, ec);
    throw;
  }
}

}  // namespace slscan::io
