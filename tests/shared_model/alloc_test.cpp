// The real-time entry points of shared_model allocate nothing: SpscRing try_push / try_pop /
// try_pop_n / discard_all, Seqlock write / try_read / try_read_if_newer, Heartbeat beat / fresh.
// Each runs 100 000 times inside a MallocGuard (the Drake limit_malloc idea), with the real
// message types. A first test shows that the guard does count, so these tests can fail.

#include <gtest/gtest.h>

#include <array>
#include <cstdint>
#include <cstdlib>
#include <memory>

#include "ipc_test_support.hpp"
#include "lancet/shared_model/heartbeat.hpp"
#include "lancet/shared_model/messages.hpp"
#include "lancet/shared_model/seqlock.hpp"
#include "lancet/shared_model/spsc_ring.hpp"
#include "malloc_guard.hpp"

namespace lancet {
namespace {

using test::MallocGuard;
constexpr int kCalls = 100000;

TEST(AllocGuard, CountsOperatorNew) {
  MallocGuard guard;
  int* volatile p = new int(42);  // volatile: the allocation cannot be optimised away
  EXPECT_GT(guard.count(), 0u);
  delete p;
}

TEST(AllocGuard, CountsMallocWhenNoSanitizerOwnsIt) {
  if (!test::malloc_is_counted()) {
    GTEST_SKIP() << "a sanitizer owns malloc in this build; operator new is still counted";
  }
  MallocGuard guard;
  void* volatile p = std::malloc(64);
  EXPECT_GT(guard.count(), 0u);
  std::free(p);
}

TEST(AllocFree, SpscRingPushPopAndBatchPop) {
  auto ring = std::make_unique<SpscRing<ToolSample, 1024>>();
  auto batch = std::make_unique<std::array<ToolSample, 64>>();
  ToolSample s{};
  ToolSample out{};
  std::uint64_t pushed = 0;
  std::uint64_t popped = 0;

  MallocGuard guard;
  for (int i = 0; i < kCalls; ++i) {
    s.seq = static_cast<std::uint64_t>(i);
    if (ring->try_push(s)) ++pushed;
    switch (i % 4) {
      case 0: popped += ring->try_pop(out) ? 1 : 0; break;
      case 1: popped += ring->try_pop_n(batch->data(), batch->size()); break;
      case 2: break;  // let the ring fill now and then, so that full pushes are covered too
      default: if (i % 1000 == 3) popped += ring->discard_all(); break;
    }
  }
  (void)ring->size_approx();
  (void)ring->overflow_count();
  const std::size_t allocations = guard.count();

  EXPECT_EQ(allocations, 0u) << "SpscRing allocated on the real-time path";
  EXPECT_EQ(pushed, ring->pushed_count());
  EXPECT_EQ(pushed - popped, ring->size_approx());
  EXPECT_GT(popped, 0u);
}

TEST(AllocFree, SpscRingFullAndEmpty) {
  auto ring = std::make_unique<SpscRing<Command, 256>>();
  Command c{};
  MallocGuard guard;
  for (int i = 0; i < kCalls / 2; ++i) (void)ring->try_push(c);  // mostly refused: full
  for (int i = 0; i < kCalls / 2; ++i) (void)ring->try_pop(c);   // mostly empty
  EXPECT_EQ(guard.count(), 0u);
  EXPECT_EQ(ring->overflow_count(), static_cast<std::uint64_t>(kCalls / 2 - 256));
}

TEST(AllocFree, SeqlockWriteAndRead) {
  auto status_lock = std::make_unique<Seqlock<RtStatus>>();
  auto patch_lock = std::make_unique<Seqlock<TissuePatch>>();
  auto patch = std::make_unique<TissuePatch>();
  RtStatus st{};
  RtStatus got{};
  std::uint64_t seen = 0;
  std::uint64_t ok = 0;

  MallocGuard guard;
  for (int i = 0; i < kCalls; ++i) {
    st.tick = static_cast<std::uint64_t>(i);
    status_lock->write(st);
    ok += status_lock->try_read(got) == ReadStatus::kOk ? 1 : 0;
    ok += status_lock->try_read_if_newer(got, seen) == ReadStatus::kOk ? 1 : 0;
    (void)status_lock->version();
  }
  // The 48 KB payload: fewer rounds, same paths.
  for (int i = 0; i < kCalls / 100; ++i) {
    patch->seq = static_cast<std::uint64_t>(i);
    patch_lock->write(*patch);
    ok += patch_lock->try_read(*patch) == ReadStatus::kOk ? 1 : 0;
  }
  const std::size_t allocations = guard.count();

  EXPECT_EQ(allocations, 0u) << "Seqlock allocated on the real-time path";
  EXPECT_EQ(ok, 2u * kCalls + kCalls / 100);
}

TEST(AllocFree, HeartbeatBeatAndFresh) {
  Heartbeat hb;
  std::uint64_t fresh = 0;
  MallocGuard guard;
  for (int i = 1; i <= kCalls; ++i) {
    hb.beat(static_cast<std::int64_t>(i) * 1000, 1234);
    fresh += hb.fresh(static_cast<std::int64_t>(i) * 1000 + 500, 1000) ? 1 : 0;
    (void)hb.last_ns();
    (void)hb.count();
  }
  EXPECT_EQ(guard.count(), 0u);
  EXPECT_EQ(hb.count(), static_cast<std::uint64_t>(kCalls));
  EXPECT_EQ(fresh, static_cast<std::uint64_t>(kCalls));
}

}  // namespace
}  // namespace lancet
