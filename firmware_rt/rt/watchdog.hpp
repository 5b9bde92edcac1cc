#pragma once
// Watchdog of the servo loop: N consecutive missed deadlines, or one tick whose computation took
// longer than a budget, trips it. A tripped watchdog means zero force until someone re-arms it
// explicitly (a Command from the viz or lancetctl): it never clears itself.

#include <cstdint>

#include "lancet/shared_model/device_codes.hpp"

namespace lancet::rt {

struct WatchdogParams {
  std::uint32_t max_consecutive_misses = 0;  ///< trip after this many missed deadlines in a row (0: off)
  std::int64_t tick_budget_ns = 0;           ///< trip when one tick computes longer (0: off)
};

class Watchdog {
 public:
  using Reason = ::lancet::WatchdogReason;

  /// After each tick: was its deadline missed, and how long did it compute? Returns true when the
  /// watchdog trips on this call. Real-time safe.
  bool observe(const WatchdogParams& p, bool missed, std::int64_t compute_ns) noexcept {
    consecutive_ = missed ? consecutive_ + 1 : 0;
    if (tripped_) return false;
    Reason why = Reason::kNone;
    if (p.max_consecutive_misses > 0 && consecutive_ >= p.max_consecutive_misses) why = Reason::kConsecutiveMisses;
    if (p.tick_budget_ns > 0 && compute_ns > p.tick_budget_ns) why = Reason::kTickOverBudget;
    if (why == Reason::kNone) return false;
    tripped_ = true;
    reason_ = why;
    ++trips_;
    return true;
  }
  /// Clears the fault (the explicit re-arm). Real-time safe.
  void rearm() noexcept {
    tripped_ = false;
    reason_ = Reason::kNone;
    consecutive_ = 0;
  }
  [[nodiscard]] bool tripped() const noexcept { return tripped_; }
  [[nodiscard]] Reason reason() const noexcept { return reason_; }
  [[nodiscard]] std::uint64_t trips() const noexcept { return trips_; }

 private:
  bool tripped_ = false;
  Reason reason_ = Reason::kNone;
  std::uint32_t consecutive_ = 0;
  std::uint64_t trips_ = 0;
};

using ::lancet::to_string;

}  // namespace lancet::rt
