// A mutex shared between the real-time sequencer and normal-priority threads (the streamer, the
// virtual devices' renderer). With std::mutex a normal-priority holder that the scheduler
// preempts keeps the SCHED_FIFO sequencer waiting for as long as the machine is busy: a
// missed pattern deadline of tens of milliseconds (priority inversion). PTHREAD_PRIO_INHERIT
// lends the waiter's priority to the holder until it unlocks.
// Meets Lockable: use it with std::lock_guard / std::unique_lock and std::condition_variable_any.
#pragma once

#include <pthread.h>

namespace slscand {

class PriorityInheritanceMutex {
 public:
  PriorityInheritanceMutex() {
    pthread_mutexattr_t attributes;
    pthread_mutexattr_init(&attributes);
    pthread_mutexattr_setprotocol(&attributes, PTHREAD_PRIO_INHERIT);
    pthread_mutex_init(&mutex_, &attributes);
    pthread_mutexattr_destroy(&attributes);
  }
  ~PriorityInheritanceMutex() { pthread_mutex_destroy(&mutex_); }
  PriorityInheritanceMutex(const PriorityInheritanceMutex&) = delete;
  PriorityInheritanceMutex& operator=(const PriorityInheritanceMutex&) = delete;

  void lock() { pthread_mutex_lock(&mutex_); }
  bool try_lock() { return pthread_mutex_trylock(&mutex_) == 0; }
  void unlock() { pthread_mutex_unlock(&mutex_); }

 private:
  pthread_mutex_t mutex_;
};

}  // namespace slscand
