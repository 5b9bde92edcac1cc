#include "app/replay_clock.hpp"

#include <algorithm>

namespace lancet::viz {

Result<void> ReplayClock::advance(record::Replay& replay, double wall_dt, bool headless) {
  if (headless) {  // every frame now, nothing drawn between them: Replay::run, the blood behind the frames
    if (replay.done()) return {};
    auto ran = replay.run();
    if (!ran.ok()) return ran.error();
    return {};
  }
  if (!paused_) clock_s_ += std::min(wall_dt, 0.1) * speed_;
  const auto& frames = replay.recording().frames;
  const auto due = [&] { return static_cast<double>(frames[replay.frame()].t_ns - frames.front().t_ns) * 1e-9 <= clock_s_; };
  while (!replay.done() && due()) {
    auto stepped = replay.step_frame();
    if (!stepped.ok()) return stepped.error();
  }
  return {};
}

}  // namespace lancet::viz
