#include "rt/latency_histogram.hpp"

#include <algorithm>
#include <cmath>

namespace lancet::rt {

std::uint64_t nearest_rank(double p, std::uint64_t count) noexcept {
  const double x = std::clamp(p, 0.0, 100.0) / 100.0 * static_cast<double>(count);
  return std::max<std::uint64_t>(1, static_cast<std::uint64_t>(std::ceil(x - 1e-9 * std::max(1.0, x))));
}

void LatencyHistogram::merge(const LatencyHistogram& o) noexcept {
  if (o.count_ == 0) return;
  for (std::size_t i = 0; i < kBuckets; ++i) buckets_[i] += o.buckets_[i];
  min_ = count_ ? std::min(min_, o.min_) : o.min_;
  max_ = std::max(max_, o.max_);
  count_ += o.count_;
  sum_ += o.sum_;
}

std::int64_t LatencyHistogram::percentile_ns(double p) const noexcept {
  if (count_ == 0) return 0;
  const std::uint64_t rank = nearest_rank(p, count_);
  std::uint64_t cumulative = 0;
  for (std::size_t i = 0; i < kBuckets; ++i) {
    cumulative += buckets_[i];
    // In the unbounded overflow bucket the value is only known to lie in [1 s, max]: report max.
    if (cumulative >= rank) return i == kOverflowBucket ? max_ : std::clamp(bucket_lower_ns(i), min_, max_);
  }
  return max_;
}

}  // namespace lancet::rt
