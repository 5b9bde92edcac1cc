#include "rt/rt_loop.hpp"

namespace lancet::rt {

RtLoop::RtLoop(const LoopParams& params) : params_(params), stats_(std::make_unique<LoopStats>()) {
  // Reserve and touch the time-series storage now, so recording into it later never faults.
  stats_->window_max_us.resize(params_.max_windows);
  stats_->window_max_us.clear();
}

void MonotonicClock::sleep_until(std::int64_t t_ns) const noexcept {
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(t_ns / kNsPerSecond);
  ts.tv_nsec = static_cast<long>(t_ns % kNsPerSecond);
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
}

void RtLoop::refresh_live() noexcept {
  LoopStats& s = *stats_;
  LoopLive& l = s.live;
  l.ticks = s.ticks;
  l.overruns = s.overruns;
  l.missed = s.missed;
  l.wake_p50_ns = s.wake_latency.percentile_ns(50);
  l.wake_p99_ns = s.wake_latency.percentile_ns(99);
  l.wake_p999_ns = s.wake_latency.percentile_ns(99.9);
  l.wake_max_ns = s.wake_latency.max_ns();
  l.compute_p99_ns = s.compute.percentile_ns(99);
  l.compute_max_ns = s.compute.max_ns();
  l.longest_stall_ns = s.longest_stall_ns;
  l.wake_histogram = wake_bins(s.wake_latency);
}

std::array<std::uint64_t, kWakeBins> wake_bins(const LatencyHistogram& h) noexcept {
  // Every coarse edge is an edge of the fine buckets, so each bucket falls in one bin.
  std::array<std::uint64_t, kWakeBins> bins{};
  std::size_t bin = 0;
  for (std::size_t b = 0; b < LatencyHistogram::kBuckets; ++b) {
    const std::int64_t lower = LatencyHistogram::bucket_lower_ns(b);
    while (bin + 1 < kWakeBins && lower >= static_cast<std::int64_t>(kWakeBinLowerUs[bin + 1]) * 1000) ++bin;
    bins[bin] += h.bucket_count(b);
  }
  return bins;
}

void RtLoop::thread_faults(long& minor, long& major) noexcept {
  rusage ru{};
  getrusage(RUSAGE_THREAD, &ru);
  minor = ru.ru_minflt;
  major = ru.ru_majflt;
}

}  // namespace lancet::rt
