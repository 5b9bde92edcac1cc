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
// - The other side is untrusted: it lives in another process, and anything that can write the
//   segment can write garbage into its index. A sane pair always has 0 <= head - tail <= N; each
//   side checks that against the other's index, and when it does not hold, resets its OWN index
//   to the other's (the ring is then empty), counts the reset (resets_seen on that side) and
//   tells the caller. Neither side ever loops on, or reads more than N slots because of, a value
//   the other side wrote. Slot contents are the caller's to validate.
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
  /// is full; never blocks. When the consumer's index is impossible (ahead of head, or more than N
  /// behind) the producer restarts from it, sets *reset (when given) and pushes into the then empty
  /// ring. Real-time safe.
  [[nodiscard]] bool try_push(const T& v, bool* reset = nullptr) noexcept { return try_push_n(&v, 1, reset); }

  /// Producer only. Copies v[0..n) into the ring all at once, or nothing (false, one overflow
  /// counted) when fewer than n slots are free: the consumer sees all n or none of them, never a
  /// part (two hands' resets that must reach one tick). An impossible consumer index is handled as
  /// in try_push. Real-time safe, O(n).
  [[nodiscard]] bool try_push_n(const T* v, std::size_t n, bool* reset = nullptr) noexcept {
    if (n > N) return false;
    std::uint64_t head = head_.load(std::memory_order_relaxed);
    if (head - tail_cache_ + n > N) {
      tail_cache_ = tail_.load(std::memory_order_acquire);
      const std::uint64_t used = head - tail_cache_;
      if (used > N) {
        head = tail_cache_;
        head_.store(head, std::memory_order_release);
        producer_resets_.store(producer_resets_.load(std::memory_order_relaxed) + 1, std::memory_order_relaxed);
        if (reset != nullptr) *reset = true;
      } else if (used + n > N) {
        overflows_.store(overflows_.load(std::memory_order_relaxed) + 1, std::memory_order_relaxed);
        return false;
      }
    }
    for (std::size_t i = 0; i < n; ++i) slots_[(head + i) & kMask] = v[i];
    head_.store(head + n, std::memory_order_release);
    return true;
  }

  /// Consumer only. Pops one element into out; false when empty. Real-time safe.
  [[nodiscard]] bool try_pop(T& out) noexcept { return try_pop_n(&out, 1) == 1; }

  /// Consumer only. Pops up to max elements into out[0..max) in FIFO order and returns how many.
  /// One acquire load and one release store for the whole batch. When the producer's index is
  /// impossible (behind tail, or more than N ahead) the consumer skips to it, sets *reset (when
  /// given) and returns 0. Real-time safe, O(min(max, N)).
  [[nodiscard]] std::size_t try_pop_n(T* out, std::size_t max, bool* reset = nullptr) noexcept {
    const std::uint64_t tail = tail_.load(std::memory_order_relaxed);
    std::uint64_t avail = head_cache_ - tail;
    if (avail < max || avail > N) {
      head_cache_ = head_.load(std::memory_order_acquire);
      avail = head_cache_ - tail;
    }
    if (avail > N) {  // head < tail or head > tail + N: not something a sane producer publishes
      skip_to_head(reset);
      return 0;
    }
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
  std::size_t discard_all(bool* reset = nullptr) noexcept {
    const std::uint64_t tail = tail_.load(std::memory_order_relaxed);
    head_cache_ = head_.load(std::memory_order_acquire);
    const std::uint64_t n = head_cache_ - tail;
    if (n > N) {
      skip_to_head(reset);
      return 0;
    }
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
  /// Any thread. Times the producer / the consumer found the other's index impossible and reset
  /// its own (a corrupted segment; never happens between sane peers). Informational: these
  /// counters live in the segment too, so each side also counts through the `reset` flags.
  [[nodiscard]] std::uint64_t producer_resets() const noexcept { return producer_resets_.load(std::memory_order_relaxed); }
  [[nodiscard]] std::uint64_t consumer_resets() const noexcept { return consumer_resets_.load(std::memory_order_relaxed); }
  static constexpr std::size_t capacity() noexcept { return N; }
  /// Byte offsets of the producer's and the consumer's index inside the ring, for tests and fuzzers
  /// that play a corrupted peer.
  static constexpr std::size_t head_offset() noexcept { return offsetof(SpscRing, head_); }
  static constexpr std::size_t tail_offset() noexcept { return offsetof(SpscRing, tail_); }

 private:
  static constexpr std::uint64_t kMask = N - 1;

  void skip_to_head(bool* reset) noexcept {
    tail_.store(head_cache_, std::memory_order_release);
    consumer_resets_.store(consumer_resets_.load(std::memory_order_relaxed) + 1, std::memory_order_relaxed);
    if (reset != nullptr) *reset = true;
  }

  // Producer-written line: head and the overflow and reset counters.
  alignas(kCacheLine) std::atomic<std::uint64_t> head_{0};
  std::atomic<std::uint64_t> overflows_{0};
  std::atomic<std::uint64_t> producer_resets_{0};
  // Producer-private line: its cached copy of the consumer's index.
  alignas(kCacheLine) std::uint64_t tail_cache_{0};
  // Consumer-written line.
  alignas(kCacheLine) std::atomic<std::uint64_t> tail_{0};
  std::atomic<std::uint64_t> consumer_resets_{0};
  // Consumer-private line: its cached copy of the producer's index.
  alignas(kCacheLine) std::uint64_t head_cache_{0};
  // Value-initialised: a default-constructed ring is fully defined (construction happens once, at
  // configure time), and GCC does not warn about reads of slots it cannot prove were written.
  alignas(kCacheLine) T slots_[N]{};
};

}  // namespace lancet
