// Seqlock<T> and TripleBuffer<T> under contention, with threads (also under ThreadSanitizer) and
// with two processes sharing them in a MAP_SHARED mapping. Every read that reports kOk must be a
// value some write published whole (no torn reads), with versions that never go backwards.
//
// The tests count events, never time: a writer writes until the readers have done their share
// (so writes and reads overlap however the machine schedules them), and what must hold holds
// for every read, not for a share of them.
//   Seqlock, writer flat out        every kOk is whole; the version try_read_if_newer reports is
//                                   the value's; readers get through (each waits for 200 kOk
//                                   reads; the deadline only catches a hang)
//   Seqlock, writer waits for them  a read made while no write is in progress succeeds at its
//                                   first attempt and returns the newest value
//   TripleBuffer, writer flat out   every read of the claiming reader is kOk or kUnchanged,
//   (TissuePatch size)              never kBusy (no reader starved by a busy writer), whole,
//                                   newest-so-far; a second, non-claiming reader stays safe
// (A seqlock reader gives up (kBusy) while a write overlaps its copy: that is its contract, so no
// share of kBusy is asserted for it; how often it happens is measured by lancet-bench-ipc.)
//
// A value is "stamped": every 64-bit word holds the write counter c and the last word holds a
// checksum of c, so a read that mixes two writes cannot pass the check.

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <thread>
#include <vector>

#include "ipc_test_support.hpp"
#include "lancet/shared_model/messages.hpp"
#include "lancet/shared_model/seqlock.hpp"
#include "lancet/shared_model/triple_buffer.hpp"
#include "wait.hpp"

namespace lancet {
namespace {

using test::mix64;

template <std::size_t Bytes>
struct Stamped {
  static_assert(Bytes % 8 == 0 && Bytes >= 16);
  static constexpr std::size_t kWords = Bytes / 8 - 1;
  std::uint64_t word[kWords];  ///< all equal to the write counter
  std::uint64_t check;         ///< mix64(counter)

  void stamp(std::uint64_t c) noexcept {
    std::fill(std::begin(word), std::end(word), c);
    check = mix64(c);
  }
  /// True when every word carries the same counter and the checksum matches it.
  [[nodiscard]] bool intact() const noexcept {
    const std::uint64_t c = word[0];
    for (std::uint64_t w : word) {
      if (w != c) return false;
    }
    return check == mix64(c);
  }
};

using Stamped512 = Stamped<512>;
// The largest payload of the real protocol, rounded up to whole words.
using StampedPatch = Stamped<(sizeof(TissuePatch) + 7) / 8 * 8>;
static_assert(sizeof(Stamped512) == 512);
static_assert(sizeof(StampedPatch) >= sizeof(TissuePatch));

struct ReadStats {
  std::uint64_t ok = 0;
  std::uint64_t busy = 0;
  std::uint64_t unchanged = 0;
  std::uint64_t empty = 0;
  std::uint64_t torn = 0;           ///< kOk reads whose words disagree: must stay 0
  std::uint64_t version_wrong = 0;  ///< kOk reads whose version is not the stamped counter: 0
  std::uint64_t went_back = 0;      ///< kOk reads older than an earlier one: must stay 0

  void add(const ReadStats& o) {
    ok += o.ok, busy += o.busy, unchanged += o.unchanged, empty += o.empty;
    torn += o.torn, version_wrong += o.version_wrong, went_back += o.went_back;
  }
};

void report(const char* what, const ReadStats& st, std::uint64_t writes) {
  std::printf("[%s] writes %llu, reads: ok %llu, busy %llu, unchanged %llu, empty %llu\n", what,
              static_cast<unsigned long long>(writes), static_cast<unsigned long long>(st.ok),
              static_cast<unsigned long long>(st.busy), static_cast<unsigned long long>(st.unchanged),
              static_cast<unsigned long long>(st.empty));
}

void expect_whole(const ReadStats& st) {
  EXPECT_EQ(st.torn, 0u) << "a read reported kOk but mixed two writes";
  EXPECT_EQ(st.version_wrong, 0u) << "a read reported a version other than the value's";
  EXPECT_EQ(st.went_back, 0u) << "a reader saw an older value after a newer one";
}

// One kOk read checked: whole, its version the stamped counter, never older than the last.
template <class T>
void check_ok(const T& out, bool has_version, std::uint64_t version, std::uint64_t& last, ReadStats& st) {
  ++st.ok;
  if (!out.intact()) {
    ++st.torn;
    return;
  }
  const std::uint64_t c = out.word[0];
  if (has_version && version != c) ++st.version_wrong;
  if (c < last) ++st.went_back;
  last = std::max(last, c);
}

void count(ReadStatus s, ReadStats& st) {
  if (s == ReadStatus::kBusy) ++st.busy;
  if (s == ReadStatus::kUnchanged) ++st.unchanged;
  if (s == ReadStatus::kEmpty) ++st.empty;
}

// --- Seqlock, writer flat out ------------------------------------------------------------------

// What the writer and the readers share (in a MAP_SHARED mapping for the two-process runs).
template <class Lock>
struct Arena {
  Lock lock;
  std::atomic<bool> stop{false};            ///< readers are done: the writer stops
  std::atomic<std::uint64_t> writes{0};     ///< written so far
};

template <class T, class Lock>
void write_until_stopped(Arena<Lock>& a) {
  auto value = std::make_unique<T>();
  std::uint64_t c = 0;
  while (!a.stop.load(std::memory_order_relaxed)) {
    value->stamp(++c);
    if constexpr (requires { a.lock.publish(*value); }) {
      a.lock.publish(*value);
    } else {
      a.lock.write(*value);
    }
    a.writes.store(c, std::memory_order_relaxed);
  }
}

// Reads until `wanted` kOk reads while the writer writes, alternating try_read and
// try_read_if_newer so that both paths are checked. Returns false if that never happened (a hang).
template <class T>
bool seqlock_read(const Seqlock<T>& lock, std::uint64_t wanted, ReadStats& st) {
  auto out = std::make_unique<T>();
  std::uint64_t last = 0, seen = 0;
  const auto deadline = std::chrono::steady_clock::now() + test::kHangTimeout;
  for (std::uint64_t i = 0; st.ok < wanted; ++i) {
    if ((i & 1023) == 0 && std::chrono::steady_clock::now() > deadline) return false;
    const bool newer = (i & 1) != 0;
    const ReadStatus s = newer ? lock.try_read_if_newer(*out, seen) : lock.try_read(*out);
    if (s == ReadStatus::kOk) {
      check_ok(*out, newer, seen, last, st);
    } else {
      count(s, st);
    }
  }
  return true;
}

constexpr std::uint64_t kSeqlockReads = 200;  ///< kOk reads each reader waits for

template <class T>
void seqlock_flat_out_threads(const char* what) {
  constexpr int kReaders = 2;
  auto a = std::make_unique<Arena<Seqlock<T>>>();
  std::thread writer([&] { write_until_stopped<T>(*a); });
  ASSERT_TRUE(test::eventually([&] { return a->lock.version() > 0; })) << "the writer never wrote";
  std::vector<ReadStats> stats(kReaders);
  std::vector<char> done(kReaders, 0);
  std::vector<std::thread> readers;
  for (int r = 0; r < kReaders; ++r) readers.emplace_back([&, r] { done[r] = seqlock_read(a->lock, kSeqlockReads, stats[r]) ? 1 : 0; });
  for (auto& t : readers) t.join();
  a->stop.store(true);
  writer.join();
  ReadStats total;
  for (int r = 0; r < kReaders; ++r) {
    EXPECT_TRUE(done[r]) << "reader " << r << " got fewer than " << kSeqlockReads << " whole reads in "
                         << test::kHangTimeout.count() << " s: starved for good";
    total.add(stats[r]);
  }
  report(what, total, a->writes.load());
  expect_whole(total);
}

TEST(SeqlockTornRead, Threads512BytesFlatOut) { seqlock_flat_out_threads<Stamped512>("seqlock, threads, 512 B, flat out"); }

TEST(SeqlockTornRead, TwoProcesses512BytesFlatOut) {
  if (LANCET_TEST_TSAN) GTEST_SKIP() << "ThreadSanitizer build: TSan does not support fork() well and cannot see "
                                         "the other process's accesses; the threads variants cover this";
  test::SharedMapping<Arena<Seqlock<Stamped512>>> a;
  const pid_t child = test::fork_child([&] {
    write_until_stopped<Stamped512>(*a);
    return 0;
  });
  ASSERT_GT(child, 0) << "fork failed";
  ReadStats st;
  const bool done = test::eventually([&] { return a->lock.version() > 0; }) && seqlock_read(a->lock, kSeqlockReads, st);
  a->stop.store(true);
  EXPECT_EQ(test::wait_exit_status(child), 0) << "the writer process failed";
  EXPECT_TRUE(done) << "the reader got fewer than " << kSeqlockReads << " whole reads: starved for good";
  report("seqlock, two processes, 512 B, flat out", st, a->writes.load());
  expect_whole(st);
}

// --- Seqlock, writer waits for the readers ------------------------------------------------------

// The writer writes value c, then waits until every reader has read it; a reader reads once the
// writer waits for it (so no write is in progress) with a single attempt. Each such read must be
// kOk and the newest value: a quiet seqlock is read at the first try.
template <class T>
void seqlock_quiet_reads(const char* what, std::uint64_t writes) {
  constexpr int kReaders = 2;
  auto lock = std::make_unique<Seqlock<T>>();
  std::atomic<std::uint64_t> turn{0};            // the value the writer waits on
  std::array<std::atomic<std::uint64_t>, kReaders> acked{};  // the last value each reader read
  std::atomic<bool> hung{false};
  std::thread writer([&] {
    auto value = std::make_unique<T>();
    for (std::uint64_t c = 1; c <= writes && !hung.load(); ++c) {
      value->stamp(c);
      lock->write(*value);
      turn.store(c, std::memory_order_release);
      if (!test::eventually([&] { return std::all_of(acked.begin(), acked.end(), [&](const auto& x) { return x.load() >= c; }); }))
        hung.store(true);
    }
  });
  std::vector<ReadStats> stats(kReaders);
  std::vector<std::uint64_t> wrong(kReaders, 0);
  std::vector<std::thread> readers;
  for (int r = 0; r < kReaders; ++r) {
    readers.emplace_back([&, r] {
      auto out = std::make_unique<T>();
      std::uint64_t last = 0;
      for (std::uint64_t c = 1; c <= writes; ++c) {
        if (!test::eventually([&] { return turn.load(std::memory_order_acquire) >= c || hung.load(); }) || hung.load()) return;
        const ReadStatus s = lock->try_read(*out, /*max_attempts=*/1);
        if (s == ReadStatus::kOk) {
          check_ok(*out, false, 0, last, stats[r]);
          if (out->word[0] != c) ++wrong[r];
        } else {
          count(s, stats[r]);
        }
        acked[r].store(c, std::memory_order_release);
      }
    });
  }
  for (auto& t : readers) t.join();
  writer.join();
  ASSERT_FALSE(hung.load()) << "a reader never acknowledged a write";
  ReadStats total;
  for (int r = 0; r < kReaders; ++r) {
    total.add(stats[r]);
    EXPECT_EQ(wrong[r], 0u) << "reader " << r << " read an older value than the one written";
  }
  report(what, total, writes);
  expect_whole(total);
  EXPECT_EQ(total.ok, writes * kReaders) << "a read with no write in progress did not succeed at its first attempt";
  EXPECT_EQ(total.busy, 0u);
}

TEST(SeqlockTornRead, AQuietSeqlockIsReadAtTheFirstAttempt512Bytes) {
  seqlock_quiet_reads<Stamped512>("seqlock, 512 B, writer waits for the readers", 500);
}
TEST(SeqlockTornRead, AQuietSeqlockIsReadAtTheFirstAttemptTissuePatchSize) {
  seqlock_quiet_reads<StampedPatch>("seqlock, TissuePatch size, writer waits for the readers", LANCET_TEST_TSAN ? 20 : 200);
}

// --- TripleBuffer, writer flat out ---------------------------------------------------------------

// The claiming reader reads until it has `wanted` kOk reads and the writer has written at least
// `min_writes` values; every read must be kOk or kUnchanged.
template <class T>
bool triple_read(TripleBuffer<T>& buf, const std::atomic<std::uint64_t>& writes, std::uint64_t wanted, std::uint64_t min_writes,
                 ReadStats& st) {
  auto out = std::make_unique<T>();
  std::uint64_t last = 0, seen = 0;
  const auto deadline = std::chrono::steady_clock::now() + test::kHangTimeout;
  for (std::uint64_t i = 0; st.ok < wanted || writes.load(std::memory_order_relaxed) < min_writes; ++i) {
    if ((i & 255) == 0 && std::chrono::steady_clock::now() > deadline) return false;
    const bool newer = (i & 1) != 0;
    const ReadStatus s = newer ? buf.try_read_if_newer(*out, seen) : buf.try_read(*out);
    if (s == ReadStatus::kOk) {
      check_ok(*out, newer, seen, last, st);
    } else {
      count(s, st);
    }
  }
  return true;
}

// A second reader that does not claim (a monitor): it may be turned away, never given a torn value.
template <class T>
void peek_until(const TripleBuffer<T>& buf, const std::atomic<bool>& stop, ReadStats& st) {
  auto out = std::make_unique<T>();
  std::uint64_t last = 0;
  while (!stop.load(std::memory_order_relaxed)) {
    const ReadStatus s = buf.try_peek(*out);
    if (s == ReadStatus::kOk) {
      check_ok(*out, false, 0, last, st);
    } else {
      count(s, st);
    }
  }
}

// Reads wanted from the claiming reader, and writes the writer makes at least, so that reads and
// writes overlap many times whatever the scheduling (a 720 KB write takes ~20 ms under TSan).
constexpr std::uint64_t kTripleReads = LANCET_TEST_TSAN ? 30 : 300;
constexpr std::uint64_t kTripleWrites = LANCET_TEST_TSAN ? 30 : 300;

template <class T>
void triple_flat_out_threads(const char* what) {
  auto a = std::make_unique<Arena<TripleBuffer<T>>>();
  std::thread writer([&] { write_until_stopped<T>(*a); });
  ASSERT_TRUE(test::eventually([&] { return a->lock.version() > 0; })) << "the writer never wrote";
  ReadStats claimed, peeked;
  std::atomic<bool> peek_stop{false};
  std::thread peeker([&] { peek_until(a->lock, peek_stop, peeked); });
  const bool done = triple_read(a->lock, a->writes, kTripleReads, kTripleWrites, claimed);
  a->stop.store(true);
  writer.join();
  peek_stop.store(true);
  peeker.join();
  EXPECT_TRUE(done) << "the claiming reader did not get " << kTripleReads << " reads while the writer wrote " << kTripleWrites;
  report(what, claimed, a->writes.load());
  report("  the non-claiming reader", peeked, a->writes.load());
  expect_whole(claimed);
  expect_whole(peeked);
  EXPECT_EQ(claimed.busy, 0u) << "the claiming reader was turned away by the writer";
  EXPECT_GE(claimed.ok, kTripleReads);
}

TEST(TripleBufferTornRead, ThreadsTissuePatchSizeFlatOutTheReaderIsNeverTurnedAway) {
  triple_flat_out_threads<StampedPatch>("triple buffer, threads, TissuePatch size, flat out");
}
TEST(TripleBufferTornRead, Threads512BytesFlatOutTheReaderIsNeverTurnedAway) {
  triple_flat_out_threads<Stamped512>("triple buffer, threads, 512 B, flat out");
}

TEST(TripleBufferTornRead, TwoProcessesTissuePatchSizeFlatOutTheReaderIsNeverTurnedAway) {
  if (LANCET_TEST_TSAN) GTEST_SKIP() << "ThreadSanitizer build: TSan does not support fork() well and cannot see "
                                         "the other process's accesses; the threads variants cover this";
  test::SharedMapping<Arena<TripleBuffer<StampedPatch>>> a;
  const pid_t child = test::fork_child([&] {
    write_until_stopped<StampedPatch>(*a);
    return 0;
  });
  ASSERT_GT(child, 0) << "fork failed";
  ReadStats st;
  const bool done = test::eventually([&] { return a->lock.version() > 0; }) && triple_read(a->lock, a->writes, kTripleReads, kTripleWrites, st);
  a->stop.store(true);
  EXPECT_EQ(test::wait_exit_status(child), 0) << "the writer process failed";
  EXPECT_TRUE(done) << "the reader did not get " << kTripleReads << " reads while the writer wrote " << kTripleWrites;
  report("triple buffer, two processes, TissuePatch size, flat out", st, a->writes.load());
  expect_whole(st);
  EXPECT_EQ(st.busy, 0u) << "the claiming reader was turned away by the writer";
}

}  // namespace
}  // namespace lancet
