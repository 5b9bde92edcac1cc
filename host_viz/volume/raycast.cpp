#include "volume/raycast.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace lancet::volume {
namespace {

struct F3 {
  float x, y, z;
};
F3 operator+(F3 a, F3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
F3 operator-(F3 a, F3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
F3 operator*(float s, F3 a) { return {s * a.x, s * a.y, s * a.z}; }
float comp(F3 a, int i) { return i == 0 ? a.x : i == 1 ? a.y : a.z; }

// The same operations, in the same order, as the GLSL in render/volume_raycaster.cpp.
float mixf(float a, float b, float t) { return a + (b - a) * t; }

struct Field {
  const float* data;
  int nx, ny, nz;
  float at(int i, int j, int k) const {
    return data[static_cast<std::size_t>(i) + static_cast<std::size_t>(nx) * (static_cast<std::size_t>(j) + static_cast<std::size_t>(ny) * static_cast<std::size_t>(k))];
  }
  // Trilinear, p in voxel indices, clamped to [0, n − 1].
  float sample(F3 p) const {
    const float px = std::clamp(p.x, 0.0f, static_cast<float>(nx - 1)), py = std::clamp(p.y, 0.0f, static_cast<float>(ny - 1)),
                pz = std::clamp(p.z, 0.0f, static_cast<float>(nz - 1));
    const int i = std::min(static_cast<int>(std::floor(px)), std::max(nx - 2, 0));
    const int j = std::min(static_cast<int>(std::floor(py)), std::max(ny - 2, 0));
    const int k = std::min(static_cast<int>(std::floor(pz)), std::max(nz - 2, 0));
    const int i1 = std::min(i + 1, nx - 1), j1 = std::min(j + 1, ny - 1), k1 = std::min(k + 1, nz - 1);
    const float fx = px - static_cast<float>(i), fy = py - static_cast<float>(j), fz = pz - static_cast<float>(k);
    const float c00 = mixf(at(i, j, k), at(i1, j, k), fx), c10 = mixf(at(i, j1, k), at(i1, j1, k), fx);
    const float c01 = mixf(at(i, j, k1), at(i1, j, k1), fx), c11 = mixf(at(i, j1, k1), at(i1, j1, k1), fx);
    return mixf(mixf(c00, c10, fy), mixf(c01, c11, fy), fz);
  }
};

std::array<float, 4> mul(const std::array<float, 16>& m, float x, float y, float z, float w) {
  std::array<float, 4> r{};
  for (int row = 0; row < 4; ++row)
    r[static_cast<std::size_t>(row)] = m[static_cast<std::size_t>(row)] * x + m[static_cast<std::size_t>(4 + row)] * y +
                                       m[static_cast<std::size_t>(8 + row)] * z + m[static_cast<std::size_t>(12 + row)] * w;
  return r;
}

TfSpec preset_spec(TfPreset p) {
  switch (p) {
    case TfPreset::kCtSkin:
      return {{{-1000, 0, 0, 0, 0}, {-600, 0.76f, 0.50f, 0.40f, 0.0f}, {-400, 0.90f, 0.65f, 0.55f, 0.6f},
               {100, 0.95f, 0.75f, 0.65f, 0.9f}, {3000, 1, 1, 1, 1}},
              -1000, 3000, false};
    case TfPreset::kCtSoftTissue:
      return {{{-1000, 0, 0, 0, 0}, {-200, 0.70f, 0.50f, 0.30f, 0.0f}, {-50, 0.95f, 0.85f, 0.40f, 0.05f},
               {40, 0.80f, 0.25f, 0.20f, 0.25f}, {80, 0.90f, 0.40f, 0.30f, 0.30f}, {300, 0.95f, 0.90f, 0.85f, 0.6f},
               {3000, 1, 1, 1, 0.9f}},
              -1000, 3000, false};
    case TfPreset::kCtBone:
      return {{{-1000, 0, 0, 0, 0}, {150, 0.55f, 0.25f, 0.15f, 0.0f}, {300, 0.90f, 0.80f, 0.70f, 0.4f},
               {1000, 1.0f, 0.97f, 0.90f, 0.9f}, {3000, 1, 1, 1, 1}},
              -1000, 3000, false};
    case TfPreset::kCtVessels:
      return {{{-1000, 0, 0, 0, 0}, {120, 0.60f, 0.10f, 0.10f, 0.0f}, {220, 0.85f, 0.15f, 0.12f, 0.7f},
               {400, 0.95f, 0.30f, 0.25f, 0.85f}, {600, 1.0f, 0.95f, 0.90f, 0.9f}, {3000, 1, 1, 1, 1}},
              -1000, 3000, false};
    case TfPreset::kMip:
      return {{{-1000, 0, 0, 0, 0}, {2000, 1, 1, 1, 1}}, -1000, 3000, true};
  }
  return {};
}

}  // namespace

// ---- transfer function --------------------------------------------------------------------------

TransferFunction TransferFunction::from_points(std::span<const TfPoint> points, float lo, float hi) {
  TransferFunction tf;
  tf.lo = lo;
  tf.hi = hi > lo ? hi : lo + 1;
  for (int e = 0; e < kSize; ++e) {
    const float v = tf.lo + (tf.hi - tf.lo) * static_cast<float>(e) / static_cast<float>(kSize - 1);
    std::array<float, 4> c{};
    if (!points.empty()) {
      if (v <= points.front().value) {
        c = {points.front().r, points.front().g, points.front().b, points.front().a};
      } else if (v >= points.back().value) {
        c = {points.back().r, points.back().g, points.back().b, points.back().a};
      } else {
        for (std::size_t i = 1; i < points.size(); ++i) {
          if (v > points[i].value) continue;
          const TfPoint& a = points[i - 1];
          const TfPoint& b = points[i];
          const float f = b.value > a.value ? (v - a.value) / (b.value - a.value) : 1.0f;
          c = {mixf(a.r, b.r, f), mixf(a.g, b.g, f), mixf(a.b, b.b, f), mixf(a.a, b.a, f)};
          break;
        }
      }
    }
    for (float& x : c) x = std::clamp(x, 0.0f, 1.0f);
    tf.table[static_cast<std::size_t>(e)] = c;
  }
  return tf;
}

std::array<float, 4> TransferFunction::lookup(float v) const noexcept {
  const float x = std::clamp((v - lo) / (hi - lo) * static_cast<float>(kSize - 1), 0.0f, static_cast<float>(kSize - 1));
  const int i = std::min(static_cast<int>(x), kSize - 2);
  const float f = x - static_cast<float>(i);
  const auto& a = table[static_cast<std::size_t>(i)];
  const auto& b = table[static_cast<std::size_t>(i + 1)];
  return {mixf(a[0], b[0], f), mixf(a[1], b[1], f), mixf(a[2], b[2], f), mixf(a[3], b[3], f)};
}

float TransferFunction::max_alpha(float a, float b) const noexcept {
  const auto entry = [&](float v) {
    return std::clamp((v - lo) / (hi - lo) * static_cast<float>(kSize - 1), 0.0f, static_cast<float>(kSize - 1));
  };
  const int i0 = static_cast<int>(std::floor(entry(std::min(a, b)))), i1 = static_cast<int>(std::ceil(entry(std::max(a, b))));
  float m = 0;
  for (int i = std::max(i0, 0); i <= std::min(i1, kSize - 1); ++i) m = std::max(m, table[static_cast<std::size_t>(i)][3]);
  return m;
}

float TransferFunction::constant_from() const noexcept {
  int last = -1;  // the last entry that differs from the top one
  for (int i = kSize - 2; i >= 0 && last < 0; --i)
    if (table[static_cast<std::size_t>(i)] != table[kSize - 1]) last = i;
  // lookup() blends entries i and i+1 with i = floor(x): from x >= last + 1 both are the top one.
  // One entry more of margin, against rounding in the value-to-entry mapping.
  if (last + 2 > kSize - 1) return std::numeric_limits<float>::infinity();
  return lo + (hi - lo) * static_cast<float>(last + 2) / static_cast<float>(kSize - 1);
}

std::string_view tf_preset_name(TfPreset p) noexcept {
  switch (p) {
    case TfPreset::kCtSkin: return "CT-Skin";
    case TfPreset::kCtSoftTissue: return "CT-Soft-Tissue";
    case TfPreset::kCtBone: return "CT-Bone";
    case TfPreset::kCtVessels: return "CT-Vessels (contrast)";
    case TfPreset::kMip: return "MIP";
  }
  return "?";
}

TransferFunction tf_preset(TfPreset p) { return tf_preset(p, 0.0f, 1.0f); }

TfSpec tf_preset_spec(TfPreset p, float level_shift, float width_scale) {
  TfSpec s = preset_spec(p);
  // The window's centre: the middle of the inner control points (the ends only pin the table).
  float centre = 0;
  if (s.points.size() > 2) {
    for (std::size_t i = 1; i + 1 < s.points.size(); ++i) centre += s.points[i].value;
    centre /= static_cast<float>(s.points.size() - 2);
  }
  const float w = std::max(width_scale, 0.01f);
  for (std::size_t i = 1; i + 1 < s.points.size(); ++i) s.points[i].value = centre + (s.points[i].value - centre) * w + level_shift;
  std::sort(s.points.begin(), s.points.end(), [](const TfPoint& a, const TfPoint& b) { return a.value < b.value; });
  return s;
}

TransferFunction TfSpec::table() const {
  TransferFunction tf = TransferFunction::from_points(points, lo, hi);
  tf.mip = mip;
  return tf;
}

TransferFunction tf_preset(TfPreset p, float level_shift, float width_scale) {
  return tf_preset_spec(p, level_shift, width_scale).table();
}

// ---- bricks -------------------------------------------------------------------------------------

BrickGrid::BrickGrid(const Volume& v) {
  for (int a = 0; a < 3; ++a) dims_[static_cast<std::size_t>(a)] = std::max(1, (v.dims[static_cast<std::size_t>(a)] + kBrick - 1) / kBrick);
  const std::size_t n = static_cast<std::size_t>(dims_[0]) * static_cast<std::size_t>(dims_[1]) * static_cast<std::size_t>(dims_[2]);
  min_.assign(n, 0);
  max_.assign(n, 0);
  update(v, VoxelBox{{0, 0, 0}, v.dims});
}

void BrickGrid::compute(const Volume& v, int bx, int by, int bz) {
  float lo = std::numeric_limits<float>::max(), hi = std::numeric_limits<float>::lowest();
  const int i0 = std::max(bx * kBrick - 1, 0), i1 = std::min(bx * kBrick + kBrick + 1, v.dims[0] - 1);
  const int j0 = std::max(by * kBrick - 1, 0), j1 = std::min(by * kBrick + kBrick + 1, v.dims[1] - 1);
  const int k0 = std::max(bz * kBrick - 1, 0), k1 = std::min(bz * kBrick + kBrick + 1, v.dims[2] - 1);
  for (int k = k0; k <= k1; ++k)
    for (int j = j0; j <= j1; ++j)
      for (int i = i0; i <= i1; ++i) {
        const float x = v.data[v.index(i, j, k)];
        lo = std::min(lo, x);
        hi = std::max(hi, x);
      }
  const std::size_t b = static_cast<std::size_t>(bx) + static_cast<std::size_t>(dims_[0]) * (static_cast<std::size_t>(by) + static_cast<std::size_t>(dims_[1]) * static_cast<std::size_t>(bz));
  min_[b] = lo;
  max_[b] = hi;
}

void BrickGrid::update(const Volume& v, VoxelBox box) {
  if (box.empty() || v.data.empty()) return;
  std::array<int, 3> lo{}, hi{};
  for (std::size_t a = 0; a < 3; ++a) {
    // A voxel is in the apron of the bricks one voxel (below) and two voxels (above) around it.
    lo[a] = std::clamp((box.lo[a] - 2) / kBrick, 0, dims_[a] - 1);
    hi[a] = std::clamp((box.hi[a] + 1) / kBrick, 0, dims_[a] - 1);
  }
  for (int bz = lo[2]; bz <= hi[2]; ++bz)
    for (int by = lo[1]; by <= hi[1]; ++by)
      for (int bx = lo[0]; bx <= hi[0]; ++bx) compute(v, bx, by, bz);
}

std::vector<std::uint8_t> BrickGrid::empty_mask(const TransferFunction& tf) const {
  std::vector<std::uint8_t> m(min_.size());
  for (std::size_t b = 0; b < m.size(); ++b) m[b] = !tf.mip && tf.max_alpha(min_[b], max_[b]) <= 0.0f ? 1 : 0;
  return m;
}

// ---- the reference ray caster -------------------------------------------------------------------

float reference_step(const Volume& v) noexcept {
  return static_cast<float>(std::min({v.spacing.x, v.spacing.y, v.spacing.z}));
}

float ray_jitter(int x, int y) noexcept {
  std::uint32_t h = static_cast<std::uint32_t>(x) * 1973u + static_cast<std::uint32_t>(y) * 9277u + 26699u;
  h = (h ^ 61u) ^ (h >> 16);
  h *= 9u;
  h ^= h >> 4;
  h *= 0x27d4eb2du;
  h ^= h >> 15;
  return static_cast<float>(h >> 8) * (1.0f / 16777216.0f);
}

void raycast_cpu(const Volume& v, const BrickGrid& grid, const TransferFunction& tf, const RayCamera& cam,
                 const RaycastParams& params, std::span<const float> max_t, RgbaImage& out, RaycastStats* stats) {
  out.width = cam.width;
  out.height = cam.height;
  out.rgba.assign(static_cast<std::size_t>(cam.width) * static_cast<std::size_t>(cam.height) * 4, 0.0f);
  if (v.data.empty()) return;
  const Field field{v.data.data(), v.dims[0], v.dims[1], v.dims[2]};
  const F3 origin{static_cast<float>(v.origin.x), static_cast<float>(v.origin.y), static_cast<float>(v.origin.z)};
  const F3 spacing{static_cast<float>(v.spacing.x), static_cast<float>(v.spacing.y), static_cast<float>(v.spacing.z)};
  const float ref = reference_step(v);
  const float ds = params.step * ref;
  const std::vector<std::uint8_t> empty = grid.empty_mask(tf);
  const std::span<const float> brick_max = grid.max();
  const float mip_stop = tf.constant_from();
  const auto bd = grid.dims();
  RaycastStats st;
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      const float nx = 2.0f * (static_cast<float>(x) + 0.5f) / static_cast<float>(cam.width) - 1.0f;
      const float ny = 2.0f * (static_cast<float>(y) + 0.5f) / static_cast<float>(cam.height) - 1.0f;
      const auto a = mul(cam.inv_view_proj, nx, ny, -1, 1), b = mul(cam.inv_view_proj, nx, ny, 1, 1);
      const F3 pn{a[0] / a[3], a[1] / a[3], a[2] / a[3]}, pf{b[0] / b[3], b[1] / b[3], b[2] / b[3]};
      F3 dir = pf - pn;
      const float len = std::sqrt(dir.x * dir.x + dir.y * dir.y + dir.z * dir.z);
      dir = (1.0f / len) * dir;
      // In voxel indices: q(t) = q0 + t·qd.
      const F3 q0{(pn.x - origin.x) / spacing.x, (pn.y - origin.y) / spacing.y, (pn.z - origin.z) / spacing.z};
      const F3 qd{dir.x / spacing.x, dir.y / spacing.y, dir.z / spacing.z};
      float t_in = 0, t_out = len;
      for (int ax = 0; ax < 3; ++ax) {
        const float o = comp(q0, ax), d = comp(qd, ax), hi = static_cast<float>(v.dims[static_cast<std::size_t>(ax)] - 1);
        if (d == 0.0f) {
          if (o < 0.0f || o > hi) t_out = -1;
          continue;
        }
        const float t0 = (0.0f - o) / d, t1 = (hi - o) / d;
        t_in = std::max(t_in, std::min(t0, t1));
        t_out = std::min(t_out, std::max(t0, t1));
      }
      const std::size_t pix = static_cast<std::size_t>(y) * static_cast<std::size_t>(cam.width) + static_cast<std::size_t>(x);
      if (!max_t.empty()) t_out = std::min(t_out, max_t[pix]);
      if (params.clip) {  // keep the part of the ray where the plane's function is <= 0
        const auto& c = params.clip_plane;
        const float f0 = c[0] * pn.x + c[1] * pn.y + c[2] * pn.z + c[3], fd = c[0] * dir.x + c[1] * dir.y + c[2] * dir.z;
        if (fd > 0.0f) {
          t_out = std::min(t_out, -f0 / fd);
        } else if (fd < 0.0f) {
          t_in = std::max(t_in, -f0 / fd);
        } else if (f0 > 0.0f) {
          t_out = -1;
        }
      }
      float cr = 0, cg = 0, cb = 0, ca = 0, vmax = std::numeric_limits<float>::lowest();
      const float j = params.jitter ? ray_jitter(x, y) : 0.0f;
      bool any = false;
      for (int k = 0;;) {
        const float t = t_in + (static_cast<float>(k) + j) * ds;
        if (!(t <= t_out)) break;
        const F3 p = q0 + t * qd;
        if (params.skip_empty) {
          const int bx = std::clamp(static_cast<int>(std::floor(p.x / 8.0f)), 0, bd[0] - 1);
          const int by = std::clamp(static_cast<int>(std::floor(p.y / 8.0f)), 0, bd[1] - 1);
          const int bz = std::clamp(static_cast<int>(std::floor(p.z / 8.0f)), 0, bd[2] - 1);
          const std::size_t brick = static_cast<std::size_t>(bx) + static_cast<std::size_t>(bd[0]) * (static_cast<std::size_t>(by) + static_cast<std::size_t>(bd[1]) * static_cast<std::size_t>(bz));
          if (tf.mip ? any && brick_max[brick] <= vmax : empty[brick] != 0) {
            float t_exit = std::numeric_limits<float>::max();
            const int bi[3] = {bx, by, bz};
            for (int ax = 0; ax < 3; ++ax) {
              const float d = comp(qd, ax), o = comp(q0, ax);
              if (d > 0.0f) t_exit = std::min(t_exit, (static_cast<float>((bi[ax] + 1) * 8) - o) / d);
              else if (d < 0.0f) t_exit = std::min(t_exit, (static_cast<float>(bi[ax] * 8) - o) / d);
            }
            const int next = static_cast<int>(std::ceil((t_exit - t_in) / ds - j));
            k = std::max(next, k + 1);
            ++st.skipped_bricks;
            continue;
          }
        }
        const float value = field.sample(p);
        ++st.samples;
        any = true;
        if (tf.mip) {
          vmax = std::max(vmax, value);
          if (vmax >= mip_stop) {  // the table gives every larger value the same colour
            ++st.early_stops;
            break;
          }
          ++k;
          continue;
        }
        const auto c = tf.lookup(value);
        if (c[3] > 0.0f) {
          const float alpha = params.opacity_correction ? 1.0f - std::pow(1.0f - c[3], params.step) : c[3];
          float light = 1.0f;
          if (params.shade) {
            const F3 ex{1, 0, 0}, ey{0, 1, 0}, ez{0, 0, 1};
            const float gx = (field.sample(p + ex) - field.sample(p - ex)) * 0.5f / spacing.x;
            const float gy = (field.sample(p + ey) - field.sample(p - ey)) * 0.5f / spacing.y;
            const float gz = (field.sample(p + ez) - field.sample(p - ez)) * 0.5f / spacing.z;
            const float gl = std::sqrt(gx * gx + gy * gy + gz * gz);
            if (gl > 1e-3f) light = 0.3f + 0.7f * std::abs((gx * dir.x + gy * dir.y + gz * dir.z) / gl);
          }
          const float w = (1.0f - ca) * alpha;
          cr += w * c[0] * light;
          cg += w * c[1] * light;
          cb += w * c[2] * light;
          ca += w;
          if (ca >= params.early_stop) {
            ++st.early_stops;
            break;
          }
        }
        ++k;
      }
      if (tf.mip && any) {
        const auto c = tf.lookup(vmax);
        cr = c[0] * c[3], cg = c[1] * c[3], cb = c[2] * c[3], ca = c[3];
      }
      float* o = out.rgba.data() + 4 * pix;
      o[0] = cr, o[1] = cg, o[2] = cb, o[3] = ca;
    }
  if (stats != nullptr) *stats = st;
}

}  // namespace lancet::volume
