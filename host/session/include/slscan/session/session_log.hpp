// How a session tells its user what is happening, and how it learns that the user wants it to
// stop. The CLI's console implements the log (text or JSON lines); tests pass a quiet one.
#pragma once

#include <atomic>
#include <cstddef>
#include <stdexcept>
#include <string>

namespace slscan::session {

// How far a long step has come: `done` of `total` items of `stage`, counted in `unit`
// ("frames", "poses"; empty when the items are steps of unequal length, which have no rate or
// ETA), and which of them is under way (`step`, e.g. the reconstruction stage's name).
struct Progress {
  std::string stage;
  std::size_t done = 0;
  std::size_t total = 0;
  std::string unit;
  std::string step;
};

class SessionLog {
 public:
  virtual ~SessionLog() = default;
  virtual void info(const std::string& text) const = 0;
  virtual void warn(const std::string& text) const = 0;
  // A long step's progress, and its end.
  virtual void progress(const Progress& progress) const = 0;
  virtual void end_progress() const = 0;
};

// Says nothing (tests, and callers that report only the result).
class QuietLog final : public SessionLog {
 public:
  void info(const std::string&) const override {}
  void warn(const std::string&) const override {}
  void progress(const Progress&) const override {}
  void end_progress() const override {}
};

// Problems with the scanner itself: connection, protocol, errors the board reports. The CLI
// turns it into its "device" exit code (docs/cli.md).
class DeviceError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Set (e.g. by a SIGINT handler) when the user wants the session to stop; sessions poll it.
using StopFlag = const std::atomic<bool>*;

}  // namespace slscan::session
