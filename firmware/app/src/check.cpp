#include "slscand/app/check.hpp"

#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <thread>

#include "slproto/file_util.hpp"
#include "slproto/transport.hpp"
#include "slscand/app/config.hpp"
#include "slscand/app/security.hpp"
#include "slscand/hal/backends.hpp"
#include "slscand/hal/grbl/grbl_turntable.hpp"
#if defined(SLSCAND_HAVE_SIM)
#include "slscand/hal/sim/sim_rig.hpp"
#endif

namespace slscand {

namespace {

bool contains(const std::string& text, const char* what) { return text.find(what) != std::string::npos; }

std::string lines_text(const hal::DlpLines& lines) {
  return "TRIG_IN_1 " + std::to_string(lines.trig_in_1) + ", TRIG_IN_2 " + std::to_string(lines.trig_in_2) +
         ", TRIG_OUT_1 " + std::to_string(lines.trig_out_1);
}

bool is_loopback(const std::string& address) {
  return address == "127.0.0.1" || address == "::1" || address == "localhost" || address.rfind("127.", 0) == 0;
}

struct Checker {
  CheckReport report;
  void ok(std::string name, std::string detail) {
    report.items.push_back({std::move(name), CheckState::ok, std::move(detail), {}});
  }
  void missing(std::string name, std::string detail, std::string fix) {
    report.items.push_back({std::move(name), CheckState::missing, std::move(detail), std::move(fix)});
  }
  void skipped(std::string name, std::string why) {
    report.items.push_back({std::move(name), CheckState::skipped, std::move(why), {}});
  }
};

std::string permission_fix(const std::string& error, const std::string& group, const std::string& otherwise) {
  if (contains(error, "Permission denied") || contains(error, "EACCES") || contains(error, "Operation not permitted"))
    return "the user running slscand may not open it: add it to group '" + group +
           "' (the slscand package's service does; by hand: `sudo adduser $USER " + group +
           "`, log in again) and check the udev rule /usr/lib/udev/rules.d/60-slscan.rules is applied "
           "(`sudo udevadm trigger`)";
  return otherwise;
}

void check_gpio(Checker& c, const hal::BoardConfig& board, hal::BoardDevices& devices) {
  const std::string chip_name = "gpio chip '" + board.gpio_chip + "' (" + board.gpio_backend + ")";
  auto chip = hal::open_board_gpio_chip(board, devices);
  if (!chip) {
    const std::string& e = chip.error().message;
    std::string fix = contains(e, "built without")
                          ? "install a slscand built with the '" + board.gpio_backend +
                                "' backend, or change [gpio] backend in " + board.source_path
                          : permission_fix(e, "slscan",
                                           "`gpiodetect` lists this machine's chips with their labels; put the "
                                           "header's chip in [gpio] chip of " +
                                               board.source_path +
                                               " (Pi 4: pinctrl-bcm2711; Pi 5: pinctrl-rp1; BeagleBone: gpiochip0..3)");
    c.missing(chip_name, e, fix);
    c.skipped("gpio lines projector.left", "needs the GPIO chip");
    c.skipped("gpio lines projector.right", "needs the GPIO chip");
    return;
  }
  devices.chip = std::move(*chip);
  c.ok(chip_name, "opened");
  const char* names[2] = {"projector.left", "projector.right"};
  for (int side = 0; side < 2; ++side) {
    const std::string item = std::string("gpio lines ") + names[side];
    auto projector = hal::DlpProjector::open(*devices.chip, board.projectors[side], names[side]);
    if (!projector) {
      c.missing(item + " (" + lines_text(board.projectors[side]) + ")", projector.error().message,
                permission_fix(projector.error().message, "slscan",
                               "a line is held by another program or driver: `gpioinfo " + board.gpio_chip +
                                   "` shows each line's consumer; free it (e.g. a dtoverlay or a script using it) "
                                   "or move the wire and change [" +
                                   names[side] + "] in " + board.source_path));
      continue;
    }
    c.ok(item, lines_text(board.projectors[side]) + " requested");
    devices.projectors[side] = std::move(*projector);
  }
  if (board.trigger_source == hal::CameraTriggerSource::gpio) {
    hal::LineRequestConfig config;
    config.consumer = "slscand --check";
    config.lines = {{*board.camera_trigger_line, hal::LineDirection::output, false, hal::EdgeDetection::none, false,
                     "camera.trigger_line"}};
    auto request = devices.chip->request_lines(config);
    if (!request)
      c.missing("gpio camera trigger line " + std::to_string(*board.camera_trigger_line), request.error().message,
                "`gpioinfo " + board.gpio_chip + "` shows who holds the line; free it or change [camera] trigger_line");
    else
      c.ok("gpio camera trigger line", "line " + std::to_string(*board.camera_trigger_line) + " requested");
  }
}

void check_camera(Checker& c, const hal::BoardConfig& board, hal::BoardDevices& devices) {
  const std::string name = "camera '" + board.camera_device + "' (" + board.camera_backend + ")";
  auto camera = hal::open_board_camera(board, devices);
  if (!camera) {
    const std::string& e = camera.error().message;
    std::string fix;
    if (contains(e, "built without"))
      fix = "install a slscand built with the '" + board.camera_backend + "' backend, or change [camera] backend";
    else if (board.camera_backend == "aravis")
      fix =
          "the camera must answer GigE Vision discovery (or be on USB3): check its power and cable, put it on the "
          "board's subnet (or give its IP address in [camera] device), and see docs/hardware.md for MTU and "
          "socket buffers";
    else if (board.camera_backend == "libcamera")
      fix = permission_fix(e, "video",
                           "`rpicam-hello --list-cameras` (libcamera-hello on older images) must list the camera: "
                           "check the ribbon cable and the overlay in /boot/firmware/config.txt (e.g. "
                           "dtoverlay=imx296), reboot; then set [camera] device (\"auto\" = the first camera)");
    else
      fix = permission_fix(e, "video",
                           "`v4l2-ctl --list-devices` lists the cameras: plug the camera in and put its "
                           "/dev/videoN (or /dev/v4l/by-id/...) in [camera] device of " +
                               board.source_path);
    c.missing(name, e, fix);
    c.skipped("camera controls", "needs the camera");
    return;
  }
  devices.camera = std::move(*camera);
  c.ok(name, devices.camera->describe());
  for (const auto& detail : devices.camera->check_details()) c.ok(detail.name, detail.detail);
  std::vector<std::string> problems;
  auto format = devices.camera->set_format(board.camera_format);
  if (!format) problems.push_back("format: " + format.error().message);
  if (auto s = devices.camera->set_exposure_us(board.pattern_exposure_us); !s)
    problems.push_back("exposure: " + s.error().message);
  if (auto s = devices.camera->set_gain(board.gain); !s) problems.push_back("gain: " + s.error().message);
  const hal::TriggerMode trigger = hal::camera_trigger_mode(board);
  if (auto s = devices.camera->set_trigger_mode(trigger); !s)
    problems.push_back(std::string(hal::trigger_mode_name(trigger)) + " trigger: " + s.error().message);
  if (problems.empty()) {
    std::string trigger_text = hal::trigger_mode_name(trigger) + std::string(" trigger");
    if (board.camera_backend == "aravis" && trigger == hal::TriggerMode::external)
      trigger_text += " on " + board.camera_trigger_input + " (" + board.camera_trigger_activation + ")";
    c.ok("camera controls", std::to_string(format->width) + " x " + std::to_string(format->height) + " " +
                                hal::pixel_format_name(format->pixel_format) + ", exposure " +
                                std::to_string(static_cast<long>(board.pattern_exposure_us)) + " us, gain, " +
                                trigger_text);
    devices.camera_format = *format;
  } else {
    std::string detail;
    for (const auto& p : problems) detail += (detail.empty() ? "" : "; ") + p;
    if (board.camera_backend == "aravis") {
      c.missing("camera controls", detail,
                "the camera does not take the board file's settings: compare [camera] width, height, offset_x, "
                "offset_y and pixel_format with the \"camera features\" line above, and trigger_input with its "
                "trigger sources (docs/hardware.md, GigE Vision cameras)");
    } else {
      c.missing("camera controls", detail,
                "the camera does not take the board file's settings: compare [camera] width, height, pixel_format "
                "with `v4l2-ctl -d DEVICE --list-formats-ext --list-ctrls`; external trigger needs the sensor's "
                "trigger mode (docs/hardware.md)");
    }
  }
}

void check_turntable(Checker& c, const hal::BoardConfig& board, hal::BoardDevices& devices) {
  const std::string name = "serial port '" + board.serial_port + "' (" + board.serial_backend + ")";
  auto port = hal::open_board_serial_port(board, devices);
  if (!port) {
    const std::string& e = port.error().message;
    c.missing(
        name, e,
        contains(e, "built without")
            ? "install a slscand built with the '" + board.serial_backend + "' backend, or change [turntable] serial"
            : permission_fix(e, "dialout",
                             "plug in the turntable's USB serial adapter; `ls -l /dev/serial/by-id/` shows it "
                             "(and `lsusb` its usb:VVVV:PPPP id); put it in [turntable] port of " +
                                 board.source_path));
    c.skipped("turntable answer", "needs the serial port");
    return;
  }
  c.ok(name, "opened at " + std::to_string(board.baud) + " baud");
  hal::GrblOptions grbl;
  grbl.feed_deg_per_min = board.feed_deg_per_min;
  grbl.tolerance_deg = board.angle_tolerance_deg;
  auto table = hal::GrblTurntable::connect(std::move(*port), grbl);
  if (!table) {
    c.missing("turntable answer", table.error().message,
              "the port opened but GRBL did not answer: is the turntable powered, is the Arduino running GRBL, "
              "is [turntable] baud (" +
                  std::to_string(board.baud) + ") its rate? (`screen PORT " + std::to_string(board.baud) +
                  "` then Ctrl-X should print the Grbl banner)");
    return;
  }
  auto status = (*table)->status();
  if (!status) {
    c.missing("turntable answer", status.error().message,
              "GRBL answered its reset but not a status query: check its firmware settings ($$) against "
              "docs/turntable.md");
    return;
  }
  char angle[32];
  std::snprintf(angle, sizeof angle, "%.2f", status->angle_deg);
  c.ok("turntable answer", std::string("GRBL answered; angle ") + angle + " deg");
  devices.turntable = std::move(*table);
}

void check_realtime(Checker& c, const hal::BoardConfig& board, const CheckOptions& options) {
  if (!board.realtime || !options.realtime) {
    c.skipped("real-time", !board.realtime ? "[realtime] enabled = false in the board file"
                                           : "disabled by --no-realtime / the configuration");
    return;
  }
  // Probed on a throw-away thread: the checking process itself stays an ordinary one.
  int fifo_error = 0, pin_error = 0;
  std::thread probe([&] {
    sched_param param{};
    param.sched_priority = board.realtime_priority;
    fifo_error = pthread_setschedparam(pthread_self(), SCHED_FIFO, &param);
    if (board.cpu >= 0) {
      cpu_set_t set;
      CPU_ZERO(&set);
      CPU_SET(static_cast<unsigned>(board.cpu), &set);
      pin_error = pthread_setaffinity_np(pthread_self(), sizeof set, &set);
    }
  });
  probe.join();
  const std::string fifo = "SCHED_FIFO priority " + std::to_string(board.realtime_priority);
  if (fifo_error == 0)
    c.ok("real-time scheduling", fifo + " granted");
  else
    c.missing("real-time scheduling", fifo + ": " + slproto::errno_text(fifo_error),
              "run slscand as the packaged service (AmbientCapabilities=CAP_SYS_NICE, LimitRTPRIO=99 in "
              "slscand.service), or for a manual run give the user an rtprio limit in "
              "/etc/security/limits.d/ (e.g. `slscand - rtprio 99`); or set [realtime] enabled = false");
  if (::mlockall(MCL_CURRENT) == 0) {
    ::munlockall();
    c.ok("memory locking", "mlockall granted");
  } else {
    c.missing("memory locking", "mlockall: " + slproto::errno_text(errno),
              "the packaged service grants it (AmbientCapabilities=CAP_IPC_LOCK, LimitMEMLOCK=infinity); by hand: "
              "`ulimit -l unlimited` or a memlock line in /etc/security/limits.d/");
  }
  if (board.cpu >= 0) {
    const long cpus = ::sysconf(_SC_NPROCESSORS_ONLN);
    if (pin_error == 0)
      c.ok("cpu pinning", "cpu " + std::to_string(board.cpu) + " of " + std::to_string(cpus));
    else
      c.missing("cpu pinning",
                "cpu " + std::to_string(board.cpu) + ": " + slproto::errno_text(pin_error) + " (this machine has " +
                    std::to_string(cpus) + " online cpus)",
                "set [realtime] cpu in " + board.source_path + " to an online cpu (0.." + std::to_string(cpus - 1) +
                    ") or -1 for no pinning");
  }
}

void check_network(Checker& c, const hal::BoardConfig& board, const CheckOptions& options) {
  const std::string address = options.bind_address.empty() ? board.bind_address : options.bind_address;
  const int port = options.port < 0 ? board.port : options.port;
  const std::string name = "network bind " + address + ":" + std::to_string(port);
  auto server = slproto::Server::listen(address, static_cast<std::uint16_t>(port));
  if (!server) {
    const std::string& e = server.error().message;
    std::string fix;
    if (contains(e, "in use"))
      fix =
          "another program listens there: an slscand already running? (`systemctl status slscand`, `ss -ltnp "
          "'sport = :" +
          std::to_string(port) + "'`); stop it for the check or choose another port";
    else if (contains(e, "assign"))
      fix = "the address is not one of this machine's (`ip -br addr`): use 0.0.0.0 (every interface) or one of them";
    else if (contains(e, "denied"))
      fix = "ports below 1024 need CAP_NET_BIND_SERVICE: use a port >= 1024";
    else
      fix = "check bind_address and port in the configuration and [network] in " + board.source_path;
    c.missing(name, e, fix);
  } else {
    c.ok(name, "can listen");
  }

  const std::string token_item = "token";
  if (!options.token_file.empty()) {
    auto token = read_token_file(options.token_file);
    if (!token && contains(token.error().message, "Permission denied"))
      // Mode and type already passed (read_token_file checks them first): this is the packaged
      // root-only file, which the service receives as a systemd credential.
      c.ok(token_item, options.token_file + ": private, root-only; the service gets it through LoadCredential");
    else if (!token)
      c.missing(token_item, token.error().message,
                contains(token.error().message, "No such file")
                    ? "create it: `head -c 32 /dev/urandom | base64 | sudo tee " + options.token_file +
                          " >/dev/null && sudo chmod 600 " + options.token_file +
                          "` (the slscand package's postinst does this)"
                    : "make it private and non-empty: `sudo chmod 600 " + options.token_file + "`");
    else
      c.ok(token_item, options.token_file + " (" + std::to_string(token->size()) + " characters, mode 0600-like)");
  } else if (options.token_given) {
    c.ok(token_item, "given on the command line (visible in ps: prefer a token file)");
  } else if (is_loopback(address)) {
    c.ok(token_item, "none: loopback only, no token needed");
  } else {
    c.missing(token_item, "none, and slscand listens on " + address + ": anyone on the network can drive the scanner",
              "set token_file = \"/etc/slscan/token\" in /etc/slscan/slscand.toml (the package creates the file) "
              "and copy the token to the host (docs/appliance.md)");
  }
}

}  // namespace

bool CheckReport::all_ok() const {
  for (const auto& item : items)
    if (item.state == CheckState::missing) return false;
  return true;
}

const CheckItem* CheckReport::find(const std::string& name) const {
  for (const auto& item : items)
    if (item.name.rfind(name, 0) == 0) return &item;
  return nullptr;
}

std::string CheckReport::to_text() const {
  std::string out = "slscand --check: board '" + board_name + "' (" + board_path + ")\n";
  int missing = 0;
  for (const auto& item : items) {
    const char* tag = item.state == CheckState::ok        ? "[ok]     "
                      : item.state == CheckState::missing ? "[MISSING]"
                                                          : "[skipped]";
    out += std::string(tag) + " " + item.name + ": " + item.detail + "\n";
    if (item.state == CheckState::missing) {
      ++missing;
      out += "          fix: " + item.fix + "\n";
    }
  }
  out += missing == 0 ? "all " + std::to_string(items.size()) + " checks passed\n"
                      : std::to_string(missing) + " of " + std::to_string(items.size()) +
                            " checks missing: see the fixes above\n";
  return out;
}

CheckReport check_board(const hal::BoardConfig& board, const CheckOptions& options) {
  Checker c;
  c.report.board_name = board.name;
  c.report.board_path = board.source_path;
  c.ok("backends", hal::available_backends());
  hal::BoardDevices devices;
  if (auto s = hal::open_board_simulation(board, devices); !s) {
    c.missing("sim rig", s.error().message, "check [sim] in " + board.source_path);
    return c.report;
  }
  check_gpio(c, board, devices);
  check_camera(c, board, devices);
  check_turntable(c, board, devices);
  check_realtime(c, board, options);
  check_network(c, board, options);
  return c.report;
}

}  // namespace slscand
