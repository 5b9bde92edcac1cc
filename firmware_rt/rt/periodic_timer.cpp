#include "periodic_timer.hpp"

#include <cerrno>
#include <ctime>

#include "lancet/shared_model/units.hpp"

namespace lancet::rt {

Wake PeriodicTimer::wait() noexcept {
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(next_ns_ / kNsPerSecond);
  ts.tv_nsec = static_cast<long>(next_ns_ % kNsPerSecond);
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
  Wake w{next_ns_, monotonic_ns(), 0};
  next_ns_ += period_ns_;
  // Woke more than a whole period late: skip the deadlines already missed instead of bursting.
  if (w.woke_ns >= next_ns_) {
    const std::int64_t behind = (w.woke_ns - next_ns_) / period_ns_ + 1;
    next_ns_ += behind * period_ns_;
    w.skipped = static_cast<std::uint32_t>(behind);
    overruns_ += static_cast<std::uint64_t>(behind);
  }
  return w;
}

}  // namespace lancet::rt
