// Opens every device a board file names, with the backend it names. The one place that knows
// which backends this build has (libcamera's pipeline-handler registry, in one function).
#pragma once

#include <array>
#include <memory>
#include <optional>
#include <string>

#include "slproto/calibration.hpp"
#include "slproto/calibration_poses.hpp"
#include "slproto/pattern_plan.hpp"
#include "slproto/result.hpp"
#include "slscand/hal/board.hpp"
#include "slscand/hal/camera.hpp"
#include "slscand/hal/gpio.hpp"
#include "slscand/hal/projector.hpp"
#include "slscand/hal/serial_port.hpp"
#include "slscand/hal/turntable.hpp"

namespace slrig {
struct Scene;
}

namespace slscand::hal {
namespace sim {
class SimRig;
}

struct BoardDevices {
  // Declaration order is teardown order in reverse: requests before their chip, the turntable
  // before the emulator it talks to.
  std::shared_ptr<sim::SimRig> sim_rig;  // set on sim boards (fault injection, edge records)
  std::unique_ptr<GpioChip> chip;
  std::array<std::unique_ptr<DlpProjector>, 2> projectors;
  std::unique_ptr<LineRequest> camera_trigger;  // trigger = "gpio" boards only
  std::unique_ptr<Camera> camera;
  CameraFormat camera_format;
  std::unique_ptr<Turntable> turntable;

  // Puts the plan's patterns and the exposure into the projectors' memory. On hardware the
  // DLPC350 is flashed beforehand (docs/hardware.md), so this only checks the plan fits.
  slproto::Status load_patterns(const slproto::PatternPlan& plan, Nanos exposure_ns);
  // A simulated board puts its checkerboard where the request says (nullopt: back to the
  // board's own scene); on hardware the user places the board, so this does nothing.
  slproto::Status place_calibration_target(const std::optional<slproto::CalibrationTargetPlacement>& target);
  // Whether place_calibration_target does anything here (CAPABILITY_CALIBRATION_TARGET).
  bool places_calibration_target() const { return sim_rig != nullptr; }
  // Whether the devices are the virtual rig's, not hardware (CAPABILITY_SIMULATED, the mDNS advert).
  bool simulated() const { return sim_rig != nullptr; }
  // A simulated board's exact calibration (`slscand --write-true-calibration`); hardware has
  // none to give (Errc::unsupported): it is calibrated (`slscan calibrate --connect`).
  slproto::Result<slproto::RigCalibration> true_calibration() const;
};

struct OpenOptions {
  const slrig::Scene* sim_scene = nullptr;  // overrides the board's sim.scene preset
};

slproto::Result<BoardDevices> open_board_devices(const BoardConfig& board, const OpenOptions& options = {});

// The first step of open_board_devices: on a board whose devices are simulated, opens the
// virtual rig they are drawn from (devices.sim_rig); on any other board it does nothing. The
// only place that asks what kind of board this is (the sim backend's hook).
slproto::Status open_board_simulation(const BoardConfig& board, BoardDevices& devices, const OpenOptions& options = {});

// The steps of open_board_devices one at a time, for `slscand --check` (which goes on past a
// missing device to report the others). On sim boards `devices.sim_rig` must be set first.
slproto::Result<std::unique_ptr<GpioChip>> open_board_gpio_chip(const BoardConfig& board, BoardDevices& devices);
slproto::Result<std::unique_ptr<Camera>> open_board_camera(const BoardConfig& board, BoardDevices& devices);
slproto::Result<std::unique_ptr<SerialPort>> open_board_serial_port(const BoardConfig& board, BoardDevices& devices);

// The camera's trigger mode on this board: external (a line), or software (camera.trigger = "software").
TriggerMode camera_trigger_mode(const BoardConfig& board);

// "gpio: gpiod(v1) sim; camera: v4l2 libcamera sim; serial: termios libserialport emulator".
std::string available_backends();

}  // namespace slscand::hal
