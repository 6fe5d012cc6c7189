// GRBL-dialect turntable driver (docs/turntable.md). GRBL acknowledges a motion line when it is
// queued, not when the move is done, so a move is: G1 (ok = queued), then G4 P0, whose ok comes
// only once the planner is empty; meanwhile `?` status polls watch the progress (stall) and the
// final poll checks the angle actually reached.
#include "slscand/hal/grbl/grbl_turntable.hpp"

#include <cmath>
#include <cstdio>
#include <cstdlib>

namespace slscand::hal {

using slproto::Errc;
using slproto::make_error;

namespace {

// Drops bytes that cannot be part of a GRBL reply (line noise, a bootloader's binary chatter).
std::string printable(const std::string& line) {
  std::string out;
  out.reserve(line.size());
  for (const char c : line) {
    if (c >= 0x20 && c <= 0x7e) out.push_back(c);
  }
  return out;
}

std::string format_angle(double deg) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.3f", deg);
  return buffer;
}

}  // namespace

Result<TurntableStatus> parse_grbl_status(const std::string& line) {
  if (line.size() < 3 || line.front() != '<' || line.back() != '>') {
    return make_error(Errc::malformed, "not a GRBL status report: '" + line + "'");
  }
  const std::string body = line.substr(1, line.size() - 2);
  const auto bar = body.find('|');
  const std::string state_text = body.substr(0, std::min(bar, body.find(':')));
  TurntableStatus status;
  if (state_text == "Idle") {
    status.state = TurntableState::idle;
  } else if (state_text == "Run" || state_text == "Jog" || state_text == "Home" || state_text == "Hold") {
    status.state = TurntableState::moving;
  } else if (state_text == "Alarm" || state_text == "Door") {
    status.state = TurntableState::alarm;
  } else {
    status.state = TurntableState::unknown;
  }
  auto pos = body.find("MPos:");
  if (pos == std::string::npos) pos = body.find("WPos:");
  if (pos == std::string::npos)
    return make_error(Errc::malformed, "GRBL status report without a position: '" + line + "'");
  const char* start = body.c_str() + pos + 5;
  char* end = nullptr;
  status.angle_deg = std::strtod(start, &end);
  if (end == start || !std::isfinite(status.angle_deg)) {
    return make_error(Errc::malformed, "GRBL status report with an unreadable position: '" + line + "'");
  }
  return status;
}

GrblTurntable::GrblTurntable(std::unique_ptr<SerialPort> port, const GrblOptions& options)
    : port_(std::move(port)), options_(options) {}

Result<std::unique_ptr<GrblTurntable>> GrblTurntable::connect(std::unique_ptr<SerialPort> port,
                                                              const GrblOptions& options) {
  if (!port) return make_error(Errc::invalid_argument, "turntable: no serial port");
  std::unique_ptr<GrblTurntable> table(new GrblTurntable(std::move(port), options));
  if (auto s = table->reset_and_wait_banner(); !s) return s.error();
  const Nanos deadline = monotonic_now_ns() + options.reply_timeout_ns;
  if (auto s = table->command("G90", deadline); !s) return s.error();  // absolute angles
  return table;
}

Status GrblTurntable::reset_and_wait_banner() {
  (void)port_->discard_input();
  carry_.clear();
  if (auto s = port_->write_all("\x18", options_.reply_timeout_ns); !s) return s;
  const Nanos deadline = monotonic_now_ns() + options_.banner_timeout_ns;
  for (;;) {
    auto line = read_line(*port_, carry_, deadline);
    if (!line) {
      if (line.error().code == Errc::malformed) continue;
      if (line.error().code == Errc::timeout) {
        return make_error(Errc::timeout, "turntable on " + port_->name() + " sent no GRBL banner within " +
                                             std::to_string(options_.banner_timeout_ns / kMilli) +
                                             " ms of a reset (wrong port, baud rate or firmware?)");
      }
      return line.error();
    }
    const std::string text = printable(*line);
    if (text.rfind("Grbl", 0) == 0) break;
  }
  // A reset during a move leaves GRBL in alarm; $X unlocks (the position is re-read anyway).
  return command("$X", monotonic_now_ns() + options_.reply_timeout_ns);
}

Status GrblTurntable::command(const std::string& line, Nanos deadline_ns) {
  if (auto s = port_->write_all(line + "\n", options_.reply_timeout_ns); !s) return s;
  for (;;) {
    auto reply = read_line(*port_, carry_, deadline_ns);
    if (!reply) {
      if (reply.error().code == Errc::malformed) continue;  // noise: keep listening
      if (reply.error().code == Errc::timeout) {
        return make_error(Errc::timeout, "turntable did not acknowledge '" + line + "' in time");
      }
      return reply.error();
    }
    const std::string text = printable(*reply);
    if (text == "ok") return slproto::Ok{};
    if (text.rfind("error:", 0) == 0) {
      return make_error(Errc::hardware, "turntable rejected '" + line + "': " + text);
    }
    if (text.rfind("ALARM:", 0) == 0) {
      return make_error(Errc::hardware, "turntable raised " + text + " on '" + line + "'");
    }
    // Status reports, [MSG:...] and noise lines are not the answer to this command.
  }
}

Result<TurntableStatus> GrblTurntable::poll_status(Nanos deadline_ns) {
  if (auto s = port_->write_all("?", options_.reply_timeout_ns); !s) return s.error();
  for (;;) {
    auto reply = read_line(*port_, carry_, deadline_ns);
    if (!reply) {
      if (reply.error().code == Errc::malformed) continue;
      if (reply.error().code == Errc::timeout)
        return make_error(Errc::timeout, "turntable did not answer a status query");
      return std::move(reply).error();
    }
    const std::string text = printable(*reply);
    if (!text.empty() && text.front() == '<') {
      auto status = parse_grbl_status(text);
      if (status) return status;
    }
  }
}

Result<TurntableStatus> GrblTurntable::status() { return poll_status(monotonic_now_ns() + options_.reply_timeout_ns); }

Status GrblTurntable::home(Nanos timeout_ns) {
  // GRBL answers $H only once the homing cycle is over.
  return command("$H", monotonic_now_ns() + timeout_ns);
}

Result<double> GrblTurntable::rotate_to(double angle_deg, Nanos timeout_ns, const std::atomic<bool>* cancel) {
  if (!std::isfinite(angle_deg)) return make_error(Errc::invalid_argument, "turntable: angle is not finite");
  if (cancel != nullptr && cancel->load()) {
    return make_error(Errc::aborted, "turntable move to " + format_angle(angle_deg) + " deg aborted before it began");
  }
  const Nanos deadline = monotonic_now_ns() + timeout_ns;
  const std::string move = "G1X" + format_angle(angle_deg) + "F" + format_angle(options_.feed_deg_per_min);
  if (auto s = command(move, std::min(deadline, monotonic_now_ns() + options_.reply_timeout_ns)); !s) return s.error();
  if (auto s = port_->write_all("G4P0\n", options_.reply_timeout_ns); !s) return s.error();

  // Wait for the dwell's ok; poll `?` meanwhile to see progress and catch a stall.
  double last_angle = NAN;
  Nanos last_progress = monotonic_now_ns();
  Nanos next_poll = last_progress + options_.poll_interval_ns;
  bool done = false;
  while (!done) {
    if (cancel != nullptr && cancel->load()) {
      const auto stopped = stop();
      std::string where = std::isnan(last_angle) ? std::string() : " near " + format_angle(last_angle) + " deg";
      return make_error(Errc::aborted,
                        "turntable move to " + format_angle(angle_deg) + " deg aborted" + where +
                            (stopped ? "; table stopped" : "; stopping it failed: " + stopped.error().message));
    }
    const Nanos now = monotonic_now_ns();
    if (now >= deadline) {
      (void)stop();
      return make_error(Errc::timeout, "turntable did not reach " + format_angle(angle_deg) + " deg within " +
                                           std::to_string(timeout_ns / kMilli) + " ms");
    }
    if (now >= next_poll) {
      if (auto s = port_->write_all("?", options_.reply_timeout_ns); !s) return s.error();
      next_poll = now + options_.poll_interval_ns;
    }
    auto reply = read_line(*port_, carry_, std::min(deadline, next_poll));
    if (!reply) {
      if (reply.error().code == Errc::timeout || reply.error().code == Errc::malformed) continue;
      return std::move(reply).error();
    }
    const std::string text = printable(*reply);
    if (text == "ok") {
      done = true;
    } else if (text.rfind("error:", 0) == 0 || text.rfind("ALARM:", 0) == 0) {
      (void)stop();
      return make_error(Errc::hardware, "turntable failed moving to " + format_angle(angle_deg) + " deg: " + text);
    } else if (!text.empty() && text.front() == '<') {
      auto status = parse_grbl_status(text);
      if (!status) continue;
      if (status->state == TurntableState::alarm) {
        (void)stop();
        return make_error(Errc::hardware, "turntable in alarm while moving to " + format_angle(angle_deg) + " deg");
      }
      const Nanos seen = monotonic_now_ns();
      if (std::isnan(last_angle) || std::abs(status->angle_deg - last_angle) > 1e-4 ||
          status->state != TurntableState::moving) {
        last_angle = status->angle_deg;
        last_progress = seen;
      } else if (seen - last_progress > options_.stall_timeout_ns) {
        (void)stop();
        return make_error(Errc::hardware, "turntable stalled at " + format_angle(status->angle_deg) +
                                              " deg while moving to " + format_angle(angle_deg) +
                                              " deg (no progress for " +
                                              std::to_string(options_.stall_timeout_ns / kMilli) + " ms)");
      }
    }
  }
  auto final_status = poll_status(std::max(deadline, monotonic_now_ns() + options_.reply_timeout_ns));
  if (!final_status) return std::move(final_status).error();
  if (std::abs(final_status->angle_deg - angle_deg) > options_.tolerance_deg) {
    return make_error(Errc::hardware, "turntable reports " + format_angle(final_status->angle_deg) +
                                          " deg after a move to " + format_angle(angle_deg) + " deg (tolerance " +
                                          format_angle(options_.tolerance_deg) + " deg)");
  }
  return final_status->angle_deg;
}

Status GrblTurntable::stop() {
  // Feed hold stops the motion with deceleration; the reset then empties GRBL's queue.
  if (auto s = port_->write_all("!", options_.reply_timeout_ns); !s) return s;
  return reset_and_wait_banner();
}

}  // namespace slscand::hal
