#pragma once
// PeriodicTimer: absolute-deadline periodic wake-ups on CLOCK_MONOTONIC.
// Deadlines advance by exactly one period (`next += period`), so the loop's average rate is exact.
// A tick that starts more than a period late is an overrun: the missed deadlines are skipped
// (counted, never caught up by bursting).

#include <cstdint>

namespace lancet::rt {

/// What one wait() observed.
struct Wake {
  std::int64_t deadline_ns;   ///< the deadline this tick was scheduled for
  std::int64_t woke_ns;       ///< when the thread actually resumed
  std::uint32_t skipped;      ///< deadlines skipped because the previous tick ran long
};

class PeriodicTimer {
 public:
  /// period_ns > 0. The first deadline is start_ns + period_ns.
  PeriodicTimer(std::int64_t period_ns, std::int64_t start_ns) noexcept
      : period_ns_(period_ns), next_ns_(start_ns + period_ns) {}

  /// Sleeps until the next deadline (clock_nanosleep TIMER_ABSTIME, retried on EINTR) and
  /// advances it. Real-time safe (one system call, no allocation).
  Wake wait() noexcept;

  [[nodiscard]] std::int64_t period_ns() const noexcept { return period_ns_; }
  [[nodiscard]] std::uint64_t overruns() const noexcept { return overruns_; }

 private:
  std::int64_t period_ns_;
  std::int64_t next_ns_;
  std::uint64_t overruns_ = 0;
};

}  // namespace lancet::rt
