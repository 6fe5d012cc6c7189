#include "slscan/io/calibration_capture_files.hpp"

#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

#include "slproto/calibration.hpp"
#include "slproto/file_util.hpp"
#include "slproto/json_fields.hpp"
#include "slscan/io/image_file.hpp"
#include "slscan/io/io_error.hpp"

namespace slscan::io {

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

constexpr const char* kFormat = "slscan-calibration-capture";
constexpr int kFormatVersion = 1;

[[noreturn]] void fail(const std::string& origin, const std::string& what) { throw IoError(origin + ": " + what); }

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

CalibrationCaptureFolder::CalibrationCaptureFolder(const std::string& folder) : folder_(folder) {
  const std::string origin = (fs::path(folder) / "manifest.json").string();
  auto text = slproto::read_whole_file(origin);
  if (!text) fail(origin, "cannot open (is '" + folder + "' a calibration capture folder?)");
  try {
    read_manifest(slproto::parse_json_strict(*text), origin);
  } catch (const slproto::JsonFieldError& e) {
    fail(origin, e.what());
  }
}

void CalibrationCaptureFolder::read_manifest(const nlohmann::json& doc, const std::string& origin) {
  slproto::JsonObject r(doc, "");
  if (r.text("format") != kFormat) r.fail("format", std::string("expected \"") + kFormat + "\"");
  if (const int version = r.integer<int>("format_version"); version != kFormatVersion)
    r.fail("format_version", std::to_string(version) + " is not supported (this build reads version " +
                                 std::to_string(kFormatVersion) + ")");

  core::CalibrationCapture& capture = capture_;
  slproto::JsonObject target = r.object("target");
  capture.target.squares_x = target.integer<int>("squares_x", 3, 100);
  capture.target.squares_y = target.integer<int>("squares_y", 3, 100);
  capture.target.square_mm = target.number("square_mm");
  capture.target.thickness_mm = target.number("thickness_mm");
  target.finish();
  if (!(capture.target.square_mm > 0) || !(capture.target.thickness_mm >= 0))
    fail(origin, "target: square_mm must be > 0 and thickness_mm >= 0");
  capture.pattern_plan = slproto::read_pattern_plan(r.object("pattern_plan"));
  if (auto status = capture.pattern_plan.check(); !status) fail(origin, "pattern_plan: " + status.error().message);
  capture.bit_depth = r.integer<int>("bit_depth");
  if (capture.bit_depth != 8 && capture.bit_depth != 10 && capture.bit_depth != 12 && capture.bit_depth != 16)
    fail(origin, "bit_depth " + std::to_string(capture.bit_depth) + ": expected 8, 10, 12 or 16");
  capture.platform_radius_mm = r.number("platform_radius_mm");
  if (!(capture.platform_radius_mm > 0)) fail(origin, "platform_radius_mm must be > 0");
  capture.source = folder_;
  r.read("source", capture.source);

  const slproto::JsonArray poses = r.array("poses", 1);
  for (std::size_t i = 0; i < poses.size(); ++i) {
    slproto::JsonObject pose = poses.object(i);
    capture.poses.push_back({pose.text("name"), pose.boolean("on_turntable"), pose.number("table_angle_deg")});
    pose.finish();
  }
  const std::array<slproto::PatternPlan, 2> plans{capture.plan(slproto::CodingAxis::columns),
                                                  capture.plan(slproto::CodingAxis::rows)};
  const slproto::JsonArray frames = r.array("frames", 1);
  r.finish();
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const std::string path = frames.path_of(i);
    slproto::JsonObject f = frames.object(i);
    core::CalibrationFrame frame;
    frame.pose = f.integer<int>("pose", 0, static_cast<int>(capture.poses.size()) - 1);
    frame.kind = f.choice<core::CalibrationFrame::Kind>(
        "kind", {{"camera", core::CalibrationFrame::Kind::camera}, {"pattern", core::CalibrationFrame::Kind::pattern}});
    if (frame.kind == core::CalibrationFrame::Kind::pattern) {
      frame.side = f.choice<slproto::ProjectorSide>(
          "projector", {{"left", slproto::ProjectorSide::left}, {"right", slproto::ProjectorSide::right}});
      frame.axis = f.choice<slproto::CodingAxis>(
          "axis", {{"columns", slproto::CodingAxis::columns}, {"rows", slproto::CodingAxis::rows}});
      const std::size_t count = plans[static_cast<std::size_t>(frame.axis)].size();
      frame.pattern_index = f.integer<std::size_t>("pattern", 0, count - 1);
    }
    const std::string name = f.text("file");
    f.finish();
    files_.push_back((fs::path(folder_) / name).string());
    entries_.push_back(path);
    capture.frames.push_back(std::move(frame));
  }
}

cv::Mat CalibrationCaptureFolder::read_frame(std::size_t i) const {
  const std::string& file = files_.at(i);
  cv::Mat image = read_image_file(file, file + " (" + entries_[i] + ")");
  if (image.channels() != 1) fail(file, "expected a single-channel (grey) image");
  const int expected_depth = capture_.bit_depth > 8 ? CV_16U : CV_8U;
  if (image.depth() != expected_depth)
    fail(file, std::string("the image is ") + (image.depth() == CV_16U ? "16" : "8") +
                   "-bit, the manifest's bit_depth is " + std::to_string(capture_.bit_depth));
  if (size_.empty()) {
    size_ = image.size();
    size_file_ = file;
  }
  if (image.size() != size_)
    fail(file, std::to_string(image.cols) + " x " + std::to_string(image.rows) + " differs from " +
                   std::to_string(size_.width) + " x " + std::to_string(size_.height) + " of " + size_file_);
  return image;
}

core::CalibrationCapture CalibrationCaptureFolder::read_pose(int pose) const {
  if (pose < 0 || pose >= static_cast<int>(capture_.poses.size()))
    throw std::invalid_argument(folder_ + ": pose " + std::to_string(pose) + " of " +
                                std::to_string(capture_.poses.size()));
  core::CalibrationCapture one = capture_;
  one.frames.clear();
  for (std::size_t i = 0; i < capture_.frames.size(); ++i) {
    if (capture_.frames[i].pose != pose) continue;
    core::CalibrationFrame frame = capture_.frames[i];
    frame.image = read_frame(i);
    one.frames.push_back(std::move(frame));
  }
  return one;
}

core::CalibrationCapture read_calibration_capture(const std::string& folder) {
  const CalibrationCaptureFolder on_disk(folder);
  core::CalibrationCapture capture = on_disk.capture();
  for (std::size_t i = 0; i < capture.frames.size(); ++i) capture.frames[i].image = on_disk.read_frame(i);
  return capture;
}

namespace {

json manifest(const core::CalibrationCapture& capture) {
  json poses = json::array();
  for (const core::CalibrationPose& pose : capture.poses)
    poses.push_back(
        {{"name", pose.name}, {"on_turntable", pose.on_turntable}, {"table_angle_deg", pose.table_angle_deg}});
  json frames = json::array();
  for (const core::CalibrationFrame& frame : capture.frames) {
    json entry = {{"pose", frame.pose}, {"kind", kind_name(frame.kind)}, {"file", frame_file(frame)}};
    if (frame.kind == core::CalibrationFrame::Kind::pattern) {
      entry["projector"] = slproto::projector_side_name(frame.side);
      entry["axis"] = slproto::coding_axis_name(frame.axis);
      entry["pattern"] = frame.pattern_index;
    }
    frames.push_back(std::move(entry));
  }
  return {{"format", kFormat},
          {"format_version", kFormatVersion},
          {"target",
           {{"squares_x", capture.target.squares_x},
            {"squares_y", capture.target.squares_y},
            {"square_mm", capture.target.square_mm},
            {"thickness_mm", capture.target.thickness_mm}}},
          {"pattern_plan", slproto::pattern_plan_to_json(capture.pattern_plan)},
          {"bit_depth", capture.bit_depth},
          {"platform_radius_mm", capture.platform_radius_mm},
          {"source", capture.source},
          {"poses", poses},
          {"frames", frames}};
}

void write_frame(const core::CalibrationFrame& frame, const fs::path& folder) {
  const std::string name = frame_file(frame);
  fs::create_directories((folder / name).parent_path());
  // Fast compression: sensor noise barely compresses, and a full-resolution capture is 766 frames.
  if (!cv::imwrite((folder / name).string(), frame.image, {cv::IMWRITE_PNG_COMPRESSION, 1}))
    throw IoError((folder / name).string() + ": cannot write");
}

void write_manifest(const core::CalibrationCapture& capture, const fs::path& folder) {
  if (auto status = slproto::write_file_atomically((folder / "manifest.json").string(), manifest(capture).dump(1));
      !status)
    throw IoError(status.error().message);
}

}  // namespace

void write_calibration_capture(const core::CalibrationCapture& capture, const std::string& folder) {
  if (fs::exists(folder)) throw IoError(folder + ": already exists (not overwritten)");
  const fs::path tmp = folder + ".tmp." + std::to_string(::getpid());
  std::error_code ec;
  fs::remove_all(tmp, ec);
  try {
    for (const core::CalibrationFrame& frame : capture.frames) write_frame(frame, tmp);
    write_manifest(capture, tmp);
    fs::rename(tmp, folder);
  } catch (...) {
    fs::remove_all(tmp, ec);
    throw;
  }
}

void write_calibration_capture_pose(const core::CalibrationCapture& capture, int pose, const std::string& folder) {
  fs::create_directories(folder);
  for (const core::CalibrationFrame& frame : capture.frames)
    if (frame.pose == pose) write_frame(frame, folder);
  write_manifest(capture, folder);
}

}  // namespace slscan::io
