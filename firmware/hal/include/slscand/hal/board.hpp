// A board description (boards/*.toml): which backend drives each device, on which GPIO lines,
// device nodes and serial port, with which timing. Loading checks every field and names the
// first one that is missing, mistyped or contradicts another.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>

#include "slproto/result.hpp"
#include "slscand/hal/camera.hpp"
#include "slscand/hal/projector.hpp"

namespace slscand::hal {

enum class CameraTriggerSource : std::uint8_t {
  projector,  // the projectors' TRIG_OUT_1 are wired (ORed) to the camera trigger input
  gpio,       // the board drives the camera trigger from its own GPIO line
};

struct BoardConfig {
  std::string name;
  std::string description;
  std::string source_path;  // the file it came from, for messages

  // [network]
  std::string bind_address = "127.0.0.1";
  std::uint16_t port = 7878;

  // [gpio]
  std::string gpio_backend;  // "gpiod" or "sim"
  std::string gpio_chip;     // "gpiochip0", a path, or a label for gpiod

  // [projector.left], [projector.right]
  std::array<DlpLines, 2> projectors{};

  // [camera]
  std::string camera_backend;  // "v4l2", "libcamera" or "sim"
  std::string camera_device;   // "/dev/video0", a libcamera id, or "virtual"
  CameraFormat camera_format;
  double gain = 1.0;
  CameraTriggerSource trigger_source = CameraTriggerSource::projector;
  std::optional<unsigned> camera_trigger_line;  // [camera] trigger_line, for trigger = "gpio"
  double readout_us = 0;                        // sensor read-out after the exposure

  // [timing]
  double pattern_exposure_us = 8333;
  double pattern_period_us = 16667;
  double settle_ms = 200;
  double ack_timeout_ms = 20;
  double frame_timeout_ms = 500;
  double move_timeout_s = 20;

  // [turntable]
  std::string turntable_backend;  // "grbl"
  std::string serial_backend;     // "termios", "libserialport" or "emulator" (sim)
  std::string serial_port;        // path, "usb:VVVV:PPPP" (libserialport) or "pty" (emulator)
  int baud = 115200;
  double feed_deg_per_min = 3600;
  double angle_tolerance_deg = 0.05;

  // [realtime]
  bool realtime = true;  // SCHED_FIFO + mlockall when permitted
  int realtime_priority = 80;
  int cpu = -1;  // pin the sequencer thread; -1 = no pinning

  // [sim] (sim backends only)
  std::string sim_scene = "sphere";
  std::string sim_rig_size = "small";    // "small" (640 x 512) or "full"
  double sim_projector_latency_us = 15;  // TRIG_IN_1 -> TRIG_OUT_1
  double sim_camera_latency_us = 5;      // trigger edge -> exposure start

  bool is_sim() const { return gpio_backend == "sim"; }
  // Cross-field checks (loading runs them; a board built in code should too).
  slproto::Status check() const;
};

slproto::Result<BoardConfig> load_board(const std::string& path);
slproto::Result<BoardConfig> parse_board(const std::string& toml_text, const std::string& source_name);

}  // namespace slscand::hal
