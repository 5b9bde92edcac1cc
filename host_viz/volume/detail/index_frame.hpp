#pragma once
// The map from voxel indices to world positions, world = origin + M · index with
// M = direction · diag(spacing), and its inverse. Shared by marching cubes (normals from the
// gradient) and drilling (the burr in index space). Internal.

#include <cmath>
#include <cstddef>

#include "volume/volume.hpp"

namespace lancet::volume::detail {

struct IndexFrame {
  double m[3][3];    ///< m[r][a]: world component r of one step along index axis a
  double inv[3][3];  ///< M⁻¹ (all zeros when M is singular)
  double det;
};

inline IndexFrame index_frame(const Volume& vol) noexcept {
  IndexFrame f{};
  const double s[3] = {vol.spacing.x, vol.spacing.y, vol.spacing.z};
  for (int r = 0; r < 3; ++r)
    for (int a = 0; a < 3; ++a) f.m[r][a] = vol.direction[static_cast<std::size_t>(r * 3 + a)] * s[a];
  const auto& m = f.m;
  f.det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
          m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
  if (!(std::abs(f.det) > 0)) return f;
  const double d = f.det;
  f.inv[0][0] = (m[1][1] * m[2][2] - m[1][2] * m[2][1]) / d;
  f.inv[0][1] = (m[0][2] * m[2][1] - m[0][1] * m[2][2]) / d;
  f.inv[0][2] = (m[0][1] * m[1][2] - m[0][2] * m[1][1]) / d;
  f.inv[1][0] = (m[1][2] * m[2][0] - m[1][0] * m[2][2]) / d;
  f.inv[1][1] = (m[0][0] * m[2][2] - m[0][2] * m[2][0]) / d;
  f.inv[1][2] = (m[0][2] * m[1][0] - m[0][0] * m[1][2]) / d;
  f.inv[2][0] = (m[1][0] * m[2][1] - m[1][1] * m[2][0]) / d;
  f.inv[2][1] = (m[0][1] * m[2][0] - m[0][0] * m[2][1]) / d;
  f.inv[2][2] = (m[0][0] * m[1][1] - m[0][1] * m[1][0]) / d;
  return f;
}

}  // namespace lancet::volume::detail
