#include "slscand/hal/board.hpp"

#include <algorithm>
#include <cstdio>
#include <map>
#include <set>

#include "slproto/number_text.hpp"
// Header-only and without exceptions: the firmware reports errors as values, and the board
// build then needs only the headers in its sysroot.
#define TOML_HEADER_ONLY 1
#define TOML_EXCEPTIONS 0
// toml++ 3.3 checks internal invariants with assertions that some malformed documents break
// ("l=[}": parse_value's "not a value terminator"); release builds (NDEBUG, GCC) compile them
// to nothing and the parser then reports the syntax error. Debug and fuzz builds do the same,
// so the fuzzer (with ASan and UBSan) tests the parser that ships.
#ifndef NDEBUG
#define TOML_ASSERT(expr) static_assert(true)
#endif
#include <toml++/toml.h>

namespace slscand::hal {

using slproto::Errc;
using slproto::make_error;

namespace {

bool is_bare_key_char(char c) {
  return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' || c == '-';
}

// Two inputs on which toml++ 3.3 (Debian 12) reaches undefined behaviour, both found by the
// board file fuzzer (tests/fuzz/corpus/board_file/crash-*), are refused before toml++ sees them:
// - a non-ASCII character where it tests for whitespace: its generated Unicode tables end in
//   __builtin_unreachable() for some code points ("2" + U+030C). Board files are ASCII.
// - a table header whose '[' is not followed by a key ("[#", "[[[x]]"): an assertion in debug
//   builds, an assumption (so undefined behaviour) in clang release builds. A line of a
//   multi-line nested array could start the same way; no board key takes one.
slproto::Status check_toml_input(const std::string& text, const std::string& source_name) {
  std::size_t line_start = 0;
  for (int line = 1; line_start < text.size(); ++line) {
    const std::size_t line_end = std::min(text.find('\n', line_start), text.size());
    for (std::size_t c = line_start; c < line_end; ++c) {
      if (static_cast<unsigned char>(text[c]) >= 0x80) {
        char byte[8];
        std::snprintf(byte, sizeof byte, "0x%02X", static_cast<unsigned char>(text[c]));
        return make_error(Errc::malformed, source_name + ":" + std::to_string(line) + ":" +
                                               std::to_string(c - line_start + 1) + ": non-ASCII byte " + byte +
                                               " (board files are ASCII, comments included)");
      }
    }
    std::size_t i = line_start;
    auto skip_blanks = [&] {
      while (i < line_end && (text[i] == ' ' || text[i] == '\t')) ++i;
    };
    skip_blanks();
    if (i < line_end && text[i] == '[') {
      // The same steps as toml++'s parse_table_header: '[', blanks, an optional second '['
      // (toml++ itself refuses "[ [") and blanks, then the name.
      ++i;
      const std::size_t after_bracket = i;
      skip_blanks();
      bool array_header = false;
      if (i < line_end && text[i] == '[' && i == after_bracket) {
        array_header = true;
        ++i;
        skip_blanks();
      }
      const bool name_follows = i < line_end && (is_bare_key_char(text[i]) || text[i] == '"' || text[i] == '\'' ||
                                                 text[i] == ']' || (text[i] == '[' && !array_header));
      if (!name_follows) {
        return make_error(Errc::malformed, source_name + ":" + std::to_string(line) +
                                               ": a table header '[' must be followed by a table name");
      }
    }
    line_start = line_end + 1;
  }
  return slproto::Ok{};
}

// Reads typed fields out of a toml table, remembering the first problem with its dotted name.
class FieldReader {
 public:
  FieldReader(const toml::table& root, std::string source) : root_(root), source_(std::move(source)) {}

  bool failed() const { return !error_.empty(); }
  slproto::Error error() const { return make_error(Errc::invalid_argument, source_ + ": " + error_); }

  const toml::node* node(const std::string& path) const { return root_.at_path(path).node(); }

  template <class T>
  void required(const std::string& path, T& out) {
    if (failed()) return;
    if (node(path) == nullptr) {
      error_ = "missing field '" + path + "'";
      return;
    }
    read(path, out);
  }
  template <class T>
  void optional(const std::string& path, T& out) {
    if (failed() || node(path) == nullptr) return;
    read(path, out);
  }

  void fail(const std::string& message) {
    if (!failed()) error_ = message;
  }

  // Every key must be one we know: a typo must not silently fall back to a default.
  void only_keys(const std::string& table_path, std::initializer_list<const char*> keys) {
    if (failed()) return;
    const toml::node* n = table_path.empty() ? &root_ : node(table_path);
    if (n == nullptr) return;
    const toml::table* table = n->as_table();
    if (table == nullptr) {
      fail("'" + table_path + "' must be a table");
      return;
    }
    const std::set<std::string> allowed(keys.begin(), keys.end());
    for (const auto& [key, value] : *table) {
      (void)value;
      if (!allowed.count(std::string(key.str()))) {
        fail("unknown field '" + (table_path.empty() ? "" : table_path + ".") + std::string(key.str()) + "'");
        return;
      }
    }
  }

 private:
  void read(const std::string& path, std::string& out) {
    if (auto v = node(path)->value<std::string>()) {
      out = *v;
    } else {
      error_ = "field '" + path + "' must be a string";
    }
  }
  void read(const std::string& path, double& out) {
    if (auto v = node(path)->value<double>()) {
      out = *v;
    } else {
      error_ = "field '" + path + "' must be a number";
    }
  }
  void read(const std::string& path, bool& out) {
    if (auto v = node(path)->value<bool>()) {
      out = *v;
    } else {
      error_ = "field '" + path + "' must be true or false";
    }
  }
  void read(const std::string& path, int& out) {
    auto v = node(path)->value<std::int64_t>();
    if (!v || !node(path)->is_integer() || *v < INT32_MIN || *v > INT32_MAX) {
      error_ = "field '" + path + "' must be an integer";
      return;
    }
    out = static_cast<int>(*v);
  }
  void read(const std::string& path, unsigned& out) {
    int v = 0;
    read(path, v);
    if (failed()) return;
    if (v < 0) {
      error_ = "field '" + path + "' must not be negative";
      return;
    }
    out = static_cast<unsigned>(v);
  }

  const toml::table& root_;
  std::string source_;
  std::string error_;
};

}  // namespace

slproto::Status BoardConfig::check() const {
  const std::string where = (source_path.empty() ? "board '" + name + "'" : source_path) + ": ";
  auto fail = [&](const std::string& message) { return make_error(Errc::invalid_argument, where + message); };

  if (gpio_backend != "gpiod" && gpio_backend != "sim")
    return fail("gpio.backend must be \"gpiod\" or \"sim\", not \"" + gpio_backend + "\"");
  if (camera_backend != "v4l2" && camera_backend != "libcamera" && camera_backend != "aravis" &&
      camera_backend != "sim") {
    return fail("camera.backend must be \"v4l2\", \"libcamera\", \"aravis\" or \"sim\", not \"" + camera_backend +
                "\"");
  }
  if (turntable_backend != "grbl") return fail("turntable.backend must be \"grbl\", not \"" + turntable_backend + "\"");
  if (serial_backend != "termios" && serial_backend != "libserialport" && serial_backend != "emulator") {
    return fail("turntable.serial must be \"termios\", \"libserialport\" or \"emulator\", not \"" + serial_backend +
                "\"");
  }
  // An empty name would only fail later, when the device is opened, with a less direct message.
  if (gpio_chip.empty()) return fail("gpio.chip must name a GPIO chip (a label, a name or a /dev path)");
  if (camera_device.empty()) return fail("camera.device must not be empty (\"auto\" takes the first camera)");
  if (serial_port.empty()) return fail("turntable.port must name a serial port (a path or usb:VID:PID)");
  const bool sim_gpio = gpio_backend == "sim";
  // The virtual camera obeys the virtual GPIO lines and renders at the emulated table's angle. A
  // real GenICam camera may join the virtual projectors and table on the bench (the fake GigE
  // Vision camera in the tests), triggered in software: no virtual line reaches its input.
  const bool bench_camera = sim_gpio && camera_backend == "aravis" && trigger_source == CameraTriggerSource::software;
  if ((sim_gpio != (camera_backend == "sim") && !bench_camera) || sim_gpio != (serial_backend == "emulator")) {
    return fail(
        "gpio.backend = \"sim\", camera.backend = \"sim\" and turntable.serial = \"emulator\" go together "
        "(the virtual camera obeys the virtual GPIO lines and renders at the emulated table's angle; an "
        "\"aravis\" camera may replace it with camera.trigger = \"software\")");
  }
  if (trigger_source == CameraTriggerSource::software && camera_backend != "aravis") {
    return fail(
        "camera.trigger = \"software\" needs camera.backend = \"aravis\" (the only backend with a "
        "software trigger)");
  }
  if (camera_backend == "aravis") {
    if (camera_trigger_input.empty()) return fail("camera.trigger_input must name the camera's input (e.g. Line0)");
    if (camera_trigger_activation != "RisingEdge" && camera_trigger_activation != "FallingEdge") {
      return fail("camera.trigger_activation must be \"RisingEdge\" or \"FallingEdge\", not \"" +
                  camera_trigger_activation + "\"");
    }
    if (camera_offset_x < 0 || camera_offset_y < 0)
      return fail("camera.offset_x and camera.offset_y must not be negative");
    if (camera_packet_size != 0 && (camera_packet_size < 576 || camera_packet_size > 16384)) {
      return fail("camera.packet_size must be 0 (negotiate) or 576..16384 bytes, not " +
                  std::to_string(camera_packet_size));
    }
    if (camera_buffers < 2 || camera_buffers > 64) return fail("camera.buffers must be in 2..64");
  }

  // Every line has one function.
  std::map<unsigned, std::string> used;
  auto claim = [&](unsigned offset, const std::string& field) -> std::string {
    auto [it, inserted] = used.emplace(offset, field);
    if (!inserted) {
      return "GPIO line " + std::to_string(offset) + " is assigned twice: " + it->second + " and " + field;
    }
    return {};
  };
  const char* sides[2] = {"projector.left", "projector.right"};
  for (int s = 0; s < 2; ++s) {
    const std::string side = sides[s];
    for (const auto& [offset, field] : {std::pair{projectors[s].trig_in_1, side + ".trig_in_1"},
                                        std::pair{projectors[s].trig_in_2, side + ".trig_in_2"},
                                        std::pair{projectors[s].trig_out_1, side + ".trig_out_1"}}) {
      if (auto problem = claim(offset, field); !problem.empty()) return fail(problem);
    }
  }
  if (trigger_source == CameraTriggerSource::gpio) {
    if (!camera_trigger_line) return fail("camera.trigger = \"gpio\" needs camera.trigger_line");
    if (auto problem = claim(*camera_trigger_line, "camera.trigger_line"); !problem.empty()) return fail(problem);
  } else if (camera_trigger_line) {
    return fail(
        "camera.trigger_line is set but camera.trigger = \"projector\" (the projectors' TRIG_OUT_1 drive the "
        "camera); remove one of them");
  }

  if (camera_format.width <= 0 || camera_format.height <= 0)
    return fail("camera.width and camera.height must be positive");
  if (!(pattern_exposure_us > 0)) return fail("timing.pattern_exposure_us must be positive");
  if (pattern_exposure_us < 235) return fail("timing.pattern_exposure_us below the DLP4500's 235 us minimum");
  if (!(readout_us >= 0)) return fail("camera.readout_us must not be negative");
  if (exposure_change_frames < 0 || exposure_change_frames > 16)
    return fail("camera.exposure_change_frames must be within 0 to 16 frames (" +
                std::to_string(exposure_change_frames) + ")");
  if (!(projector_latency_us >= 0 && projector_latency_us <= 1e6))
    return fail("timing.projector_latency_us must be within 0 to 1e6 us (one second)");
  if (!(pattern_period_us > pattern_exposure_us + readout_us)) {
    return fail("timing.pattern_period_us (" + slproto::short_number(pattern_period_us) +
                ") must exceed timing.pattern_exposure_us + camera.readout_us (" +
                slproto::short_number(pattern_exposure_us + readout_us) + ")");
  }
  if (!(settle_ms >= 0)) return fail("timing.settle_ms must not be negative");
  if (!(ack_timeout_ms > 0) || !(frame_timeout_ms > 0) || !(move_timeout_s > 0)) {
    return fail("timing.ack_timeout_ms, timing.frame_timeout_ms and timing.move_timeout_s must be positive");
  }
  if (!(gain > 0)) return fail("camera.gain must be positive");
  if (baud <= 0) return fail("turntable.baud must be positive");
  if (!(feed_deg_per_min > 0)) return fail("turntable.feed_deg_per_min must be positive");
  if (!(angle_tolerance_deg > 0)) return fail("turntable.angle_tolerance_deg must be positive");
  if (bind_address.empty()) return fail("network.bind_address must not be empty");
  if (port == 0) return fail("network.port must be in 1..65535");
  if (realtime_priority < 1 || realtime_priority > 99) return fail("realtime.priority must be in 1..99");
  if (sim_rig_size != "small" && sim_rig_size != "full") return fail("sim.rig_size must be \"small\" or \"full\"");
  return slproto::Ok{};
}

slproto::Result<BoardConfig> parse_board(const std::string& toml_text, const std::string& source_name) {
  if (auto input = check_toml_input(toml_text, source_name); !input) return input.error();
  toml::parse_result parsed = toml::parse(toml_text, source_name);
  if (!parsed) {
    const auto& err = parsed.error();
    return make_error(Errc::malformed, source_name + ":" + std::to_string(err.source().begin.line) + ":" +
                                           std::to_string(err.source().begin.column) + ": " +
                                           std::string(err.description()));
  }
  const toml::table& root = parsed.table();
  FieldReader r(root, source_name);
  BoardConfig b;
  b.source_path = source_name;

  r.only_keys("", {"board", "network", "gpio", "projector", "camera", "timing", "turntable", "realtime", "sim",
                   "timing_budget", "observer"});
  r.only_keys("board", {"name", "description"});
  r.only_keys("network", {"bind_address", "port"});
  r.only_keys("gpio", {"backend", "chip"});
  r.only_keys("projector", {"left", "right"});
  r.only_keys("projector.left", {"trig_in_1", "trig_in_2", "trig_out_1"});
  r.only_keys("projector.right", {"trig_in_1", "trig_in_2", "trig_out_1"});
  r.only_keys("camera", {"backend", "device", "width", "height", "pixel_format", "gain", "trigger", "trigger_line",
                         "readout_us", "exposure_change_frames", "trigger_input", "trigger_activation", "offset_x",
                         "offset_y", "packet_size", "buffers"});
  r.only_keys("timing", {"pattern_exposure_us", "pattern_period_us", "projector_latency_us", "settle_ms",
                         "ack_timeout_ms", "frame_timeout_ms", "move_timeout_s"});
  r.only_keys("turntable", {"backend", "serial", "port", "baud", "feed_deg_per_min", "angle_tolerance_deg"});
  r.only_keys("realtime", {"enabled", "priority", "cpu"});
  r.only_keys("timing_budget",
              {"period_mean_error_us", "period_jitter_p50_us", "period_jitter_p99_us", "period_jitter_max_us",
               "trigger_to_exposure_max_us", "exposure_error_max_us", "frame_delivery_p99_us", "frame_delivery_max_us",
               "move_settle_max_ms", "scan_time_ratio_max", "observer_tolerance_us"});
  r.only_keys("observer", {"chip", "left_trig_in_1", "left_trig_out_1", "right_trig_in_1", "right_trig_out_1"});
  r.only_keys("sim", {"scene", "rig_size", "camera_latency_us"});

  r.required("board.name", b.name);
  r.optional("board.description", b.description);
  r.required("network.bind_address", b.bind_address);
  int port = 0;
  r.required("network.port", port);
  if (!r.failed() && (port < 1 || port > 65535)) r.fail("field 'network.port' must be in 1..65535");
  b.port = static_cast<std::uint16_t>(port);
  r.required("gpio.backend", b.gpio_backend);
  r.required("gpio.chip", b.gpio_chip);
  const char* sides[2] = {"projector.left", "projector.right"};
  for (int s = 0; s < 2; ++s) {
    r.required(std::string(sides[s]) + ".trig_in_1", b.projectors[s].trig_in_1);
    r.required(std::string(sides[s]) + ".trig_in_2", b.projectors[s].trig_in_2);
    r.required(std::string(sides[s]) + ".trig_out_1", b.projectors[s].trig_out_1);
  }
  r.required("camera.backend", b.camera_backend);
  r.required("camera.device", b.camera_device);
  r.required("camera.width", b.camera_format.width);
  r.required("camera.height", b.camera_format.height);
  std::string pixel_format, trigger;
  r.required("camera.pixel_format", pixel_format);
  if (!r.failed()) {
    auto format = parse_pixel_format(pixel_format);
    if (!format)
      r.fail("field 'camera.pixel_format': " + format.error().message);
    else
      b.camera_format.pixel_format = *format;
  }
  r.optional("camera.gain", b.gain);
  r.required("camera.trigger", trigger);
  if (!r.failed()) {
    if (trigger == "projector")
      b.trigger_source = CameraTriggerSource::projector;
    else if (trigger == "gpio")
      b.trigger_source = CameraTriggerSource::gpio;
    else if (trigger == "software")
      b.trigger_source = CameraTriggerSource::software;
    else
      r.fail("field 'camera.trigger' must be \"projector\", \"gpio\" or \"software\", not \"" + trigger + "\"");
  }
  if (r.node("camera.trigger_line") != nullptr) {
    unsigned line = 0;
    r.required("camera.trigger_line", line);
    b.camera_trigger_line = line;
  }
  r.optional("camera.readout_us", b.readout_us);
  r.optional("camera.exposure_change_frames", b.exposure_change_frames);
  const bool genicam = b.camera_backend == "aravis";
  for (const char* key : {"camera.trigger_input", "camera.trigger_activation", "camera.offset_x", "camera.offset_y",
                          "camera.packet_size", "camera.buffers"}) {
    if (!genicam && r.node(key) != nullptr) {
      r.fail(std::string("field '") + key + "' applies to camera.backend = \"aravis\" only");
    }
  }
  r.optional("camera.trigger_input", b.camera_trigger_input);
  r.optional("camera.trigger_activation", b.camera_trigger_activation);
  r.optional("camera.offset_x", b.camera_offset_x);
  r.optional("camera.offset_y", b.camera_offset_y);
  r.optional("camera.packet_size", b.camera_packet_size);
  r.optional("camera.buffers", b.camera_buffers);
  r.required("timing.pattern_exposure_us", b.pattern_exposure_us);
  r.optional("timing.projector_latency_us", b.projector_latency_us);
  r.required("timing.pattern_period_us", b.pattern_period_us);
  r.optional("timing.settle_ms", b.settle_ms);
  r.optional("timing.ack_timeout_ms", b.ack_timeout_ms);
  r.optional("timing.frame_timeout_ms", b.frame_timeout_ms);
  r.optional("timing.move_timeout_s", b.move_timeout_s);
  r.required("turntable.backend", b.turntable_backend);
  r.required("turntable.serial", b.serial_backend);
  r.required("turntable.port", b.serial_port);
  r.required("turntable.baud", b.baud);
  r.optional("turntable.feed_deg_per_min", b.feed_deg_per_min);
  r.optional("turntable.angle_tolerance_deg", b.angle_tolerance_deg);
  r.optional("realtime.enabled", b.realtime);
  r.optional("realtime.priority", b.realtime_priority);
  r.optional("realtime.cpu", b.cpu);
  r.optional("sim.scene", b.sim_scene);
  r.optional("sim.rig_size", b.sim_rig_size);
  r.optional("sim.camera_latency_us", b.sim_camera_latency_us);
  TimingBudget& t = b.budget;
  for (const auto& [key, field] : {std::pair{"period_mean_error_us", &t.period_mean_error_us},
                                   std::pair{"period_jitter_p50_us", &t.period_jitter_p50_us},
                                   std::pair{"period_jitter_p99_us", &t.period_jitter_p99_us},
                                   std::pair{"period_jitter_max_us", &t.period_jitter_max_us},
                                   std::pair{"trigger_to_exposure_max_us", &t.trigger_to_exposure_max_us},
                                   std::pair{"exposure_error_max_us", &t.exposure_error_max_us},
                                   std::pair{"frame_delivery_p99_us", &t.frame_delivery_p99_us},
                                   std::pair{"frame_delivery_max_us", &t.frame_delivery_max_us},
                                   std::pair{"move_settle_max_ms", &t.move_settle_max_ms},
                                   std::pair{"scan_time_ratio_max", &t.scan_time_ratio_max},
                                   std::pair{"observer_tolerance_us", &t.observer_tolerance_us}}) {
    r.optional(std::string("timing_budget.") + key, *field);
    if (!r.failed() && !(*field >= 0)) r.fail(std::string("field 'timing_budget.") + key + "' must not be negative");
  }
  r.optional("observer.chip", b.observer.chip);
  for (const auto& [key, field] : {std::pair{"left_trig_in_1", &b.observer.left_trig_in_1},
                                   std::pair{"left_trig_out_1", &b.observer.left_trig_out_1},
                                   std::pair{"right_trig_in_1", &b.observer.right_trig_in_1},
                                   std::pair{"right_trig_out_1", &b.observer.right_trig_out_1}}) {
    if (r.node(std::string("observer.") + key) == nullptr) continue;
    unsigned line = 0;
    r.required(std::string("observer.") + key, line);
    *field = line;
  }
  if (!r.failed() && b.observer.chip.empty() &&
      (b.observer.left_trig_in_1 || b.observer.left_trig_out_1 || b.observer.right_trig_in_1 ||
       b.observer.right_trig_out_1)) {
    r.fail("observer lines are set but observer.chip is not");
  }
  if (r.failed()) return r.error();
  if (auto s = b.check(); !s) return s.error();
  return b;
}

slproto::Result<BoardConfig> load_board(const std::string& path) {
  std::FILE* file = std::fopen(path.c_str(), "rb");
  if (file == nullptr) return make_error(Errc::io_error, "cannot open board file " + path);
  std::string text;
  char buffer[4096];
  std::size_t n = 0;
  while ((n = std::fread(buffer, 1, sizeof buffer, file)) > 0) text.append(buffer, n);
  std::fclose(file);
  return parse_board(text, path);
}

}  // namespace slscand::hal
