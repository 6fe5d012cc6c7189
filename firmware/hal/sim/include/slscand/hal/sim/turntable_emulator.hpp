// A GRBL-speaking turntable on a pseudo-terminal. The driver opens slave_path() through the
// termios serial port exactly as it would a USB-serial adapter. Used by the protocol tests and
// by the sim board, whose virtual camera renders at the angle this table physically reached.
// Faults can be switched on at any time to test the driver's error paths.
#pragma once

#include <atomic>
#include <cmath>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include "slproto/result.hpp"
#include "slscand/hal/clock.hpp"

namespace slscand::hal::sim {

struct TurntableFaults {
  bool silent = false;           // reads everything, answers nothing (a dead controller)
  bool garbage = false;          // a line of noise bytes before every reply
  double stall_at_deg = NAN;     // the motor stops here (reported as Run, no progress)
  double landing_error_deg = 0;  // each move ends this far from the commanded angle
};

class TurntableEmulator {
 public:
  static slproto::Result<std::unique_ptr<TurntableEmulator>> start(double max_speed_deg_per_s = 360);
  ~TurntableEmulator();
  TurntableEmulator(const TurntableEmulator&) = delete;
  TurntableEmulator& operator=(const TurntableEmulator&) = delete;

  const std::string& slave_path() const { return slave_path_; }
  void set_faults(const TurntableFaults& faults);
  double angle_deg() const;  // where the platform physically is
  bool moving() const;
  std::uint64_t lines_received() const { return lines_received_.load(); }
  std::uint64_t resets() const { return resets_.load(); }

 private:
  TurntableEmulator(int master_fd, int slave_fd, std::string slave_path, double max_speed);
  void run();
  void handle_byte(char c, Nanos now);
  void handle_line(const std::string& line, Nanos now);
  void update_motion(Nanos now);
  void reply(const std::string& text);
  std::string status_report() const;

  int master_fd_;
  int slave_fd_;
  std::string slave_path_;
  double max_speed_;
  std::thread thread_;
  std::atomic<bool> quit_{false};
  std::atomic<std::uint64_t> lines_received_{0};
  std::atomic<std::uint64_t> resets_{0};

  mutable std::mutex mutex_;  // guards everything below
  TurntableFaults faults_;
  std::string line_;
  double angle_ = 0;
  std::deque<double> targets_;
  double speed_ = 60;  // deg/s, from the last F word
  bool relative_ = false;
  bool alarm_ = false;
  bool hold_ = false;
  int pending_dwell_oks_ = 0;  // G4 P0 acks owed once the queue is empty
  Nanos last_update_ = 0;
  std::uint32_t noise_seed_ = 12345;
};

}  // namespace slscand::hal::sim
