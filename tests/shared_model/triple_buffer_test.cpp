// TripleBuffer<T>, one thread (and a waiter): empty state, round trips, versions, prefixes, the
// doorbell, and garbage in the segment. Concurrent writer and readers: seqlock_torn_read_test.cpp.

#include "lancet/shared_model/triple_buffer.hpp"

#include <gtest/gtest.h>

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <memory>
#include <random>
#include <thread>
#include <type_traits>

#include "lancet/shared_model/messages.hpp"
#include "wait.hpp"

namespace lancet {
namespace {

struct Value {
  std::uint64_t n;       ///< how many items follow
  std::uint64_t item[63];
};
std::size_t used_bytes(const Value& v) { return offsetof(Value, item) + std::min<std::uint64_t>(v.n, 63) * 8; }

Value make(std::uint64_t n, std::uint64_t seed) {
  Value v{};
  v.n = n;
  for (std::uint64_t i = 0; i < 63; ++i) v.item[i] = i < n ? seed * 1000 + i : 0xdead;
  return v;
}

// It lives in shared memory: no destructor work, no pointers, standard layout.
static_assert(std::is_standard_layout_v<TripleBuffer<Value>>);
static_assert(std::is_trivially_destructible_v<TripleBuffer<TissuePatch>>);
static_assert(!std::is_copy_constructible_v<TripleBuffer<Value>>);

TEST(TripleBuffer, EmptyReadsSayEmptyAndLeaveTheOutputAlone) {
  TripleBuffer<Value> b;
  Value out = make(3, 9);
  std::uint64_t seen = 0;
  EXPECT_EQ(b.try_read_if_newer(out, seen), ReadStatus::kEmpty);
  EXPECT_EQ(b.try_read(out), ReadStatus::kEmpty);
  EXPECT_EQ(b.try_peek(out), ReadStatus::kEmpty);
  EXPECT_EQ(out.item[0], 9000u);
  EXPECT_EQ(b.version(), 0u);
}

TEST(TripleBuffer, EveryPublishIsReadWholeOnceThenUnchanged) {
  TripleBuffer<Value> b;
  std::uint64_t seen = 0;
  for (std::uint64_t k = 1; k <= 10; ++k) {
    b.publish(make(k, k));
    EXPECT_EQ(b.version(), k);
    Value out{};
    ASSERT_EQ(b.try_read_if_newer(out, seen), ReadStatus::kOk);
    EXPECT_EQ(seen, k);
    const Value want = make(k, k);
    EXPECT_EQ(std::memcmp(&out, &want, sizeof(Value)), 0) << "publish " << k;
    EXPECT_EQ(b.try_read_if_newer(out, seen), ReadStatus::kUnchanged);
    Value peeked{};
    ASSERT_EQ(b.try_peek(peeked), ReadStatus::kOk);
    EXPECT_EQ(peeked.item[0], k * 1000);
  }
}

TEST(TripleBuffer, OnlyTheNewestOfSeveralPublishesIsRead) {
  TripleBuffer<Value> b;
  for (std::uint64_t k = 1; k <= 5; ++k) b.publish(make(4, k));
  Value out{};
  std::uint64_t seen = 0;
  ASSERT_EQ(b.try_read_if_newer(out, seen), ReadStatus::kOk);
  EXPECT_EQ(seen, 5u);
  EXPECT_EQ(out.item[3], 5003u);
}

TEST(TripleBuffer, APrefixReadCopiesOnlyTheExtentAndLeavesTheRestAlone) {
  TripleBuffer<Value> b;
  b.publish_prefix(make(5, 7), used_bytes(make(5, 7)));
  Value out = make(63, 1);  // every item set: the ones past 5 must survive
  std::uint64_t seen = 0;
  ASSERT_EQ(b.try_read_prefix_if_newer(out, seen, offsetof(Value, item), used_bytes), ReadStatus::kOk);
  EXPECT_EQ(out.n, 5u);
  EXPECT_EQ(out.item[4], 7004u);
  EXPECT_EQ(out.item[5], 1005u) << "a byte past the extent was copied";
  // A header claiming more than the value holds is capped by the extent function.
  Value big = make(5, 8);
  big.n = 1'000'000;
  b.publish_prefix(big, sizeof(Value));
  ASSERT_EQ(b.try_read_prefix_if_newer(out, seen, offsetof(Value, item), used_bytes), ReadStatus::kOk);
  EXPECT_EQ(out.item[62], 0xdeadu);
}

TEST(TripleBuffer, WaitNewerReturnsAtOnceForAPublishAlreadyThereAndWakesForTheNext) {
  TripleBuffer<Value> b;
  b.publish(make(1, 1));
  EXPECT_TRUE(b.wait_newer(0, 1'000'000'000)) << "version 1 is newer than 0: no wait";
  EXPECT_FALSE(b.wait_newer(1, 1'000'000)) << "nothing newer than 1: the wait times out";
  std::atomic<bool> waiting{false}, woke{false};
  std::thread waiter([&] {
    waiting.store(true);
    woke.store(b.wait_newer(1, std::chrono::nanoseconds(test::kHangTimeout).count()));
  });
  ASSERT_TRUE(test::eventually([&] { return waiting.load(); }));
  b.publish(make(1, 2));
  waiter.join();
  EXPECT_TRUE(woke.load()) << "the publish did not end the wait";
}

// Anything may be in the segment: reads never crash, loop or return a torn value, and the next
// honest publish is read.
TEST(TripleBuffer, GarbageInTheSegmentIsSurvivedAndTheNextPublishIsRead) {
  std::mt19937_64 rng(23);
  auto b = std::make_unique<TripleBuffer<Value>>();
  for (int round = 0; round < 200; ++round) {
    b->publish(make(10, static_cast<std::uint64_t>(round)));
    auto* bytes = reinterpret_cast<unsigned char*>(b.get());
    // Scribble on the control words (the first cache lines) and on a few random bytes.
    for (int i = 0; i < 24; ++i) bytes[rng() % (round % 2 == 0 ? 256 : sizeof(*b))] = static_cast<unsigned char>(rng());
    Value out{};
    std::uint64_t seen = rng() % 4;
    (void)b->try_read_if_newer(out, seen, 4);
    (void)b->try_peek(out);
    (void)b->wait_newer(seen, 1000);
    // An honest writer publishes again: whatever was scribbled, the reader gets it whole.
    b->publish(make(10, 5000 + static_cast<std::uint64_t>(round)));
    seen = ~std::uint64_t{0};
    ASSERT_EQ(b->try_read_if_newer(out, seen), ReadStatus::kOk) << "round " << round;
    EXPECT_EQ(out.item[9], (5000 + static_cast<std::uint64_t>(round)) * 1000 + 9) << "round " << round;
  }
}

}  // namespace
}  // namespace lancet
