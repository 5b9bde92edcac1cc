#include "haptics/force_safety.hpp"

#include <algorithm>
#include <cmath>

#include "lancet/shared_model/messages.hpp"

namespace lancet::haptics {

Vec3 apply_safety(const SafetyParams& p, SafetyData& d, Vec3 f, Vec3 x, Vec3 v, double dt,
                  std::uint32_t& events) noexcept {
  if (!is_finite(f) || !is_finite(v) || !is_finite(x)) {
    f = Vec3{};
    ++d.nan_guards;
    events |= event::kFault;
    if (!is_finite(v)) v = Vec3{};
    if (!is_finite(x)) x = d.last_position;
  }
  // Passivity: the environment may give back only energy it was given.
  if (p.passivity) {
    // Work done on the hand by the force held during the last tick.
    if (d.has_position) d.energy += dot(d.last, x - d.last_position);
    const double v2 = dot(v, v);
    if (d.energy > 0 && v2 > 1e-12) {
      // Damping that takes the excess back over the coming tick (α·|v|²·dt = energy).
      const double alpha = d.energy / (dt * v2);
      f -= alpha * v;
      ++d.passivity_actions;
    }
    d.energy = std::max(d.energy, -0.05);  // a bounded reserve (50 mJ), so stored energy cannot bank
  }
  d.last_position = x;
  d.has_position = true;
  const double mag = norm(f);
  if (mag > p.max_force) {
    f = (p.max_force / mag) * f;
    ++d.clamps;
    events |= event::kForceClamped;
  }
  if (p.max_slew > 0) {
    const Vec3 step = f - d.last;
    const double s = norm(step), lim = p.max_slew * dt;
    if (s > lim) {
      f = d.last + (lim / s) * step;
      ++d.slew_limits;
    }
  }
  d.last = f;
  return f;
}

}  // namespace lancet::haptics
