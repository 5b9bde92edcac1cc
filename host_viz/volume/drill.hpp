#pragma once
// Drilling (thesis 3.3.3): a spherical burr removes the voxels whose centres lie inside it, sets
// them to the empty value (air), and reports the box of voxels it changed, so the surface can be
// re-extracted there (LiveIsosurface::update), and the material it removed.
// Allocating nothing per call; viz frame time.

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>

#include "lancet/shared_model/geometry.hpp"
#include "lancet/shared_model/result.hpp"
#include "volume/live_isosurface.hpp"
#include "volume/volume.hpp"

namespace lancet::volume {

struct DrillParams {
  Vec3 centre{};              ///< m, world
  double radius = 0.0025;     ///< m (a 5 mm burr)
  float empty_value = -1000;  ///< what removed voxels become (air in HU)
  float material_above = -500;  ///< without labels, a voxel above this value counts as material
  std::uint8_t empty_label = 0;  ///< with labels, a voxel not of this label counts as material
};

struct DrillResult {
  VoxelBox dirty;                    ///< voxels changed (empty when nothing was removed)
  std::size_t voxels_removed = 0;    ///< voxels that held material (see DrillParams)
  double removed_mm3 = 0;            ///< their volume
  std::array<double, 256> removed_mm3_by_label{};  ///< by label when labels were given
};

/// Removes material inside the sphere. labels (optional, one per voxel) are set to empty_label
/// and the removed volume is split by label. Errors: a non-finite centre, a radius that is not
/// positive and finite, or labels of the wrong size.
[[nodiscard]] Result<DrillResult> drill_sphere(Volume& volume, const DrillParams& params, std::span<std::uint8_t> labels = {});

}  // namespace lancet::volume
