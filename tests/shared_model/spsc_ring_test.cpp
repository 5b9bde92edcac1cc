// SpscRing<T, N>, single thread: the contract of every member function, wrap-around of the
// free-running indices, batch pops across the end of the slot array, and the static properties
// that let a ring live in shared memory.

#include "lancet/shared_model/spsc_ring.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <cstring>
#include <memory>
#include <type_traits>
#include <vector>

#include "ipc_test_support.hpp"
#include "lancet/shared_model/messages.hpp"
#include "lancet/shared_model/shared_state.hpp"

namespace lancet {
namespace {

using Ring8 = SpscRing<std::uint64_t, 8>;

// --- static properties ----------------------------------------------------------------------

template <class R>
constexpr bool kShmFriendly = std::is_standard_layout_v<R> && std::is_trivially_destructible_v<R> &&
                              !std::is_copy_constructible_v<R> && !std::is_move_constructible_v<R> &&
                              !std::is_copy_assignable_v<R> && !std::is_move_assignable_v<R>;

static_assert(kShmFriendly<Ring8>);
static_assert(kShmFriendly<SpscRing<ToolSample, kSampleRingCapacity>>);
static_assert(kShmFriendly<SpscRing<Command, kCommandRingCapacity>>);
static_assert(kShmFriendly<SpscRing<test::StressMessage, 4096>>);
// Indices are cache-line aligned, so the ring is too; the slots hold exactly N elements.
static_assert(alignof(Ring8) >= kCacheLine);
static_assert(sizeof(SpscRing<ToolSample, 16>) >= 16 * sizeof(ToolSample));
static_assert(Ring8::capacity() == 8 && Ring8::kCapacity == 8);
static_assert(std::is_same_v<Ring8::value_type, std::uint64_t>);

// --- basic semantics ------------------------------------------------------------------------

TEST(SpscRing, FreshRingIsEmptyAndPopFails) {
  Ring8 ring;
  std::uint64_t out = 12345;
  EXPECT_FALSE(ring.try_pop(out));
  EXPECT_EQ(out, 12345u) << "a failed pop must leave out untouched";
  std::array<std::uint64_t, 4> batch{};
  EXPECT_EQ(ring.try_pop_n(batch.data(), batch.size()), 0u);
  EXPECT_EQ(ring.size_approx(), 0u);
  EXPECT_TRUE(ring.empty_approx());
  EXPECT_EQ(ring.pushed_count(), 0u);
  EXPECT_EQ(ring.overflow_count(), 0u);
}

TEST(SpscRing, PopsInFifoOrder) {
  Ring8 ring;
  for (std::uint64_t v = 1; v <= 5; ++v) ASSERT_TRUE(ring.try_push(v * 10));
  for (std::uint64_t v = 1; v <= 5; ++v) {
    std::uint64_t out = 0;
    ASSERT_TRUE(ring.try_pop(out));
    EXPECT_EQ(out, v * 10);
  }
  std::uint64_t out = 0;
  EXPECT_FALSE(ring.try_pop(out));
}

TEST(SpscRing, HoldsExactlyNAndCountsOverflows) {
  Ring8 ring;
  for (std::uint64_t v = 0; v < 8; ++v) ASSERT_TRUE(ring.try_push(v)) << "push " << v << " of 8";
  EXPECT_EQ(ring.size_approx(), 8u);
  EXPECT_EQ(ring.pushed_count(), 8u);
  EXPECT_EQ(ring.overflow_count(), 0u);

  // Full: pushes fail, count overflows, and change nothing else.
  EXPECT_FALSE(ring.try_push(100));
  EXPECT_FALSE(ring.try_push(101));
  EXPECT_EQ(ring.overflow_count(), 2u);
  EXPECT_EQ(ring.pushed_count(), 8u);
  EXPECT_EQ(ring.size_approx(), 8u);

  // One pop makes room for exactly one push.
  std::uint64_t out = 99;
  ASSERT_TRUE(ring.try_pop(out));
  EXPECT_EQ(out, 0u);
  EXPECT_TRUE(ring.try_push(8));
  EXPECT_FALSE(ring.try_push(9));
  EXPECT_EQ(ring.overflow_count(), 3u);
  EXPECT_EQ(ring.pushed_count(), 9u);

  // The refused values never entered the ring.
  for (std::uint64_t v = 1; v <= 8; ++v) {
    ASSERT_TRUE(ring.try_pop(out));
    EXPECT_EQ(out, v);
  }
  EXPECT_FALSE(ring.try_pop(out));
}

TEST(SpscRing, MinimumCapacityTwo) {
  SpscRing<std::uint64_t, 2> ring;
  EXPECT_TRUE(ring.try_push(1));
  EXPECT_TRUE(ring.try_push(2));
  EXPECT_FALSE(ring.try_push(3));
  std::uint64_t out = 0;
  ASSERT_TRUE(ring.try_pop(out));
  EXPECT_EQ(out, 1u);
  ASSERT_TRUE(ring.try_pop(out));
  EXPECT_EQ(out, 2u);
  EXPECT_FALSE(ring.try_pop(out));
}

// The indices are free-running counters masked into the slots: run them around many times, at
// every fill level, and check order and counts on the way.
TEST(SpscRing, WrapsAroundManyLaps) {
  Ring8 ring;
  std::uint64_t next_push = 0;
  std::uint64_t next_pop = 0;
  constexpr int kLaps = 5000;
  for (int lap = 0; lap < kLaps; ++lap) {
    // Fill to a level that varies lap by lap (up to completely full) on top of any leftover.
    const std::size_t left = ring.size_approx();
    const std::size_t fill = std::min<std::size_t>(1 + static_cast<std::size_t>(lap) % 8, 8 - left);
    for (std::size_t i = 0; i < fill; ++i) ASSERT_TRUE(ring.try_push(next_push++)) << "lap " << lap;
    ASSERT_EQ(ring.size_approx(), left + fill);
    // Drain completely, or leave one behind so the next lap starts mid-ring.
    const std::size_t keep = lap % 3 == 0 ? 0 : 1;
    while (ring.size_approx() > keep) {
      std::uint64_t out = 0;
      ASSERT_TRUE(ring.try_pop(out));
      ASSERT_EQ(out, next_pop++) << "lap " << lap;
    }
  }
  std::uint64_t out = 0;
  while (ring.try_pop(out)) ASSERT_EQ(out, next_pop++);
  EXPECT_EQ(next_pop, next_push);
  EXPECT_EQ(ring.pushed_count(), next_push);
  EXPECT_GT(next_push, 8u * 1000u) << "the test must run the indices around many laps";
  EXPECT_EQ(ring.overflow_count(), 0u);
}

TEST(SpscRing, BatchPopAcrossTheWrapBoundary) {
  Ring8 ring;
  // Move the indices to slot 6 so that the next 8 elements occupy slots 6, 7, 0, 1, ..., 5.
  for (std::uint64_t v = 0; v < 6; ++v) ASSERT_TRUE(ring.try_push(v));
  std::array<std::uint64_t, 8> out{};
  ASSERT_EQ(ring.try_pop_n(out.data(), out.size()), 6u);

  for (std::uint64_t v = 100; v < 108; ++v) ASSERT_TRUE(ring.try_push(v));
  out.fill(0);
  ASSERT_EQ(ring.try_pop_n(out.data(), out.size()), 8u);
  for (std::size_t i = 0; i < 8; ++i) EXPECT_EQ(out[i], 100 + i) << "index " << i;
  EXPECT_EQ(ring.size_approx(), 0u);
}

TEST(SpscRing, BatchPopTakesAtMostMaxAndAtMostWhatIsThere) {
  Ring8 ring;
  for (std::uint64_t v = 0; v < 7; ++v) ASSERT_TRUE(ring.try_push(v));
  std::array<std::uint64_t, 16> out{};
  EXPECT_EQ(ring.try_pop_n(out.data(), 0), 0u);
  ASSERT_EQ(ring.try_pop_n(out.data(), 3), 3u);
  EXPECT_EQ(out[0], 0u);
  EXPECT_EQ(out[2], 2u);
  // Asking for more than is queued returns what is there and leaves the rest of out alone.
  out.fill(777);
  ASSERT_EQ(ring.try_pop_n(out.data(), out.size()), 4u);
  EXPECT_EQ(out[0], 3u);
  EXPECT_EQ(out[3], 6u);
  EXPECT_EQ(out[4], 777u);
  EXPECT_EQ(ring.try_pop_n(out.data(), out.size()), 0u);
}

// Batch pops of every size, started at every slot, against a reference sequence.
TEST(SpscRing, BatchPopAllSizesAndOffsets) {
  SpscRing<std::uint64_t, 16> ring;
  std::uint64_t next_push = 0;
  std::uint64_t next_pop = 0;
  std::array<std::uint64_t, 16> out{};
  for (std::size_t round = 0; round < 16; ++round) {
    for (std::size_t batch = 1; batch <= 16; ++batch) {
      while (ring.size_approx() < 16) ASSERT_TRUE(ring.try_push(next_push++));
      const std::size_t n = ring.try_pop_n(out.data(), batch);
      ASSERT_EQ(n, batch);
      for (std::size_t i = 0; i < n; ++i) ASSERT_EQ(out[i], next_pop++) << "round " << round << " batch " << batch;
    }
    // One more element through the ring: each round then advances the start slot by 137, which
    // is odd, so the 16 rounds start batches at all 16 slots.
    ASSERT_TRUE(ring.try_push(next_push++));
    std::uint64_t one = 0;
    ASSERT_TRUE(ring.try_pop(one));
    ASSERT_EQ(one, next_pop++);
  }
}

TEST(SpscRing, DiscardAllDropsTheBacklog) {
  Ring8 ring;
  EXPECT_EQ(ring.discard_all(), 0u);
  for (std::uint64_t v = 0; v < 5; ++v) ASSERT_TRUE(ring.try_push(v));
  EXPECT_EQ(ring.discard_all(), 5u);
  EXPECT_EQ(ring.size_approx(), 0u);
  std::uint64_t out = 0;
  EXPECT_FALSE(ring.try_pop(out));
  EXPECT_EQ(ring.pushed_count(), 5u) << "discarding does not rewrite history";

  // The ring keeps working after a discard, across the wrap boundary, and a full ring discards N.
  for (std::uint64_t v = 10; v < 18; ++v) ASSERT_TRUE(ring.try_push(v));
  EXPECT_FALSE(ring.try_push(18));
  EXPECT_EQ(ring.discard_all(), 8u);
  ASSERT_TRUE(ring.try_push(42));
  ASSERT_TRUE(ring.try_pop(out));
  EXPECT_EQ(out, 42u);
}

TEST(SpscRing, SizeApproxTracksPushesAndPops) {
  Ring8 ring;
  for (std::size_t i = 1; i <= 8; ++i) {
    ASSERT_TRUE(ring.try_push(i));
    EXPECT_EQ(ring.size_approx(), i);
    EXPECT_FALSE(ring.empty_approx());
  }
  std::array<std::uint64_t, 3> out{};
  ASSERT_EQ(ring.try_pop_n(out.data(), 3), 3u);
  EXPECT_EQ(ring.size_approx(), 5u);
  ring.discard_all();
  EXPECT_EQ(ring.size_approx(), 0u);
  EXPECT_TRUE(ring.empty_approx());
}

// The real message type: every byte survives the trip, including the payload of events.
TEST(SpscRing, CarriesToolSamplesBitExact) {
  auto ring = std::make_unique<SpscRing<ToolSample, 64>>();
  std::vector<ToolSample> sent;
  for (std::uint64_t i = 0; i < 100; ++i) {
    ToolSample s{};
    s.seq = i;
    s.t_ns = static_cast<std::int64_t>(i * 1'000'000);
    s.n_joints = 6;
    s.mode = ToolMode::kScalpel;
    s.stage = Stage::kCutting;
    for (std::uint32_t j = 0; j < kMaxJoints; ++j) {
      s.q[j] = 0.1 * static_cast<double>(i + j);
      s.qd[j] = -0.2 * static_cast<double>(j);
      s.tau[j] = 1e-3 * static_cast<double>(i * j);
    }
    s.tool.position = {0.01 * static_cast<double>(i), 0.02, 0.03};
    s.force = {1.0, -2.0, static_cast<double>(i)};
    s.events = event::kRupture | event::kContactBegin;
    s.payload.magnitude = 3.5;
    sent.push_back(s);
  }
  std::size_t popped = 0;
  std::uint64_t refused = 0;
  for (const ToolSample& s : sent) {
    if (!ring->try_push(s)) {
      ++refused;
      // Drain half when full, checking what comes out.
      std::array<ToolSample, 32> out{};
      const std::size_t n = ring->try_pop_n(out.data(), out.size());
      for (std::size_t k = 0; k < n; ++k, ++popped) {
        ASSERT_EQ(std::memcmp(&out[k], &sent[popped], sizeof(ToolSample)), 0) << "sample " << popped;
      }
      ASSERT_TRUE(ring->try_push(s));
    }
  }
  ToolSample out{};
  while (ring->try_pop(out)) {
    ASSERT_EQ(std::memcmp(&out, &sent[popped], sizeof(ToolSample)), 0) << "sample " << popped;
    ++popped;
  }
  EXPECT_EQ(popped, sent.size());
  EXPECT_EQ(refused, 2u) << "100 samples through 64 slots, drained 32 at a time";
  EXPECT_EQ(ring->overflow_count(), refused);
}

// A corrupted peer: anything with write access to the segment may write any index. Each side
// checks the other's index, resets its own, counts it, and never reads more than N slots.
template <class Ring>
void poke(Ring& r, std::size_t offset, std::uint64_t v) {
  std::memcpy(reinterpret_cast<unsigned char*>(&r) + offset, &v, sizeof v);
}

TEST(SpscRingCorruptPeer, AHeadFarAheadIsResetNotReadAndTheRingWorksOn) {
  SpscRing<std::uint64_t, 8> ring;
  for (std::uint64_t v = 1; v <= 3; ++v) ASSERT_TRUE(ring.try_push(v));
  poke(ring, ring.head_offset(), 0x7fffffffffff1234ull);  // the attacker's eight bytes
  std::array<std::uint64_t, 64> out{};
  bool reset = false;
  for (int i = 0; i < 3; ++i) EXPECT_EQ(ring.try_pop_n(out.data(), out.size(), &reset), 0u) << "nothing read from garbage";
  EXPECT_TRUE(reset);
  EXPECT_EQ(ring.consumer_resets(), 1u) << "reset once, then consistent";
  // The producer goes on from its (garbage) index; consumer and producer agree again.
  ASSERT_TRUE(ring.try_push(42));
  ASSERT_EQ(ring.try_pop_n(out.data(), out.size()), 1u);
  EXPECT_EQ(out[0], 42u);
}

TEST(SpscRingCorruptPeer, AHeadBehindTailIsResetToo) {
  SpscRing<std::uint64_t, 8> ring;
  for (std::uint64_t v = 1; v <= 5; ++v) ASSERT_TRUE(ring.try_push(v));
  std::uint64_t x = 0;
  ASSERT_TRUE(ring.try_pop(x));
  ASSERT_TRUE(ring.try_pop(x));
  poke(ring, ring.head_offset(), 1);  // behind tail (2)
  bool reset = false;
  std::array<std::uint64_t, 8> out{};
  EXPECT_EQ(ring.try_pop_n(out.data(), out.size(), &reset), 0u);
  EXPECT_TRUE(reset);
  EXPECT_EQ(ring.size_approx(), 0u);
}

TEST(SpscRingCorruptPeer, AHeadWithinCapacityIsDrainedBoundedByN) {
  SpscRing<std::uint64_t, 8> ring;
  ASSERT_TRUE(ring.try_push(1));
  poke(ring, ring.head_offset(), 8);  // tail 0, head 8: a full ring of stale slots, plausible
  std::array<std::uint64_t, 64> out{};
  EXPECT_EQ(ring.try_pop_n(out.data(), out.size()), 8u) << "at most N";
  EXPECT_EQ(ring.try_pop_n(out.data(), out.size()), 0u);
}

TEST(SpscRingCorruptPeer, AGarbageTailMakesTheProducerRestartFromIt) {
  SpscRing<std::uint64_t, 8> ring;
  for (std::uint64_t v = 0; v < 8; ++v) ASSERT_TRUE(ring.try_push(v));
  EXPECT_FALSE(ring.try_push(99)) << "full";
  poke(ring, ring.tail_offset(), 0x5555555555555555ull);
  bool reset = false;
  EXPECT_TRUE(ring.try_push(7, &reset)) << "the producer restarts from the consumer's index and pushes";
  EXPECT_TRUE(reset);
  EXPECT_EQ(ring.producer_resets(), 1u);
  EXPECT_EQ(ring.overflow_count(), 1u);
  std::uint64_t x = 0;
  ASSERT_TRUE(ring.try_pop(x));
  EXPECT_EQ(x, 7u);
  EXPECT_FALSE(ring.try_pop(x));
}

TEST(SpscRingCorruptPeer, DiscardAllOnAGarbageHeadResetsAndReturnsZero) {
  SpscRing<std::uint64_t, 8> ring;
  ASSERT_TRUE(ring.try_push(1));
  poke(ring, ring.head_offset(), ~0ull - 3);
  bool reset = false;
  EXPECT_EQ(ring.discard_all(&reset), 0u);
  EXPECT_TRUE(reset);
  EXPECT_EQ(ring.size_approx(), 0u);
}

TEST(SpscRingCorruptPeer, RandomIndicesNeverYieldMoreThanNAndAlwaysRecover) {
  SpscRing<std::uint64_t, 16> ring;
  std::uint64_t state = 12345;
  auto next = [&] {
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    return state;
  };
  std::array<std::uint64_t, 64> out{};
  for (int round = 0; round < 10'000; ++round) {
    poke(ring, next() % 2 == 0 ? ring.head_offset() : ring.tail_offset(), next() >> (next() % 64));
    for (int k = 0; k < 3; ++k) (void)ring.try_push(static_cast<std::uint64_t>(round));
    const std::size_t n = ring.try_pop_n(out.data(), out.size());
    ASSERT_LE(n, 16u);
    // After one more push and pop the pair is consistent again: what is pushed comes out.
    (void)ring.try_pop_n(out.data(), out.size());
    ASSERT_TRUE(ring.try_push(1'000'000u + static_cast<std::uint64_t>(round)) || ring.size_approx() == 16u);
    std::size_t got = ring.try_pop_n(out.data(), out.size());
    ASSERT_GE(got, 1u) << "round " << round;
    ASSERT_EQ(out[got - 1], 1'000'000u + static_cast<std::uint64_t>(round)) << "round " << round;
  }
}

}  // namespace
}  // namespace lancet
