// Real-time set-up of the sequencer thread: mlockall (no page faults mid-scan), SCHED_FIFO and
// optionally a CPU, each applied if the process may and reported if not.
#pragma once

#include <string>

namespace slscand {

struct RealtimeResult {
  bool memory_locked = false;
  bool fifo = false;
  bool pinned = false;
  std::string warnings;  // empty when everything asked for was granted
};

// Locks memory for the whole process (once) and makes the calling thread SCHED_FIFO at
// `priority`, pinned to `cpu` when cpu >= 0.
RealtimeResult enter_realtime(int priority, int cpu);

}  // namespace slscand
