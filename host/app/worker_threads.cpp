#include "worker_threads.hpp"

#include <oneapi/tbb/blocked_range.h>
#include <oneapi/tbb/global_control.h>
#include <oneapi/tbb/parallel_for.h>
#include <oneapi/tbb/partitioner.h>
#include <oneapi/tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <memory>
#include <stdexcept>
#include <string_view>
#include <system_error>
#include <thread>

namespace slscan::app {
namespace {

std::atomic<bool> unreliable{false};

// Held for the rest of the process once a thread could not be started: TBB then runs every
// parallel loop on the calling thread and asks for no more workers.
std::unique_ptr<tbb::global_control> one_thread_only;

}  // namespace

bool is_thread_start_failure(const std::exception& error) {
  if (const auto* system = dynamic_cast<const std::system_error*>(&error))
    return system->code() == std::errc::resource_unavailable_try_again ||
           system->code() == std::errc::not_enough_memory;
  // TBB reports a failed pthread_create through handle_perror, whose message starts with the
  // call's name (oneTBB src/tbb/rml_thread_monitor.h); it has no exception type of its own.
  if (dynamic_cast<const std::runtime_error*>(&error) != nullptr)
    return std::string_view(error.what()).starts_with("pthread_create has failed");
  return false;
}

bool worker_threads_unreliable() { return unreliable.load(); }

void mark_worker_threads_unreliable() {
  unreliable.store(true);
  if (!one_thread_only)
    one_thread_only = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, 1);
}

WorkerThreads start_worker_threads() {
  WorkerThreads threads;
  threads.wanted = tbb::this_task_arena::max_concurrency();
  if (threads.wanted <= 1) return threads;
  // Each of `wanted` tasks waits until every thread has arrived, so the tasks cannot all run on
  // the main thread and TBB has to start all its workers now. The deadline only bounds a
  // machine too busy to schedule them: a worker that arrives later is still started.
  std::atomic<int> arrived{0};
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(2);
  try {
    tbb::parallel_for(
        tbb::blocked_range<int>(0, threads.wanted, 1),
        [&](const tbb::blocked_range<int>&) {
          arrived.fetch_add(1);
          while (arrived.load() < threads.wanted && std::chrono::steady_clock::now() < deadline)
            std::this_thread::yield();
        },
        tbb::simple_partitioner{});
  } catch (const std::exception& error) {
    if (!is_thread_start_failure(error)) throw;
    threads.start_failed = true;
    threads.failure = error.what();
    mark_worker_threads_unreliable();
  }
  threads.running = std::min(arrived.load(), threads.wanted);
  if (threads.start_failed) threads.running = 1;
  return threads;
}

}  // namespace slscan::app
