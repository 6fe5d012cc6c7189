// Board time: CLOCK_MONOTONIC nanoseconds, the clock of GPIO edge events and V4L2 buffer
// timestamps (docs/conventions.md). Every timestamp the firmware logs or streams is on it.
#pragma once

#include <cstdint>

namespace slscand {

using Nanos = std::int64_t;

constexpr Nanos kMicro = 1'000;
constexpr Nanos kMilli = 1'000'000;
constexpr Nanos kSecond = 1'000'000'000;

Nanos monotonic_now_ns() noexcept;

// Sleeps until the absolute CLOCK_MONOTONIC deadline (TIMER_ABSTIME, restarted on EINTR), so
// a late wake-up never accumulates into the next deadline.
void sleep_until_ns(Nanos deadline) noexcept;

// CLOCK_BOOTTIME -> CLOCK_MONOTONIC. The two differ by the time spent in suspend; the offset
// is measured by bracketing a BOOTTIME read between two MONOTONIC reads.
Nanos boottime_to_monotonic_ns(Nanos boottime_ns) noexcept;

}  // namespace slscand
