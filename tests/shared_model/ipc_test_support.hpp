#pragma once
// Helpers shared by the shared_model tests: a checksummed stress message, a shared anonymous
// mapping that survives fork(), a forked child that reports through its exit status, and unique
// shared-memory names.
//
// Test-only code: allocation and system calls are fine here.

#include <sys/mman.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstddef>
#include <cstdint>
#include <new>
#include <string>
#include <type_traits>
#include <utility>

// True in a ThreadSanitizer build: TSan does not support fork() from a process that has run
// threads (the child inherits the runtime in an unknown state), so multi-process tests skip.
#if defined(__SANITIZE_THREAD__)
#define LANCET_TEST_TSAN 1
#elif defined(__has_feature)
#if __has_feature(thread_sanitizer)
#define LANCET_TEST_TSAN 1
#endif
#endif
#ifndef LANCET_TEST_TSAN
#define LANCET_TEST_TSAN 0
#endif

// True when timing says little about the code: a sanitizer instruments every access, or the
// build is not optimised (the debug preset). Tests keep their correctness checks there and drop
// their timing-based ones.
#if LANCET_TEST_TSAN || defined(__SANITIZE_ADDRESS__) || !defined(__OPTIMIZE__)
#define LANCET_TEST_TIMING_DISTORTED 1
#else
#define LANCET_TEST_TIMING_DISTORTED 0
#endif

namespace lancet::test {

/// Mixes a 64-bit value (splitmix64 finaliser); used to derive payload words and checksums.
constexpr std::uint64_t mix64(std::uint64_t x) noexcept {
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

/// One cache line: a sequence number, six payload words derived from it, and a checksum over
/// all seven. A lost, duplicated, reordered or torn message fails check().
struct StressMessage {
  std::uint64_t seq;
  std::uint64_t payload[6];
  std::uint64_t checksum;

  static constexpr StressMessage make(std::uint64_t seq) noexcept {
    StressMessage m{};
    m.seq = seq;
    for (std::size_t i = 0; i < 6; ++i) m.payload[i] = mix64(seq * 8 + i);
    m.checksum = sum(m);
    return m;
  }
  static constexpr std::uint64_t sum(const StressMessage& m) noexcept {
    std::uint64_t h = mix64(m.seq);
    for (std::size_t i = 0; i < 6; ++i) h = mix64(h ^ m.payload[i]);
    return h;
  }
  /// True when the payload and checksum belong to seq.
  [[nodiscard]] constexpr bool intact() const noexcept {
    for (std::size_t i = 0; i < 6; ++i) {
      if (payload[i] != mix64(seq * 8 + i)) return false;
    }
    return checksum == sum(*this);
  }
};
static_assert(sizeof(StressMessage) == 64);
static_assert(std::is_trivially_copyable_v<StressMessage>);

/// A T constructed in a MAP_SHARED | MAP_ANONYMOUS mapping, so that a fork()ed child shares it.
/// T must be trivially destructible (it lives in shared memory).
template <class T>
class SharedMapping {
  static_assert(std::is_trivially_destructible_v<T>);

 public:
  SharedMapping() {
    void* p = ::mmap(nullptr, sizeof(T), PROT_READ | PROT_WRITE, MAP_SHARED | MAP_ANONYMOUS, -1, 0);
    if (p == MAP_FAILED) throw std::bad_alloc();
    ptr_ = new (p) T{};
  }
  ~SharedMapping() { ::munmap(static_cast<void*>(ptr_), sizeof(T)); }
  SharedMapping(const SharedMapping&) = delete;
  SharedMapping& operator=(const SharedMapping&) = delete;

  T& operator*() const noexcept { return *ptr_; }
  T* operator->() const noexcept { return ptr_; }

 private:
  T* ptr_ = nullptr;
};

/// Forks; the child runs fn() (which returns an exit status) and _exit()s without running
/// destructors or atexit handlers. Returns the child's pid, or -1 when fork failed.
template <class Fn>
pid_t fork_child(Fn&& fn) {
  const pid_t pid = ::fork();
  if (pid == 0) {
    int status = 100;
    try {
      status = std::forward<Fn>(fn)();
    } catch (...) {
      status = 101;
    }
    ::_exit(status);
  }
  return pid;
}

/// Waits for pid and returns its exit status, or -1 (killed by a signal) or -2 (waitpid failed).
inline int wait_exit_status(pid_t pid) {
  int status = 0;
  pid_t r;
  do {
    r = ::waitpid(pid, &status, 0);
  } while (r < 0 && errno == EINTR);
  if (r != pid) return -2;
  if (WIFEXITED(status)) return WEXITSTATUS(status);
  return -1;
}

/// A shared-memory name unique to this process and call: "/lancet-test-<pid>-<n>".
inline std::string unique_shm_name() {
  static std::atomic<int> counter{0};
  return "/lancet-test-" + std::to_string(::getpid()) + "-" + std::to_string(counter.fetch_add(1));
}

/// Path of a POSIX shared-memory object on Linux.
inline std::string dev_shm_path(const std::string& name) { return "/dev/shm" + name; }

}  // namespace lancet::test
