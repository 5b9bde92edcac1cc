#pragma once
// Distribution: a latency distribution in microseconds, as reported by the jitter rig for our
// loop and for cyclictest alike (so both print, compare and plot the same way). Allocating; not
// for the real-time path.

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "rt/latency_histogram.hpp"

namespace lancet::rt {

struct Distribution {
  std::string name;                                   ///< "lancet" or "cyclictest"
  std::uint64_t count = 0;                            ///< samples
  double min_us = 0, avg_us = 0, max_us = 0;
  std::vector<std::pair<double, std::uint64_t>> buckets;  ///< (lower edge µs, count), ascending, non-empty only
  std::uint64_t overflows = 0;                        ///< samples above the histogram range
  double overflow_above_us = 0;                       ///< where that range ends (µs); 0 when unbounded

  /// Nearest-rank percentile (p in [0, 100]) from the buckets, in µs; a rank that falls among the
  /// overflows returns max_us. 0 when empty.
  [[nodiscard]] double percentile_us(double p) const;
};

/// The distribution of a LatencyHistogram.
Distribution to_distribution(const LatencyHistogram& h, std::string name);

/// The percentiles every report prints, in order.
inline constexpr double kReportPercentiles[] = {50.0, 90.0, 99.0, 99.9, 99.99};

}  // namespace lancet::rt
