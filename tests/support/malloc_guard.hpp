#pragma once
// MallocGuard: counts heap allocations made by the current thread while the guard is alive
// (the Drake limit_malloc idea). Link lancet::test_support into a test executable to get it: that
// replaces the global operator new family and, when no sanitizer owns the allocator, malloc,
// calloc, realloc and the aligned allocators as well.
//
//   lancet::test::MallocGuard guard;
//   ring.try_push(x);
//   EXPECT_EQ(guard.count(), 0u);

#include <cstddef>

namespace lancet::test {

class MallocGuard {
 public:
  MallocGuard() noexcept;
  ~MallocGuard();
  MallocGuard(const MallocGuard&) = delete;
  MallocGuard& operator=(const MallocGuard&) = delete;
  /// Allocations by this thread since the guard was made.
  [[nodiscard]] std::size_t count() const noexcept;

 private:
  std::size_t start_;
};

/// True in AddressSanitizer builds, where some checks mean nothing: ASan's shadow memory faults
/// pages in lazily (so page-fault counts are not zero) and it intercepts mlockall, returning
/// success without locking anything.
constexpr bool kAddressSanitizer =
#if defined(__SANITIZE_ADDRESS__)
    true;
#else
    false;
#endif

/// True when plain malloc is counted too (false under ASan/TSan, which own malloc; operator new
/// is counted in every build).
bool malloc_is_counted() noexcept;

}  // namespace lancet::test
