#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "rt/distribution.hpp"
#include "rt/latency_histogram.hpp"
#include "rt/watchdog.hpp"

namespace lancet::rt {
namespace {

// Nearest-rank percentile of a sorted array (the rank itself is pinned by NearestRank tests).
std::int64_t exact(const std::vector<std::int64_t>& sorted, double p) {
  return sorted[nearest_rank(p, sorted.size()) - 1];
}

void check_against_sorted(std::vector<std::int64_t> values) {
  LatencyHistogram h;
  for (auto v : values) h.record(v);
  std::sort(values.begin(), values.end());
  ASSERT_EQ(h.count(), values.size());
  EXPECT_EQ(h.min_ns(), values.front());
  EXPECT_EQ(h.max_ns(), values.back());
  for (double p : {0.0, 1.0, 10.0, 50.0, 90.0, 99.0, 99.9, 99.99, 100.0}) {
    const std::int64_t e = exact(values, p);
    const std::int64_t got = h.percentile_ns(p);
    const std::size_t b = LatencyHistogram::bucket_of(e);
    // Same bucket as the exact value: off by less than that bucket's width.
    EXPECT_EQ(LatencyHistogram::bucket_of(got), b) << "p" << p << ": exact " << e << " got " << got;
    if (b == LatencyHistogram::kOverflowBucket) {
      EXPECT_EQ(got, values.back()) << "p" << p << ": beyond 1 s the histogram reports the max";
    } else {
      EXPECT_LE(std::llabs(got - e), LatencyHistogram::bucket_width_ns(b)) << "p" << p;
    }
  }
  // The reporting Distribution agrees with the histogram.
  const Distribution d = to_distribution(h, "t");
  for (double p : kReportPercentiles) {
    EXPECT_NEAR(d.percentile_us(p), static_cast<double>(h.percentile_ns(p)) / 1e3, 1e-9) << "p" << p;
  }
}

TEST(LatencyHistogram, PercentilesMatchASortedArray) {
  std::mt19937_64 rng(42);
  {
    std::uniform_int_distribution<std::int64_t> u(0, 2'000'000);  // 0–2 ms
    std::vector<std::int64_t> v(100'000);
    for (auto& x : v) x = u(rng);
    check_against_sorted(v);
  }
  {
    std::exponential_distribution<double> e(1.0 / 30'000.0);  // mean 30 µs, a long tail
    std::vector<std::int64_t> v(200'000);
    for (auto& x : v) x = static_cast<std::int64_t>(e(rng));
    check_against_sorted(v);
  }
  {
    std::lognormal_distribution<double> ln(11.0, 2.5);  // spans µs to seconds, overflow included
    std::vector<std::int64_t> v(50'000);
    for (auto& x : v) x = static_cast<std::int64_t>(ln(rng));
    check_against_sorted(v);
  }
  check_against_sorted({5});
}

TEST(LatencyHistogram, NearestRankIsExactAtBoundaries) {
  EXPECT_EQ(nearest_rank(96.7, 2000), 1934u);  // 96.7/100*2000 is 1934.0000000000002 in doubles
  EXPECT_EQ(nearest_rank(50, 2), 1u);
  EXPECT_EQ(nearest_rank(50.1, 2), 2u);
  EXPECT_EQ(nearest_rank(0, 10), 1u);
  EXPECT_EQ(nearest_rank(100, 10), 10u);
  EXPECT_EQ(nearest_rank(99.99, 10000), 9999u);
}

TEST(LatencyHistogram, BucketEdgesAreContiguous) {
  for (std::size_t i = 0; i + 1 < LatencyHistogram::kOverflowBucket; ++i) {
    ASSERT_EQ(LatencyHistogram::bucket_lower_ns(i) + LatencyHistogram::bucket_width_ns(i),
              LatencyHistogram::bucket_lower_ns(i + 1)) << i;
    ASSERT_EQ(LatencyHistogram::bucket_of(LatencyHistogram::bucket_lower_ns(i)), i);
    ASSERT_EQ(LatencyHistogram::bucket_of(LatencyHistogram::bucket_lower_ns(i + 1) - 1), i);
  }
  EXPECT_EQ(LatencyHistogram::bucket_of(999), 0u);
  EXPECT_EQ(LatencyHistogram::bucket_of(999'999), 999u);
  EXPECT_EQ(LatencyHistogram::bucket_of(1'000'000), 1000u);
  EXPECT_EQ(LatencyHistogram::bucket_of(5'000'000'000), LatencyHistogram::kOverflowBucket);
}

TEST(LatencyHistogram, MergeEqualsRecordingEverything) {
  LatencyHistogram a, b, all;
  for (std::int64_t v = 0; v < 3'000'000; v += 7'919) {
    ((v / 7'919) % 2 ? a : b).record(v);
    all.record(v);
  }
  a.merge(b);
  EXPECT_EQ(a.count(), all.count());
  EXPECT_EQ(a.min_ns(), all.min_ns());
  EXPECT_EQ(a.max_ns(), all.max_ns());
  EXPECT_DOUBLE_EQ(a.mean_ns(), all.mean_ns());
  for (double p : kReportPercentiles) EXPECT_EQ(a.percentile_ns(p), all.percentile_ns(p));
}

TEST(LatencyHistogram, EmptyAndNegative) {
  LatencyHistogram h;
  EXPECT_EQ(h.percentile_ns(99), 0);
  h.record(-50);  // a clock that went backwards counts as zero latency
  EXPECT_EQ(h.min_ns(), 0);
  EXPECT_EQ(h.percentile_ns(50), 0);
}

TEST(Watchdog, TripsOnConsecutiveMissesOrBudgetAndNeedsReArm) {
  WatchdogParams p;
  p.max_consecutive_misses = 3;
  Watchdog w;
  EXPECT_FALSE(w.observe(p, true, 0));
  EXPECT_FALSE(w.observe(p, true, 0));
  EXPECT_FALSE(w.observe(p, false, 0));  // the run of misses is broken
  EXPECT_FALSE(w.observe(p, true, 0));
  EXPECT_FALSE(w.observe(p, true, 0));
  EXPECT_TRUE(w.observe(p, true, 0));
  EXPECT_TRUE(w.tripped());
  EXPECT_EQ(w.reason(), Watchdog::Reason::kConsecutiveMisses);
  // Good ticks do not clear it.
  for (int i = 0; i < 100; ++i) EXPECT_FALSE(w.observe(p, false, 0));
  EXPECT_TRUE(w.tripped());
  w.rearm();
  EXPECT_FALSE(w.tripped());
  p.tick_budget_ns = 500'000;
  EXPECT_FALSE(w.observe(p, false, 499'999));
  EXPECT_TRUE(w.observe(p, false, 500'001));
  EXPECT_EQ(w.reason(), Watchdog::Reason::kTickOverBudget);
  EXPECT_EQ(w.trips(), 2u);
}

TEST(Watchdog, OffByDefault) {
  Watchdog w;
  for (int i = 0; i < 1000; ++i) EXPECT_FALSE(w.observe({}, true, 1'000'000'000));
  EXPECT_FALSE(w.tripped());
}

}  // namespace
}  // namespace lancet::rt
