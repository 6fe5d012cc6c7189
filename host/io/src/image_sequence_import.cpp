#include "slscan/io/image_sequence_import.hpp"

#include <algorithm>
#include <cmath>
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
#include "slproto/json_fields.hpp"
#include "slproto/messages.hpp"
#include "slscan/io/image_file.hpp"
#include "slscan/io/io_error.hpp"

namespace slscan::io {

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

[[noreturn]] void fail(const std::string& origin, const std::string& what) { throw IoError(origin + ": " + what); }

std::string resolve(const std::string& base_dir, const std::string& name) {
  const fs::path p(name);
  return (p.is_absolute() || base_dir.empty() ? p : fs::path(base_dir) / p).string();
}

// Strict descriptions: an object may hold only the listed fields; anything else is refused with
// its path and the nearest known name ("phase.offset_radians: unknown field; did you mean
// offset_rad?"), through the one strict JSON field reader (slproto/json_fields.hpp).
void only_fields(const json& node, const std::string& origin, const std::string& path,
                 std::initializer_list<const char*> keys) {
  try {
    slproto::JsonObject object(node, path);
    for (const char* key : keys) (void)object.has(key);
    object.finish();
  } catch (const slproto::JsonFieldError& e) {
    fail(origin, e.what());
  }
}

std::string file_name(const json& node, const std::string& origin, const std::string& field) {
  if (!node.is_string() || node.get<std::string>().empty()) fail(origin, field + " must be a file name");
  return node.get<std::string>();
}

// An optional integer field in [min, max] (absent: `fallback`), refused (never wrapped or
// thrown as a JSON library error) when it is anything else.
long long int_field(const json& object, const char* key, long long fallback, long long min, long long max,
                    const std::string& origin, const std::string& field) {
  if (!object.contains(key)) return fallback;
  const json& v = object[key];
  const std::string range = "[" + std::to_string(min) + ", " + std::to_string(max) + "]";
  if (!v.is_number_integer()) fail(origin, field + " must be an integer in " + range + ", got " + v.dump());
  if (v.is_number_unsigned() ? v.get<unsigned long long>() > static_cast<unsigned long long>(max)
                             : (v.get<long long>() < min || v.get<long long>() > max))
    fail(origin, field + " must be an integer in " + range + ", got " + v.dump());
  return v.get<long long>();
}

// An optional text field (absent: `fallback`).
std::string text_field(const json& object, const char* key, const std::string& fallback, const std::string& origin,
                       const std::string& field) {
  if (!object.contains(key)) return fallback;
  const json& v = object[key];
  if (!v.is_string()) fail(origin, field + " must be a string, got " + v.dump());
  return v.get<std::string>();
}

// The widest zero-padded or space-padded number a file name pattern may ask for: an int has at
// most 10 digits, and a width of 999999999 would make each name a gigabyte (seconds of CPU each).
constexpr std::size_t kMaxPatternWidthDigits = 2;
constexpr int kMaxPatternWidth = 16;

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
  only_fields(node, origin, field, {"pattern", "first", "count"});
  const int first = static_cast<int>(int_field(node, "first", 0, 0, 1000000, origin, field + ".first"));
  const std::string pattern = file_name(node["pattern"], origin, field + ".pattern");
  if (pattern.find('%') == std::string::npos || pattern.find('%') != pattern.rfind('%') ||
      pattern.find_first_of("diu", pattern.find('%')) == std::string::npos)
    fail(origin, field + ".pattern '" + pattern + "' needs exactly one integer conversion such as %02d");
  const std::size_t conversion_end = pattern.find_first_of("diu", pattern.find('%'));
  if (pattern.find_first_not_of("0123456789", pattern.find('%') + 1) != conversion_end)
    fail(origin, field + ".pattern '" + pattern + "' may only have a width between % and d");
  const std::string width_digits = pattern.substr(pattern.find('%') + 1, conversion_end - pattern.find('%') - 1);
  const std::size_t significant = width_digits.find_first_not_of('0');
  if (significant != std::string::npos && (width_digits.size() - significant > kMaxPatternWidthDigits ||
                                           std::stoi(width_digits.substr(significant)) > kMaxPatternWidth))
    fail(origin, field + ".pattern '" + pattern + "': the width " + width_digits.substr(significant) + " is over " +
                     std::to_string(kMaxPatternWidth) + " (a name padded to at most " +
                     std::to_string(kMaxPatternWidth) + " characters per number)");
  if (!node.contains("count")) fail(origin, field + ".count is missing");
  const int count = static_cast<int>(int_field(node, "count", 0, 1, 4096, origin, field + ".count"));
  for (int i = 0; i < count; ++i) {
    std::vector<char> buffer(pattern.size() + kMaxPatternWidth + 16);
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
  return static_cast<int>(int_field(object, key, 0, 1, 65535, origin, field + "." + key));
}

}  // namespace

SequenceDescription parse_sequence_description(const std::string& json_text, const std::string& base_dir,
                                               const std::string& origin) {
  json doc;
  try {
    doc = slproto::parse_json_strict(json_text);  // syntax, duplicate keys (with their path), depth
  } catch (const std::exception& e) {
    fail(origin, std::string("not valid JSON: ") + e.what());
  }
  if (!doc.is_object()) fail(origin, "the description must be a JSON object");
  if (doc.contains("inverse"))
    fail(origin, "unknown field 'inverse': list the inverse (negative) Gray frames as gray.inverse_files");
  only_fields(doc, origin, "",
              {"projector", "axis", "camera", "white", "black", "gray", "phase", "complementary",
               "complementary_inverse", "image_dir", "comment", "calibration_keys"});
  if (doc.contains("projector") && doc["projector"].is_object())
    only_fields(doc["projector"], origin, "projector", {"width", "height"});
  if (doc.contains("camera") && doc["camera"].is_object())
    only_fields(doc["camera"], origin, "camera", {"width", "height", "bit_depth"});
  if (doc.contains("phase") && doc["phase"].is_object())
    only_fields(doc["phase"], origin, "phase", {"files", "period_px", "offset_steps", "offset_rad"});

  SequenceDescription d;
  if (doc.contains("calibration_keys")) {
    const json& keys = doc["calibration_keys"];
    if (!keys.is_object()) fail(origin, "calibration_keys must be an object {field: key in the calibration file}");
    for (const auto& [field, key] : keys.items()) {
      if (!key.is_string() || key.get<std::string>().empty())
        fail(origin, "calibration_keys." + field + " must be the name of an entry in the calibration file");
      d.calibration_keys[field] = key.get<std::string>();
    }
  }
  if (!doc.contains("projector") || !doc["projector"].is_object()) fail(origin, "projector {width, height} is missing");
  d.plan.projector_width = positive_int(doc["projector"], "width", origin, "projector", -1);
  d.plan.projector_height = positive_int(doc["projector"], "height", origin, "projector", -1);
  const std::string axis = text_field(doc, "axis", "columns", origin, "axis");
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
  only_fields(gray, origin, "gray", {"files", "inverse_files", "bit_order", "bits_not_projected", "convention"});
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
  const std::string order = text_field(gray, "bit_order", "msb_first", origin, "gray.bit_order");
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
  const int not_projected =
      static_cast<int>(int_field(gray, "bits_not_projected", 0, 0, 12, origin, "gray.bits_not_projected"));

  std::vector<std::string> phase_files;
  if (doc.contains("phase")) {
    const json& phase = doc["phase"];
    if (!phase.is_object() || !phase.contains("files") || !phase.contains("period_px"))
      fail(origin, "phase must be {files, period_px}");
    phase_files = file_list(phase["files"], origin, "phase.files");
    d.plan.period_px = positive_int(phase, "period_px", origin, "phase", -1);
    d.plan.phase_steps = static_cast<int>(phase_files.size());
    // Another scanner's phase origin (docs/real-data.md): which listed frame shows our step 0,
    // and a continuous offset (the phase its frames show at projector coordinate 0).
    if (phase.contains("offset_steps")) {
      const json& v = phase["offset_steps"];
      if (!v.is_number_integer() || (v.is_number_unsigned() && v.get<unsigned long long>() > (1u << 20)) ||
          v.get<long long>() < 0 || v.get<long long>() >= d.plan.phase_steps)
        fail(origin, "phase.offset_steps must be an integer in [0, " + std::to_string(d.plan.phase_steps) +
                         ") (the position in phase.files of the frame that shows step 0), got " + v.dump());
      d.plan.phase_offset_steps = v.get<int>();
    }
    if (phase.contains("offset_rad")) {
      const json& v = phase["offset_rad"];
      if (!v.is_number() || !std::isfinite(v.get<double>()) || std::abs(v.get<double>()) > 2 * 3.14159265358979323846)
        fail(origin, "phase.offset_rad must be a number of radians within [-2 pi, 2 pi], got " + v.dump());
      d.plan.phase_offset_rad = v.get<double>();
    }
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

namespace {

// One image as stored: grey, 8 or 16 bit.
ImageCache::Image load_image(const std::string& path, const std::string& what) {
  cv::Mat image = read_image_file(path, what);
  if (image.channels() == 3 || image.channels() == 4) {
    cv::Mat grey;
    cv::cvtColor(image, grey, image.channels() == 3 ? cv::COLOR_BGR2GRAY : cv::COLOR_BGRA2GRAY);
    image = grey;
  }
  if (image.channels() != 1) throw IoError(what + ": " + std::to_string(image.channels()) + " channels");
  if (image.depth() != CV_8U && image.depth() != CV_16U)
    throw IoError(what + ": the image is float; only 8- and 16-bit images are read");
  ImageCache::Image out;
  out.width = image.cols;
  out.height = image.rows;
  out.depth = image.depth() == CV_8U ? 8 : 16;
  const std::size_t row_bytes = static_cast<std::size_t>(image.cols) * image.elemSize();
  out.bytes.resize(row_bytes * static_cast<std::size_t>(image.rows));
  for (int y = 0; y < image.rows; ++y)
    std::memcpy(out.bytes.data() + static_cast<std::size_t>(y) * row_bytes, image.ptr(y), row_bytes);
  return out;
}

}  // namespace

ImportedSequence read_image_sequence(const SequenceDescription& description, ImageCache* cache) {
  ImportedSequence out;
  out.plan = slproto::PatternPlan(description.plan);
  if (description.files.size() != out.plan.size())
    throw IoError("import: the description gives " + std::to_string(description.files.size()) +
                  " images but its pattern plan has " + std::to_string(out.plan.size()) + " frames");
  out.source_bit_depth = description.bit_depth;
  out.bit_depth = description.bit_depth == 16 ? 12 : description.bit_depth;
  const int expected_depth = description.bit_depth == 8 ? 8 : 16;
  out.frames.reserve(description.files.size());
  for (std::size_t i = 0; i < description.files.size(); ++i) {
    const std::string& path = description.files[i];
    const std::string what =
        path + " (" + slproto::pattern_kind_name(out.plan[i].kind) + " " + std::to_string(out.plan[i].index) + ")";
    ImageCache::Image loaded;
    const ImageCache::Image* image = nullptr;
    if (cache != nullptr) {
      auto it = cache->images.find(path);
      if (it == cache->images.end()) it = cache->images.emplace(path, load_image(path, what)).first;
      image = &it->second;
    } else {
      loaded = load_image(path, what);
      image = &loaded;
    }
    if (image->depth != expected_depth)
      throw IoError(what + ": the image is " + std::to_string(image->depth) +
                    "-bit, the description says camera.bit_depth " + std::to_string(description.bit_depth));
    if (i == 0) {
      out.width = image->width;
      out.height = image->height;
      if ((description.camera_width && description.camera_width != out.width) ||
          (description.camera_height && description.camera_height != out.height))
        throw IoError(what + ": the image is " + std::to_string(out.width) + " x " + std::to_string(out.height) +
                      ", the description says " + std::to_string(description.camera_width) + " x " +
                      std::to_string(description.camera_height));
    } else if (image->width != out.width || image->height != out.height) {
      throw IoError(what + ": the image is " + std::to_string(image->width) + " x " + std::to_string(image->height) +
                    ", the first image is " + std::to_string(out.width) + " x " + std::to_string(out.height));
    }
    std::vector<std::uint8_t> bytes = image->bytes;
    if (description.bit_depth > 8) {
      auto* samples = reinterpret_cast<std::uint16_t*>(bytes.data());
      const std::size_t count = bytes.size() / 2;
      if (description.bit_depth == 10 || description.bit_depth == 12) {
        const std::uint16_t max_value = count ? *std::max_element(samples, samples + count) : 0;
        if (max_value >= (1 << description.bit_depth))
          throw IoError(what + ": holds the value " + std::to_string(max_value) + ", beyond camera.bit_depth " +
                        std::to_string(description.bit_depth));
      }
      if (description.bit_depth == 16)  // wire formats stop at 12 bits
        for (std::size_t k = 0; k < count; ++k)
          samples[k] = static_cast<std::uint16_t>(std::min(4095, (samples[k] + 8) >> 4));
    }
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
