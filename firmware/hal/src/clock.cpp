#include "slscand/hal/clock.hpp"

#include <cerrno>
#include <ctime>

namespace slscand {
namespace {
Nanos read_clock(clockid_t id) noexcept {
  timespec ts{};
  clock_gettime(id, &ts);
  return static_cast<Nanos>(ts.tv_sec) * kSecond + ts.tv_nsec;
}
}  // namespace

Nanos monotonic_now_ns() noexcept { return read_clock(CLOCK_MONOTONIC); }

void sleep_until_ns(Nanos deadline) noexcept {
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(deadline / kSecond);
  ts.tv_nsec = static_cast<long>(deadline % kSecond);
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
}

Nanos boottime_to_monotonic_ns(Nanos boottime_ns) noexcept {
  const Nanos mono_before = read_clock(CLOCK_MONOTONIC);
  const Nanos boot = read_clock(CLOCK_BOOTTIME);
  const Nanos mono_after = read_clock(CLOCK_MONOTONIC);
  const Nanos offset = boot - (mono_before + (mono_after - mono_before) / 2);
  return boottime_ns - offset;
}

}  // namespace slscand
