#include "volume/phantom.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <utility>
#include <vector>

#include "volume/marching_cubes.hpp"

namespace lancet::volume {
namespace {

PhantomParams small() {
  PhantomParams p;
  p.dims = {100, 100, 40};
  return p;
}

TEST(LabelledVolume, GeometryAndUnits) {
  const LabelledVolume ph = make_phantom(small());
  const Volume& v = ph.volume;
  EXPECT_EQ(v.dims, (std::array<int, 3>{100, 100, 40}));
  EXPECT_EQ(v.value_unit, "HU");
  EXPECT_DOUBLE_EQ(v.spacing.x, 0.001);
  EXPECT_EQ(v.data.size(), 100u * 100u * 40u);
  EXPECT_EQ(ph.material.size(), v.data.size());
  // Centred on the origin.
  const Vec3 mid = v.position(49.5, 49.5, 19.5);
  EXPECT_NEAR(norm(mid), 0, 1e-12);
}

TEST(LabelledVolume, DeterministicFromTheSeed) {
  PhantomParams p = small();
  const LabelledVolume a = make_phantom(p), b = make_phantom(p);
  EXPECT_EQ(a.volume.data, b.volume.data);
  p.seed = 2;
  const LabelledVolume c = make_phantom(p);
  EXPECT_NE(a.volume.data, c.volume.data);
  EXPECT_EQ(a.material, c.material);  // only the noise depends on the seed
}

TEST(LabelledVolume, LayersHaveTheirHounsfieldUnitsAndTheNoiseItsSpread) {
  PhantomParams p = small();
  p.partial_volume = false;  // every voxel its material's value, so the means are exact
  const LabelledVolume ph = make_phantom(p);
  double sum[7] = {}, sum2[7] = {};
  std::size_t n[7] = {};
  for (std::size_t i = 0; i < ph.material.size(); ++i) {
    const auto m = ph.material[i];
    sum[m] += ph.volume.data[i];
    sum2[m] += static_cast<double>(ph.volume.data[i]) * ph.volume.data[i];
    ++n[m];
  }
  for (int m = 0; m < 7; ++m) {
    ASSERT_GT(n[m], 100u) << "material " << m << " missing";
    const double mean = sum[m] / static_cast<double>(n[m]);
    const double sd = std::sqrt(sum2[m] / static_cast<double>(n[m]) - mean * mean);
    EXPECT_NEAR(mean, phantom_hu(static_cast<PhantomMaterial>(m)), 4 * p.noise_hu / std::sqrt(static_cast<double>(n[m])) + 0.05)
        << "material " << m;
    EXPECT_NEAR(sd, p.noise_hu, 0.1 * p.noise_hu) << "material " << m;
  }
}

TEST(LabelledVolume, LayersAreOrderedFromTheOutside) {
  // Along +x from outside to the centre line at mid length: air, skin, fat, muscle, then bone.
  const LabelledVolume ph = make_phantom(small());
  const Volume& v = ph.volume;
  const int j = 50, k = 20;
  std::vector<std::uint8_t> seen;
  for (int i = 99; i >= 50; --i) {
    const auto m = ph.material[v.index(i, j, k)];
    if (seen.empty() || seen.back() != m) seen.push_back(m);
  }
  ASSERT_GE(seen.size(), 5u);
  EXPECT_EQ(seen[0], kAir);
  EXPECT_EQ(seen[1], kSkin);
  EXPECT_EQ(seen[2], kFat);
  EXPECT_EQ(seen[3], kMuscle);
  EXPECT_EQ(seen[4], kCorticalBone);
}

TEST(LabelledVolume, PartialVolumeBlendsOnlyTheVoxelsABoundaryPassesNear) {
  // A voxel more than a voxel from every boundary (every voxel within two of it on each axis
  // shares its material: a thin vessel passing diagonally can miss the axis neighbours alone)
  // keeps its material's value exactly; closer, it is blended.
  PhantomParams p = small();
  p.noise_hu = 0;
  const LabelledVolume ph = make_phantom(p);
  const Volume& v = ph.volume;
  std::size_t blended = 0, interior = 0;
  for (int k = 2; k + 2 < v.dims[2]; ++k)
    for (int j = 2; j + 2 < v.dims[1]; ++j)
      for (int i = 2; i + 2 < v.dims[0]; ++i) {
        const std::size_t idx = v.index(i, j, k);
        const auto m = ph.material[idx];
        bool near_boundary = false;
        for (int c = -2; c <= 2 && !near_boundary; ++c)
          for (int b = -2; b <= 2 && !near_boundary; ++b)
            for (int a = -2; a <= 2 && !near_boundary; ++a) near_boundary = ph.material[v.index(i + a, j + b, k + c)] != m;
        if (!near_boundary) {
          ASSERT_FLOAT_EQ(v.data[idx], phantom_hu(static_cast<PhantomMaterial>(m))) << i << " " << j << " " << k;
          ++interior;
        } else {
          blended += v.data[idx] != phantom_hu(static_cast<PhantomMaterial>(m)) ? 1 : 0;
        }
      }
  EXPECT_GT(interior, 100000u);
  EXPECT_GT(blended, 1000u) << "boundary voxels carry partial volumes";
}

// The skin's isosurface (as lancet-viz extracts it) against the analytic limb: an elliptical
// section r = hypot(x, y / 0.85) = R (1 − 0.075 z / L) tapering along z.
struct NormalError {
  double mean_deg = 0, p95_deg = 0;
};
NormalError skin_normal_error(bool partial_volume, double noise = 12) {
  PhantomParams p;
  p.dims = {100, 100, 60};
  p.partial_volume = partial_volume;
  p.noise_hu = noise;
  const LabelledVolume ph = make_phantom(p);
  IsoOptions o;
  o.iso = -300;
  o.pad_border = true;
  o.pad_value = -1000;
  o.normals = false;
  auto s = extract_isosurface(ph.volume, o);
  EXPECT_TRUE(s.ok());
  const IsoSurface& iso = s.value();
  const double half_len = 0.5 * (p.dims[2] - 1) * p.spacing, ey = 0.85;
  std::vector<std::pair<double, double>> angle_area;  // (degrees, area), area-weighted statistics
  double total = 0;
  for (const auto& t : iso.triangles) {
    const Vec3 a = to_vec3(iso.positions[t[0]]), b = to_vec3(iso.positions[t[1]]), c = to_vec3(iso.positions[t[2]]);
    const Vec3 centre = (1.0 / 3.0) * (a + b + c);
    if (std::abs(centre.z) > half_len - 0.004) continue;  // the caps the padding closes
    const Vec3 face = cross(b - a, c - a);
    const double area = 0.5 * norm(face);
    if (area <= 0) continue;
    const double r = std::hypot(centre.x, centre.y / ey);
    const Vec3 analytic = normalized(Vec3{centre.x / r, centre.y / (ey * ey * r), 0.075 * p.limb_radius / half_len});
    const double cosine = std::clamp(dot(normalized(face), analytic), -1.0, 1.0);
    angle_area.emplace_back(std::acos(cosine) * 180 / 3.141592653589793, area);
    total += area;
  }
  NormalError e;
  for (const auto& [deg, area] : angle_area) e.mean_deg += deg * area / total;
  std::sort(angle_area.begin(), angle_area.end());
  double acc = 0;
  for (const auto& [deg, area] : angle_area) {
    acc += area;
    if (acc >= 0.95 * total) {
      e.p95_deg = deg;
      break;
    }
  }
  return e;
}

TEST(LabelledVolume, TheSkinSurfaceIsSmoothNotTerraced) {
  const NormalError smooth = skin_normal_error(true), hard = skin_normal_error(false);
  const NormalError quiet = skin_normal_error(true, 0);
  std::printf("[ info     ] skin face normals against the analytic limb (area-weighted): partial volume mean %.2f° "
              "p95 %.2f° (without noise %.2f° / %.2f°); hard labels mean %.2f° p95 %.2f°\n",
              smooth.mean_deg, smooth.p95_deg, quiet.mean_deg, quiet.p95_deg, hard.mean_deg, hard.p95_deg);
  EXPECT_LT(smooth.mean_deg, 3.0);
  EXPECT_LT(smooth.p95_deg, 6.0);
  EXPECT_LT(quiet.mean_deg, 1.5) << "without the CT noise, the shape itself";
  EXPECT_GT(hard.mean_deg, 2 * smooth.mean_deg) << "the test tells terraces from a smooth skin";
}

}  // namespace
}  // namespace lancet::volume
