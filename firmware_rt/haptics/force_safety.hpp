#pragma once
// The force safety layer of the haptic step: NaN/Inf guard (zero force, counted), magnitude clamp,
// slew-rate limit, and a passivity controller (Hannaford & Ryu 2002): it integrates the energy the
// rendered force puts into the hand and, when that energy turns positive (the wall at 1 kHz with
// a sample-and-hold device would be pumping energy in), adds exactly the damping that removes it.
// Real-time safe.

#include <cstdint>

#include "lancet/shared_model/geometry.hpp"

namespace lancet::haptics {

struct SafetyParams {
  double max_force = 8.0;                   ///< N, per arm
  double max_slew = 2000.0;                 ///< N/s; 0: no slew limit
  bool passivity = true;                    ///< run the passivity observer/controller
};

struct SafetyData {
  Vec3 last{};                  ///< force sent last tick (N)
  Vec3 last_position{};         ///< device position last tick (m)
  bool has_position = false;
  double energy = 0;            ///< J, energy delivered to the hand so far (observer)
  std::uint64_t nan_guards = 0, clamps = 0, slew_limits = 0, passivity_actions = 0;
};

/// Applies the layer to `force` (N, on the hand) for a tick of dt seconds, the device at
/// `position` (m) moving at `velocity` (m/s). (Fading the force when the tissue is not trusted is
/// the servo's ForceFade, after this layer.) The passivity observer counts the work the force held over the last tick really did,
/// last force · (position − last position), which is exact for a sample-and-hold device. Sets
/// event bits (event::kFault, kForceClamped) in `events`. Returns the force to send.
Vec3 apply_safety(const SafetyParams& p, SafetyData& d, Vec3 force, Vec3 position, Vec3 velocity, double dt, std::uint32_t& events) noexcept;

}  // namespace lancet::haptics
