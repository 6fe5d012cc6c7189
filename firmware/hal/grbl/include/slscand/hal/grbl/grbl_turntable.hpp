// The GRBL turntable driver (docs/turntable.md): slscand's Turntable over any SerialPort
// (termios or libserialport), for a GRBL 1.1 controller whose axis X is the table in degrees.
#pragma once

#include <memory>
#include <string>

#include "slproto/result.hpp"
#include "slscand/hal/clock.hpp"
#include "slscand/hal/serial_port.hpp"
#include "slscand/hal/turntable.hpp"

namespace slscand::hal {

// GRBL 1.1 dialect (docs/turntable.md): the table is axis X in degrees.
struct GrblOptions {
  double feed_deg_per_min = 3600;         // 60 deg/s
  double tolerance_deg = 0.05;            // |reported - commanded| allowed after a move
  Nanos reply_timeout_ns = 500 * kMilli;  // for one `ok`
  Nanos poll_interval_ns = 20 * kMilli;   // `?` status polls during a move
  Nanos stall_timeout_ns = 500 * kMilli;  // no progress while running for this long = stalled
  Nanos banner_timeout_ns = 2 * kSecond;
};

class GrblTurntable final : public Turntable {
 public:
  // Resets the controller (Ctrl-X), waits for its banner and sets absolute, degree mode.
  static Result<std::unique_ptr<GrblTurntable>> connect(std::unique_ptr<SerialPort> port, const GrblOptions& options);
  Status home(Nanos timeout_ns) override;
  Result<double> rotate_to(double angle_deg, Nanos timeout_ns, const std::atomic<bool>* cancel = nullptr) override;
  Result<TurntableStatus> status() override;
  Status stop() override;

 private:
  GrblTurntable(std::unique_ptr<SerialPort> port, const GrblOptions& options);
  Status command(const std::string& line, Nanos deadline_ns);  // waits for its ok / error
  Result<TurntableStatus> poll_status(Nanos deadline_ns);
  Status reset_and_wait_banner();

  std::unique_ptr<SerialPort> port_;
  GrblOptions options_;
  std::string carry_;
};

// Parses a GRBL status report "<Idle|MPos:60.000,0.000,0.000|FS:0,0>" (axis X = degrees).
Result<TurntableStatus> parse_grbl_status(const std::string& line);

}  // namespace slscand::hal
