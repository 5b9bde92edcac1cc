// Seqlock<T>, single thread: empty state, round trips, versions, try_read_if_newer, payloads
// whose size is not a multiple of the 8-byte word, and the real (48 KB) TissuePatch.
// Concurrent readers and writers: seqlock_torn_read_test.cpp.

#include "lancet/shared_model/seqlock.hpp"

#include <gtest/gtest.h>

#include <array>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <memory>
#include <type_traits>

#include "lancet/shared_model/messages.hpp"

namespace lancet {
namespace {

struct Small {
  std::uint64_t a;
  double b;
  std::int32_t c;
  std::uint32_t d;
};

template <std::size_t Bytes>
struct Blob {
  unsigned char b[Bytes];
};

template <class T>
T pattern(unsigned seed) {
  T v;
  auto* p = reinterpret_cast<unsigned char*>(&v);
  for (std::size_t i = 0; i < sizeof(T); ++i) p[i] = static_cast<unsigned char>(seed * 131u + i * 7u + 1u);
  return v;
}

template <class T>
bool same_bytes(const T& a, const T& b) {
  return std::memcmp(&a, &b, sizeof(T)) == 0;
}

// A seqlock lives in shared memory: no destructor work, no pointers, standard layout.
static_assert(std::is_standard_layout_v<Seqlock<Small>>);
static_assert(std::is_trivially_destructible_v<Seqlock<Small>>);
static_assert(std::is_trivially_destructible_v<Seqlock<TissuePatch>>);
static_assert(!std::is_copy_constructible_v<Seqlock<Small>>);
static_assert(sizeof(Seqlock<Blob<13>>) >= 13);

TEST(Seqlock, EmptyReadReturnsEmptyAndLeavesOutAlone) {
  Seqlock<Small> lock;
  Small out{7, 8.0, 9, 10};
  EXPECT_EQ(lock.try_read(out), ReadStatus::kEmpty);
  EXPECT_EQ(out.a, 7u);
  EXPECT_EQ(out.c, 9);
  EXPECT_EQ(lock.version(), 0u);

  std::uint64_t seen = 0;
  EXPECT_EQ(lock.try_read_if_newer(out, seen), ReadStatus::kEmpty);
  EXPECT_EQ(seen, 0u);
  EXPECT_EQ(out.a, 7u);
}

TEST(Seqlock, WriteThenReadRoundTrips) {
  Seqlock<Small> lock;
  const Small in{0x0123456789abcdefull, -2.5, -42, 0xdeadbeefu};
  lock.write(in);
  Small out{};
  ASSERT_EQ(lock.try_read(out), ReadStatus::kOk);
  EXPECT_EQ(out.a, in.a);
  EXPECT_EQ(out.b, in.b);
  EXPECT_EQ(out.c, in.c);
  EXPECT_EQ(out.d, in.d);
  // Reading does not consume: the value stays until the next write.
  Small again{};
  ASSERT_EQ(lock.try_read(again), ReadStatus::kOk);
  EXPECT_TRUE(same_bytes(again, in));
}

TEST(Seqlock, LatestWriteWins) {
  Seqlock<Small> lock;
  for (std::uint64_t i = 1; i <= 10; ++i) lock.write(Small{i, 0.0, 0, 0});
  Small out{};
  ASSERT_EQ(lock.try_read(out), ReadStatus::kOk);
  EXPECT_EQ(out.a, 10u);
}

TEST(Seqlock, VersionCountsCompletedWrites) {
  Seqlock<Small> lock;
  EXPECT_EQ(lock.version(), 0u);
  for (std::uint64_t i = 1; i <= 5; ++i) {
    lock.write(Small{i, 0.0, 0, 0});
    EXPECT_EQ(lock.version(), i);
  }
}

TEST(Seqlock, TryReadIfNewerReportsUnchangedUntilTheNextWrite) {
  Seqlock<Small> lock;
  std::uint64_t seen = 0;
  Small out{};

  lock.write(Small{1, 1.0, 1, 1});
  ASSERT_EQ(lock.try_read_if_newer(out, seen), ReadStatus::kOk);
  EXPECT_EQ(seen, 1u);
  EXPECT_EQ(out.a, 1u);

  out.a = 999;
  EXPECT_EQ(lock.try_read_if_newer(out, seen), ReadStatus::kUnchanged);
  EXPECT_EQ(lock.try_read_if_newer(out, seen), ReadStatus::kUnchanged);
  EXPECT_EQ(out.a, 999u) << "kUnchanged must not copy";
  EXPECT_EQ(seen, 1u);

  // Two writes in between: the reader skips straight to the latest and its version.
  lock.write(Small{2, 2.0, 2, 2});
  lock.write(Small{3, 3.0, 3, 3});
  ASSERT_EQ(lock.try_read_if_newer(out, seen), ReadStatus::kOk);
  EXPECT_EQ(seen, 3u);
  EXPECT_EQ(out.a, 3u);
  EXPECT_EQ(lock.try_read_if_newer(out, seen), ReadStatus::kUnchanged);

  // A reader that starts from an older version (or from 0) gets the current value.
  std::uint64_t fresh = 0;
  Small other{};
  ASSERT_EQ(lock.try_read_if_newer(other, fresh), ReadStatus::kOk);
  EXPECT_EQ(fresh, 3u);
  EXPECT_EQ(other.a, 3u);
}

// sizeof(T) not a multiple of 8: the tail word carries the last bytes and nothing is written
// past the end of out.
template <class T>
class SeqlockOddSize : public ::testing::Test {};
using OddSizes = ::testing::Types<Blob<1>, Blob<7>, Blob<9>, Blob<13>, Blob<63>, Blob<517>>;
TYPED_TEST_SUITE(SeqlockOddSize, OddSizes);

TYPED_TEST(SeqlockOddSize, RoundTripsWithoutTouchingBytesPastTheEnd) {
  using T = TypeParam;
  static_assert(sizeof(T) % 8 != 0);
  Seqlock<T> lock;
  for (unsigned seed = 1; seed <= 3; ++seed) {
    const T in = pattern<T>(seed);
    lock.write(in);
    // out sits between two guard areas: a read must fill exactly sizeof(T) bytes.
    struct Guarded {
      unsigned char before[16];
      T value;
      unsigned char after[16];
    } g;
    std::memset(&g, 0xa5, sizeof g);
    ASSERT_EQ(lock.try_read(g.value), ReadStatus::kOk);
    EXPECT_TRUE(same_bytes(g.value, in)) << "seed " << seed << ", " << sizeof(T) << " bytes";
    for (unsigned char c : g.before) ASSERT_EQ(c, 0xa5);
    for (unsigned char c : g.after) ASSERT_EQ(c, 0xa5);
  }
  EXPECT_EQ(lock.version(), 3u);
}

TEST(Seqlock, TissuePatchRoundTrips) {
  static_assert(sizeof(TissuePatch) > 700000, "TissuePatch is the large seqlock payload");
  auto lock = std::make_unique<Seqlock<TissuePatch>>();
  auto in = std::make_unique<TissuePatch>(pattern<TissuePatch>(5));
  auto out = std::make_unique<TissuePatch>();
  EXPECT_EQ(lock->try_read(*out), ReadStatus::kEmpty);
  lock->write(*in);
  ASSERT_EQ(lock->try_read(*out), ReadStatus::kOk);
  EXPECT_TRUE(same_bytes(*out, *in));
  EXPECT_EQ(lock->version(), 1u);
}

// A patch crosses the segment by the triangles in use only: the reader copies the header, reads
// n_triangles from it, and copies that many; nothing past them is read or written.
TEST(Seqlock, PatchPrefixCopiesOnlyTheTrianglesInUse) {
  auto lock = std::make_unique<Seqlock<TissuePatch>>();
  auto in = std::make_unique<TissuePatch>(pattern<TissuePatch>(7));
  in->n_triangles = 37;
  auto out = std::make_unique<TissuePatch>();
  std::memset(static_cast<void*>(out.get()), 0x5a, sizeof(TissuePatch));
  const auto extent = [](const TissuePatch& p) { return tissue_patch_bytes(p); };
  std::uint64_t seen = 0;
  EXPECT_EQ(lock->try_read_prefix_if_newer(*out, seen, offsetof(TissuePatch, triangles), extent), ReadStatus::kEmpty);
  lock->write_prefix(*in, tissue_patch_bytes(*in));
  ASSERT_EQ(lock->try_read_prefix_if_newer(*out, seen, offsetof(TissuePatch, triangles), extent), ReadStatus::kOk);
  EXPECT_EQ(seen, 1u);
  const std::size_t used = tissue_patch_bytes(*in);
  EXPECT_EQ(used, offsetof(TissuePatch, triangles) + 37 * sizeof(PatchTriangle));
  EXPECT_EQ(std::memcmp(out.get(), in.get(), used), 0) << "the header, the brick and the 37 triangles arrive";
  const auto* tail = reinterpret_cast<const unsigned char*>(out.get());
  // Past the last word the writer wrote (the extent rounds up to whole words), the reader's bytes stay.
  for (std::size_t i = (used + 7) / 8 * 8; i < sizeof(TissuePatch); ++i) ASSERT_EQ(tail[i], 0x5a) << "byte " << i << " was copied";
  EXPECT_EQ(lock->try_read_prefix_if_newer(*out, seen, offsetof(TissuePatch, triangles), extent), ReadStatus::kUnchanged);

  // A header claiming more than the capacity is capped: the copy stops at the end of the value.
  in->n_triangles = 0xffffffffu;
  lock->write(*in);
  ASSERT_EQ(lock->try_read_prefix_if_newer(*out, seen, offsetof(TissuePatch, triangles), extent), ReadStatus::kOk);
  EXPECT_TRUE(same_bytes(*out, *in));
  EXPECT_EQ(tissue_patch_bytes(*in), sizeof(TissuePatch));
}

TEST(Seqlock, AnOddCounterLeftByACorruptPeerIsHealedByTheNextWrite) {
  Seqlock<std::uint64_t> lock;
  lock.write(1);
  // Someone wrote an odd value into the counter: readers would see a write in progress forever.
  const std::uint64_t odd = 7;
  std::memcpy(reinterpret_cast<unsigned char*>(&lock), &odd, sizeof odd);
  std::uint64_t v = 0;
  EXPECT_EQ(lock.try_read(v, 8), ReadStatus::kBusy) << "bounded: gives up instead of spinning";
  lock.write(2);
  EXPECT_EQ(lock.try_read(v), ReadStatus::kOk);
  EXPECT_EQ(v, 2u);
}

}  // namespace
}  // namespace lancet
