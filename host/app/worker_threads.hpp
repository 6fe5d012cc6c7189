// TBB's worker threads, started once at start-up so that an address space too small for them
// (ulimit -v, a container's limit) is found there, not in the middle of a stage.
//
// Why: TBB starts its workers lazily, from whichever thread first asks for more parallelism.
// When pthread_create fails there (EAGAIN: no room for an 8 MiB stack), TBB throws from inside
// its scheduler: on a worker thread that is std::terminate (abort, exit 134); on the main thread
// it is a std::runtime_error ("pthread_create has failed: ...") that leaves the failed worker
// half-started, and tbb::finalize() then waits for it forever (a hang at 80 % CPU). Measured
// on the small rig's reprocess under prlimit --as=300M (issue 17).
#pragma once

#include <exception>
#include <string>

namespace slscan::app {

struct WorkerThreads {
  int wanted = 1;             // TBB's default concurrency (the CPUs this process may use)
  int running = 1;            // threads that took part in the start-up (the main thread included)
  bool start_failed = false;  // a pthread_create failed: the process runs on one thread
  std::string failure;        // what the failure said, for the warning
};

// Starts every worker TBB will use and waits (at most ~2 s) until each has run a task. When a
// thread cannot be started, TBB is limited to the one thread for the rest of the process and
// start_failed is set; the process goes on (slower, same results: the outputs do not depend on
// the thread count).
WorkerThreads start_worker_threads();

// True for the exceptions a failed thread start throws: TBB's std::runtime_error
// ("pthread_create has failed: ...") and std::thread's std::system_error (EAGAIN).
bool is_thread_start_failure(const std::exception& error);

// Set once a thread failed to start (at start-up or later): TBB may then hold a half-started
// worker, so the process must not wait for its workers at exit (tbb::finalize would hang).
bool worker_threads_unreliable();
void mark_worker_threads_unreliable();

}  // namespace slscan::app
