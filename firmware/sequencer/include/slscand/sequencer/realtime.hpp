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

// Makes glibc's malloc keep the memory of freed frames for the next ones instead of handing it
// back to the kernel: blocks up to 32 MiB (16 on 32-bit) come from the heap, not from their own
// mmap, and up to 128 MiB of free heap stays mapped. Why: a scan allocates and frees a
// frame-sized buffer per frame; returned to the kernel, each one is faulted in and zeroed again
// (and, with mlockall, faulted in whole at allocation). Measured on the sim board
// (docs/calibration.md, "Memory and time"): the small rig's calibration capture 19.3 -> 14.4 s.
// Call once, before threads.
void reuse_freed_frame_memory();

}  // namespace slscand
