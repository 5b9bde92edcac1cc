#include "tissue/volume_brick.hpp"

#include <algorithm>
#include <cmath>

namespace lancet::tissue {
namespace {

double& at(Vec3& v, int a) noexcept { return a == 0 ? v.x : a == 1 ? v.y : v.z; }
double at(const Vec3& v, int a) noexcept { return a == 0 ? v.x : a == 1 ? v.y : v.z; }

bool identity_direction(const volume::Volume& v) noexcept {
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      if (v.direction[static_cast<std::size_t>(3 * r + c)] != (r == c ? 1.0 : 0.0)) return false;
  return true;
}

}  // namespace

Vec3 VolumePlacement::to_world(Vec3 v) const noexcept {
  Vec3 w;
  for (int a = 0; a < 3; ++a) at(w, a) = sign[static_cast<std::size_t>(a)] * at(v, axis[static_cast<std::size_t>(a)]) + at(offset, a);
  return w;
}

Vec3 VolumePlacement::to_volume(Vec3 world) const noexcept {
  Vec3 v;
  for (int a = 0; a < 3; ++a)
    at(v, axis[static_cast<std::size_t>(a)]) = (at(world, a) - at(offset, a)) * sign[static_cast<std::size_t>(a)];
  return v;
}

bool VolumePlacement::valid() const noexcept {
  std::array<bool, 3> seen{};
  for (int a = 0; a < 3; ++a) {
    const int ax = axis[static_cast<std::size_t>(a)];
    if (ax < 0 || ax > 2 || seen[static_cast<std::size_t>(ax)]) return false;
    seen[static_cast<std::size_t>(ax)] = true;
    if (sign[static_cast<std::size_t>(a)] != 1 && sign[static_cast<std::size_t>(a)] != -1) return false;
  }
  return true;
}

void fill_brick(const volume::Volume& volume, const VolumePlacement& placement, Vec3 centre, VoxelBrick& brick) noexcept {
  brick.valid = 0;
  brick.dim = kBrickDim;
  if (volume.voxel_count() == 0 || volume.data.size() != volume.voxel_count() || !identity_direction(volume) ||
      !placement.valid() || !is_finite(centre))
    return;
  // The brick's spacing along world axis a is the volume's along the axis that maps onto it.
  Vec3 spacing;
  for (int a = 0; a < 3; ++a) at(spacing, a) = at(volume.spacing, placement.axis[static_cast<std::size_t>(a)]);
  const double half = 0.5 * (kBrickDim - 1);
  // Voxel (0, 0, 0) of the brick: the volume voxel nearest the brick's corner, so every brick
  // voxel is a volume voxel.
  const Vec3 corner = placement.to_volume(centre - Vec3{half * spacing.x, half * spacing.y, half * spacing.z});
  std::array<long, 3> base{};
  for (int a = 0; a < 3; ++a)
    base[static_cast<std::size_t>(a)] = std::lround((at(corner, a) - at(volume.origin, a)) / at(volume.spacing, a));
  brick.origin = placement.to_world(volume.origin + Vec3{static_cast<double>(base[0]) * volume.spacing.x,
                                                        static_cast<double>(base[1]) * volume.spacing.y,
                                                        static_cast<double>(base[2]) * volume.spacing.z});
  brick.spacing = spacing;
  // Stepping the brick along world axis a steps the volume index along axis[a] by sign[a].
  for (std::uint32_t k = 0; k < kBrickDim; ++k)
    for (std::uint32_t j = 0; j < kBrickDim; ++j)
      for (std::uint32_t i = 0; i < kBrickDim; ++i) {
        const std::array<std::uint32_t, 3> b{i, j, k};
        std::array<long, 3> idx = base;
        for (std::size_t a = 0; a < 3; ++a) idx[static_cast<std::size_t>(placement.axis[a])] += placement.sign[a] * static_cast<long>(b[a]);
        float hu = -1000.0f;
        if (idx[0] >= 0 && idx[1] >= 0 && idx[2] >= 0 && idx[0] < volume.dims[0] && idx[1] < volume.dims[1] && idx[2] < volume.dims[2]) {
          hu = volume.at(static_cast<int>(idx[0]), static_cast<int>(idx[1]), static_cast<int>(idx[2]));
        }
        if (!std::isfinite(hu)) hu = -1000.0f;
        brick.hu[i + kBrickDim * (j + kBrickDim * k)] = static_cast<std::int16_t>(std::lround(std::clamp(hu, -32768.0f, 32767.0f)));
      }
  brick.valid = 1;
}

}  // namespace lancet::tissue
