#pragma once
// The voxel brick of a TissuePatch, cut from the scene's volume around the tool: what lancet-rt's
// drill pushes against and carves (ALGORITHMS.md §1, the volumetric half of the hybrid model).
//
// The volume sits in the world by a placement: a signed permutation of its axes and an offset
// (the built-in phantom lies along x with its top at z = 0; a CT is placed as its scenario says).
// The brick is axis-aligned in the world with the volume's voxel spacing, and its voxels are the
// volume's own voxels (the permutation maps grid to grid), so nothing is resampled.

#include <array>
#include <cstdint>

#include "lancet/shared_model/geometry.hpp"
#include "lancet/shared_model/messages.hpp"
#include "volume/volume.hpp"

namespace lancet::tissue {

/// world[a] = sign[a] · v[axis[a]] + offset[a], where v is a position in the volume's own frame
/// (Volume::position). Identity by default.
struct VolumePlacement {
  std::array<int, 3> axis{0, 1, 2};   ///< a permutation of {0, 1, 2}
  std::array<int, 3> sign{1, 1, 1};   ///< each +1 or −1
  Vec3 offset{};                      ///< m

  [[nodiscard]] Vec3 to_world(Vec3 v) const noexcept;
  [[nodiscard]] Vec3 to_volume(Vec3 world) const noexcept;
  /// True when axis is a permutation and every sign is ±1.
  [[nodiscard]] bool valid() const noexcept;
};

/// Fills brick with the kBrickDim³ voxels of volume nearest centre (world, m), in HU rounded and
/// clamped to int16; voxels outside the volume read as air (−1000). brick.valid = 0 when the
/// volume is empty, its direction is not the identity, the placement is invalid or centre is not
/// finite. Allocates nothing.
void fill_brick(const volume::Volume& volume, const VolumePlacement& placement, Vec3 centre, VoxelBrick& brick) noexcept;

}  // namespace lancet::tissue
