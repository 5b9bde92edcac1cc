#pragma once
// TripleBuffer<T>: the newest of a large value (the 720 KB TissuePatch), published by one writer
// and read whole by one reader, neither of which ever waits for the other — and, unlike a
// Seqlock, a reader that is never turned away because the writer is busy.
//
// Three slots, each a Seqlock<T> (so a slot written into while it is read is detected, never
// returned torn), a published word (the newest complete slot and its version) and a claim word
// (the slot the reader is copying):
//
//   writer   picks a slot that is neither published nor claimed (of three, one always is),
//            writes it whole, then publishes it: published = version << 2 | slot.
//   reader   loads published, claims its slot, loads published again: unchanged, the slot is
//            its own until it lets go (the writer sees the claim before it next picks a slot);
//            changed, it claims the newer one. Then it copies the slot, checks the slot's own
//            sequence did not move, and lets go.
//
// Why the claim holds: the claim store and the writer's publish store are followed, on each side,
// by a load of the other's word, all sequentially consistent (Dekker's pattern). A reader whose
// second load still sees the slot published stored its claim before the writer's next publish,
// so the writer's next pick, which loads the claim after that publish, sees it. The slot the
// writer is filling when the reader claims was picked while another slot was published, so it
// is never the one the reader claims. A reader retries only when a publish lands between its two
// loads of published (a few nanoseconds; each retry needs another publish): max_attempts of them
// in a row give kBusy, which a writer that writes anything larger than a cache line cannot cause.
//
// The segment is untrusted: whatever is in published or claim is range-checked (a slot index out
// of range counts as none), a slot that a misbehaving writer scribbles over while it is claimed
// fails the slot's own sequence check (kBusy), and the copy is the caller's to validate (it is
// the reader's own: nobody can change it after the check). A writer that died mid-write leaves
// its slot odd and unpublished; the next writer starts that slot afresh (Seqlock::write_prefix).
//
// One reader claims: a second reader (a monitor, a test) is safe — it may copy a slot the
// writer is reusing, which its sequence check turns into kBusy, never into a torn value — but
// only one reader has the no-starvation guarantee. Works inside POSIX shared memory (no pointers;
// zero bytes are a valid "never written" state). The doorbell (a futex word) lets a reader sleep
// until the next publish instead of polling.

#include <linux/futex.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>

#include "lancet/shared_model/seqlock.hpp"

namespace lancet {

template <class T>
class TripleBuffer {
 public:
  static constexpr std::uint32_t kSlots = 3;
  static constexpr int kDefaultAttempts = 16;

  TripleBuffer() noexcept = default;
  TripleBuffer(const TripleBuffer&) = delete;
  TripleBuffer& operator=(const TripleBuffer&) = delete;

  /// Single writer. Publishes the first `bytes` bytes of v (as Seqlock::write_prefix; readers take
  /// it with try_read_prefix_if_newer and the same extent), then rings the doorbell. Never waits
  /// for a reader: O(bytes) plus one futex wake system call (not real-time: the writer is the
  /// visualizer).
  void publish_prefix(const T& v, std::size_t bytes) noexcept {
    const std::uint64_t p = published_.load(std::memory_order_seq_cst);
    const std::uint32_t claimed = claim_.load(std::memory_order_seq_cst);
    const std::uint32_t pub_slot = p == 0 ? kSlots : slot_of(p);
    const std::uint32_t claim_slot = claimed >= 1 && claimed <= kSlots ? claimed - 1 : kSlots;
    std::uint32_t w = 0;
    while (w == pub_slot || w == claim_slot) ++w;  // of three, one is free
    slots_[w].write_prefix(v, bytes);
    std::uint64_t version = (version_of(p) + 1) & kVersionMask;
    if (version == 0) version = 1;  // (only after garbage in the segment: 0 means "nothing yet")
    published_.store(version << 2 | w, std::memory_order_seq_cst);
    doorbell_.fetch_add(1, std::memory_order_release);
    syscall(SYS_futex, reinterpret_cast<std::uint32_t*>(&doorbell_), FUTEX_WAKE, 1, nullptr, nullptr, 0);
  }
  /// Single writer. Publishes v whole.
  void publish(const T& v) noexcept { publish_prefix(v, sizeof(T)); }

  /// The reader. Copies the newest value into out when it is newer than version `seen` (updated on
  /// kOk): the first `header_bytes`, then up to extent(out) bytes (extent sees the header just
  /// copied, possibly from a misbehaving writer: it must bound its answer itself). kUnchanged
  /// without copying when nothing newer was published, kEmpty when nothing ever was. kBusy (out
  /// unspecified) only when publishes kept landing inside the claim (max_attempts times) or the
  /// claimed slot was written into (a misbehaving writer). Real-time safe: no allocation, no
  /// system call, bounded by O(extent) plus max_attempts claims.
  template <class Extent>
  [[nodiscard]] ReadStatus try_read_prefix_if_newer(T& out, std::uint64_t& seen, std::size_t header_bytes, Extent&& extent,
                                                    int max_attempts = kDefaultAttempts) noexcept {
    std::uint64_t p = published_.load(std::memory_order_seq_cst);
    for (int attempt = 0; attempt < max_attempts; ++attempt) {
      if (p == 0) return ReadStatus::kEmpty;
      if (version_of(p) == seen) return ReadStatus::kUnchanged;
      const std::uint32_t s = slot_of(p);
      if (s >= kSlots) return ReadStatus::kBusy;  // garbage in the segment: nothing to read
      claim_.store(s + 1, std::memory_order_seq_cst);
      const std::uint64_t again = published_.load(std::memory_order_seq_cst);
      if (again != p) {  // a publish landed in between: claim the newer one
        p = again;
        continue;
      }
      const ReadStatus r = slots_[s].try_read_prefix(out, header_bytes, extent, 1);
      claim_.store(0, std::memory_order_release);
      if (r != ReadStatus::kOk) return ReadStatus::kBusy;  // the claimed slot was written into
      seen = version_of(p);
      return ReadStatus::kOk;
    }
    claim_.store(0, std::memory_order_release);
    return ReadStatus::kBusy;
  }
  /// The reader. The whole value, if newer than `seen`.
  [[nodiscard]] ReadStatus try_read_if_newer(T& out, std::uint64_t& seen, int max_attempts = kDefaultAttempts) noexcept {
    return try_read_prefix_if_newer(out, seen, sizeof(T), whole, max_attempts);
  }
  /// The reader. The whole newest value.
  [[nodiscard]] ReadStatus try_read(T& out, int max_attempts = kDefaultAttempts) noexcept {
    std::uint64_t seen = ~std::uint64_t{0};
    return try_read_if_newer(out, seen, max_attempts);
  }

  /// Any other reader (a monitor, a test): the newest value, whole, without claiming its slot. Never
  /// torn and never older than what was published when it began, but kBusy when the writer
  /// published during the copy (the slot may then be reused). Real-time safe, O(sizeof(T)).
  [[nodiscard]] ReadStatus try_peek(T& out) const noexcept {
    const std::uint64_t p = published_.load(std::memory_order_acquire);
    if (p == 0) return ReadStatus::kEmpty;
    const std::uint32_t s = slot_of(p);
    if (s >= kSlots) return ReadStatus::kBusy;
    if (slots_[s].try_read(out, 1) != ReadStatus::kOk) return ReadStatus::kBusy;
    // Unchanged: the writer never writes the published slot, so the copy is that version.
    return published_.load(std::memory_order_acquire) == p ? ReadStatus::kOk : ReadStatus::kBusy;
  }

  /// Number of values published (0: none). Any thread.
  [[nodiscard]] std::uint64_t version() const noexcept { return version_of(published_.load(std::memory_order_acquire)); }

  /// Any reader thread: sleeps until a publish after version `seen` or until timeout_ns (then
  /// returns false), whichever comes first; returns at once when one is already there. Spurious
  /// wake-ups (a doorbell rung by anything that can write the segment) return false or true as
  /// the version says. Not real-time (a futex wait).
  bool wait_newer(std::uint64_t seen, std::int64_t timeout_ns) const noexcept {
    const std::uint32_t bell = doorbell_.load(std::memory_order_acquire);
    if (version() != seen) return true;
    timespec ts{static_cast<time_t>(timeout_ns / 1'000'000'000), static_cast<long>(timeout_ns % 1'000'000'000)};
    // The doorbell is rung after every publish: if it moved since `bell`, the wait returns at once.
    syscall(SYS_futex, reinterpret_cast<const std::uint32_t*>(&doorbell_), FUTEX_WAIT, bell, &ts, nullptr, 0);
    return version() != seen;
  }
  /// Wakes whoever sleeps in wait_newer (it then sees whether anything is newer). Changes nothing.
  void wake_waiters() const noexcept {
    syscall(SYS_futex, reinterpret_cast<const std::uint32_t*>(&doorbell_), FUTEX_WAKE, 1 << 30, nullptr, nullptr, 0);
  }

 private:
  static constexpr std::uint64_t kVersionMask = (std::uint64_t{1} << 62) - 1;
  static constexpr std::uint32_t slot_of(std::uint64_t p) noexcept { return static_cast<std::uint32_t>(p & 3u); }
  static constexpr std::uint64_t version_of(std::uint64_t p) noexcept { return p >> 2; }
  static constexpr std::size_t whole(const T&) noexcept { return sizeof(T); }

  alignas(64) std::atomic<std::uint64_t> published_{0};  ///< version << 2 | slot (0: nothing yet)
  alignas(64) std::atomic<std::uint32_t> claim_{0};      ///< slot + 1 the reader is copying (0: none)
  alignas(64) std::atomic<std::uint32_t> doorbell_{0};   ///< rung after each publish (a futex word)
  std::array<Seqlock<T>, kSlots> slots_{};
};

static_assert(sizeof(std::atomic<std::uint32_t>) == sizeof(std::uint32_t), "the doorbell is a futex word");

}  // namespace lancet
