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
    if (d.energy > 0 && v2 > 0) {
      // Damping that takes the excess back over the coming tick (α·|v|²·dt = energy), bounded.
      // Hannaford & Ryu's α = E/(dt·|v|²) grows without bound as the hand stops: a little energy
      // owed by a nearly still hand became a shove, or turned the tissue's push into a pull.
      // (Those abrupt forces are what Ryu, Preusche, Hannaford & Hirzinger 2005, "Time domain
      // passivity control with reference energy following", IEEE T-CST 13(5), spread over time.)
      // Two bounds:
      // - α <= max_passivity_damping. A sampled device renders a damper passively only up to
      //   about the physical damping at its handle (Colgate & Schenkel 1997, "Passivity of a
      //   class of sampled-data systems", J. Robotic Systems 14(1): b > KT/2 + |B|), here the
      //   hand's; and one tick of a damper with α·dt above the moving mass turns the motion
      //   around. It also bounds the change of force by α_max·|v|, which fades with the velocity
      //   and is computed without dividing by it.
      // - Where the force pushes the hand along its motion (f·v > 0), the damping at most cancels
      //   that component (α·|v|² <= f·v): the controller removes the force that delivers the
      //   energy but never pulls the hand where the tissue pushed it (a reversal held for a tick
      //   on a velocity that may itself be turning is how the controller chattered). Where the
      //   force already resists the motion, or there is none (free air), the damping adds
      //   resistance in the same sense.
      // What the bounds hold back stays in d.energy and is taken back on the following ticks as
      // the hand moves. Nothing is credited here: next tick the observer counts the work of the
      // force actually sent (after the clamp and the slew limit), so the energy taken back is
      // exactly what the damping really dissipated.
      const double room = dt * v2;  // m²/s: energy the damping takes back per N·s/m of α
      double alpha = p.max_passivity_damping;
      if (d.energy < alpha * room) alpha = d.energy / room;  // room > 0 here, and the quotient < α_max
      const double fv = dot(f, v);
      if (fv > 0 && alpha * v2 > fv) alpha = fv / v2;  // < α_max: no division by ~0 can blow up
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
