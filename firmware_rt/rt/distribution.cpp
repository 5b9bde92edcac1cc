#include "rt/distribution.hpp"

#include <algorithm>
#include <cmath>

namespace lancet::rt {

double Distribution::percentile_us(double p) const {
  if (count == 0) return 0;
  const std::uint64_t rank = nearest_rank(p, count);
  std::uint64_t cumulative = 0;
  for (const auto& [edge, n] : buckets) {
    cumulative += n;
    if (cumulative >= rank) return std::clamp(edge, min_us, max_us);
  }
  return max_us;  // among the overflows
}

Distribution to_distribution(const LatencyHistogram& h, std::string name) {
  Distribution d;
  d.name = std::move(name);
  d.count = h.count();
  d.min_us = static_cast<double>(h.min_ns()) / 1e3;
  d.max_us = static_cast<double>(h.max_ns()) / 1e3;
  d.avg_us = h.mean_ns() / 1e3;
  for (std::size_t i = 0; i < LatencyHistogram::kOverflowBucket; ++i) {
    if (h.bucket_count(i) != 0) d.buckets.emplace_back(static_cast<double>(LatencyHistogram::bucket_lower_ns(i)) / 1e3, h.bucket_count(i));
  }
  d.overflows = h.bucket_count(LatencyHistogram::kOverflowBucket);
  d.overflow_above_us = static_cast<double>(LatencyHistogram::bucket_lower_ns(LatencyHistogram::kOverflowBucket)) / 1e3;
  return d;
}

}  // namespace lancet::rt
