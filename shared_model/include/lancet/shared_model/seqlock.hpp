#pragma once
// Seqlock<T>: the latest value of T, published by one writer that never waits and read by any
// number of readers that never block the writer.
//
// The payload is stored as an array of 64-bit atomics, bracketed by the sequence counter (Boehm,
// "Can seqlocks get along with programming language memory models?", 2012). The writer stores
// each word with release and readers load each word with acquire, so a reader that sees any word
// of a newer write also sees that write's odd sequence number when it re-checks, and gives up on
// the copy. That makes the copy free of data races under the C++ memory model without standalone
// fences, which ThreadSanitizer does not model (GCC rejects atomic_thread_fence under
// -fsanitize=thread -Werror). On x86-64 release stores and acquire loads are plain moves: the
// code is the same as with relaxed accesses and fences. (On weakly ordered CPUs the per-word
// ordering costs more than two fences would.)
//
// A reader retries a bounded number of times and reports failure instead of returning a torn
// value. Works inside POSIX shared memory (no pointers; zero bytes are a valid "never written"
// state).

#include <algorithm>
#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <type_traits>

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#endif

namespace lancet {

/// Outcome of a seqlock read.
enum class ReadStatus : std::uint8_t {
  kOk = 0,     ///< out holds a consistent snapshot
  kEmpty = 1,  ///< nothing was ever written; out is untouched
  kBusy = 2,   ///< every attempt overlapped a write; out holds unspecified bytes
  kUnchanged = 3,  ///< (try_read_if_newer) no write since the version the caller has; out untouched
};

template <class T>
class Seqlock {
  static_assert(std::is_trivially_copyable_v<T>, "Seqlock: T must be trivially copyable");
  static_assert(std::atomic<std::uint64_t>::is_always_lock_free);

 public:
  static constexpr int kDefaultRetries = 64;

  Seqlock() noexcept = default;
  Seqlock(const Seqlock&) = delete;
  Seqlock& operator=(const Seqlock&) = delete;

  /// Single writer. Publishes v; never waits. Real-time safe, O(sizeof(T)).
  void write(const T& v) noexcept { write_prefix(v, sizeof(T)); }

  /// Single writer. Publishes the first `bytes` bytes of v (rounded up to whole words, at most
  /// sizeof(T)); the rest of the stored value keeps older bytes, so readers must take it with
  /// try_read_prefix_if_newer and the same extent. For values whose tail is an array used only in
  /// part (TissuePatch). Real-time safe, O(bytes).
  void write_prefix(const T& v, std::size_t bytes) noexcept {
    const std::size_t words = bytes >= sizeof(T) ? kWords : (bytes + 7) / 8;
    // Even between writes; an odd value here means someone else wrote the counter (a corrupted
    // segment): start from the even value below it, so readers are not locked out for good.
    const std::uint64_t s = seq_.load(std::memory_order_relaxed) & ~std::uint64_t{1};
    seq_.store(s + 1, std::memory_order_relaxed);
    // Release on every word: whoever reads a word of this write also sees the odd s + 1 above.
    const auto* src = reinterpret_cast<const unsigned char*>(&v);
    const std::size_t full = words < kFullWords ? words : kFullWords;
    for (std::size_t i = 0; i < full; ++i) {
      std::uint64_t w;
      std::memcpy(&w, src + i * 8, 8);
      words_[i].store(w, std::memory_order_release);
    }
    if constexpr (kTailBytes != 0) {
      if (words == kWords) {
        std::uint64_t w = 0;
        std::memcpy(&w, src + kFullWords * 8, kTailBytes);
        words_[kFullWords].store(w, std::memory_order_release);
      }
    }
    seq_.store(s + 2, std::memory_order_release);
  }

  /// Any reader. Copies the latest value into out. Tries at most max_attempts times. On kBusy,
  /// out holds unspecified bytes: read into a scratch copy when the previous value must survive.
  /// Real-time safe, bounded by max_attempts * O(sizeof(T)).
  [[nodiscard]] ReadStatus try_read(T& out, int max_attempts = kDefaultRetries) const noexcept {
    std::uint64_t ignored = 0;
    return read_impl(out, max_attempts, /*only_newer=*/false, ignored, sizeof(T), whole);
  }

  /// Any reader. Like try_read, but returns kUnchanged without copying when nothing was written
  /// since version `seen`; on kOk, `seen` is updated to the version that was read.
  [[nodiscard]] ReadStatus try_read_if_newer(T& out, std::uint64_t& seen,
                                             int max_attempts = kDefaultRetries) const noexcept {
    return read_impl(out, max_attempts, /*only_newer=*/true, seen, sizeof(T), whole);
  }

  /// Any reader, of a value published with write_prefix. Like try_read_if_newer, but copies the
  /// first `header_bytes` first, then only up to extent(out) bytes of it (extent sees the header
  /// just copied, possibly torn: it must bound its answer itself; it is capped at sizeof(T)
  /// here). The bytes of out past the extent are left as they were. Real-time safe, bounded by
  /// max_attempts * O(extent).
  template <class Extent>
  [[nodiscard]] ReadStatus try_read_prefix_if_newer(T& out, std::uint64_t& seen, std::size_t header_bytes, Extent&& extent,
                                                    int max_attempts = kDefaultRetries) const noexcept {
    return read_impl(out, max_attempts, /*only_newer=*/true, seen, header_bytes, extent);
  }

  /// Any reader, of a value published with write_prefix: like try_read_prefix_if_newer, whatever
  /// the version. TripleBuffer reads its claimed slot with it.
  template <class Extent>
  [[nodiscard]] ReadStatus try_read_prefix(T& out, std::size_t header_bytes, Extent&& extent,
                                           int max_attempts = kDefaultRetries) const noexcept {
    std::uint64_t ignored = 0;
    return read_impl(out, max_attempts, /*only_newer=*/false, ignored, header_bytes, extent);
  }

  /// Number of completed writes (a version number; 0 means never written).
  [[nodiscard]] std::uint64_t version() const noexcept {
    return seq_.load(std::memory_order_acquire) / 2;
  }

 private:
  static constexpr std::size_t kFullWords = sizeof(T) / 8;
  static constexpr std::size_t kTailBytes = sizeof(T) % 8;
  static constexpr std::size_t kWords = kFullWords + (kTailBytes != 0 ? 1 : 0);

  static void cpu_relax() noexcept {
#if defined(__x86_64__) || defined(__i386__)
    _mm_pause();
#endif
  }

  void copy_words(unsigned char* dst, std::size_t from, std::size_t to) const noexcept {
    for (std::size_t i = from; i < to; ++i) {
      const std::uint64_t w = words_[i].load(std::memory_order_acquire);
      std::memcpy(dst + i * 8, &w, 8);
    }
  }

  // Copies the first header_bytes, then up to extent(out) bytes (all of T when header_bytes is
  // sizeof(T)), and re-checks the sequence.
  template <class Extent>
  ReadStatus read_impl(T& out, int max_attempts, bool only_newer, std::uint64_t& seen, std::size_t header_bytes,
                       Extent&& extent) const noexcept {
    auto* dst = reinterpret_cast<unsigned char*>(&out);
    const std::size_t head = std::min((header_bytes + 7) / 8, kFullWords);
    for (int attempt = 0; attempt < max_attempts; ++attempt) {
      const std::uint64_t s0 = seq_.load(std::memory_order_acquire);
      if (s0 == 0) return ReadStatus::kEmpty;
      if (only_newer && s0 / 2 == seen && (s0 & 1) == 0) return ReadStatus::kUnchanged;
      if (s0 & 1) {
        cpu_relax();
        continue;
      }
      copy_words(dst, 0, head);
      const std::size_t bytes = std::min<std::size_t>(extent(static_cast<const T&>(out)), sizeof(T));
      const std::size_t words = bytes >= sizeof(T) ? kWords : std::max((bytes + 7) / 8, head);
      copy_words(dst, head, std::min(words, kFullWords));
      if constexpr (kTailBytes != 0) {
        if (words == kWords) {
          const std::uint64_t w = words_[kFullWords].load(std::memory_order_acquire);
          std::memcpy(dst + kFullWords * 8, &w, kTailBytes);
        }
      }
      // The acquire loads above keep this re-check after the copy.
      if (seq_.load(std::memory_order_relaxed) == s0) {
        seen = s0 / 2;
        return ReadStatus::kOk;
      }
      cpu_relax();
    }
    return ReadStatus::kBusy;
  }

  static constexpr std::size_t whole(const T&) noexcept { return sizeof(T); }

  alignas(64) std::atomic<std::uint64_t> seq_{0};
  alignas(64) std::array<std::atomic<std::uint64_t>, kWords> words_{};
};

}  // namespace lancet
