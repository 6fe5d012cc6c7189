#include "slscand/sequencer/realtime.hpp"

#include <malloc.h>
#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>

#include <cerrno>
#include <cstring>

#include "slproto/file_util.hpp"

namespace slscand {

namespace {
#if defined(__SANITIZE_ADDRESS__)
constexpr bool kAddressSanitizer = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
constexpr bool kAddressSanitizer = true;
#else
constexpr bool kAddressSanitizer = false;
#endif
#else
constexpr bool kAddressSanitizer = false;
#endif
}  // namespace

RealtimeResult enter_realtime(int priority, int cpu) {
  RealtimeResult result;
  if (kAddressSanitizer) {
    // ASan reserves terabytes of shadow memory; locking it would exhaust RAM.
    result.warnings += "mlockall skipped in an AddressSanitizer build; ";
  } else if (::mlockall(MCL_CURRENT | MCL_FUTURE) == 0) {
    result.memory_locked = true;
  } else {
    result.warnings += "mlockall failed (" + slproto::errno_text(errno) +
                       "): page faults may delay triggers (needs CAP_IPC_LOCK or a higher RLIMIT_MEMLOCK); ";
  }
  sched_param param{};
  param.sched_priority = priority;
  if (const int rv = ::pthread_setschedparam(::pthread_self(), SCHED_FIFO, &param); rv == 0) {
    result.fifo = true;
  } else {
    result.warnings += "SCHED_FIFO refused (" + slproto::errno_text(rv) +
                       "): the sequencer runs at normal priority and its timing jitter will be larger (needs "
                       "CAP_SYS_NICE or an RLIMIT_RTPRIO >= " +
                       std::to_string(priority) + "); ";
  }
  if (cpu >= 0) {
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(cpu, &set);
    if (const int rv = ::pthread_setaffinity_np(::pthread_self(), sizeof set, &set); rv == 0) {
      result.pinned = true;
    } else {
      result.warnings +=
          "cannot pin the sequencer to CPU " + std::to_string(cpu) + " (" + slproto::errno_text(rv) + "); ";
    }
  }
  return result;
}

void reuse_freed_frame_memory() {
  // glibc's largest M_MMAP_THRESHOLD (32 MiB on 64-bit, 16 MiB on 32-bit boards); setting
  // either value turns off glibc's own adjustment of both, so both are set.
  constexpr int kLargestHeapBlock = static_cast<int>(4 * 1024 * 1024 * sizeof(long));
  constexpr int kFreeHeapKept = 128 << 20;
  // NOLINTBEGIN(concurrency-mt-unsafe): called once at start-up, before any thread
  (void)::mallopt(M_MMAP_THRESHOLD, kLargestHeapBlock);
  (void)::mallopt(M_TRIM_THRESHOLD, kFreeHeapKept);
  // NOLINTEND(concurrency-mt-unsafe)
}

}  // namespace slscand
