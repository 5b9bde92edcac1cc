// SpscRing under load: LANCET_STRESS_MESSAGES (50 million; fewer under sanitizers) checksummed
// messages from a producer to a consumer, between two threads and between two processes. The
// consumer checks every message: its sequence number is the next one expected (none lost,
// duplicated or reordered) and its payload matches its checksum (none torn).
//
// The 2-core dev VM shares its cores with other work, so both sides yield when the ring is full
// or empty instead of spinning a whole time slice away.

#include "lancet/shared_model/spsc_ring.hpp"

#include <sys/types.h>

#include <gtest/gtest.h>

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <thread>

#include "ipc_test_support.hpp"

namespace lancet {
namespace {

using test::StressMessage;
using Clock = std::chrono::steady_clock;

constexpr std::uint64_t kMessages = LANCET_STRESS_MESSAGES;
constexpr std::size_t kCapacity = 4096;
constexpr std::size_t kBatch = 256;
// A consumer that sees no message for this long gives up (the producer died or hung).
constexpr auto kStallLimit = std::chrono::seconds(30);

using Ring = SpscRing<StressMessage, kCapacity>;

/// Everything both sides share; lives in a MAP_SHARED mapping for the process test.
struct Channel {
  Ring ring;
  std::atomic<bool> abort{false};         ///< consumer → producer: stop, the test failed
  std::atomic<std::uint64_t> refused{0};  ///< producer: pushes that found the ring full
};

/// Producer: pushes messages 0 .. n-1, yielding while the ring is full. Returns false when told
/// to abort.
bool produce(Channel& ch, std::uint64_t n) {
  std::uint64_t refused = 0;
  for (std::uint64_t seq = 0; seq < n; ++seq) {
    const StressMessage m = StressMessage::make(seq);
    while (!ch.ring.try_push(m)) {
      ++refused;
      if (ch.abort.load(std::memory_order_relaxed)) return false;
      std::this_thread::yield();
    }
  }
  ch.refused.store(refused, std::memory_order_relaxed);
  return true;
}

struct ConsumeResult {
  std::uint64_t received = 0;
  std::uint64_t first_bad_index = 0;  ///< valid when bad
  StressMessage first_bad{};
  bool bad = false;
  bool stalled = false;
  std::uint64_t batches = 0;
  std::uint64_t empty_polls = 0;
};

/// Consumer: pops n messages in batches and checks each one; stops at the first bad message or
/// when nothing arrives for kStallLimit (or producer_gone() says the producer has left).
template <class ProducerGone>
ConsumeResult consume(Channel& ch, std::uint64_t n, ProducerGone producer_gone) {
  ConsumeResult r;
  std::array<StressMessage, kBatch> buf;
  auto last_progress = Clock::now();
  while (r.received < n) {
    const std::size_t got = ch.ring.try_pop_n(buf.data(), buf.size());
    if (got == 0) {
      ++r.empty_polls;
      if ((r.empty_polls & 1023) == 0) {
        if (Clock::now() - last_progress > kStallLimit || (producer_gone() && ch.ring.empty_approx())) {
          r.stalled = true;
          break;
        }
      }
      std::this_thread::yield();
      continue;
    }
    ++r.batches;
    for (std::size_t i = 0; i < got; ++i) {
      const StressMessage& m = buf[i];
      if (m.seq != r.received || !m.intact()) {
        r.bad = true;
        r.first_bad_index = r.received;
        r.first_bad = m;
        return r;
      }
      ++r.received;
    }
    last_progress = Clock::now();
  }
  return r;
}

void expect_all_received(const ConsumeResult& r, const Channel& ch, std::uint64_t n, double seconds) {
  EXPECT_FALSE(r.bad) << "message " << r.first_bad_index << " came out as seq " << r.first_bad.seq
                      << (r.first_bad.intact() ? " (intact: lost, duplicated or reordered)"
                                               : " (torn: checksum wrong)");
  EXPECT_FALSE(r.stalled) << "the producer stopped after " << r.received << " of " << n << " messages";
  EXPECT_EQ(r.received, n);
  EXPECT_EQ(ch.ring.pushed_count(), n);
  EXPECT_EQ(ch.ring.overflow_count(), ch.refused.load()) << "every refused push is counted";
  EXPECT_TRUE(ch.ring.empty_approx());
  std::printf("[stress] %llu messages in %.2f s (%.1f M msg/s), %llu batches (avg %.1f), %llu pushes refused (full), "
              "%llu polls empty\n",
              static_cast<unsigned long long>(r.received), seconds, static_cast<double>(r.received) / seconds / 1e6,
              static_cast<unsigned long long>(r.batches),
              r.batches ? static_cast<double>(r.received) / static_cast<double>(r.batches) : 0.0,
              static_cast<unsigned long long>(ch.refused.load()), static_cast<unsigned long long>(r.empty_polls));
}

TEST(RingStress, TwoThreads) {
  auto ch = std::make_unique<Channel>();
  std::atomic<bool> producer_done{false};
  const auto t0 = Clock::now();
  std::thread producer([&] {
    produce(*ch, kMessages);
    producer_done.store(true);
  });
  const ConsumeResult r = consume(*ch, kMessages, [&] { return producer_done.load(); });
  ch->abort.store(true);
  producer.join();
  const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  expect_all_received(r, *ch, kMessages, seconds);
}

TEST(RingStress, TwoProcesses) {
  if (LANCET_TEST_TSAN) {
    GTEST_SKIP() << "ThreadSanitizer build: TSan does not support fork() well and cannot see the other process's "
                    "memory accesses anyway; RingStress.TwoThreads covers the ring under TSan";
  }
  // The ring sits in a MAP_SHARED | MAP_ANONYMOUS mapping: after fork() both processes see the
  // same physical pages, as with the real segment.
  test::SharedMapping<Channel> ch;
  const auto t0 = Clock::now();
  const pid_t child = test::fork_child([&] { return produce(*ch, kMessages) ? 0 : 3; });
  ASSERT_GT(child, 0) << "fork failed";

  // The producer counts as gone once it has exited (checked without reaping it).
  const ConsumeResult r = consume(*ch, kMessages, [&] {
    siginfo_t info{};
    return ::waitid(P_PID, static_cast<id_t>(child), &info, WEXITED | WNOHANG | WNOWAIT) == 0 && info.si_pid == child;
  });
  if (r.bad || r.stalled) ch->abort.store(true);
  const int status = test::wait_exit_status(child);
  const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  EXPECT_EQ(status, r.bad ? 3 : 0) << "producer process exit status";
  expect_all_received(r, *ch, kMessages, seconds);
}

}  // namespace
}  // namespace lancet
