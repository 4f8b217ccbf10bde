// HugePageAllocator: a std::allocator for large arrays that asks the kernel
// for transparent huge pages (madvise MADV_HUGEPAGE) where the system allows
// them in "madvise" mode. First touching a 2 MiB page costs one fault
// instead of 512; on this project's 2-core VMs page faults were 8-11 % of a
// bake's CPU time. Small arrays (< 4 MiB) use operator new as usual.
// Unlike std::allocator, resize() does not zero new elements (below).
//
// Stateless; thread-safe.
#ifndef CLNERF_CORE_BAKE_HUGE_PAGES_H_
#define CLNERF_CORE_BAKE_HUGE_PAGES_H_

#include <sys/mman.h>

#include <cstddef>
#include <cstdlib>
#include <new>
#include <utility>
#include <vector>

namespace clnerf {

template <class T>
struct HugePageAllocator {
  using value_type = T;
  static constexpr size_t kHugePage = size_t(2) << 20;
  static constexpr size_t kMinBytes = size_t(4) << 20;
  HugePageAllocator() = default;
  template <class U>
  HugePageAllocator(const HugePageAllocator<U>&) {}
  T* allocate(size_t n) {
    const size_t bytes = n * sizeof(T);
    if (bytes < kMinBytes) return static_cast<T*>(::operator new(bytes));
    const size_t rounded = (bytes + kHugePage - 1) / kHugePage * kHugePage;
    void* p = std::aligned_alloc(kHugePage, rounded);
    if (p == nullptr) throw std::bad_alloc();
    madvise(p, rounded, MADV_HUGEPAGE);  // Advice only: ignored where THP is off.
    return static_cast<T*>(p);
  }
  void deallocate(T* p, size_t n) {
    if (n * sizeof(T) < kMinBytes) {
      ::operator delete(p);
    } else {
      std::free(p);
    }
  }
  // resize() leaves new elements of trivial types uninitialised (callers
  // overwrite them): zero-filling a buffer that is about to be written costs
  // as much as writing it.
  template <class U>
  void construct(U* p) noexcept {
    ::new (static_cast<void*>(p)) U;
  }
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
  template <class U>
  bool operator==(const HugePageAllocator<U>&) const { return true; }
};

// A vector whose large buffers are backed by huge pages.
template <class T>
using HugeVector = std::vector<T, HugePageAllocator<T>>;

}  // namespace clnerf

#endif  // CLNERF_CORE_BAKE_HUGE_PAGES_H_
