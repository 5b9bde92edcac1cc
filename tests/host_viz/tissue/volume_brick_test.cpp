// The drill's voxel brick cut from a placed volume: voxels are the volume's own (no resampling),
// the placement's permutation and offset are honoured, outside is air, bad input gives no brick.

#include "tissue/volume_brick.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>

#include "tissue/block_volume.hpp"
#include "tissue/tissue_scene.hpp"
#include "volume/phantom.hpp"

namespace lancet::tissue {
namespace {

// A small volume whose value encodes its voxel index: v = i + 100 j + 10000 k would overflow
// int16, so a smaller code: i + 40 j + 1600 k (dims 20 × 20 × 10 → at most 15 979).
volume::Volume coded_volume() {
  volume::Volume v;
  v.dims = {20, 20, 10};
  v.spacing = {0.001, 0.002, 0.0015};
  v.origin = {-0.01, 0.005, 0.02};
  v.data.resize(v.voxel_count());
  for (int k = 0; k < v.dims[2]; ++k)
    for (int j = 0; j < v.dims[1]; ++j)
      for (int i = 0; i < v.dims[0]; ++i) v.data[v.index(i, j, k)] = static_cast<float>(i + 40 * j + 1600 * k);
  return v;
}

TEST(VolumeBrick, PlacementRoundTripsAndChecksItself) {
  VolumePlacement pl;
  pl.axis = {2, 0, 1};
  pl.sign = {1, -1, 1};
  pl.offset = {0.01, -0.02, 0.003};
  ASSERT_TRUE(pl.valid());
  const Vec3 v{0.004, -0.007, 0.012};
  const Vec3 w = pl.to_world(v);
  EXPECT_NEAR(w.x, 0.012 + 0.01, 1e-15);
  EXPECT_NEAR(w.y, -0.004 - 0.02, 1e-15);
  EXPECT_NEAR(w.z, -0.007 + 0.003, 1e-15);
  const Vec3 back = pl.to_volume(w);
  EXPECT_NEAR(norm(back - v), 0, 1e-15);
  pl.axis = {0, 0, 1};
  EXPECT_FALSE(pl.valid());
  pl.axis = {0, 1, 2};
  pl.sign = {1, 0, 1};
  EXPECT_FALSE(pl.valid());
}

TEST(VolumeBrick, EveryBrickVoxelIsTheVolumeVoxelAtItsPlace) {
  const volume::Volume v = coded_volume();
  VolumePlacement pl;
  pl.axis = {2, 0, 1};
  pl.sign = {1, 1, -1};
  pl.offset = {0.001, 0.0, -0.01};
  auto brick = std::make_unique<VoxelBrick>();
  const Vec3 centre = pl.to_world(v.position(6.3, 4.8, 5.1));
  fill_brick(v, pl, centre, *brick);
  ASSERT_EQ(brick->valid, 1u);
  EXPECT_EQ(brick->dim, kBrickDim);
  // World spacing along x is the volume's z spacing, along y its x, along z its y.
  EXPECT_DOUBLE_EQ(brick->spacing.x, 0.0015);
  EXPECT_DOUBLE_EQ(brick->spacing.y, 0.001);
  EXPECT_DOUBLE_EQ(brick->spacing.z, 0.002);
  std::size_t inside = 0, outside = 0;
  for (std::uint32_t k = 0; k < kBrickDim; ++k)
    for (std::uint32_t j = 0; j < kBrickDim; ++j)
      for (std::uint32_t i = 0; i < kBrickDim; ++i) {
        const Vec3 w = brick->origin + Vec3{i * brick->spacing.x, j * brick->spacing.y, k * brick->spacing.z};
        const Vec3 p = pl.to_volume(w) - v.origin;
        const double fi = p.x / v.spacing.x, fj = p.y / v.spacing.y, fk = p.z / v.spacing.z;
        // On the grid, exactly.
        ASSERT_NEAR(fi, std::round(fi), 1e-6);
        ASSERT_NEAR(fj, std::round(fj), 1e-6);
        ASSERT_NEAR(fk, std::round(fk), 1e-6);
        const long ii = std::lround(fi), jj = std::lround(fj), kk = std::lround(fk);
        const std::int16_t got = brick->hu[i + kBrickDim * (j + kBrickDim * k)];
        if (ii >= 0 && jj >= 0 && kk >= 0 && ii < v.dims[0] && jj < v.dims[1] && kk < v.dims[2]) {
          ASSERT_EQ(got, static_cast<std::int16_t>(ii + 40 * jj + 1600 * kk)) << i << " " << j << " " << k;
          ++inside;
        } else {
          ASSERT_EQ(got, -1000) << "outside the volume is air";
          ++outside;
        }
      }
  EXPECT_GT(inside, 0u);
  EXPECT_GT(outside, 0u);
  // The brick is centred on the tool within a voxel.
  const Vec3 mid = brick->origin + 7.5 * brick->spacing;
  EXPECT_LT(std::abs(mid.x - centre.x), brick->spacing.x);
  EXPECT_LT(std::abs(mid.y - centre.y), brick->spacing.y);
  EXPECT_LT(std::abs(mid.z - centre.z), brick->spacing.z);
}

TEST(VolumeBrick, BadInputGivesNoBrick) {
  volume::Volume v = coded_volume();
  auto brick = std::make_unique<VoxelBrick>();
  fill_brick(v, VolumePlacement{}, {std::nan(""), 0, 0}, *brick);
  EXPECT_EQ(brick->valid, 0u);
  VolumePlacement bad;
  bad.axis = {1, 1, 2};
  fill_brick(v, bad, {0, 0, 0}, *brick);
  EXPECT_EQ(brick->valid, 0u);
  v.direction = {0, 1, 0, 1, 0, 0, 0, 0, 1};
  fill_brick(v, VolumePlacement{}, {0, 0, 0}, *brick);
  EXPECT_EQ(brick->valid, 0u) << "an oblique volume is not supported (yet)";
  fill_brick(volume::Volume{}, VolumePlacement{}, {0, 0, 0}, *brick);
  EXPECT_EQ(brick->valid, 0u);
}

TEST(VolumeBrick, ThePhantomsBoneIsInTheBrickWhereTheVizPutsIt) {
  // The viz's placement of the phantom (its tissue scene): world (x, y, z) = volume (z, x, y − top).
  auto made = TissueScene::create({});
  ASSERT_TRUE(made.ok()) << made.error().message;
  const TissueScene& scene = *made.value();
  const VolumePlacement pl = scene.placement();
  surface::TriangleMesh skin;
  scene.surface().to_triangle_mesh(skin);
  ASSERT_FALSE(skin.triangles.empty());
  EXPECT_EQ(pl.axis, (std::array<int, 3>{2, 0, 1}));
  float top = -1;
  for (const auto& v : skin.vertices) top = std::max(top, v.z);
  EXPECT_NEAR(top, 0.0f, 1e-6f) << "the skin's top at z = 0";
  auto brick = std::make_unique<VoxelBrick>();
  // The bone's centre: volume (6, −4) mm in x, y; mid-length.
  fill_brick(scene.volume(), pl, pl.to_world({0.006, -0.004, 0.0}), *brick);
  ASSERT_EQ(brick->valid, 1u);
  EXPECT_GT(brick->hu[7 + kBrickDim * (7 + kBrickDim * 7)], 200) << "marrow at the centre";
}

TEST(BlockVolume, LayersLieParallelToTheBlocksSurfaceAtTheirDepths) {
  surface::TissueBlockParams block;
  block.half_extent = 0.02;
  const volume::LabelledVolume v = make_block_volume(block);
  const BlockLayers L;
  // Down a column, the labels run air, skin, fat, muscle, cortex, marrow, each boundary at its
  // depth under the (wavy) surface there, within a voxel.
  for (const double x : {-0.012, 0.0, 0.009}) {
    const double h = surface::tissue_block_height(block, x, 0.004);
    const double edges[5] = {0, L.skin, L.skin + L.fat, L.skin + L.fat + L.muscle, L.skin + L.fat + L.muscle + L.cortex};
    const std::uint8_t below[5] = {volume::kSkin, volume::kFat, volume::kMuscle, volume::kCorticalBone, volume::kMarrow};
    const int i = static_cast<int>(std::lround((x - v.volume.origin.x) / v.volume.spacing.x));
    const int j = static_cast<int>(std::lround((0.004 - v.volume.origin.y) / v.volume.spacing.y));
    for (int e = 0; e < 5; ++e) {
      const double z_above = h - edges[e] + 0.0011, z_below = h - edges[e] - 0.0011;
      const auto label_at = [&](double z) {
        const int k = static_cast<int>(std::lround((z - v.volume.origin.z) / v.volume.spacing.z));
        return v.material[v.volume.index(i, j, k)];
      };
      EXPECT_EQ(label_at(z_below), below[e]) << "x " << x << ", boundary " << e;
      EXPECT_NE(label_at(z_above), below[e]) << "x " << x << ", boundary " << e;
    }
  }
  // Bone is hard to the drill (above its 300 HU), the soft layers are not.
  auto brick = std::make_unique<VoxelBrick>();
  fill_brick(v.volume, VolumePlacement{}, {0.0, 0.0, -0.023}, *brick);
  ASSERT_EQ(brick->valid, 1u);
  EXPECT_GT(brick->hu[7 + kBrickDim * (7 + kBrickDim * 7)], 1000) << "cortex 23 mm down";
  fill_brick(v.volume, VolumePlacement{}, {0.0, 0.0, -0.012}, *brick);
  EXPECT_LT(brick->hu[7 + kBrickDim * (7 + kBrickDim * 7)], 300) << "muscle 12 mm down";
}

}  // namespace
}  // namespace lancet::tissue
