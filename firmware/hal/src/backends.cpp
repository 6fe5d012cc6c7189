#include "slscand/hal/backends.hpp"

#include "slscand/hal/grbl/grbl_turntable.hpp"

#if defined(SLSCAND_HAVE_GPIOD)
#include "slscand/hal/gpiod/gpiod_chip.hpp"
#endif
#if defined(SLSCAND_HAVE_V4L2)
#include "slscand/hal/v4l2/v4l2_camera.hpp"
#endif
#if defined(SLSCAND_HAVE_LIBCAMERA)
#include "slscand/hal/libcamera/libcamera_camera.hpp"
#endif
#if defined(SLSCAND_HAVE_ARAVIS)
#include "slscand/hal/aravis/aravis_camera.hpp"
#endif
#if defined(SLSCAND_HAVE_SIM)
#include "slscand/hal/sim/sim_rig.hpp"
#endif

namespace slscand::hal {

using slproto::Errc;
using slproto::make_error;

namespace {

slproto::Error not_built(const std::string& field, const std::string& backend) {
  return make_error(Errc::unsupported, field + " = \"" + backend + "\": this slscand was built without that backend (" +
                                           available_backends() + ")");
}

Result<std::unique_ptr<GpioChip>> open_chip(const BoardConfig& board, BoardDevices& devices) {
  if (board.gpio_backend == "sim") {
#if defined(SLSCAND_HAVE_SIM)
    return devices.sim_rig->make_gpio_chip();
#endif
  }
  if (board.gpio_backend == "gpiod") {
#if defined(SLSCAND_HAVE_GPIOD)
    return open_gpiod_chip(board.gpio_chip);
#endif
  }
  (void)devices;
  return not_built("gpio.backend", board.gpio_backend);
}

Result<std::unique_ptr<Camera>> open_camera(const BoardConfig& board, BoardDevices& devices) {
  if (board.camera_backend == "sim") {
#if defined(SLSCAND_HAVE_SIM)
    return devices.sim_rig->make_camera();
#endif
  }
  if (board.camera_backend == "v4l2") {
#if defined(SLSCAND_HAVE_V4L2)
    return open_v4l2_camera(board.camera_device);
#endif
  }
  if (board.camera_backend == "libcamera") {
#if defined(SLSCAND_HAVE_LIBCAMERA)
    return open_libcamera_camera(board.camera_device);
#endif
  }
  if (board.camera_backend == "aravis") {
#if defined(SLSCAND_HAVE_ARAVIS)
    AravisOptions options;
    options.device = board.camera_device;
    options.offset_x = board.camera_offset_x;
    options.offset_y = board.camera_offset_y;
    options.trigger_input = board.camera_trigger_input;
    options.trigger_activation = board.camera_trigger_activation;
    options.packet_size = board.camera_packet_size;
    options.buffers = board.camera_buffers;
    return open_aravis_camera(options);
#endif
  }
  (void)devices;
  return not_built("camera.backend", board.camera_backend);
}

Result<std::unique_ptr<SerialPort>> open_serial(const BoardConfig& board, BoardDevices& devices) {
  if (board.serial_backend == "emulator") {
#if defined(SLSCAND_HAVE_SIM)
    return open_termios_port(devices.sim_rig->turntable().slave_path(), board.baud);
#endif
  }
  if (board.serial_backend == "termios") return open_termios_port(board.serial_port, board.baud);
  if (board.serial_backend == "libserialport") {
#if defined(SLSCAND_HAVE_LIBSERIALPORT)
    auto path = resolve_serial_port(board.serial_port);
    if (!path) return std::move(path).error();
    return open_libserialport_port(*path, board.baud);
#endif
  }
  (void)devices;
  return not_built("turntable.serial", board.serial_backend);
}

}  // namespace

TriggerMode camera_trigger_mode(const BoardConfig& board) {
  return board.trigger_source == CameraTriggerSource::software ? TriggerMode::software : TriggerMode::external;
}

Result<std::unique_ptr<GpioChip>> open_board_gpio_chip(const BoardConfig& board, BoardDevices& devices) {
  return open_chip(board, devices);
}
Result<std::unique_ptr<Camera>> open_board_camera(const BoardConfig& board, BoardDevices& devices) {
  return open_camera(board, devices);
}
Result<std::unique_ptr<SerialPort>> open_board_serial_port(const BoardConfig& board, BoardDevices& devices) {
  return open_serial(board, devices);
}

std::string available_backends() {
  std::string gpio = "gpio:";
  std::string camera = "camera:";
  std::string serial = "serial: termios";
#if defined(SLSCAND_HAVE_GPIOD)
  gpio += " gpiod(v" + std::to_string(SLSCAND_GPIOD_API) + ")";
#endif
#if defined(SLSCAND_HAVE_V4L2)
  camera += " v4l2";
#endif
#if defined(SLSCAND_HAVE_LIBCAMERA)
  camera += " libcamera";
#endif
#if defined(SLSCAND_HAVE_ARAVIS)
  camera += " aravis";
#endif
#if defined(SLSCAND_HAVE_LIBSERIALPORT)
  serial += " libserialport";
#endif
#if defined(SLSCAND_HAVE_SIM)
  gpio += " sim";
  camera += " sim";
  serial += " emulator";
#endif
  return gpio + "; " + camera + "; " + serial;
}

slproto::Status BoardDevices::load_patterns(const slproto::PatternPlan& plan, Nanos exposure_ns) {
#if defined(SLSCAND_HAVE_SIM)
  if (sim_rig) {
    sim_rig->load_patterns(plan, exposure_ns);
    return slproto::Ok{};
  }
#endif
  // DLPC350 pattern memory holds at most 256 one-bit (32 eight-bit) patterns per sequence.
  if (plan.size() > 32) {
    return make_error(Errc::unsupported,
                      "the projectors hold at most 32 8-bit patterns; the plan has " + std::to_string(plan.size()));
  }
  (void)exposure_ns;
  return slproto::Ok{};
}

slproto::Status BoardDevices::place_calibration_target(
    const std::optional<slproto::CalibrationTargetPlacement>& target) {
#if defined(SLSCAND_HAVE_SIM)
  if (sim_rig) return sim_rig->place_calibration_target(target);
#endif
  (void)target;
  return slproto::Ok{};
}

slproto::Result<slproto::RigCalibration> BoardDevices::true_calibration() const {
#if defined(SLSCAND_HAVE_SIM)
  if (sim_rig) return sim_rig->true_calibration();
#endif
  return slproto::make_error(slproto::Errc::unsupported,
                             "the board drives hardware, whose true calibration nobody knows: calibrate it "
                             "(slscan calibrate --connect, docs/calibration.md)");
}

slproto::Status open_board_simulation(const BoardConfig& board, BoardDevices& devices, const OpenOptions& options) {
  if (!board.is_sim()) return slproto::Ok{};
#if defined(SLSCAND_HAVE_SIM)
  auto rig = sim::SimRig::create(board, options.sim_scene);
  if (!rig) return std::move(rig).error();
  devices.sim_rig = std::move(*rig);
  return slproto::Ok{};
#else
  (void)devices;
  (void)options;
  return not_built("gpio.backend", board.gpio_backend);
#endif
}

slproto::Result<BoardDevices> open_board_devices(const BoardConfig& board, const OpenOptions& options) {
  if (auto s = board.check(); !s) return s.error();
  BoardDevices devices;
  if (auto s = open_board_simulation(board, devices, options); !s) return s.error();

  auto chip = open_chip(board, devices);
  if (!chip) return std::move(chip).error();
  devices.chip = std::move(*chip);
  const char* names[2] = {"projector.left", "projector.right"};
  for (int side = 0; side < 2; ++side) {
    auto projector = DlpProjector::open(*devices.chip, board.projectors[side], names[side]);
    if (!projector) return std::move(projector).error();
    if (auto s = (*projector)->stop(); !s) return s.error();
    devices.projectors[side] = std::move(*projector);
  }
  if (board.trigger_source == CameraTriggerSource::gpio) {
    LineRequestConfig config;
    config.consumer = "slscand camera trigger";
    config.lines = {
        {*board.camera_trigger_line, LineDirection::output, false, EdgeDetection::none, false, "camera.trigger_line"}};
    auto request = devices.chip->request_lines(config);
    if (!request) return std::move(request).error();
    devices.camera_trigger = std::move(*request);
  }

  auto camera = open_camera(board, devices);
  if (!camera) return std::move(camera).error();
  devices.camera = std::move(*camera);
  auto format = devices.camera->set_format(board.camera_format);
  if (!format) return std::move(format).error();
  devices.camera_format = *format;
  if (auto s = devices.camera->set_exposure_us(board.pattern_exposure_us); !s) return s.error();
  if (auto s = devices.camera->set_gain(board.gain); !s) return s.error();
  if (auto s = devices.camera->set_trigger_mode(camera_trigger_mode(board)); !s) return s.error();

  auto port = open_serial(board, devices);
  if (!port) return std::move(port).error();
  GrblOptions grbl;
  grbl.feed_deg_per_min = board.feed_deg_per_min;
  grbl.tolerance_deg = board.angle_tolerance_deg;
  auto table = GrblTurntable::connect(std::move(*port), grbl);
  if (!table) return std::move(table).error();
  devices.turntable = std::move(*table);
  return devices;
}

}  // namespace slscand::hal
