#pragma once
// What every bus backend derives the same way from what its arm reports: joint velocities from
// successive encoder positions, the config's buttons from the device's raw button word, and what a
// status word's named bits say is wrong with the drives. Real-time safe: no allocation, no exceptions.

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
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

/// What a status word's named bits (arm::StatusBits) say is wrong with the drives, in words an
/// integrator can act on, written to out (always NUL-terminated): "status 0x0005: fault (bit 2),
/// not ready (bit 0 low)". An active fault, estop or comm_lost is always a problem; an inactive
/// ready or enabled only when `drives_on` (the driver has enabled the drives). Returns the number of
/// problems (0: out holds "status 0x…" alone). Real-time safe (snprintf into the caller's buffer).
inline int describe_status(const arm::StatusBits& bits, std::uint32_t word, bool drives_on, char* out, std::size_t size) noexcept {
  if (size == 0) return 0;
  int n = std::snprintf(out, size, "status 0x%04X", static_cast<unsigned>(word));
  int problems = 0;
  const auto add = [&](const arm::StatusBit& b, bool want_active, const char* what) {
    if (!b.mapped() || b.active(word) != want_active) return;
    // The level the bit reads now: active-high bits read high when active, active-low ones low.
    const bool reads_high = want_active != b.active_low;
    const std::size_t at = n < 0 ? size : std::min(size, static_cast<std::size_t>(n));
    const int k = std::snprintf(out + at, size - at, "%s%s (bit %d%s)", problems == 0 ? ": " : ", ", what, b.bit,
                                reads_high ? (b.active_low ? " high" : "") : " low");
    if (k > 0) n += k;
    ++problems;
  };
  add(bits.fault, true, "fault");
  add(bits.estop, true, "e-stop");
  add(bits.comm_lost, true, "communication lost");
  if (drives_on) {
    add(bits.ready, false, "not ready");
    add(bits.enabled, false, "not enabled");
  }
  return problems;
}

}  // namespace lancet::device
