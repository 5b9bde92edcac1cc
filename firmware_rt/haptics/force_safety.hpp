#pragma once
// The force safety layer of the haptic step: NaN/Inf guard (zero force, counted), magnitude clamp,
// slew-rate limit, and a passivity controller (Hannaford & Ryu 2002): it integrates the energy the
// rendered force puts into the hand and, when that energy turns positive (the wall at 1 kHz with
// a sample-and-hold device would be pumping energy in), adds the damping that removes it over the
// coming tick, bounded (see apply_safety): at most max_passivity_damping, and never more than
// cancels the part of the force that pushes the hand along its motion. What the bound holds back
// stays owed and is taken back on the following ticks. Real-time safe.

#include <cstdint>

#include "lancet/shared_model/geometry.hpp"
#include "lancet/shared_model/word_hasher.hpp"

namespace lancet::haptics {

struct SafetyParams {
  double max_force = 8.0;                   ///< N, per arm
  double max_slew = 2000.0;                 ///< N/s; 0: no slew limit
  /// N·s/m, > 0: the most damping the passivity controller adds (its α; see apply_safety). The
  /// default is about the damping of the hand holding the stylus (the sim's hand_damping is
  /// 21 N·s/m), which bounds what a 1 kHz device renders passively, and in a 1 ms tick it turns
  /// around no moving mass above 20 g.
  double max_passivity_damping = 20.0;
  bool passivity = true;                    ///< run the passivity observer/controller
};

struct SafetyData {
  Vec3 last{};                  ///< force sent last tick (N)
  Vec3 last_position{};         ///< device position last tick (m)
  bool has_position = false;
  double energy = 0;            ///< J, energy delivered to the hand so far (observer)
  std::uint64_t nan_guards = 0, clamps = 0, slew_limits = 0, passivity_actions = 0;

  void hash(WordHasher& w) const noexcept {
    w.v(last), w.v(last_position), w.b(has_position), w.f(energy);
    w.word(nan_guards), w.word(clamps), w.word(slew_limits), w.word(passivity_actions);
  }
};

/// Applies the layer to `force` (N, on the hand) for a tick of dt seconds, the device at
/// `position` (m) moving at `velocity` (m/s). (Fading the force when the tissue is not trusted is
/// the servo's ForceFade, after this layer.) The passivity observer counts the work the force held over the last tick really did,
/// last force · (position − last position), which is exact for a sample-and-hold device. While
/// energy E is owed the controller subtracts α·velocity with α = E/(dt·|v|²), bounded by
/// max_passivity_damping and, where the force pushes along the motion, by what cancels that
/// component (never reversed); the force then changes by at most max_passivity_damping·|v|, so a
/// still hand (v → 0, down to exactly 0) gets no kick and nothing is divided by ~0. Sets event
/// bits (event::kFault, kForceClamped) in `events`. Returns the force to send. Real-time safe.
Vec3 apply_safety(const SafetyParams& p, SafetyData& d, Vec3 force, Vec3 position, Vec3 velocity, double dt, std::uint32_t& events) noexcept;

}  // namespace lancet::haptics
