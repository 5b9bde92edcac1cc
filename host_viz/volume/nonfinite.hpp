#pragma once
// Non-finite voxels (NaN, +inf, -inf). A float volume can hold them (a failed reconstruction, a
// mask written as NaN), and every figure made from them is NaN too: an isosurface vertex on an
// edge with a NaN end, a mean, a histogram. Programs count them, then refuse them or replace them
// with a value before meshing. Allocation-free, one pass over the voxels; not for the real-time
// path (O(voxels)).

#include <cstddef>

#include "volume/volume.hpp"

namespace lancet::volume {

struct NonFiniteVoxels {
  std::size_t nan = 0;       ///< NaN voxels
  std::size_t infinite = 0;  ///< +inf or -inf voxels
  std::size_t first = 0;     ///< data index (Volume::index) of the first one; meaningful when total() > 0

  [[nodiscard]] std::size_t total() const noexcept { return nan + infinite; }
};

/// Counts the NaN and infinite voxels of volume.data.
[[nodiscard]] NonFiniteVoxels count_nonfinite(const Volume& volume) noexcept;

/// Replaces every NaN and infinite voxel with `value`, which must be finite (asserted); returns how
/// many were replaced.
std::size_t replace_nonfinite(Volume& volume, float value) noexcept;

}  // namespace lancet::volume
