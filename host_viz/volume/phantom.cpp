#include "volume/phantom.hpp"

#include "volume/in_two_halves.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace lancet::volume {
namespace {

// splitmix64: a fast, well-mixed hash of a 64-bit key.
std::uint64_t mix(std::uint64_t x) noexcept {
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

// A standard normal sample from (seed, index) by Box–Muller on two hashed uniforms.
double gaussian(std::uint64_t seed, std::uint64_t index) noexcept {
  const std::uint64_t a = mix(seed ^ mix(index * 2 + 1)), b = mix(seed ^ mix(index * 2 + 2));
  const double u1 = (static_cast<double>(a >> 11) + 1.0) * 0x1.0p-53;  // (0, 1]
  const double u2 = static_cast<double>(b >> 11) * 0x1.0p-53;
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * std::numbers::pi * u2);
}

double lerp(double a, double b, double t) noexcept { return a + (b - a) * t; }

}  // namespace

double partial_volume_fraction(double d, double spacing) noexcept { return std::clamp(0.5 + d / (2.0 * spacing), 0.0, 1.0); }

float phantom_hu(PhantomMaterial m) noexcept {
  switch (m) {
    case kAir: return -1000.0f;
    case kSkin: return 40.0f;
    case kFat: return -100.0f;
    case kMuscle: return 50.0f;
    case kCorticalBone: return 1200.0f;
    case kMarrow: return 300.0f;
    case kVessel: return 250.0f;  // contrast-enhanced blood
    case kVein: return 45.0f;     // blood without contrast
  }
  return -1000.0f;
}

LabelledVolume make_phantom(const PhantomParams& p) {
  LabelledVolume ph;
  Volume& v = ph.volume;
  v.dims = p.dims;
  v.spacing = {p.spacing, p.spacing, p.spacing};
  v.origin = {-0.5 * (p.dims[0] - 1) * p.spacing, -0.5 * (p.dims[1] - 1) * p.spacing, -0.5 * (p.dims[2] - 1) * p.spacing};
  v.source_type = VoxelType::kF32;
  v.value_unit = "HU";
  v.modality = "CT";  // a simulated CT
  v.data.resize(v.voxel_count());
  ph.material.resize(v.voxel_count());
  const double half_len = 0.5 * (p.dims[2] - 1) * p.spacing;
  // Slice k depends on nothing but k, so the slices are shared between two threads (the same
  // numbers either way).
  const auto slice = [&](int k) {
    const Vec3 c = v.position(0, 0, k);
    const double zn = half_len > 0 ? c.z / half_len : 0;  // −1 … 1 along the limb
    // Cross-section: slightly elliptical, tapering toward +z.
    const double outer = p.limb_radius * (1.0 - 0.075 * zn);
    const double ey = 0.85;  // the limb is flatter front to back
    // The bone sits off centre; two vessels wind beside it.
    const Vec3 bone{0.006, -0.004, 0};
    const Vec3 artery{-0.012 + 0.003 * std::sin(3.0 * zn), 0.012 + 0.002 * std::cos(2.0 * zn), 0};
    const Vec3 vein{0.018 + 0.002 * std::cos(2.5 * zn), 0.014, 0};
    // A superficial vein (2 mm radius) in the fat under the skin's top (+y is the front: up in the
    // scene), its centre 5.5 mm below the surface, so that a 6 mm incision across it opens it.
    const double top_x = 0.012 + 0.002 * std::sin(2.0 * zn);
    const Vec3 superficial{top_x, ey * std::sqrt(std::max(outer * outer - top_x * top_x, 0.0)) - 0.0055, 0};
    for (int j = 0; j < p.dims[1]; ++j) {
      for (int i = 0; i < p.dims[0]; ++i) {
        const Vec3 w = v.position(i, j, k);
        const double r = std::hypot(w.x, w.y / ey);
        const double rb = std::hypot(w.x - bone.x, w.y - bone.y);
        const double ra = std::hypot(w.x - artery.x, w.y - artery.y), rv = std::hypot(w.x - vein.x, w.y - vein.y);
        const double rs = std::hypot(w.x - superficial.x, w.y - superficial.y);
        PhantomMaterial m = kAir;
        if (r <= outer) {
          m = r > outer - p.skin ? kSkin : r > outer - p.skin - p.fat ? kFat : kMuscle;
          if (rb <= p.bone_radius) m = rb > p.bone_radius - p.cortex ? kCorticalBone : kMarrow;
          if (ra <= 0.003 || rv <= 0.0022) m = kVessel;
          if (rs <= 0.002) m = kVein;
        }
        const std::size_t idx = v.index(i, j, k);
        ph.material[idx] = m;
        double hu = phantom_hu(m);
        if (p.partial_volume) {
          // Distances to each boundary (positive inside it). The layers are level sets of the
          // elliptical radius r; dividing by |∇r| turns a difference of r into a distance.
          const double g = r > 0 ? std::hypot(w.x, w.y / (ey * ey)) / r : 1.0;
          const auto hu_of = [](PhantomMaterial mat) { return static_cast<double>(phantom_hu(mat)); };
          const double h = p.spacing;
          const double fat_layer = lerp(hu_of(kFat), hu_of(kMuscle), partial_volume_fraction((outer - p.skin - p.fat - r) / g, h));
          const double skin_layer = lerp(hu_of(kSkin), fat_layer, partial_volume_fraction((outer - p.skin - r) / g, h));
          hu = lerp(hu_of(kAir), skin_layer, partial_volume_fraction((outer - r) / g, h));
          const double bone_hu = lerp(hu_of(kCorticalBone), hu_of(kMarrow), partial_volume_fraction(p.bone_radius - p.cortex - rb, h));
          hu = lerp(hu, bone_hu, partial_volume_fraction(p.bone_radius - rb, h));
          const double vessel = std::max(partial_volume_fraction(0.003 - ra, h), partial_volume_fraction(0.0022 - rv, h));
          hu = lerp(hu, hu_of(kVessel), vessel);
          hu = lerp(hu, hu_of(kVein), partial_volume_fraction(0.002 - rs, h));
        }
        v.data[idx] = static_cast<float>(hu + p.noise_hu * gaussian(p.seed, idx));
      }
    }
  };
  in_two_halves(static_cast<std::size_t>(p.dims[2]), p.threads >= 2 && v.voxel_count() >= (std::size_t{1} << 16),
                [&](std::size_t begin, std::size_t end, int) {
                  for (std::size_t k = begin; k < end; ++k) slice(static_cast<int>(k));
                });
  return ph;
}

}  // namespace lancet::volume
