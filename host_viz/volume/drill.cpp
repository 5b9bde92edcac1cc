#include "volume/drill.hpp"

#include "volume/detail/index_frame.hpp"

#include <algorithm>
#include <cmath>
#include <string>

namespace lancet::volume {

Result<DrillResult> drill_sphere(Volume& volume, const DrillParams& p, std::span<std::uint8_t> labels) {
  if (!is_finite(p.centre)) return Error{ErrorCode::kInvalid, "drill: centre must be finite"};
  if (!(p.radius > 0) || !std::isfinite(p.radius))
    return Error{ErrorCode::kInvalid, "drill: radius must be positive and finite, found " + std::to_string(p.radius) + " m"};
  if (!labels.empty() && labels.size() != volume.voxel_count())
    return Error{ErrorCode::kInvalid, "drill: labels have " + std::to_string(labels.size()) + " entries, expected " +
                                          std::to_string(volume.voxel_count())};
  const detail::IndexFrame fr = detail::index_frame(volume);
  if (!(std::abs(fr.det) > 0)) return Error{ErrorCode::kInvalid, "drill: the volume's spacing or direction is singular"};
  const auto& inv = fr.inv;
  const double det = fr.det;
  const Vec3 rel = p.centre - volume.origin;
  const double c[3] = {inv[0][0] * rel.x + inv[0][1] * rel.y + inv[0][2] * rel.z, inv[1][0] * rel.x + inv[1][1] * rel.y + inv[1][2] * rel.z,
                       inv[2][0] * rel.x + inv[2][1] * rel.y + inv[2][2] * rel.z};
  DrillResult out;
  std::array<int, 3> lo{}, hi{};
  for (std::size_t a = 0; a < 3; ++a) {
    // The sphere's extent along index axis a is radius · |row a of M⁻¹|.
    const double reach = p.radius * std::sqrt(inv[a][0] * inv[a][0] + inv[a][1] * inv[a][1] + inv[a][2] * inv[a][2]);
    lo[a] = static_cast<int>(std::clamp(std::floor(c[a] - reach), 0.0, double(volume.dims[a])));
    hi[a] = static_cast<int>(std::clamp(std::ceil(c[a] + reach) + 1, 0.0, double(volume.dims[a])));
  }
  const double voxel_mm3 = std::abs(det) * 1e9;
  const double r2 = p.radius * p.radius;
  out.dirty = {{volume.dims[0], volume.dims[1], volume.dims[2]}, {0, 0, 0}};
  for (int k = lo[2]; k < hi[2]; ++k)
    for (int j = lo[1]; j < hi[1]; ++j)
      for (int i = lo[0]; i < hi[0]; ++i) {
        const Vec3 q = volume.position(i, j, k) - p.centre;
        if (dot(q, q) > r2) continue;
        const std::size_t n = volume.index(i, j, k);
        float& v = volume.data[n];
        const bool label_changes = !labels.empty() && labels[n] != p.empty_label;
        const bool had_material = labels.empty() ? v > p.material_above : label_changes;
        if (v == p.empty_value && !label_changes) continue;  // already drilled
        if (had_material) {
          ++out.voxels_removed;
          out.removed_mm3 += voxel_mm3;
          if (!labels.empty()) out.removed_mm3_by_label[labels[n]] += voxel_mm3;
        }
        v = p.empty_value;
        if (!labels.empty()) labels[n] = p.empty_label;
        const int idx[3] = {i, j, k};
        for (std::size_t a = 0; a < 3; ++a) {
          out.dirty.lo[a] = std::min(out.dirty.lo[a], idx[a]);
          out.dirty.hi[a] = std::max(out.dirty.hi[a], idx[a] + 1);
        }
      }
  if (out.dirty.empty()) out.dirty = VoxelBox{};
  return out;
}

}  // namespace lancet::volume
