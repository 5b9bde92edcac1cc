#include "app/live_frame.hpp"

namespace lancet::viz {

Result<sim::FrameBatch> LiveFrame::drain() {
  const std::span<const ToolSample> drained = session_.drain(now_ns_);
  if (trace_ != nullptr) trace_->write(drained);
  sim::FrameBatch b;
  b.samples = recorder_.admit(drained, session_);
  // A scene armed for a recording stays as it was made until its session begins: its blood does
  // not flow either (a replay's starts at time 0, and the blood's own clock gates when it
  // rebuilds its network).
  const auto state = recorder_.state();
  const bool frozen = state == RecorderControl::State::kArmed || state == RecorderControl::State::kWaitingReset;
  b.blood_dt = frozen ? 0.0 : blood_dt_;
  // Each hand that has sent a sample gets its patch, around its own tool.
  if (session_.attached()) {
    for (std::size_t h = 0; h < kHandCount; ++h) {
      const auto hand = static_cast<Hand>(h);
      if (!session_.has_sample(hand)) continue;
      b.patches[h] = {&session_.patch_buffer(hand), session_.latest(hand).tool.position,
                      {session_.frames(), now_ns_, session_.samples_applied(hand)}};
    }
  }
  return b;
}

}  // namespace lancet::viz
