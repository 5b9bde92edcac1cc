#pragma once
// The force safety layer, last before the device: NaN/Inf guard (zero force, counted), stale-patch
// fade-out (linear to zero once the tissue patch is older than a threshold), magnitude clamp,
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
  std::int64_t stale_after_ns = 100'000'000;  ///< a patch older than this starts fading
  std::int64_t stale_fade_ns = 100'000'000;   ///< ... and reaches zero this much later
  bool passivity = true;                    ///< run the passivity observer/controller
};

struct SafetyData {
  Vec3 last{};                  ///< force sent last tick (N)
  Vec3 last_position{};         ///< device position last tick (m)
  bool has_position = false;
  double energy = 0;            ///< J, energy delivered to the hand so far (observer)
  std::uint64_t nan_guards = 0, clamps = 0, slew_limits = 0, fades = 0, passivity_actions = 0;
};

/// Applies the layer to `force` (N, on the hand) for a tick of dt seconds, the device at
/// `position` (m) moving at `velocity` (m/s), the patch `patch_age_ns` old (negative: no patch in
/// use). The passivity observer counts the work the force held over the last tick really did,
/// last force · (position − last position), which is exact for a sample-and-hold device. Sets
/// event bits (event::kFault, kForceClamped, kForceFaded) in `events`. Returns the force to send.
Vec3 apply_safety(const SafetyParams& p, SafetyData& d, Vec3 force, Vec3 position, Vec3 velocity,
                  std::int64_t patch_age_ns, double dt, std::uint32_t& events) noexcept;

}  // namespace lancet::haptics
