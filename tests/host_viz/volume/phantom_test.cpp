#include "volume/phantom.hpp"

#include <gtest/gtest.h>

#include <cmath>

namespace lancet::volume {
namespace {

PhantomParams small() {
  PhantomParams p;
  p.dims = {100, 100, 40};
  return p;
}

TEST(Phantom, GeometryAndUnits) {
  const Phantom ph = make_phantom(small());
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

TEST(Phantom, DeterministicFromTheSeed) {
  PhantomParams p = small();
  const Phantom a = make_phantom(p), b = make_phantom(p);
  EXPECT_EQ(a.volume.data, b.volume.data);
  p.seed = 2;
  const Phantom c = make_phantom(p);
  EXPECT_NE(a.volume.data, c.volume.data);
  EXPECT_EQ(a.material, c.material);  // only the noise depends on the seed
}

TEST(Phantom, LayersHaveTheirHounsfieldUnitsAndTheNoiseItsSpread) {
  const PhantomParams p = small();
  const Phantom ph = make_phantom(p);
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

TEST(Phantom, LayersAreOrderedFromTheOutside) {
  // Along +x from outside to the centre line at mid length: air, skin, fat, muscle, then bone.
  const Phantom ph = make_phantom(small());
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

}  // namespace
}  // namespace lancet::volume
