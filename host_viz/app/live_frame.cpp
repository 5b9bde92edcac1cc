#include "app/live_frame.hpp"

namespace lancet::viz {

Result<sim::FrameBatch> LiveFrame::drain() {
  const std::span<const ToolSample> drained = session_.drain(now_ns_);
  if (trace_ != nullptr) trace_->write(drained);
  sim::FrameBatch b;
  b.samples = recorder_.admit(drained, session_);
  b.blood_dt = blood_dt_;
  if (session_.attached() && session_.has_sample()) {
    b.patch = &session_.patch_buffer();
    b.patch_centre = session_.latest().tool.position;
    b.header = {session_.frames(), now_ns_, session_.samples_applied()};
  }
  return b;
}

}  // namespace lancet::viz
