// slscan_hil_vm_check: runs inside the HIL VM (scripts/hil-vm.sh, docs/hil.md) against real
// kernel interfaces -- gpio-sim through slscand's libgpiod backend, vivid through its V4L2
// backend, the VM's 16550 UART through its libserialport backend -- and reports one line per
// check on the console: "HIL-CHECK <name> ok|FAIL <detail>", then "HIL-DONE <failures>".
// Emulated time means nothing, so it checks behaviour: line states and edges in order, frame
// sequence numbers, the turntable's answers, and that a silent turntable is a clear error.
//
//   slscan_hil_vm_check --board FILE --sysfs-chip DIR
// DIR is gpio-sim's /sys/devices/platform/gpio-sim.N/gpiochipM: its sim_gpioK/value shows an
// output's level, and writing pull-up/pull-down to sim_gpioK/pull drives an input. There is
// no loopback between lines, so this program plays the DLP: it answers each TRIG_IN_1 pulse it
// reads back through sysfs with a TRIG_OUT_1 pulse (pull), which the projector code must see
// as an edge event.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <thread>

#include "gpiod_observer.hpp"
#include "slscand/hal/board.hpp"
#include "slscand/hal/gpiod/gpiod_chip.hpp"
#include "slscand/hal/grbl/grbl_turntable.hpp"
#include "slscand/hal/projector.hpp"
#include "slscand/hal/serial_port.hpp"
#include "slscand/hal/v4l2/v4l2_camera.hpp"

namespace {

using namespace slscand;
int failures = 0;

void report(const std::string& name, bool ok, const std::string& detail = {}) {
  if (!ok) failures++;
  std::printf("HIL-CHECK %s %s%s%s\n", name.c_str(), ok ? "ok" : "FAIL", detail.empty() ? "" : " ", detail.c_str());
  std::fflush(stdout);
}

std::string sysfs_line(const std::string& chip_dir, unsigned offset) {
  return chip_dir + "/sim_gpio" + std::to_string(offset);
}

int read_value(const std::string& chip_dir, unsigned offset) {
  std::ifstream in(sysfs_line(chip_dir, offset) + "/value");
  int v = -1;
  in >> v;
  return v;
}

bool write_pull(const std::string& chip_dir, unsigned offset, bool up) {
  std::ofstream out(sysfs_line(chip_dir, offset) + "/pull");
  out << (up ? "pull-up" : "pull-down");
  out.flush();
  return out.good();
}

void check_gpio(const hal::BoardConfig& board, const std::string& chip_dir) {
  auto chip = hal::open_gpiod_chip(board.gpio_chip);
  report("gpio.open", chip.ok(), chip.ok() ? (*chip)->name() : chip.error().message);
  if (!chip) return;
  for (int side = 0; side < 2; ++side) {
    const hal::DlpLines& lines = board.projectors[side];
    const std::string name = side == 0 ? "projector.left" : "projector.right";
    (void)write_pull(chip_dir, lines.trig_out_1, false);
    auto projector = hal::DlpProjector::open(**chip, lines, name);
    report(name + ".open", projector.ok(), projector.ok() ? "" : projector.error().message);
    if (!projector) continue;
    hal::DlpProjector& p = **projector;
    auto started = p.start();
    report(name + ".start", started.ok() && read_value(chip_dir, lines.trig_in_2) == 1,
           "trig_in_2 reads " + std::to_string(read_value(chip_dir, lines.trig_in_2)));
    constexpr int kPatterns = 5;
    int acknowledged = 0;
    std::string problem;
    Nanos previous_edge = 0;
    for (int i = 0; i < kPatterns && problem.empty(); ++i) {
      auto trigger = p.advance();
      if (!trigger) {
        problem = "advance " + std::to_string(i) + ": " + trigger.error().message;
        break;
      }
      // The pulse is over when advance() returns: TRIG_IN_1 must read low again.
      if (read_value(chip_dir, lines.trig_in_1) != 0)
        problem = "trig_in_1 still high after pattern " + std::to_string(i);
      write_pull(chip_dir, lines.trig_out_1, true);  // the DLP shows the pattern
      auto shown = p.wait_exposure_start(2 * kSecond);
      write_pull(chip_dir, lines.trig_out_1, false);
      auto ended = p.wait_exposure_end(2 * kSecond);
      if (!shown || !ended) {
        problem = "pattern " + std::to_string(i) + ": " + (!shown ? shown.error().message : ended.error().message);
        break;
      }
      // Kernel edge timestamps: CLOCK_MONOTONIC, after the trigger, rising before falling.
      if (!(shown->timestamp_ns >= *trigger && ended->timestamp_ns >= shown->timestamp_ns &&
            shown->timestamp_ns > previous_edge && shown->rising && !ended->rising)) {
        problem = "pattern " + std::to_string(i) + ": edges out of order (trigger " + std::to_string(*trigger) +
                  ", rise " + std::to_string(shown->timestamp_ns) + ", fall " + std::to_string(ended->timestamp_ns) +
                  ")";
        break;
      }
      previous_edge = ended->timestamp_ns;
      acknowledged++;
    }
    report(name + ".trig_out_1 edges", problem.empty() && acknowledged == kPatterns,
           std::to_string(acknowledged) + " of " + std::to_string(kPatterns) + " patterns acknowledged" +
               (problem.empty() ? "" : ": " + problem));
    // No acknowledgement: the projector code must time out naming the line.
    auto advance = p.advance();
    auto silent = p.wait_exposure_start(50 * kMilli);
    report(name + ".ack timeout",
           advance.ok() && !silent.ok() &&
               silent.error().message.find("TRIG_OUT_1 (line " + std::to_string(lines.trig_out_1)) != std::string::npos,
           silent.ok() ? "an edge nobody drove" : silent.error().message);
    auto stopped = p.stop();
    const int in1 = read_value(chip_dir, lines.trig_in_1), in2 = read_value(chip_dir, lines.trig_in_2);
    report(name + ".stop leaves lines low", stopped.ok() && in1 == 0 && in2 == 0,
           "trig_in_1=" + std::to_string(in1) + " trig_in_2=" + std::to_string(in2));
  }
}

// slscan_hil's real-board observer on real edge events: the test drives the [observer] inputs
// with gpio-sim's pull, as wired-back trigger lines would, and the observer must record each
// edge, in order, under the board line it watches.
void check_observer(const hal::BoardConfig& board, const std::string& chip_dir) {
  const auto& o = board.observer;
  if (!o.left_trig_in_1 || !o.right_trig_out_1) {
    report("observer.lines", false, "the VM board needs observer.left_trig_in_1 and observer.right_trig_out_1");
    return;
  }
  (void)write_pull(chip_dir, *o.left_trig_in_1, false);
  (void)write_pull(chip_dir, *o.right_trig_out_1, false);
  slscan::hil::GpiodObserver observer;
  std::string error;
  const bool started = observer.start(board, error);
  report("observer.start", started, error);
  if (!started) return;
  auto drive = [&](unsigned line, bool up) {
    (void)write_pull(chip_dir, line, up);
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  };
  for (int pulse = 0; pulse < 3; ++pulse) {  // three triggers on the left TRIG_IN_1 ...
    drive(*o.left_trig_in_1, true);
    drive(*o.left_trig_in_1, false);
  }
  drive(*o.right_trig_out_1, true);  // ... and one exposure pulse on the right TRIG_OUT_1
  drive(*o.right_trig_out_1, false);
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  observer.stop();
  const auto edges = observer.edges();
  std::string problem = observer.error();
  int left = 0, right = 0;
  for (std::size_t i = 0; i < edges.size() && problem.empty(); ++i) {
    const auto& e = edges[i];
    int& n = e.offset == board.projectors[0].trig_in_1 ? left : right;
    if (e.offset != board.projectors[0].trig_in_1 && e.offset != board.projectors[1].trig_out_1) {
      problem = "edge recorded under line " + std::to_string(e.offset);
    } else if (e.rising != (n % 2 == 0)) {
      problem = "edge " + std::to_string(i) + " on line " + std::to_string(e.offset) + " has the wrong direction";
    } else if (i > 0 && e.ns <= edges[i - 1].ns) {
      problem = "edge " + std::to_string(i) + " is not later than the one before";
    }
    n++;
  }
  report("observer.edges", problem.empty() && left == 6 && right == 2,
         std::to_string(left) + " edges on projector.left.trig_in_1 (want 6), " + std::to_string(right) +
             " on projector.right.trig_out_1 (want 2)" + (problem.empty() ? "" : ": " + problem));
}

void check_camera(const hal::BoardConfig& board) {
  auto camera = hal::open_v4l2_camera(board.camera_device);
  report("camera.open", camera.ok(), camera.ok() ? (*camera)->describe() : camera.error().message);
  if (!camera) return;
  auto format = (*camera)->set_format(board.camera_format);
  report("camera.format", format.ok(),
         format.ok() ? std::to_string(format->width) + "x" + std::to_string(format->height) : format.error().message);
  if (!format) return;
  (void)(*camera)->set_exposure_us(board.pattern_exposure_us);
  auto started = (*camera)->start();
  report("camera.start", started.ok(), started.ok() ? "" : started.error().message);
  if (!started) return;
  constexpr int kFrames = 8;
  std::string problem;
  std::uint64_t first = 0, last = 0;
  Nanos last_stamp = 0;
  int got = 0;
  for (int i = 0; i < kFrames; ++i) {
    auto frame = (*camera)->wait_frame(10 * kSecond);
    if (!frame) {
      problem = "frame " + std::to_string(i) + ": " + frame.error().message;
      break;
    }
    if (i == 0) first = frame->sequence;
    if (i > 0 && frame->sequence != last + 1) {
      problem = "sequence " + std::to_string(frame->sequence) + " after " + std::to_string(last);
    }
    if (frame->pixels.size() != format->frame_bytes())
      problem = "frame of " + std::to_string(frame->pixels.size()) + " bytes";
    // vivid stamps each buffer with its model frame time (stream start + sequence x period),
    // which under emulation can run ahead of the dequeue: require increasing CLOCK_MONOTONIC
    // stamps near the dequeue, not a physical exposure before it.
    if (frame->exposure_start_ns <= last_stamp || std::abs(frame->exposure_start_ns - frame->dequeued_ns) > kSecond) {
      problem = "frame " + std::to_string(frame->sequence) + " exposure start " +
                std::to_string(frame->exposure_start_ns) + " ns not after the previous " + std::to_string(last_stamp) +
                " ns or more than 1 s from its dequeue at " + std::to_string(frame->dequeued_ns) + " ns";
    }
    last_stamp = frame->exposure_start_ns;
    last = frame->sequence;
    got++;
    if (!problem.empty()) break;
  }
  report("camera.frames", problem.empty() && got == kFrames,
         std::to_string(got) + " frames, sequence " + std::to_string(first) + ".." + std::to_string(last) +
             (problem.empty() ? "" : ": " + problem));
  auto stopped = (*camera)->stop();
  report("camera.stop", stopped.ok(), stopped.ok() ? "" : stopped.error().message);
}

void check_turntable(const hal::BoardConfig& board) {
  auto path = hal::resolve_serial_port(board.serial_port);
  report("turntable.port", path.ok(), path.ok() ? *path : path.error().message);
  if (!path) return;
  hal::GrblOptions options;
  options.feed_deg_per_min = board.feed_deg_per_min;
  options.tolerance_deg = board.angle_tolerance_deg;
  {
    auto port = hal::open_libserialport_port(*path, board.baud);
    report("turntable.open", port.ok(), port.ok() ? (*port)->name() : port.error().message);
    if (!port) return;
    auto table = hal::GrblTurntable::connect(std::move(*port), options);
    report("turntable.connect", table.ok(), table.ok() ? "" : table.error().message);
    if (!table) return;
    for (const double angle : {60.0, 120.0}) {
      auto reached = (*table)->rotate_to(angle, 30 * kSecond);
      report("turntable.rotate_to " + std::to_string(static_cast<int>(angle)),
             reached.ok() && std::abs(*reached - angle) <= board.angle_tolerance_deg,
             reached.ok() ? "reported " + std::to_string(*reached) : reached.error().message);
    }
  }
  // The host's bridge stops answering after this line (it never reaches the emulator).
  {
    auto port = hal::open_libserialport_port(*path, board.baud);
    if (!port) return;
    (void)(*port)->write_all("$HIL-SILENT\n", kSecond);
  }
  auto port = hal::open_libserialport_port(*path, board.baud);
  if (!port) return;
  auto table = hal::GrblTurntable::connect(std::move(*port), options);
  report("turntable.silent is an error", !table.ok(),
         table.ok() ? "a silent controller was accepted" : table.error().message);
}

}  // namespace

int main(int argc, char** argv) {
  std::string board_path, chip_dir;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string arg = argv[i];
    if (arg == "--board")
      board_path = argv[i + 1];
    else if (arg == "--sysfs-chip")
      chip_dir = argv[i + 1];
  }
  if (board_path.empty() || chip_dir.empty()) {
    std::fprintf(stderr, "usage: slscan_hil_vm_check --board FILE --sysfs-chip DIR\n");
    return 2;
  }
  auto board = hal::load_board(board_path);
  if (!board) {
    std::fprintf(stderr, "slscan_hil_vm_check: %s\n", board.error().message.c_str());
    return 2;
  }
  check_gpio(*board, chip_dir);
  check_observer(*board, chip_dir);
  check_camera(*board);
  check_turntable(*board);
  std::printf("HIL-DONE %d\n", failures);
  std::fflush(stdout);
  return failures == 0 ? 0 : 1;
}
