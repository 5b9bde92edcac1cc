#include "malloc_guard.hpp"

#include <cstdlib>
#include <new>

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define LANCET_SANITIZED_ALLOCATOR 1
#else
#define LANCET_SANITIZED_ALLOCATOR 0
#endif

namespace {
thread_local std::size_t t_allocations = 0;
inline void note_allocation() noexcept { ++t_allocations; }
}  // namespace

namespace lancet::test {
MallocGuard::MallocGuard() noexcept : start_(t_allocations) {}
MallocGuard::~MallocGuard() = default;
std::size_t MallocGuard::count() const noexcept { return t_allocations - start_; }
bool malloc_is_counted() noexcept { return LANCET_SANITIZED_ALLOCATOR == 0; }
}  // namespace lancet::test

#if !LANCET_SANITIZED_ALLOCATOR
// glibc's real allocator entry points; interposing the public names routes every C allocation
// in this executable (and the libraries it loads) through the counter.
extern "C" {
void* __libc_malloc(std::size_t);
void* __libc_calloc(std::size_t, std::size_t);
void* __libc_realloc(void*, std::size_t);
void* __libc_memalign(std::size_t, std::size_t);
void __libc_free(void*);

void* malloc(std::size_t n) {
  note_allocation();
  return __libc_malloc(n);
}
void* calloc(std::size_t n, std::size_t s) {
  note_allocation();
  return __libc_calloc(n, s);
}
void* realloc(void* p, std::size_t n) {
  note_allocation();
  return __libc_realloc(p, n);
}
void free(void* p) { __libc_free(p); }
void* aligned_alloc(std::size_t a, std::size_t n) {
  note_allocation();
  return __libc_memalign(a, n);
}
void* memalign(std::size_t a, std::size_t n) {
  note_allocation();
  return __libc_memalign(a, n);
}
int posix_memalign(void** out, std::size_t a, std::size_t n) {
  note_allocation();
  void* p = __libc_memalign(a, n);
  if (p == nullptr) return 12;  // ENOMEM
  *out = p;
  return 0;
}
}
#endif

// operator new is counted in every build (sanitizers allow replacing it); it allocates through
// malloc, which a sanitizer intercepts as usual. Under plain builds the malloc above counts too,
// so a `new` counts twice: any non-zero count is a failure either way.
namespace {
void* counted_new(std::size_t n) {
  note_allocation();
  if (n == 0) n = 1;
  void* p = std::malloc(n);
  if (p == nullptr) throw std::bad_alloc();
  return p;
}
void* counted_new_aligned(std::size_t n, std::align_val_t a) {
  note_allocation();
  const auto al = static_cast<std::size_t>(a);
  n = (n + al - 1) / al * al;
  void* p = std::aligned_alloc(al, n == 0 ? al : n);
  if (p == nullptr) throw std::bad_alloc();
  return p;
}
}  // namespace

void* operator new(std::size_t n) { return counted_new(n); }
void* operator new[](std::size_t n) { return counted_new(n); }
void* operator new(std::size_t n, const std::nothrow_t&) noexcept {
  try { return counted_new(n); } catch (...) { return nullptr; }
}
void* operator new[](std::size_t n, const std::nothrow_t&) noexcept {
  try { return counted_new(n); } catch (...) { return nullptr; }
}
void* operator new(std::size_t n, std::align_val_t a) { return counted_new_aligned(n, a); }
void* operator new[](std::size_t n, std::align_val_t a) { return counted_new_aligned(n, a); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
void operator delete(void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete(void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }
