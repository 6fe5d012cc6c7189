#include "slscand/hal/sim/turntable_emulator.hpp"

#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <termios.h>
#include <unistd.h>

#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>

namespace slscand::hal::sim {

using slproto::Errc;
using slproto::make_error;

slproto::Result<std::unique_ptr<TurntableEmulator>> TurntableEmulator::start(double max_speed_deg_per_s) {
  int master = -1;
  int slave = -1;
  char name[128] = {};
  termios tio{};
  ::cfmakeraw(&tio);
  if (::openpty(&master, &slave, name, &tio, nullptr) != 0) {
    return make_error(Errc::io_error, std::string("turntable emulator: openpty failed: ") + std::strerror(errno));
  }
  ::fcntl(master, F_SETFL, ::fcntl(master, F_GETFL) | O_NONBLOCK);
  ::fcntl(master, F_SETFD, FD_CLOEXEC);
  ::fcntl(slave, F_SETFD, FD_CLOEXEC);
  std::unique_ptr<TurntableEmulator> emulator(new TurntableEmulator(master, slave, name, max_speed_deg_per_s));
  emulator->thread_ = std::thread([e = emulator.get()] { e->run(); });
  return emulator;
}

TurntableEmulator::TurntableEmulator(int master_fd, int slave_fd, std::string slave_path, double max_speed)
    : master_fd_(master_fd), slave_fd_(slave_fd), slave_path_(std::move(slave_path)), max_speed_(max_speed) {
  last_update_ = monotonic_now_ns();
}

TurntableEmulator::~TurntableEmulator() {
  quit_ = true;
  if (thread_.joinable()) thread_.join();
  ::close(master_fd_);
  ::close(slave_fd_);
}

void TurntableEmulator::set_faults(const TurntableFaults& faults) {
  std::lock_guard lock(mutex_);
  faults_ = faults;
}

double TurntableEmulator::angle_deg() const {
  std::lock_guard lock(mutex_);
  return angle_;
}

bool TurntableEmulator::moving() const {
  std::lock_guard lock(mutex_);
  return !targets_.empty() && !hold_;
}

void TurntableEmulator::run() {
  char buffer[256];
  while (!quit_) {
    pollfd pfd{master_fd_, POLLIN, 0};
    ::poll(&pfd, 1, 2);
    const Nanos now = monotonic_now_ns();
    std::lock_guard lock(mutex_);
    update_motion(now);
    if ((pfd.revents & POLLIN) != 0) {
      const ssize_t n = ::read(master_fd_, buffer, sizeof buffer);
      for (ssize_t i = 0; i < n; ++i) handle_byte(buffer[i], now);
    }
    update_motion(now);
  }
}

void TurntableEmulator::reply(const std::string& text) {
  if (faults_.silent) return;
  std::string out;
  if (faults_.garbage) {
    // Line noise: random bytes (some of them NUL, 0xff or a stray '<'), then a line end.
    for (int i = 0; i < 7; ++i) {
      noise_seed_ = noise_seed_ * 1103515245u + 12345u;
      out.push_back(static_cast<char>((noise_seed_ >> 16) & 0xff));
    }
    out += "\r\n";
  }
  out += text + "\r\n";
  // The pty buffer is far larger than any reply; a short write would mean the reader is gone.
  (void)!::write(master_fd_, out.data(), out.size());
}

std::string TurntableEmulator::status_report() const {
  const char* state = alarm_ ? "Alarm" : (hold_ && !targets_.empty()) ? "Hold" : targets_.empty() ? "Idle" : "Run";
  char buffer[96];
  std::snprintf(buffer, sizeof buffer, "<%s|MPos:%.3f,0.000,0.000|FS:%d,0>", state, angle_,
                targets_.empty() ? 0 : static_cast<int>(speed_ * 60));
  return buffer;
}

void TurntableEmulator::update_motion(Nanos now) {
  const double dt = static_cast<double>(now - last_update_) * 1e-9;
  last_update_ = now;
  if (hold_ || alarm_) return;
  double budget = speed_ * dt;
  while (!targets_.empty()) {
    const double target = targets_.front();
    const double stall = faults_.stall_at_deg;
    double step = std::min(budget, std::abs(target - angle_));
    const double direction = target >= angle_ ? 1.0 : -1.0;
    if (!std::isnan(stall) && (stall - angle_) * direction >= 0 && std::abs(stall - angle_) <= step) {
      angle_ = stall;  // the motor stops turning; the controller still thinks it is running
      return;
    }
    angle_ += direction * step;
    budget -= step;
    if (std::abs(target - angle_) > 1e-9) return;
    targets_.pop_front();
  }
  while (pending_dwell_oks_ > 0) {
    --pending_dwell_oks_;
    reply("ok");
  }
}

void TurntableEmulator::handle_byte(char c, Nanos now) {
  switch (c) {
    case 0x18:  // soft reset: stop at once; a reset during motion loses position -> alarm
      resets_++;
      if (!targets_.empty() && !hold_) alarm_ = true;
      targets_.clear();
      hold_ = false;
      pending_dwell_oks_ = 0;
      line_.clear();
      reply("");
      reply("Grbl 1.1h ['$' for help]");
      if (alarm_) reply("[MSG:'$H'|'$X' to unlock]");
      return;
    case '?':
      reply(status_report());
      return;
    case '!':
      hold_ = true;
      return;
    case '~':
      hold_ = false;
      return;
    case '\r':
      return;
    case '\n':
      lines_received_++;
      handle_line(line_, now);
      line_.clear();
      return;
    default:
      if (line_.size() < 256) line_.push_back(static_cast<char>(std::toupper(static_cast<unsigned char>(c))));
  }
}

void TurntableEmulator::handle_line(const std::string& raw, Nanos /*now*/) {
  std::string line;
  for (const char c : raw) {
    if (c != ' ') line.push_back(c);
  }
  if (line.empty()) return reply("ok");
  if (line == "$X") {
    alarm_ = false;
    return reply("ok");
  }
  if (alarm_) return reply("error:9");  // GRBL locks G-code out while in alarm
  if (line == "$H") {
    targets_.assign(1, 0.0);
    ++pending_dwell_oks_;  // $H answers when homing is over
    return;
  }
  // Words: letter + number.
  bool has_x = false, dwell = false, motion = false;
  double x = 0;
  std::size_t i = 0;
  while (i < line.size()) {
    const char letter = line[i++];
    const char* start = line.c_str() + i;
    char* end = nullptr;
    const double value = std::strtod(start, &end);
    if (end == start || !std::isalpha(static_cast<unsigned char>(letter))) return reply("error:2");
    i += static_cast<std::size_t>(end - start);
    switch (letter) {
      case 'G':
        if (value == 90)
          relative_ = false;
        else if (value == 91)
          relative_ = true;
        else if (value == 0 || value == 1)
          motion = true;
        else if (value == 4)
          dwell = true;
        else if (value != 21)
          return reply("error:20");
        break;
      case 'X':
        has_x = true;
        x = value;
        break;
      case 'F':
        if (value <= 0) return reply("error:4");
        speed_ = std::min(value / 60.0, max_speed_);
        break;
      case 'P':
        break;
      case 'M':
        if (value != 17 && value != 18) return reply("error:20");
        break;
      default:
        return reply("error:20");
    }
  }
  if (has_x) {
    motion = true;
    const double base = targets_.empty() ? angle_ : targets_.back();
    double target = relative_ ? base + x : x;
    target += faults_.landing_error_deg;
    targets_.push_back(target);
  }
  (void)motion;
  if (dwell) {
    ++pending_dwell_oks_;  // answered by update_motion once the queue is empty
    return;
  }
  reply("ok");
}

}  // namespace slscand::hal::sim
