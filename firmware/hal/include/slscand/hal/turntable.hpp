// The turntable: home, rotate to an absolute angle and wait until it is there, report status.
// Angles are degrees, counter-clockwise seen from above (docs/conventions.md). The interface
// only: the GRBL driver is slscand/hal/grbl/grbl_turntable.hpp, the sim's emulated controller
// slscand/hal/sim/turntable_emulator.hpp.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <string>

#include "slproto/result.hpp"
#include "slscand/hal/clock.hpp"

namespace slscand::hal {

enum class TurntableState : std::uint8_t { idle, moving, alarm, unknown };

struct TurntableStatus {
  TurntableState state = TurntableState::unknown;
  double angle_deg = 0;
};

class Turntable {
 public:
  virtual ~Turntable() = default;
  virtual Status home(Nanos timeout_ns) = 0;
  // Returns once the table has stopped at `angle_deg` (within the driver's tolerance) and
  // reports the angle it reached; Errc::timeout or Errc::hardware (stall, wrong angle) if not.
  // `cancel` (may be null) is watched during the move: once it is set the table is stopped
  // where it is and Errc::aborted returned, so a host's abort never waits for a long move.
  virtual Result<double> rotate_to(double angle_deg, Nanos timeout_ns, const std::atomic<bool>* cancel = nullptr) = 0;
  virtual Result<TurntableStatus> status() = 0;
  // Stops any motion now and de-energises nothing: the table holds its position.
  virtual Status stop() = 0;
};

}  // namespace slscand::hal
