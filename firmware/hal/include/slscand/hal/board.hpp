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

// [timing_budget]: what the hardware-in-the-loop harness (tests/hil, docs/hil.md) accepts from
// a scan on this board. slscand itself does not enforce it. The defaults suit a real board with
// a SCHED_FIFO sequencer; the sim board sets looser limits because it shares a loaded machine.
struct TimingBudget {
  double period_mean_error_us = 20;         // |mean trigger-to-trigger period - nominal|
  double period_jitter_p50_us = 20;         // |period - nominal|, median
  double period_jitter_p99_us = 100;        // ... 99th percentile
  double period_jitter_max_us = 500;        // ... worst
  double trigger_to_exposure_max_us = 200;  // TRIG_IN_1 driven -> camera exposure start, worst
  double exposure_error_max_us = 50;        // |exposure length - requested|, worst
  double frame_delivery_p99_us = 20'000;    // exposure end -> frame dequeued, 99th percentile
  double frame_delivery_max_us = 50'000;    // ... worst
  double move_settle_max_ms = 5'000;        // turntable move start -> settled, per view, worst
  double scan_time_ratio_max = 1.5;         // scan time / (frames x period + measured moves)
  double observer_tolerance_us = 200;       // sequencer log vs observer edge, worst disagreement
};

// [observer] (real boards): GPIO inputs wired back from the trigger outputs, on which the HIL
// harness records edges with kernel timestamps, independently of the sequencer's own log. An
// unset line is not observed. The sim board needs none: its virtual bus records every edge.
struct ObserverLines {
  std::string chip;  // "" = no observer wiring
  std::optional<unsigned> left_trig_in_1, left_trig_out_1, right_trig_in_1, right_trig_out_1;
};

enum class CameraTriggerSource : std::uint8_t {
  projector,  // the projectors' TRIG_OUT_1 are wired (ORed) to the camera trigger input
  gpio,       // the board drives the camera trigger from its own GPIO line
  software,   // the sequencer triggers the camera in software once the pattern is shown (Aravis
              // bench set-ups, e.g. the fake GigE Vision camera, which has no trigger line)
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
  std::string camera_backend;  // "v4l2", "libcamera", "aravis" or "sim"
  std::string camera_device;   // "/dev/video0", a libcamera id, an Aravis id/IP/serial, "auto" or "virtual"
  CameraFormat camera_format;
  double gain = 1.0;
  CameraTriggerSource trigger_source = CameraTriggerSource::projector;
  std::optional<unsigned> camera_trigger_line;  // [camera] trigger_line, for trigger = "gpio"
  double readout_us = 0;                        // sensor read-out after the exposure
  // Frames a new exposure time takes to apply (the camera's control latency): after changing
  // it between a bracket's passes the sequencer waits this many pattern periods before the
  // next trigger, so no frame of the new pass is exposed with the old setting.
  int exposure_change_frames = 0;
  // GenICam (aravis) cameras: where the trigger enters the camera and the sensor window.
  std::string camera_trigger_input = "Line0";  // TriggerSource for external triggers (LineN)
  std::string camera_trigger_activation = "RisingEdge";
  int camera_offset_x = 0;
  int camera_offset_y = 0;
  int camera_packet_size = 0;  // GigE Vision stream packet size in bytes; 0 = negotiate
  int camera_buffers = 8;      // the stream's buffer pool

  // [timing]
  double pattern_exposure_us = 8333;
  double pattern_period_us = 16667;
  // The projectors' TRIG_IN_1 -> TRIG_OUT_1 delay: a pattern period must hold it too (the
  // scan plan's check). The sim's projectors lag by it; 0 where the board file does not state it.
  double projector_latency_us = 0;
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
  std::string sim_rig_size = "small";  // "small" (640 x 512) or "full"
  double sim_camera_latency_us = 5;    // trigger edge -> exposure start

  // [timing_budget], [observer] (the HIL harness's; see TimingBudget)
  TimingBudget budget;
  ObserverLines observer;

  bool is_sim() const { return gpio_backend == "sim"; }
  // Cross-field checks (loading runs them; a board built in code should too).
  slproto::Status check() const;
};

slproto::Result<BoardConfig> load_board(const std::string& path);
slproto::Result<BoardConfig> parse_board(const std::string& toml_text, const std::string& source_name);

}  // namespace slscand::hal
