#include "volume/nonfinite.hpp"

#include <cassert>
#include <cmath>

namespace lancet::volume {

NonFiniteVoxels count_nonfinite(const Volume& volume) noexcept {
  NonFiniteVoxels n;
  for (std::size_t i = 0; i < volume.data.size(); ++i) {
    const float x = volume.data[i];
    if (std::isfinite(x)) continue;
    if (n.total() == 0) n.first = i;
    if (std::isnan(x)) ++n.nan;
    else ++n.infinite;
  }
  return n;
}

std::size_t replace_nonfinite(Volume& volume, float value) noexcept {
  assert(std::isfinite(value) && "replace_nonfinite: the replacement must be finite");
  std::size_t n = 0;
  for (float& x : volume.data) {
    if (!std::isfinite(x)) {
      x = value;
      ++n;
    }
  }
  return n;
}

}  // namespace lancet::volume
