#pragma once
// ForceFade: the one fade of the rendered force. The force is only as good as the tissue it was
// computed against; the tissue is trusted while
//   - the visualizer, which owns it, is alive (its heartbeat no older than timeout_ns), and
//   - the patch in use is fresh (no older than stale_after_ns; no patch at all counts as fresh:
//     there is no force to fade).
// The scale moves toward 1 (trusted) or 0 (not) by dt / fade_ns per tick, so neither edge is a
// force step. The servo (servo_step) gives the time since its last tick when fading out, skipped
// deadlines included, and one period when fading in: after the last heartbeat (or once the patch
// turned stale) the force is exactly zero within timeout (stale_after) + fade_ns + the longest gap
// between two ticks, and it ramps back in over fade_ns of ticks when trust returns.

#include <algorithm>
#include <cstdint>

namespace lancet::haptics {

struct ForceFadeParams {
  std::int64_t timeout_ns = 150'000'000;      ///< heartbeat age beyond which the visualizer counts as lost
  std::int64_t stale_after_ns = 100'000'000;  ///< patch age beyond which the tissue counts as unknown
  std::int64_t fade_ns = 100'000'000;         ///< time to go from full force to zero (and back)
};

class ForceFade {
 public:
  /// Whether the tissue is trusted: the heartbeat is fresh and the patch (age < 0: none) too.
  [[nodiscard]] static bool trusted(const ForceFadeParams& p, bool viz_alive, std::int64_t patch_age_ns) noexcept {
    return viz_alive && patch_age_ns <= p.stale_after_ns;
  }
  /// Advances by one tick of dt_ns; returns the scale in [0, 1]. Real-time safe.
  double update(bool trusted, std::int64_t dt_ns, const ForceFadeParams& p) noexcept {
    const double step = p.fade_ns > 0 ? static_cast<double>(dt_ns) / static_cast<double>(p.fade_ns) : 1.0;
    scale_ = trusted ? std::min(1.0, scale_ + step) : std::max(0.0, scale_ - step);
    return scale_;
  }
  [[nodiscard]] double scale() const noexcept { return scale_; }

 private:
  double scale_ = 0.0;  // starts faded out: force ramps in once the tissue is trusted
};

}  // namespace lancet::haptics
