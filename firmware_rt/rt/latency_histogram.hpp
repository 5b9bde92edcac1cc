#pragma once
// LatencyHistogram: a fixed-size log-linear histogram of durations, recorded on the real-time
// path without allocation.
//
// Buckets (ns → width):  [0, 1 ms) by 1 µs · [1, 10 ms) by 10 µs · [10, 100 ms) by 100 µs ·
// [100 ms, 1 s) by 1 ms · one overflow bucket for ≥ 1 s. 3701 buckets, about 30 KB.
// Exact min, max, count and sum are kept beside the buckets.

#include <array>
#include <cstddef>
#include <cstdint>

namespace lancet::rt {

/// Nearest rank (1-based) of percentile p (0..100) among count samples: ceil(p/100·count), at
/// least 1. A tolerance keeps 96.7 % of 2000 at rank 1934 although the product rounds to
/// 1934.0000000000002 in floating point.
std::uint64_t nearest_rank(double p, std::uint64_t count) noexcept;

class LatencyHistogram {
 public:
  static constexpr std::size_t kBuckets = 1000 + 900 + 900 + 900 + 1;
  static constexpr std::size_t kOverflowBucket = kBuckets - 1;

  /// Records one duration; negative values count as 0. Real-time safe, O(1).
  void record(std::int64_t ns) noexcept {
    if (ns < 0) ns = 0;
    ++buckets_[bucket_of(ns)];
    ++count_;
    sum_ += static_cast<double>(ns);
    if (count_ == 1 || ns < min_) min_ = ns;
    if (ns > max_) max_ = ns;
  }
  /// Adds other's counts to this one.
  void merge(const LatencyHistogram& other) noexcept;
  void reset() noexcept { *this = LatencyHistogram{}; }

  [[nodiscard]] std::uint64_t count() const noexcept { return count_; }
  [[nodiscard]] std::int64_t min_ns() const noexcept { return count_ ? min_ : 0; }
  [[nodiscard]] std::int64_t max_ns() const noexcept { return max_; }
  [[nodiscard]] double mean_ns() const noexcept { return count_ ? sum_ / static_cast<double>(count_) : 0.0; }
  /// Nearest-rank percentile (p in [0, 100]): the lower edge of the bucket holding the value of
  /// rank ceil(p/100·count), clamped to [min, max]; exact to within that bucket's width. A rank in
  /// the overflow bucket (≥ 1 s) returns max, an upper bound. O(kBuckets).
  [[nodiscard]] std::int64_t percentile_ns(double p) const noexcept;

  [[nodiscard]] std::uint64_t bucket_count(std::size_t i) const noexcept { return buckets_[i]; }
  /// Bucket index of a duration (ns ≥ 0).
  static constexpr std::size_t bucket_of(std::int64_t ns) noexcept {
    if (ns < 1'000'000) return static_cast<std::size_t>(ns / 1'000);
    if (ns < 10'000'000) return 1000 + static_cast<std::size_t>((ns - 1'000'000) / 10'000);
    if (ns < 100'000'000) return 1900 + static_cast<std::size_t>((ns - 10'000'000) / 100'000);
    if (ns < 1'000'000'000) return 2800 + static_cast<std::size_t>((ns - 100'000'000) / 1'000'000);
    return kOverflowBucket;
  }
  /// Lower edge of bucket i (ns).
  static constexpr std::int64_t bucket_lower_ns(std::size_t i) noexcept {
    const auto k = static_cast<std::int64_t>(i);
    if (i < 1000) return k * 1'000;
    if (i < 1900) return 1'000'000 + (k - 1000) * 10'000;
    if (i < 2800) return 10'000'000 + (k - 1900) * 100'000;
    if (i < 3700) return 100'000'000 + (k - 2800) * 1'000'000;
    return 1'000'000'000;
  }
  /// Width of bucket i (ns); the overflow bucket reports 0 (unbounded).
  static constexpr std::int64_t bucket_width_ns(std::size_t i) noexcept {
    return i < 1000 ? 1'000 : i < 1900 ? 10'000 : i < 2800 ? 100'000 : i < 3700 ? 1'000'000 : 0;
  }

 private:
  std::array<std::uint64_t, kBuckets> buckets_{};
  std::uint64_t count_ = 0;
  double sum_ = 0;
  std::int64_t min_ = 0;
  std::int64_t max_ = 0;
};

}  // namespace lancet::rt
