#pragma once
// RtLoop: the periodic servo loop and its measurement.
//
// Timing: CLOCK_MONOTONIC absolute deadlines advanced by exactly one period. A tick that wakes
// more than a period late skips the deadlines it missed (counted as overruns), never bursts to
// catch up. Two wake strategies: kSleep (clock_nanosleep to the deadline) and kSleepThenSpin
// (sleep to deadline − margin, then spin on the clock); the margin is at most half a period, so
// the thread never spins a whole period (RT throttling would take ~50 ms a second from it).
//
// Accounting: a run of duration D serves the deadlines start + k·period for k = 1 .. ⌊D/period⌋
// (those in (start, start + D]); each one is either ticked or counted as an overrun, so
// ticks + overruns = ⌊D/period⌋ whatever the host does (a late last tick does not count the
// deadlines past the end). Stopped early by the flag: the deadlines up to the last tick.
//
// The clock is a template parameter of run() (MonotonicClock in production, a simulated one in
// tests, so the accounting can be checked on exact time).
//
// Measurement without allocation: per tick, wake-up latency (woke − deadline), compute time and
// period error (|actual period − nominal|) go into LatencyHistograms in the preallocated
// LoopStats; missed deadlines, the longest stall between wake-ups, page faults after warm-up and
// the worst latency per time window are kept there too. Every 100 ms the loop refreshes LoopLive
// (percentiles and counters) for the tick to publish.

#include <sys/resource.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <cstdint>
#include <ctime>
#include <memory>
#include <vector>

#include "lancet/shared_model/messages.hpp"
#include "lancet/shared_model/units.hpp"
#include "rt/latency_histogram.hpp"
#include "rt/watchdog.hpp"

namespace lancet::rt {

enum class WakeStrategy : std::uint8_t { kSleep = 0, kSleepThenSpin = 1 };

/// The loop's time: CLOCK_MONOTONIC. Any Clock passed to RtLoop::run has these three members, all
/// real-time safe: now_ns() (the time, ns), sleep_until(t) (returns at or after t, or earlier only
/// if the clock says so) and spin_until(t) (busy-waits until now_ns() >= t).
struct MonotonicClock {
  [[nodiscard]] std::int64_t now_ns() const noexcept { return monotonic_ns(); }
  /// clock_nanosleep(TIMER_ABSTIME), resumed after signals.
  void sleep_until(std::int64_t t_ns) const noexcept;
  void spin_until(std::int64_t t_ns) const noexcept {
    while (monotonic_ns() < t_ns) {
    }
  }
};

struct LoopParams {
  std::int64_t period_ns = 1'000'000;
  WakeStrategy strategy = WakeStrategy::kSleep;
  std::int64_t spin_margin_ns = 200'000;   ///< kSleepThenSpin: wake this early, then spin (≤ period/2)
  std::int64_t duration_ns = 0;            ///< serve the deadlines within this long (0: until the stop flag)
  std::uint64_t warmup_ticks = 100;        ///< page faults are counted from the end of warm-up
  WatchdogParams watchdog{};
  std::int64_t window_ns = 100'000'000;    ///< time-series window for the worst latency
  std::size_t max_windows = 0;             ///< windows to keep (preallocated; 0: none)
};

/// Live figures, refreshed every 100 ms of loop time.
struct LoopLive {
  std::uint64_t ticks = 0;
  std::uint64_t overruns = 0;              ///< deadlines skipped
  std::uint64_t missed = 0;                ///< ticks that finished after the next deadline, plus skipped ones
  std::int64_t wake_p50_ns = 0, wake_p99_ns = 0, wake_p999_ns = 0, wake_max_ns = 0;
  std::int64_t compute_p99_ns = 0, compute_max_ns = 0;
  std::int64_t longest_stall_ns = 0;
  std::array<std::uint64_t, kWakeBins> wake_histogram{};  ///< wake-ups per bin of kWakeBinLowerUs, since start
};

/// A latency histogram in RtStatus's coarse bins (kWakeBinLowerUs). O(buckets), no allocation.
[[nodiscard]] std::array<std::uint64_t, kWakeBins> wake_bins(const LatencyHistogram& h) noexcept;

/// Everything the loop measures, allocated once.
struct LoopStats {
  LatencyHistogram wake_latency;
  LatencyHistogram compute;
  LatencyHistogram period_error;
  std::uint64_t ticks = 0;
  std::uint64_t overruns = 0;
  std::uint64_t missed = 0;
  std::int64_t longest_stall_ns = 0;       ///< longest time between two consecutive wake-ups
  long minor_faults = 0;                   ///< page faults of the loop thread after warm-up
  long major_faults = 0;
  std::vector<double> window_max_us;       ///< worst wake-up latency per window (reserved up front)
  LoopLive live{};
};

/// What a tick sees.
struct TickContext {
  std::int64_t deadline_ns;
  std::int64_t woke_ns;
  std::uint64_t tick;          ///< 1-based
  Watchdog& watchdog;          ///< tripped(): command zero force; rearm() on an explicit request
  const LoopLive& live;
};

class RtLoop {
 public:
  explicit RtLoop(const LoopParams& params);

  /// Runs the loop in the calling thread until `stop` is set or the duration has passed, calling
  /// tick(const TickContext&) once per period. Real-time safe: no allocation, no lock; the only
  /// system calls are the sleep, clock reads (vDSO) and two getrusage calls (end of warm-up, end).
  template <class Tick>
  void run(Tick&& tick, const std::atomic<bool>& stop) {
    MonotonicClock clock;
    run(tick, stop, clock);
  }
  /// The same on the given clock (see MonotonicClock for what a Clock provides). Tests pass a
  /// simulated clock; everything measured (latencies, stalls, windows, live refresh) is then in
  /// its time. Page faults are the real thread's.
  template <class Tick, class Clock>
  void run(Tick&& tick, const std::atomic<bool>& stop, Clock& clock);

  [[nodiscard]] const LoopStats& stats() const noexcept { return *stats_; }
  [[nodiscard]] const Watchdog& watchdog() const noexcept { return watchdog_; }
  [[nodiscard]] const LoopParams& params() const noexcept { return params_; }

 private:
  void refresh_live() noexcept;
  static void thread_faults(long& minor, long& major) noexcept;

  LoopParams params_;
  std::unique_ptr<LoopStats> stats_;
  Watchdog watchdog_;
};

template <class Tick, class Clock>
void RtLoop::run(Tick&& tick, const std::atomic<bool>& stop, Clock& clock) {
  LoopStats& s = *stats_;
  const std::int64_t period = params_.period_ns;
  const std::int64_t margin =
      params_.strategy == WakeStrategy::kSleepThenSpin ? std::min(params_.spin_margin_ns, period / 2) : 0;
  const std::int64_t start = clock.now_ns();
  const bool bounded = params_.duration_ns > 0;
  const std::int64_t end = bounded ? start + params_.duration_ns : INT64_MAX;
  std::int64_t deadline = start + period;
  std::int64_t prev_woke = 0;
  std::int64_t window_end = start + params_.window_ns;
  double window_max = 0;
  long minor0 = 0, major0 = 0;
  std::int64_t next_live = start + 100'000'000;

  while (!stop.load(std::memory_order_relaxed) && deadline <= end) {
    // Wake up.
    if (margin > 0) {
      clock.sleep_until(deadline - margin);
      clock.spin_until(deadline);
    } else {
      clock.sleep_until(deadline);
    }
    const std::int64_t woke = clock.now_ns();
    const std::int64_t latency = woke - deadline;
    s.wake_latency.record(latency);
    if (s.ticks > 0) {
      const std::int64_t gap = woke - prev_woke;
      s.period_error.record(gap > period ? gap - period : period - gap);
      s.longest_stall_ns = std::max(s.longest_stall_ns, gap);
    }
    prev_woke = woke;
    ++s.ticks;

    tick(TickContext{deadline, woke, s.ticks, watchdog_, s.live});

    const std::int64_t done = clock.now_ns();
    const std::int64_t compute = done - woke;
    s.compute.record(compute);
    const bool missed = done > deadline + period;
    if (missed) ++s.missed;
    (void)watchdog_.observe(params_.watchdog, missed, compute);

    // Worst latency per window, for the plot over time.
    window_max = std::max(window_max, static_cast<double>(latency) / 1e3);
    if (woke >= window_end) {
      if (s.window_max_us.size() < params_.max_windows) s.window_max_us.push_back(window_max);  // reserved
      window_max = 0;
      window_end += params_.window_ns;
    }
    if (s.ticks == params_.warmup_ticks) thread_faults(minor0, major0);
    if (woke >= next_live) {
      refresh_live();
      next_live += 100'000'000;
    }

    // Next deadline; skip the ones already missed instead of bursting. Only skipped deadlines
    // within the duration count: a late last tick has no deadlines past the end to miss.
    deadline += period;
    if (done >= deadline) {
      const std::int64_t behind = (done - deadline) / period + 1;
      const std::int64_t skipped = !bounded ? behind : deadline > end ? 0 : std::min(behind, (end - deadline) / period + 1);
      deadline += behind * period;
      s.overruns += static_cast<std::uint64_t>(skipped);
      s.missed += static_cast<std::uint64_t>(skipped);
    }
  }
  if (s.ticks >= params_.warmup_ticks) {
    long minor1 = 0, major1 = 0;
    thread_faults(minor1, major1);
    s.minor_faults = minor1 - minor0;
    s.major_faults = major1 - major0;
  }
  refresh_live();
}

}  // namespace lancet::rt
