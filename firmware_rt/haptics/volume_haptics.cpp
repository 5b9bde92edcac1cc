#include "haptics/volume_haptics.hpp"

#include <algorithm>
#include <cmath>

namespace lancet::haptics {
namespace {

bool usable(const VoxelBrick& b) {
  return b.valid == 1 && b.dim == kBrickDim && b.spacing.x > 0 && b.spacing.y > 0 && b.spacing.z > 0 &&
         is_finite(b.origin) && is_finite(b.spacing);
}

double voxel(const VoxelBrick& b, int i, int j, int k) {
  const int n = static_cast<int>(kBrickDim);
  if (i < 0 || j < 0 || k < 0 || i >= n || j >= n || k >= n) return kAirHu;
  return b.hu[static_cast<std::size_t>((k * n + j) * n + i)];
}

}  // namespace

double sample_hu(const VoxelBrick& b, Vec3 p) noexcept {
  if (!usable(b) || !is_finite(p)) return kAirHu;
  const double fx = (p.x - b.origin.x) / b.spacing.x, fy = (p.y - b.origin.y) / b.spacing.y,
               fz = (p.z - b.origin.z) / b.spacing.z;
  const double lim = static_cast<double>(kBrickDim);
  if (fx < -1 || fy < -1 || fz < -1 || fx > lim || fy > lim || fz > lim) return kAirHu;
  const int i = static_cast<int>(std::floor(fx)), j = static_cast<int>(std::floor(fy)), k = static_cast<int>(std::floor(fz));
  const double tx = fx - i, ty = fy - j, tz = fz - k;
  double v = 0;
  for (int c = 0; c < 8; ++c) {
    const int di = c & 1, dj = (c >> 1) & 1, dk = (c >> 2) & 1;
    const double w = (di ? tx : 1 - tx) * (dj ? ty : 1 - ty) * (dk ? tz : 1 - tz);
    v += w * voxel(b, i + di, j + dj, k + dk);
  }
  return v;
}

Vec3 gradient_hu(const VoxelBrick& b, Vec3 p) noexcept {
  const Vec3 h = 0.5 * b.spacing;
  return {(sample_hu(b, p + Vec3{h.x, 0, 0}) - sample_hu(b, p - Vec3{h.x, 0, 0})) / b.spacing.x,
          (sample_hu(b, p + Vec3{0, h.y, 0}) - sample_hu(b, p - Vec3{0, h.y, 0})) / b.spacing.y,
          (sample_hu(b, p + Vec3{0, 0, h.z}) - sample_hu(b, p - Vec3{0, 0, h.z})) / b.spacing.z};
}

VolumeContact volume_proxy_step(const VoxelBrick& b, double iso, Vec3 p, Vec3 goal) noexcept {
  VolumeContact r{p, {}, false};
  if (!usable(b) || !is_finite(goal)) return r;
  const double h = 0.25 * std::min({b.spacing.x, b.spacing.y, b.spacing.z});
  Vec3 rem = goal - p;
  for (int step = 0; step < 64 && dot(rem, rem) > 1e-18; ++step) {
    const double len = norm(rem);
    const Vec3 s = (std::min(h, len) / len) * rem;
    if (sample_hu(b, r.position + s) < iso) {
      r.position += s;
      rem -= s;
      continue;
    }
    // At the iso surface: the outward normal is against the density gradient. Drop the part of
    // the remaining motion that goes into the solid and slide with the rest.
    const Vec3 n = normalized(-1.0 * gradient_hu(b, r.position + s));
    r.contact = true;
    r.normal = n;
    const double into = dot(rem, n);
    if (into >= 0 || n == Vec3{}) break;  // no usable normal, or not pushing in: stop here
    rem -= into * n;
  }
  return r;
}

std::uint32_t carve_sphere(VoxelBrick& b, Vec3 centre, double radius) noexcept {
  if (!usable(b) || !is_finite(centre) || !(radius > 0)) return 0;
  const int n = static_cast<int>(kBrickDim);
  std::uint32_t changed = 0;
  const auto range = [&](double c, double o, double s, int& lo, int& hi) {
    lo = std::max(0, static_cast<int>(std::floor((c - radius - o) / s)));
    hi = std::min(n - 1, static_cast<int>(std::ceil((c + radius - o) / s)));
  };
  int i0, i1, j0, j1, k0, k1;
  range(centre.x, b.origin.x, b.spacing.x, i0, i1);
  range(centre.y, b.origin.y, b.spacing.y, j0, j1);
  range(centre.z, b.origin.z, b.spacing.z, k0, k1);
  for (int k = k0; k <= k1; ++k)
    for (int j = j0; j <= j1; ++j)
      for (int i = i0; i <= i1; ++i) {
        const Vec3 c{b.origin.x + i * b.spacing.x, b.origin.y + j * b.spacing.y, b.origin.z + k * b.spacing.z};
        std::int16_t& v = b.hu[static_cast<std::size_t>((k * n + j) * n + i)];
        if (norm(c - centre) <= radius && v != kAirHu) {
          v = kAirHu;
          ++changed;
        }
      }
  return changed;
}

}  // namespace lancet::haptics
