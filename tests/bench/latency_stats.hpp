#pragma once
// The median, 99th percentile and maximum of a benchmark's per-call times, for the device
// benches (lancet-bench-device, lancet-bench-falcon), which report the same three figures.

#include <algorithm>
#include <cstddef>
#include <vector>

namespace lancet::bench {

struct Latency {
  double p50 = 0, p99 = 0, max = 0;
};

/// Sorts `times` (any unit) and reads the figures off it; all 0 when it is empty.
inline Latency latency_of(std::vector<double>& times) {
  Latency l;
  if (times.empty()) return l;
  std::sort(times.begin(), times.end());
  const std::size_t n = times.size();
  l.p50 = times[n / 2];
  l.p99 = times[std::min(n - 1, n * 99 / 100)];
  l.max = times.back();
  return l;
}

}  // namespace lancet::bench
