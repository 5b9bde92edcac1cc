#pragma once
// Arrays for the one-off builds of a large mesh (the half-edge mesh, the BVH, the surface model's
// per-vertex arrays), whose cost on a 3-million-triangle skin is largely the first touch of fresh
// memory: each page the kernel hands over is zeroed, faulted in and then written again.
//   - ScratchVector: resize() leaves new elements of a trivial type unset, for an array that a
//     later pass writes in full: its pages are first touched by that pass (on both threads where
//     it runs on two), not zeroed on one beforehand.
//   - ZeroedVector: a block of 1 MiB or more is mapped straight from the kernel (mmap), which
//     hands over zero pages on first touch, so resize() grows with zeros without writing them and
//     a page is faulted in only when an element on it is first written; smaller blocks come from
//     calloc. (calloc alone would not do: once a large block has been freed, malloc serves the
//     next from its heap and clears it.) Valid while the vector never shrinks (a slot past
//     size() that once held an element would not be zero again); for arrays that only grow.
// Not for the real-time path (they allocate).

#include <sys/mman.h>

#include <cstdlib>
#include <limits>
#include <memory>
#include <new>
#include <utility>
#include <vector>

namespace lancet::volume {

/// An allocator whose construct() without arguments default-initialises (a trivial type is left
/// as the memory was) where std::allocator value-initialises (writes zeros).
template <class T>
struct DefaultInitAllocator : std::allocator<T> {
  template <class U>
  struct rebind {
    using other = DefaultInitAllocator<U>;
  };
  DefaultInitAllocator() = default;
  template <class U>
  DefaultInitAllocator(const DefaultInitAllocator<U>&) noexcept {}
  template <class U>
  void construct(U* p) noexcept(noexcept(::new (static_cast<void*>(p)) U)) {
    ::new (static_cast<void*>(p)) U;
  }
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
};

/// DefaultInitAllocator over fresh zero memory (mmap for a large block, calloc for a small one):
/// new elements read as zero without being written.
template <class T>
struct ZeroedAllocator : DefaultInitAllocator<T> {
  using value_type = T;
  template <class U>
  struct rebind {
    using other = ZeroedAllocator<U>;
  };
  ZeroedAllocator() = default;
  template <class U>
  ZeroedAllocator(const ZeroedAllocator<U>&) noexcept {}
  static constexpr std::size_t kMapped = std::size_t{1} << 20;  // bytes from which a block is mapped
  [[nodiscard]] T* allocate(std::size_t n) {
    if (n > std::numeric_limits<std::size_t>::max() / sizeof(T)) throw std::bad_alloc();
    if (n * sizeof(T) >= kMapped) {
      void* p = ::mmap(nullptr, n * sizeof(T), PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
      if (p == MAP_FAILED) throw std::bad_alloc();
      return static_cast<T*>(p);
    }
    void* p = std::calloc(n, sizeof(T));
    if (p == nullptr) throw std::bad_alloc();
    return static_cast<T*>(p);
  }
  void deallocate(T* p, std::size_t n) noexcept {
    if (n * sizeof(T) >= kMapped)
      ::munmap(p, n * sizeof(T));
    else
      std::free(p);
  }
  friend bool operator==(const ZeroedAllocator&, const ZeroedAllocator&) noexcept { return true; }
};

template <class T>
using ScratchVector = std::vector<T, DefaultInitAllocator<T>>;
template <class T>
using ZeroedVector = std::vector<T, ZeroedAllocator<T>>;

}  // namespace lancet::volume
