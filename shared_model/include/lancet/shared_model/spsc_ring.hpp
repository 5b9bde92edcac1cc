#pragma once
// SpscRing<T, N>: a lock-free single-producer / single-consumer ring that can live in POSIX
// shared memory between two processes.
//
// - No pointers inside: the object is position-independent, so each process may map it at a
//   different address. Construct it once (placement new) in the segment; both sides then use it.
// - N is a power of two; indices are free-running 64-bit counters (they never wrap in practice:
//   2^64 pushes at 1 GHz take 584 years), masked into the slot array.
// - Producer and consumer indices sit on their own cache lines, and each side keeps a cached copy
//   of the other side's index so the shared line is touched only when the cache runs out
//   (the rigtorp/SPSCQueue design).
// - A push into a full ring never blocks: it fails, returns false, and is counted in
//   overflow_count(), which either side (or a monitor) can read.
//
// Thread contract: exactly one producer thread calls try_push; exactly one consumer thread calls
// try_pop / try_pop_n / discard_all. Every member function is real-time safe: no allocation, no
// lock, no system call, bounded time (try_pop_n is O(max)).

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <type_traits>

namespace lancet {

inline constexpr std::size_t kCacheLine = 64;

template <class T, std::size_t N>
class SpscRing {
  static_assert(std::is_trivially_copyable_v<T>, "SpscRing: T must be trivially copyable (it crosses processes)");
  static_assert(N >= 2 && (N & (N - 1)) == 0, "SpscRing: capacity N must be a power of two >= 2");
  static_assert(std::atomic<std::uint64_t>::is_always_lock_free,
                "SpscRing: 64-bit atomics must be lock-free to be shared between processes");

 public:
  using value_type = T;
  static constexpr std::size_t kCapacity = N;

  SpscRing() noexcept = default;
  SpscRing(const SpscRing&) = delete;
  SpscRing& operator=(const SpscRing&) = delete;
  SpscRing(SpscRing&&) = delete;
  SpscRing& operator=(SpscRing&&) = delete;

  /// Producer only. Copies v into the ring. Returns false (and counts an overflow) when the ring
  /// is full; never blocks. Real-time safe.
  [[nodiscard]] bool try_push(const T& v) noexcept {
    const std::uint64_t head = head_.load(std::memory_order_relaxed);
    if (head - tail_cache_ >= N) {
      tail_cache_ = tail_.load(std::memory_order_acquire);
      if (head - tail_cache_ >= N) {
        overflows_.store(overflows_.load(std::memory_order_relaxed) + 1, std::memory_order_relaxed);
        return false;
      }
    }
    slots_[head & kMask] = v;
    head_.store(head + 1, std::memory_order_release);
    return true;
  }

  /// Consumer only. Pops one element into out; false when empty. Real-time safe.
  [[nodiscard]] bool try_pop(T& out) noexcept { return try_pop_n(&out, 1) == 1; }

  /// Consumer only. Pops up to max elements into out[0..max) in FIFO order and returns how many.
  /// One acquire load and one release store for the whole batch. Real-time safe, O(max).
  [[nodiscard]] std::size_t try_pop_n(T* out, std::size_t max) noexcept {
    const std::uint64_t tail = tail_.load(std::memory_order_relaxed);
    std::uint64_t avail = head_cache_ - tail;
    if (avail < max) {
      head_cache_ = head_.load(std::memory_order_acquire);
      avail = head_cache_ - tail;
    }
    // A corrupted peer could publish head < tail or head > tail + N; never read past N slots.
    avail = std::min<std::uint64_t>(avail, N);
    const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(avail, max));
    if (n == 0) return 0;
    const std::size_t first = static_cast<std::size_t>(tail & kMask);
    const std::size_t run = std::min(n, N - first);
    std::memcpy(static_cast<void*>(out), &slots_[first], run * sizeof(T));
    if (run < n) std::memcpy(static_cast<void*>(out + run), &slots_[0], (n - run) * sizeof(T));
    tail_.store(tail + n, std::memory_order_release);
    return n;
  }

  /// Consumer only. Drops everything currently queued (e.g. the backlog a consumer finds when it
  /// attaches late) and returns how many elements were dropped. Real-time safe.
  std::size_t discard_all() noexcept {
    const std::uint64_t tail = tail_.load(std::memory_order_relaxed);
    head_cache_ = head_.load(std::memory_order_acquire);
    const std::uint64_t n = std::min<std::uint64_t>(head_cache_ - tail, N);
    tail_.store(tail + n, std::memory_order_release);
    return static_cast<std::size_t>(n);
  }

  /// Any thread. Elements queued right now (a snapshot; exact only on the consumer side).
  [[nodiscard]] std::size_t size_approx() const noexcept {
    const std::uint64_t tail = tail_.load(std::memory_order_acquire);
    const std::uint64_t head = head_.load(std::memory_order_acquire);
    return static_cast<std::size_t>(std::min<std::uint64_t>(head - tail, N));
  }
  [[nodiscard]] bool empty_approx() const noexcept { return size_approx() == 0; }

  /// Any thread. Total successful pushes since construction.
  [[nodiscard]] std::uint64_t pushed_count() const noexcept { return head_.load(std::memory_order_acquire); }
  /// Any thread. Pushes refused because the ring was full.
  [[nodiscard]] std::uint64_t overflow_count() const noexcept { return overflows_.load(std::memory_order_relaxed); }
  static constexpr std::size_t capacity() noexcept { return N; }

 private:
  static constexpr std::uint64_t kMask = N - 1;

  // Producer-written line: head and the overflow counter.
  alignas(kCacheLine) std::atomic<std::uint64_t> head_{0};
  std::atomic<std::uint64_t> overflows_{0};
  // Producer-private line: its cached copy of the consumer's index.
  alignas(kCacheLine) std::uint64_t tail_cache_{0};
  // Consumer-written line.
  alignas(kCacheLine) std::atomic<std::uint64_t> tail_{0};
  // Consumer-private line: its cached copy of the producer's index.
  alignas(kCacheLine) std::uint64_t head_cache_{0};
  // Value-initialised: a default-constructed ring is fully defined (construction happens once, at
  // configure time), and GCC does not warn about reads of slots it cannot prove were written.
  alignas(kCacheLine) T slots_[N]{};
};

}  // namespace lancet
