#include "rt/latency_histogram.hpp"

#include <algorithm>
#include <cmath>

namespace lancet::rt {

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
  p = std::clamp(p, 0.0, 100.0);
  const auto rank = std::max<std::uint64_t>(1, static_cast<std::uint64_t>(std::ceil(p / 100.0 * static_cast<double>(count_))));
  std::uint64_t cumulative = 0;
  for (std::size_t i = 0; i < kBuckets; ++i) {
    cumulative += buckets_[i];
    // In the unbounded overflow bucket the value is only known to lie in [1 s, max]: report max.
    if (cumulative >= rank) return i == kOverflowBucket ? max_ : std::clamp(bucket_lower_ns(i), min_, max_);
  }
  return max_;
}

}  // namespace lancet::rt
