// An array of many megabytes that is written once, then read: a tree's points, a grid's sorted
// copy. On Linux its memory is asked for in 2 MB pages (transparent huge pages, where the system
// allows them on request): first touches of 4 kB pages cost ~3.6 ms per MB on the VM our
// figures come from (measured: 16 MB in 47 ms, 1 ms in 2 MB pages), more than the work done
// in them. Elsewhere, or if the system declines, it is plain memory. Shared by slscan_core and
// slscan_mesh; not part of the public API.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <new>
#include <type_traits>

#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace slscan::core::detail {

struct FreeLargeArray {
  void operator()(void* p) const { std::free(p); }
};

template <class T>
using LargeArray = std::unique_ptr<T[], FreeLargeArray>;

// `count` elements, not initialised. Throws std::bad_alloc.
template <class T>
LargeArray<T> make_large_array(std::size_t count) {
  static_assert(std::is_trivially_default_constructible_v<T> && std::is_trivially_destructible_v<T>);
  constexpr std::size_t kHugePage = std::size_t{2} << 20;
  if (count > SIZE_MAX / sizeof(T) - kHugePage) throw std::bad_alloc();
  const std::size_t bytes = count * sizeof(T);
  // Below a huge page, a huge page would only waste memory.
  const std::size_t alignment = bytes >= kHugePage ? kHugePage : alignof(std::max_align_t);
  const std::size_t rounded = (bytes + alignment - 1) / alignment * alignment;
  void* p = std::aligned_alloc(alignment, rounded == 0 ? alignment : rounded);
  if (p == nullptr) throw std::bad_alloc();
#if defined(__linux__) && defined(MADV_HUGEPAGE)
  if (alignment == kHugePage) (void)madvise(p, rounded, MADV_HUGEPAGE);  // advice only: failure is harmless
#endif
  return LargeArray<T>(static_cast<T*>(p));
}

}  // namespace slscan::core::detail
