// NaN and infinite voxels: counted, replaced, and refused by marching cubes where the surface
// passes through them (a vertex there would be NaN), with the voxel named.

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>

#include "volume/live_isosurface.hpp"
#include "volume/marching_cubes.hpp"
#include "volume/nonfinite.hpp"

namespace lancet::volume {
namespace {

// A 12³ ball of value 100 in a background of 0, 1 mm voxels.
Volume ball() {
  Volume v;
  v.dims = {12, 12, 12};
  v.spacing = {1e-3, 1e-3, 1e-3};
  v.data.assign(v.voxel_count(), 0.0f);
  for (int k = 0; k < 12; ++k)
    for (int j = 0; j < 12; ++j)
      for (int i = 0; i < 12; ++i) {
        const double r = std::hypot(i - 5.5, j - 5.5, k - 5.5);
        v.data[v.index(i, j, k)] = r < 4 ? 100.0f : 0.0f;
      }
  return v;
}

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr float kInf = std::numeric_limits<float>::infinity();

TEST(NonFinite, CountedAndReplaced) {
  Volume v = ball();
  EXPECT_EQ(count_nonfinite(v).total(), 0u);
  v.data[v.index(2, 3, 4)] = -kInf;
  v.data[v.index(5, 5, 5)] = kNaN;
  v.data[v.index(6, 5, 5)] = kNaN;
  const NonFiniteVoxels n = count_nonfinite(v);
  EXPECT_EQ(n.nan, 2u);
  EXPECT_EQ(n.infinite, 1u);
  EXPECT_EQ(n.first, v.index(2, 3, 4));
  EXPECT_EQ(replace_nonfinite(v, 7.0f), 3u);
  EXPECT_EQ(count_nonfinite(v).total(), 0u);
  EXPECT_EQ(v.at(5, 5, 5), 7.0f);
}

// A NaN on the ball's surface would give a NaN vertex: refused, naming the voxel. A NaN deep in
// the background touches no crossing edge and changes nothing.
TEST(NonFinite, MarchingCubesRefusesThemOnTheSurface) {
  Volume v = ball();
  v.data[v.index(5, 5, 9)] = kNaN;  // r = 3.5: inside, next to the surface
  IsoOptions o;
  o.iso = 50;
  auto s = extract_isosurface(v, o);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("NaN or infinite voxels on the surface"), std::string::npos) << s.error().message;
  EXPECT_NE(s.error().message.find("voxel (5, 5, "), std::string::npos) << s.error().message;
  auto live = LiveIsosurface::create(v, o);
  EXPECT_FALSE(live.ok());

  Volume far = ball();
  far.data[far.index(0, 0, 0)] = kNaN;
  auto ok = extract_isosurface(far, o);
  ASSERT_TRUE(ok.ok()) << ok.error().message;
  for (const Vec3f& p : ok.value().positions) ASSERT_TRUE(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z));
}

// The default padding value is the smallest finite value, not a NaN (or -inf) that happens to be
// first or smallest: where the surface meets the border, its vertices lie between a padding node
// and a voxel, and a NaN or -inf padding would make them NaN.
TEST(NonFinite, DefaultPadValueIgnoresThem) {
  for (const float odd : {kNaN, -kInf}) {
    Volume v = ball();
    for (int k = 0; k < 12; ++k)
      for (int j = 0; j < 12; ++j) v.data[v.index(11, j, k)] = 100.0f;  // touches the x = 11 face
    v.data[0] = odd;  // a background corner: no crossing edge of its own
    IsoOptions o;
    o.iso = 50;
    o.pad_border = true;
    auto s = extract_isosurface(v, o);
    ASSERT_TRUE(s.ok()) << odd << ": " << s.error().message;
    EXPECT_FALSE(s.value().triangles.empty());
  }
  Volume all = ball();
  for (float& x : all.data) x = kNaN;
  IsoOptions o;
  o.iso = 50;
  o.pad_border = true;
  auto none = extract_isosurface(all, o);
  ASSERT_FALSE(none.ok());
  EXPECT_NE(none.error().message.find("no voxel is finite"), std::string::npos) << none.error().message;
}

}  // namespace
}  // namespace lancet::volume
