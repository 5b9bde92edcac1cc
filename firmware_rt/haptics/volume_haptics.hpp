#pragma once
// Volume haptics on the TissuePatch's voxel brick (ALGORITHMS.md §2, thesis 4.3; Lundin,
// Palmerius): the proxy moves toward the device through voxels below the iso value and stops at
// the iso surface, whose normal is the negative density gradient; the remaining motion slides
// along that surface. The drill removes voxels (a sphere of its burr radius) at a rate that falls
// with density, on the real-time side's own copy of the brick, so drilling is felt at once; the
// removal events tell lancet-viz to carve its volume too. Real-time safe: bounded loops.

#include <cstdint>

#include "lancet/shared_model/geometry.hpp"
#include "lancet/shared_model/messages.hpp"

namespace lancet::haptics {

inline constexpr std::int16_t kAirHu = -1000;

/// Trilinear HU at p (m). Outside the brick, or when it is not valid: air.
double sample_hu(const VoxelBrick& b, Vec3 p) noexcept;
/// Gradient of HU at p (HU/m), central differences of sample_hu over one voxel.
Vec3 gradient_hu(const VoxelBrick& b, Vec3 p) noexcept;

struct VolumeContact {
  Vec3 position;      ///< new proxy (m)
  Vec3 normal;        ///< outward unit normal of the iso surface at the contact; zero when free
  bool contact = false;
};

/// Moves the proxy from p toward goal without entering HU ≥ iso; slides along the surface.
VolumeContact volume_proxy_step(const VoxelBrick& b, double iso, Vec3 p, Vec3 goal) noexcept;

/// Sets every voxel whose centre lies within radius of centre to air; returns how many changed.
std::uint32_t carve_sphere(VoxelBrick& b, Vec3 centre, double radius) noexcept;

}  // namespace lancet::haptics
