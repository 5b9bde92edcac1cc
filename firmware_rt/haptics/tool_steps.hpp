#pragma once
// The per-tool parts of haptic_step (haptic_step.hpp), one file each. Each moves the proxy and
// the stage for its tool, sets its events, and returns the raw force on the hand (N, before the
// safety layer) with, in `mat`, the material it touched. Real-time safe.

#include "haptics/haptic_step.hpp"

namespace lancet::haptics::detail {

/// The material of id `id` (ids beyond the table: the last).
[[nodiscard]] const MaterialParams& material(const HapticModel& m, std::uint32_t id) noexcept;

/// The search tree of the patch in use (the input's, or HapticData::bvh, built by haptic_step
/// when the patch's version changed); null without a patch version: then the patch is scanned.
[[nodiscard]] const PatchBvh* patch_tree(const HapticData& d, const HapticInput& in) noexcept;

/// Probe, swab, and scalpel before the rupture: proxy on the surface with friction; a scalpel
/// pressing harder than the material yields ruptures it (stage kRupture, then kCutting).
Vec3 probe_step(const HapticModel& m, HapticData& d, const HapticInput& in, Vec3 prev_proxy, HapticOutput& out) noexcept;
/// Scalpel, stage kCutting: directional cut friction until the blade leaves the tissue.
Vec3 scalpel_step(const HapticModel& m, HapticData& d, const HapticInput& in, Vec3 prev_proxy, HapticOutput& out) noexcept;
/// Retractor: snap to the surface, grab, pull up to the elastic limit, slip beyond it.
Vec3 retractor_step(const HapticModel& m, HapticData& d, const HapticInput& in, HapticOutput& out) noexcept;
/// Drill: volume haptics on the brick; pressing hard removes burr spheres.
Vec3 drill_step(const HapticModel& m, HapticData& d, const HapticInput& in, Vec3 prev_proxy, HapticOutput& out) noexcept;

}  // namespace lancet::haptics::detail
