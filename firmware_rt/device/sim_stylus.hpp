#pragma once
// Simulated stylus for the in-process `sim` device: a point mass held by the user's hand, which
// is modelled as a spring-damper pulling the stylus toward a target (a script or the viz's
// StylusTarget). The force the device renders pushes on the same mass, so a stiff surface stops
// the stylus short of a target below it, as a real hand would feel.

#include "lancet/shared_model/geometry.hpp"

namespace lancet::device {

struct SimStylusParams {
  double mass = 0.15;            ///< kg, stylus plus hand
  double hand_stiffness = 1500;  ///< N/m, hand spring toward the target
  double hand_damping = 21;      ///< N·s/m
  double max_speed = 2.0;        ///< m/s, clamp (a hand does not move faster)
};

struct SimStylusState {
  Vec3 position;  ///< m
  Vec3 velocity;  ///< m/s
};

/// Advances the stylus by dt seconds (semi-implicit Euler) under the hand spring toward target
/// and the device force (N). Real-time safe.
void step_sim_stylus(const SimStylusParams& p, SimStylusState& s, Vec3 target, Vec3 device_force, double dt) noexcept;

/// The demo's scripted hand motion (m, world frame, at time t seconds since start): descend from
/// 15 mm above the z = 0 plane to `depth` below it during the first second, then stroke along x
/// (±30 mm, 4 s period) with a slow sway in y, staying at that depth.
Vec3 scripted_target(double t, double depth) noexcept;

}  // namespace lancet::device
