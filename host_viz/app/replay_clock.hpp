#pragma once
// ReplayClock: how far lancet-viz's --replay has got. In a window the recorded frames are replayed
// as the recording's time passes (at --replay-speed, paused by space or the panel); headless, all
// of them at once, as fast as they go.

#include "lancet/shared_model/result.hpp"
#include "record/replay.hpp"

namespace lancet::viz {

class ReplayClock {
 public:
  explicit ReplayClock(double speed) : speed_(speed) {}
  /// Advances the clock by wall_dt s of the viz's time (at most 0.1 s after a stall, times the
  /// speed; not while paused) and replays every recorded frame up to it (headless: every frame).
  /// An error stops the replay: it says why.
  [[nodiscard]] Result<void> advance(record::Replay& replay, double wall_dt, bool headless);
  void toggle_pause() noexcept { paused_ = !paused_; }
  void set_speed(double speed) noexcept { speed_ = speed; }
  [[nodiscard]] bool paused() const noexcept { return paused_; }
  [[nodiscard]] double speed() const noexcept { return speed_; }

 private:
  double clock_s_ = 0;  ///< s of the recording shown
  double speed_;
  bool paused_ = false;
};

}  // namespace lancet::viz
