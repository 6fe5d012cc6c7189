#include "slscan/io/image_sequence_import.hpp"

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "slproto/capture.hpp"
#include "slproto/crc32c.hpp"
#include "slproto/framing.hpp"
#include "slproto/messages.hpp"
#include "slscan/io/ply.hpp"

namespace slscan::io {

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

[[noreturn]] void fail(const std::string& origin, const std::string& what) { throw IoError(origin + ": " + what); }

std::string resolve(const std::string& base_dir, const std::string& name) {
  const fs::path p(name);
  return (p.is_absolute() || base_dir.empty() ? p : fs::path(base_dir) / p).string();
}

std::string file_name(const json& node, const std::string& origin, const std::string& field) {
  if (!node.is_string() || node.get<std::string>().empty()) fail(origin, field + " must be a file name");
  return node.get<std::string>();
}

// A list of names, or {"pattern": "frame_%02d.png", "first": 2, "count": 10}.
std::vector<std::string> file_list(const json& node, const std::string& origin, const std::string& field) {
  std::vector<std::string> out;
  if (node.is_array()) {
    for (std::size_t i = 0; i < node.size(); ++i)
      out.push_back(file_name(node[i], origin, field + "[" + std::to_string(i) + "]"));
    return out;
  }
  if (!node.is_object() || !node.contains("pattern") || !node.contains("count"))
    fail(origin, field + " must be a list of file names or {\"pattern\", \"first\", \"count\"}");
  const std::string pattern = file_name(node["pattern"], origin, field + ".pattern");
  if (pattern.find('%') == std::string::npos || pattern.find('%') != pattern.rfind('%') ||
      pattern.find_first_of("diu", pattern.find('%')) == std::string::npos)
    fail(origin, field + ".pattern '" + pattern + "' needs exactly one integer conversion such as %02d");
  const std::size_t conversion_end = pattern.find_first_of("diu", pattern.find('%'));
  if (pattern.find_first_not_of("0123456789", pattern.find('%') + 1) != conversion_end)
    fail(origin, field + ".pattern '" + pattern + "' may only have a width between % and d");
  if (!node["count"].is_number_integer() || node["count"].get<int>() < 1 || node["count"].get<int>() > 4096)
    fail(origin, field + ".count must be an integer in [1, 4096]");
  const int first = node.value("first", 0);
  for (int i = 0; i < node["count"].get<int>(); ++i) {
    std::vector<char> buffer(pattern.size() + 32);
    std::snprintf(buffer.data(), buffer.size(), pattern.c_str(), first + i);
    out.emplace_back(buffer.data());
  }
  return out;
}

int positive_int(const json& object, const char* key, const std::string& origin, const std::string& field,
                 int fallback) {
  if (!object.contains(key)) {
    if (fallback >= 0) return fallback;
    fail(origin, field + "." + key + " is missing");
  }
  const json& v = object[key];
  if (!v.is_number_integer() || v.get<long long>() < 1 || v.get<long long>() > 65535)
    fail(origin, field + "." + key + " must be an integer in [1, 65535]");
  return v.get<int>();
}

}  // namespace

SequenceDescription parse_sequence_description(const std::string& json_text, const std::string& base_dir,
                                               const std::string& origin) {
  json doc;
  try {
    doc = json::parse(json_text);
  } catch (const json::exception& e) {  // parse_error, and out_of_range for a number beyond double
    fail(origin, std::string("not valid JSON: ") + e.what());
  }
  if (!doc.is_object()) fail(origin, "the description must be a JSON object");
  static const char* known[] = {
      "projector", "axis",   "camera", "white", "black", "gray", "phase", "complementary", "complementary_inverse",
      "image_dir", "comment"};
  if (doc.contains("inverse"))
    fail(origin, "unknown field 'inverse': list the inverse (negative) Gray frames as gray.inverse_files");
  for (const auto& [key, value] : doc.items())
    if (std::find(std::begin(known), std::end(known), key) == std::end(known))
      fail(origin, "unknown field '" + key + "'");

  SequenceDescription d;
  if (!doc.contains("projector") || !doc["projector"].is_object()) fail(origin, "projector {width, height} is missing");
  d.plan.projector_width = positive_int(doc["projector"], "width", origin, "projector", -1);
  d.plan.projector_height = positive_int(doc["projector"], "height", origin, "projector", -1);
  const std::string axis = doc.value("axis", std::string("columns"));
  if (axis != "columns" && axis != "rows") fail(origin, "axis must be \"columns\" or \"rows\", got \"" + axis + "\"");
  d.plan.axis = axis == "columns" ? slproto::CodingAxis::columns : slproto::CodingAxis::rows;
  if (doc.contains("camera")) {
    const json& camera = doc["camera"];
    if (!camera.is_object()) fail(origin, "camera must be {width, height, bit_depth}");
    d.camera_width = positive_int(camera, "width", origin, "camera", 0);
    d.camera_height = positive_int(camera, "height", origin, "camera", 0);
    d.bit_depth = positive_int(camera, "bit_depth", origin, "camera", 8);
    if (d.bit_depth != 8 && d.bit_depth != 10 && d.bit_depth != 12 && d.bit_depth != 16)
      fail(origin, "camera.bit_depth " + std::to_string(d.bit_depth) + " is not 8, 10, 12 or 16");
  }

  const bool has_white = doc.contains("white"), has_black = doc.contains("black");
  if (has_white != has_black) fail(origin, "white and black frames come as a pair: only one is given");
  d.plan.with_white_black = has_white;

  if (!doc.contains("gray") || !doc["gray"].is_object())
    fail(origin, "gray {files, bit_order, bits_not_projected} is missing");
  const json& gray = doc["gray"];
  static const char* known_gray[] = {"files", "inverse_files", "bit_order", "bits_not_projected", "convention"};
  for (const auto& [key, value] : gray.items())
    if (std::find(std::begin(known_gray), std::end(known_gray), key) == std::end(known_gray))
      fail(origin, "unknown field 'gray." + key + "'");
  if (!gray.contains("files")) fail(origin, "gray.files is missing");
  std::vector<std::string> gray_files = file_list(gray["files"], origin, "gray.files");
  std::vector<std::string> inverse_files;
  if (gray.contains("inverse_files")) {
    inverse_files = file_list(gray["inverse_files"], origin, "gray.inverse_files");
    if (inverse_files.size() != gray_files.size())
      fail(origin, "gray.inverse_files lists " + std::to_string(inverse_files.size()) +
                       " frames but gray.files lists " + std::to_string(gray_files.size()) +
                       ": each Gray frame needs its inverse");
  }
  d.plan.inverse_gray = !inverse_files.empty();
  const std::string order = gray.value("bit_order", std::string("msb_first"));
  if (order != "msb_first" && order != "lsb_first")
    fail(origin, "gray.bit_order must be \"msb_first\" or \"lsb_first\", got \"" + order + "\"");
  if (order == "lsb_first") {
    std::reverse(gray_files.begin(), gray_files.end());
    std::reverse(inverse_files.begin(), inverse_files.end());
  }
  if (gray.contains("convention")) {
    const json& convention = gray["convention"];
    if (convention == "slstudio")
      d.plan.gray_low_bits = slproto::GrayLowBits::slstudio_parity;
    else if (convention != "centre")
      fail(origin, "gray.convention must be \"centre\" or \"slstudio\", got " + convention.dump());
  }
  const int not_projected = gray.value("bits_not_projected", 0);
  if (not_projected < 0 || not_projected > 12) fail(origin, "gray.bits_not_projected must be in [0, 12]");

  std::vector<std::string> phase_files;
  if (doc.contains("phase")) {
    const json& phase = doc["phase"];
    if (!phase.is_object() || !phase.contains("files") || !phase.contains("period_px"))
      fail(origin, "phase must be {files, period_px}");
    phase_files = file_list(phase["files"], origin, "phase.files");
    d.plan.period_px = positive_int(phase, "period_px", origin, "phase", -1);
    d.plan.phase_steps = static_cast<int>(phase_files.size());
    if (not_projected != 0)
      fail(origin, "with phase frames the Gray code numbers the fringe periods: gray.bits_not_projected must be 0");
  } else {
    // Gray code alone: leaving out s low bits is our plan with period 2^s.
    d.plan.phase_steps = 0;
    d.plan.period_px = 1 << not_projected;
    if (d.plan.period_px < 2)
      fail(origin,
           "a Gray code of every projector pixel (bits_not_projected 0) has no period of at least 2 pixels; "
           "this codec needs bits_not_projected >= 1 or phase frames");
  }
  d.plan.complementary_bit = doc.contains("complementary");
  if (d.plan.complementary_bit && phase_files.empty())
    fail(origin, "a complementary bit without phase frames is one more Gray bit: list it last in gray.files");
  if (d.plan.complementary_bit && d.plan.inverse_gray != doc.contains("complementary_inverse"))
    fail(origin, d.plan.inverse_gray
                     ? "with gray.inverse_files the complementary frame needs its inverse too: complementary_inverse"
                     : "complementary_inverse is given but gray.inverse_files is not");
  if (!d.plan.complementary_bit && doc.contains("complementary_inverse"))
    fail(origin, "complementary_inverse is given without complementary");
  if (!d.plan.with_white_black && phase_files.empty() && !d.plan.inverse_gray)
    fail(origin,
         "nothing to threshold the Gray frames against: give white and black frames, gray.inverse_files or phase "
         "frames");
  if (d.plan.gray_low_bits == slproto::GrayLowBits::slstudio_parity && !phase_files.empty())
    fail(origin,
         "gray.convention \"slstudio\" is about a Gray code's unshown low bits; with phase frames the phase "
         "gives the position within a period: leave it out");
  if (auto status = d.plan.check(); !status) fail(origin, status.error().message);
  if (static_cast<int>(gray_files.size()) != d.plan.gray_bits())
    fail(origin, "gray.files lists " + std::to_string(gray_files.size()) + " frames but a Gray code of " +
                     std::to_string(d.plan.coded_extent()) + " projector " + axis + " in periods of " +
                     std::to_string(d.plan.period_px) + " px has " + std::to_string(d.plan.gray_bits()) + " bits");

  // Files in plan order.
  const slproto::PatternPlan plan(d.plan);
  for (const auto& pattern : plan.patterns()) {
    switch (pattern.kind) {
      case slproto::PatternKind::white:
        d.files.push_back(file_name(doc["white"], origin, "white"));
        break;
      case slproto::PatternKind::black:
        d.files.push_back(file_name(doc["black"], origin, "black"));
        break;
      case slproto::PatternKind::gray_bit:
        d.files.push_back(gray_files[pattern.index]);
        break;
      case slproto::PatternKind::complementary_bit:
        d.files.push_back(file_name(doc["complementary"], origin, "complementary"));
        break;
      case slproto::PatternKind::gray_bit_inverse:
        d.files.push_back(inverse_files[pattern.index]);
        break;
      case slproto::PatternKind::complementary_bit_inverse:
        d.files.push_back(file_name(doc["complementary_inverse"], origin, "complementary_inverse"));
        break;
      case slproto::PatternKind::phase_step:
        d.files.push_back(phase_files[pattern.index]);
        break;
    }
  }
  // image_dir lets a description live apart from its images (docs/examples/).
  const std::string image_dir =
      doc.contains("image_dir") ? resolve(base_dir, file_name(doc["image_dir"], origin, "image_dir")) : base_dir;
  for (auto& f : d.files) f = resolve(image_dir, f);
  return d;
}

SequenceDescription load_sequence_description(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw IoError(path + ": cannot open the sequence description");
  std::ostringstream text;
  text << in.rdbuf();
  return parse_sequence_description(text.str(), fs::path(path).parent_path().string(), path);
}

ImportedSequence read_image_sequence(const SequenceDescription& description) {
  ImportedSequence out;
  out.plan = slproto::PatternPlan(description.plan);
  if (description.files.size() != out.plan.size())
    throw IoError("import: the description gives " + std::to_string(description.files.size()) +
                  " images but its pattern plan has " + std::to_string(out.plan.size()) + " frames");
  out.source_bit_depth = description.bit_depth;
  out.bit_depth = description.bit_depth == 16 ? 12 : description.bit_depth;
  const int expected_cv_depth = description.bit_depth == 8 ? CV_8U : CV_16U;
  out.frames.reserve(description.files.size());
  for (std::size_t i = 0; i < description.files.size(); ++i) {
    const std::string& path = description.files[i];
    const std::string what =
        path + " (" + slproto::pattern_kind_name(out.plan[i].kind) + " " + std::to_string(out.plan[i].index) + ")";
    if (!fs::is_regular_file(path)) throw IoError(what + ": no such image file");
    cv::Mat image;
    try {
      image = cv::imread(path, cv::IMREAD_ANYDEPTH | cv::IMREAD_ANYCOLOR);
    } catch (const cv::Exception& e) {
      throw IoError(what + ": unreadable image (" + e.what() + ")");
    }
    if (image.empty()) throw IoError(what + ": not an image OpenCV can read (PNG, BMP, TIFF, JPG)");
    if (image.channels() == 3 || image.channels() == 4) {
      cv::Mat grey;
      cv::cvtColor(image, grey, image.channels() == 3 ? cv::COLOR_BGR2GRAY : cv::COLOR_BGRA2GRAY);
      image = grey;
    }
    if (image.channels() != 1) throw IoError(what + ": " + std::to_string(image.channels()) + " channels");
    if (image.depth() != expected_cv_depth)
      throw IoError(what + ": the image is " +
                    (image.depth() == CV_8U    ? "8"
                     : image.depth() == CV_16U ? "16"
                                               : "float") +
                    "-bit, the description says camera.bit_depth " + std::to_string(description.bit_depth));
    if (i == 0) {
      out.width = image.cols;
      out.height = image.rows;
      if ((description.camera_width && description.camera_width != out.width) ||
          (description.camera_height && description.camera_height != out.height))
        throw IoError(what + ": the image is " + std::to_string(out.width) + " x " + std::to_string(out.height) +
                      ", the description says " + std::to_string(description.camera_width) + " x " +
                      std::to_string(description.camera_height));
    } else if (image.cols != out.width || image.rows != out.height) {
      throw IoError(what + ": the image is " + std::to_string(image.cols) + " x " + std::to_string(image.rows) +
                    ", the first image is " + std::to_string(out.width) + " x " + std::to_string(out.height));
    }
    if (description.bit_depth == 10 || description.bit_depth == 12) {
      double max_value = 0;
      cv::minMaxLoc(image, nullptr, &max_value);
      if (max_value >= (1 << description.bit_depth))
        throw IoError(what + ": holds the value " + std::to_string(static_cast<int>(max_value)) +
                      ", beyond camera.bit_depth " + std::to_string(description.bit_depth));
    }
    if (description.bit_depth == 16) image.convertTo(image, CV_16U, 1.0 / 16.0);  // wire formats stop at 12 bits
    const std::size_t row_bytes = static_cast<std::size_t>(image.cols) * image.elemSize();
    std::vector<std::uint8_t> bytes(row_bytes * static_cast<std::size_t>(image.rows));
    for (int y = 0; y < image.rows; ++y)
      std::memcpy(bytes.data() + static_cast<std::size_t>(y) * row_bytes, image.ptr(y), row_bytes);
    out.frames.push_back(std::move(bytes));
  }
  return out;
}

void write_imported_capture(const std::string& path, const ImportedSequence& sequence) {
  const auto pixel_format = sequence.bit_depth == 8    ? slproto::pb::PIXEL_FORMAT_MONO8
                            : sequence.bit_depth == 10 ? slproto::pb::PIXEL_FORMAT_MONO10
                                                       : slproto::pb::PIXEL_FORMAT_MONO12;
  constexpr std::uint64_t kScanId = 1;
  slproto::pb::ScanRequest request;
  request.set_scan_id(kScanId);
  request.add_turntable_angles_deg(0.0);
  request.add_projectors(0);
  *request.mutable_plan() = slproto::to_proto(sequence.plan.config());
  // Not known for a foreign capture; plausible values keep the request valid.
  request.set_exposure_us(8333);
  request.set_pattern_period_us(10000);
  request.set_pixel_format(pixel_format);
  if (auto status = slproto::check_scan_request(request); !status)
    throw IoError(path + ": the imported scan request is invalid: " + status.error().message);

  auto check = [&](const slproto::Status& status) {
    if (!status) throw IoError(path + ": " + status.error().message);
  };
  auto capture = slproto::CaptureWriter::create(path);
  if (!capture.ok()) throw IoError(path + ": " + capture.error().message);
  auto request_bytes = slproto::encode(request);
  if (!request_bytes.ok()) throw IoError(path + ": " + request_bytes.error().message);
  check(capture->append(*request_bytes));
  std::vector<std::byte> record;
  std::uint64_t sequence_number = 0;
  for (std::size_t pattern = 0; pattern < sequence.frames.size(); ++pattern) {
    slproto::pb::FrameHeader header;
    header.set_scan_id(kScanId);
    header.set_view_index(0);
    header.set_commanded_angle_deg(0.0);
    header.set_reported_angle_deg(0.0);
    header.set_projector_id(0);
    header.set_pattern_index(static_cast<std::uint32_t>(pattern));
    header.set_sequence(sequence_number++);
    slproto::set_frame_geometry(header, static_cast<std::uint32_t>(sequence.width),
                                static_cast<std::uint32_t>(sequence.height), pixel_format);
    const auto& frame = sequence.frames[pattern];
    const std::span<const std::byte> payload(reinterpret_cast<const std::byte*>(frame.data()), frame.size());
    header.set_payload_crc32c(slproto::crc32c(payload));
    record.clear();  // encode() appends
    check(slproto::encode(header, payload, record));
    check(capture->append(record));
  }
  slproto::pb::ScanDone done;
  done.set_scan_id(kScanId);
  done.set_frames_sent(sequence_number);
  auto done_bytes = slproto::encode(done);
  if (!done_bytes.ok()) throw IoError(path + ": " + done_bytes.error().message);
  check(capture->append(*done_bytes));
  check(capture->finish());
}

}  // namespace slscan::io
