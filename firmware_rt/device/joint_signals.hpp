#pragma once
// What every bus backend derives the same way from what its arm reports: joint velocities from
// successive encoder positions, and the config's buttons from the device's raw button word.
// Real-time safe: no allocation, no exceptions.

#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numbers>
#include <span>

#include "arm/arm_config.hpp"
#include "device/device.hpp"

namespace lancet::device {

/// Joint velocities as the finite difference of successive positions through a first-order
/// low-pass, alpha = dt / (dt + 1/(2π fc)). Starts at zero on the first sample after reset() and
/// after a gap longer than max_gap_ns.
class VelocityEstimator {
 public:
  explicit VelocityEstimator(double cutoff_hz, std::int64_t max_gap_ns = std::numeric_limits<std::int64_t>::max()) noexcept
      : cutoff_hz_(cutoff_hz), max_gap_ns_(max_gap_ns) {}

  void reset() noexcept {
    have_ = false;
    q_prev_.fill(0);
    qd_.fill(0);
  }
  /// Ignores a cutoff that is not positive and finite.
  void set_cutoff_hz(double hz) noexcept {
    if (hz > 0 && std::isfinite(hz)) cutoff_hz_ = hz;
  }
  [[nodiscard]] double cutoff_hz() const noexcept { return cutoff_hz_; }

  /// Takes joints 0..n-1 of q at t_ns and writes their velocities into qd.
  void update(int n, const std::array<double, kMaxJoints>& q, std::int64_t t_ns, std::array<double, kMaxJoints>& qd) noexcept {
    const bool restart = !have_ || t_ns - t_prev_ns_ > max_gap_ns_;
    const double dt = have_ ? static_cast<double>(t_ns - t_prev_ns_) * 1e-9 : 0.0;
    const double alpha = dt > 0 ? dt / (dt + 1.0 / (2.0 * std::numbers::pi * cutoff_hz_)) : 0.0;
    for (int j = 0; j < n; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      if (restart) qd_[uj] = 0;
      else if (dt > 0) qd_[uj] += alpha * ((q[uj] - q_prev_[uj]) / dt - qd_[uj]);
      q_prev_[uj] = q[uj];
      qd[uj] = qd_[uj];
    }
    have_ = true;
    t_prev_ns_ = t_ns;
  }

 private:
  double cutoff_hz_;
  std::int64_t max_gap_ns_;
  bool have_ = false;
  std::int64_t t_prev_ns_ = 0;
  std::array<double, kMaxJoints> q_prev_{}, qd_{};
};

/// Bit i set when config button i is pressed: its bit of the raw word, inverted when active low.
[[nodiscard]] inline std::uint32_t pressed_buttons(std::span<const arm::ButtonConfig> buttons, std::uint32_t raw) noexcept {
  std::uint32_t pressed = 0;
  for (std::size_t i = 0; i < buttons.size() && i < 32; ++i) {
    const arm::ButtonConfig& b = buttons[i];
    const bool level = b.bit >= 0 && b.bit < 32 && ((raw >> b.bit) & 1u) != 0;
    if (level != b.active_low) pressed |= 1u << i;
  }
  return pressed;
}

}  // namespace lancet::device
