// The hand-off from the sequencer to the streamer: bounded, so a host that cannot keep up
// pauses the sequencer (between patterns) instead of growing memory or dropping frames.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <deque>
#include <mutex>
#include <optional>

#include "slscand/hal/priority_inheritance_mutex.hpp"

namespace slscand {

template <class T>
class BoundedQueue {
 public:
  explicit BoundedQueue(std::size_t capacity) : capacity_(capacity == 0 ? 1 : capacity) {}

  // Blocks while full. Returns false (and leaves `item` unmoved) if the queue was closed or
  // `abort` became true while waiting.
  bool push(T& item, const std::atomic<bool>& abort) {
    std::unique_lock lock(mutex_);
    while (items_.size() >= capacity_ && !closed_ && !abort.load()) {
      not_full_.wait_for(lock, std::chrono::milliseconds(5));
    }
    if (closed_ || abort.load()) return false;
    items_.push_back(std::move(item));
    high_water_ = std::max(high_water_, items_.size());
    not_empty_.notify_one();
    return true;
  }

  bool full() const {
    std::lock_guard lock(mutex_);
    return items_.size() >= capacity_;
  }

  // The next item, or nullopt once closed and drained, or after `timeout`.
  std::optional<T> pop(std::chrono::milliseconds timeout) {
    std::unique_lock lock(mutex_);
    not_empty_.wait_for(lock, timeout, [&] { return !items_.empty() || closed_; });
    if (items_.empty()) return std::nullopt;
    T item = std::move(items_.front());
    items_.pop_front();
    not_full_.notify_one();
    return item;
  }

  // No more pushes; pop() drains what is left, then returns nullopt at once.
  void close() {
    std::lock_guard lock(mutex_);
    closed_ = true;
    not_empty_.notify_all();
    not_full_.notify_all();
  }
  bool closed_and_empty() const {
    std::lock_guard lock(mutex_);
    return closed_ && items_.empty();
  }
  std::size_t high_water() const {
    std::lock_guard lock(mutex_);
    return high_water_;
  }
  std::size_t capacity() const { return capacity_; }

 private:
  // The sequencer pushes at real-time priority, the streamer pops at normal priority.
  mutable PriorityInheritanceMutex mutex_;
  std::condition_variable_any not_empty_;
  std::condition_variable_any not_full_;
  std::deque<T> items_;
  std::size_t capacity_;
  std::size_t high_water_ = 0;
  bool closed_ = false;
};

}  // namespace slscand
