#pragma once
// LiveFrame: the live viz's two ends of the frame function (sim/viz_frame.hpp). Its samples are
// those drained from lancet-rt's ring this frame (written to the --trace, then admitted by the
// recording: a scene armed for a recording waits for the servo's reset, its blood still until then); its patch is filled in the
// link's buffer around the newest tool position, once attached and a sample has arrived, with the
// frame's number, time and newest tick as its header, and published to the segment.

#include <cstdint>

#include "app/recorder_control.hpp"
#include "app/sample_trace.hpp"
#include "app/viz_session.hpp"
#include "sim/viz_frame.hpp"

namespace lancet::viz {

class LiveFrame final : public sim::FrameIo {
 public:
  /// trace may be null (no --trace). All three outlive the LiveFrame.
  LiveFrame(VizSession& session, RecorderControl& recorder, SampleTrace* trace)
      : session_(session), recorder_(recorder), trace_(trace) {}

  /// The next frame's clock (CLOCK_MONOTONIC, ns) and blood time (s); call before sim::run_frame.
  void begin(std::int64_t now_ns, double blood_dt) noexcept {
    now_ns_ = now_ns;
    blood_dt_ = blood_dt;
  }
  [[nodiscard]] Result<sim::FrameBatch> drain() override;
  void publish(const std::array<const TissuePatch*, kHandCount>& patches) override { session_.publish(patches, now_ns_); }

 private:
  VizSession& session_;
  RecorderControl& recorder_;
  SampleTrace* trace_;
  std::int64_t now_ns_ = 0;
  double blood_dt_ = 0;
};

}  // namespace lancet::viz
