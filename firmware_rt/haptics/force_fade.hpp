#pragma once
// ForceFade: scales the rendered force to zero when the tissue model (the viz) stops answering,
// and back up when it returns, at a bounded rate, so neither edge is a force step.
//   - the peer is "alive" while its heartbeat is no older than timeout;
//   - the scale moves toward 1 (alive) or 0 (lost) by dt / fade_time per tick.
// So after the last heartbeat the force is exactly zero within timeout + fade_time + one tick.

#include <algorithm>
#include <cstdint>

namespace lancet::haptics {

struct ForceFadeParams {
  std::int64_t timeout_ns = 150'000'000;  ///< heartbeat age beyond which the peer counts as lost
  std::int64_t fade_ns = 100'000'000;     ///< time to go from full force to zero
};

class ForceFade {
 public:
  /// Advances by one tick of dt_ns given whether the peer is alive; returns the scale in [0, 1].
  /// Real-time safe.
  double update(bool alive, std::int64_t dt_ns, const ForceFadeParams& p) noexcept {
    const double step = p.fade_ns > 0 ? static_cast<double>(dt_ns) / static_cast<double>(p.fade_ns) : 1.0;
    scale_ = alive ? std::min(1.0, scale_ + step) : std::max(0.0, scale_ - step);
    return scale_;
  }
  [[nodiscard]] double scale() const noexcept { return scale_; }

 private:
  double scale_ = 0.0;  // starts faded out: force ramps in once the viz is seen
};

}  // namespace lancet::haptics
