// Drilling and local re-extraction: the sphere removes what it should and reports it; the surface
// re-extracted around the hole equals a fresh extraction of the drilled volume and stays closed.

#include "volume/drill.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <numbers>
#include <tuple>
#include <vector>

#include "volume/live_isosurface.hpp"
#include "volume/marching_cubes.hpp"
#include "volume/mesh_tools.hpp"
#include "volume/phantom.hpp"

namespace lancet::volume {
namespace {

constexpr double kPi = std::numbers::pi;

Volume block(int n, double h, float inside, float outside, int margin) {
  Volume v;
  v.dims = {n, n, n};
  v.spacing = {h, h, h};
  v.data.assign(v.voxel_count(), outside);
  for (int k = margin; k < n - margin; ++k)
    for (int j = margin; j < n - margin; ++j)
      for (int i = margin; i < n - margin; ++i) v.data[v.index(i, j, k)] = inside;
  return v;
}

DrillParams burr(Vec3 c, double r) {
  DrillParams p;
  p.centre = c;
  p.radius = r;
  return p;
}

IsoOptions opts(float iso, bool pad) {
  IsoOptions o;
  o.iso = iso;
  o.pad_border = pad;
  return o;
}

TEST(Drill, RemovesTheSphereAndAccountsItsVolume) {
  Volume v = block(60, 0.0005, 1000, -1000, 0);  // solid bone, 0.5 mm voxels
  const double r = 0.005;
  auto d = drill_sphere(v, burr(v.position(30, 30, 30), r));
  ASSERT_TRUE(d.ok());
  const double sphere_mm3 = 4.0 / 3.0 * kPi * std::pow(r * 1e3, 3);
  EXPECT_NEAR(d.value().removed_mm3, sphere_mm3, 0.03 * sphere_mm3);
  EXPECT_EQ(static_cast<double>(d.value().voxels_removed) * 0.125, d.value().removed_mm3);
  // Exactly the voxels whose centres are within r are empty; the dirty box is their bounding box.
  std::size_t empty = 0;
  VoxelBox bounds{{60, 60, 60}, {0, 0, 0}};
  for (int k = 0; k < 60; ++k)
    for (int j = 0; j < 60; ++j)
      for (int i = 0; i < 60; ++i) {
        const bool in = norm(v.position(i, j, k) - v.position(30, 30, 30)) <= r;
        EXPECT_EQ(v.at(i, j, k) == -1000.0f, in) << i << "," << j << "," << k;
        empty += in;
        if (in) {
          const int idx[3] = {i, j, k};
          for (std::size_t a = 0; a < 3; ++a) {
            bounds.lo[a] = std::min(bounds.lo[a], idx[a]);
            bounds.hi[a] = std::max(bounds.hi[a], idx[a] + 1);
          }
        }
      }
  EXPECT_EQ(empty, d.value().voxels_removed);
  const VoxelBox& b = d.value().dirty;
  EXPECT_EQ(b.lo, bounds.lo);
  EXPECT_EQ(b.hi, bounds.hi);
  EXPECT_GE(b.lo[0], 20);
  EXPECT_LE(b.hi[0], 41);
  // Drilling the same place again removes nothing and changes nothing.
  auto again = drill_sphere(v, burr(v.position(30, 30, 30), r));
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again.value().voxels_removed, 0u);
  EXPECT_TRUE(again.value().dirty.empty());
}

TEST(Drill, SplitsTheRemovedVolumeByMaterialAndClearsLabels) {
  PhantomParams pp;
  pp.dims = {96, 96, 20};
  LabelledVolume ph = make_phantom(pp);
  // At the skin on the +x side: skin, fat and air all inside the burr.
  const Vec3 at{pp.limb_radius, 0, 0};
  auto d = drill_sphere(ph.volume, burr(at, 0.004), ph.material);
  ASSERT_TRUE(d.ok());
  const auto& by = d.value().removed_mm3_by_label;
  EXPECT_GT(by[kSkin], 0);
  EXPECT_GT(by[kFat], 0);
  EXPECT_EQ(by[kAir], 0) << "voxels labelled air are not material";
  double sum = 0;
  for (double x : by) sum += x;
  EXPECT_NEAR(sum, d.value().removed_mm3, 1e-9);
  const VoxelBox& b = d.value().dirty;
  for (int k = b.lo[2]; k < b.hi[2]; ++k)
    for (int j = b.lo[1]; j < b.hi[1]; ++j)
      for (int i = b.lo[0]; i < b.hi[0]; ++i)
        if (norm(ph.volume.position(i, j, k) - at) <= 0.004) {
          EXPECT_EQ(ph.material[ph.volume.index(i, j, k)], kAir);
        }
}

TEST(Drill, OutsideTheVolumeOrBadParametersIsHandled) {
  Volume v = block(10, 0.001, 500, -1000, 0);
  auto far = drill_sphere(v, burr({1, 1, 1}, 0.002));
  ASSERT_TRUE(far.ok());
  EXPECT_EQ(far.value().voxels_removed, 0u);
  EXPECT_TRUE(far.value().dirty.empty());
  EXPECT_FALSE(drill_sphere(v, burr({0, 0, 0}, 0)).ok());
  EXPECT_FALSE(drill_sphere(v, burr({0, 0, 0}, std::nan(""))).ok());
  EXPECT_FALSE(drill_sphere(v, burr({std::nan(""), 0, 0}, 0.001)).ok());
  std::vector<std::uint8_t> labels(3);
  auto bad = drill_sphere(v, burr({0, 0, 0}, 0.001), labels);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("expected 1000"), std::string::npos);
}

// The faces of a mesh as sorted position triples, for comparing two meshes built differently.
std::vector<std::array<std::array<float, 3>, 3>> face_set(const IsoMesh& m) {
  std::vector<std::array<std::array<float, 3>, 3>> out;
  for (auto f : m.faces()) {
    std::array<std::array<float, 3>, 3> t{};
    int n = 0;
    for (auto v : m.fv_range(f)) {
      const auto& p = m.point(v);
      t[static_cast<std::size_t>(n++)] = {p[0], p[1], p[2]};
    }
    // Rotate so the smallest vertex comes first (keeps the winding).
    const auto first = std::min_element(t.begin(), t.end()) - t.begin();
    std::rotate(t.begin(), t.begin() + first, t.end());
    out.push_back(t);
  }
  std::sort(out.begin(), out.end());
  return out;
}

TEST(LiveIsosurface, LocalReextractionEqualsAFreshExtractionAndStaysClosed) {
  PhantomParams pp;
  pp.dims = {72, 72, 40};
  LabelledVolume ph = make_phantom(pp);
  const IsoOptions o = opts(300, true);  // bone
  auto live = LiveIsosurface::create(ph.volume, o, ph.material);
  ASSERT_TRUE(live.ok()) << live.error().message;
  auto& s = *live.value();
  EXPECT_EQ(s.refused_at_creation(), 0u);
  const MeshStats before = mesh_stats(s.mesh());
  ASSERT_TRUE(before.closed());
  // Drill into the bone several times, at overlapping and separate places.
  const std::vector<Vec3> holes = {{0.012, 0.002, 0.0}, {0.014, 0.003, 0.002}, {0.0, 0.0, 0.0}, {0.010, -0.006, -0.012}};
  double removed = 0;
  for (const Vec3& c : holes) {
    auto d = drill_sphere(ph.volume, burr(c, 0.0035), ph.material);
    ASSERT_TRUE(d.ok());
    removed += d.value().removed_mm3;
    auto u = s.update(ph.volume, d.value().dirty, ph.material);
    ASSERT_TRUE(u.ok()) << u.error().message;
    EXPECT_EQ(u.value().refused, 0u);
    EXPECT_GT(u.value().faces_removed + u.value().faces_added, 0u);
    const MeshStats st = mesh_stats(s.mesh());
    EXPECT_TRUE(st.closed()) << st.boundary_edges << " boundary edges after the hole at " << c.x << "," << c.y << "," << c.z;
    EXPECT_EQ(st.degenerate_faces, 0u);
    EXPECT_EQ(st.isolated_vertices, 0u);
  }
  EXPECT_GT(removed, 0);
  // The stitched mesh is the mesh a fresh extraction of the drilled volume gives.
  auto fresh = extract_isosurface(ph.volume, o, ph.material);
  ASSERT_TRUE(fresh.ok());
  const IsoMesh fm = to_openmesh(fresh.value());
  EXPECT_EQ(face_set(s.mesh()), face_set(fm));
  const MeshStats a = mesh_stats(s.mesh()), b = mesh_stats(fm);
  EXPECT_EQ(a.faces, b.faces);
  EXPECT_EQ(a.vertices, b.vertices);
  EXPECT_NEAR(a.volume, b.volume, 1e-12);
  EXPECT_LT(a.volume, before.volume) << "drilling removes bone";
  // Normals and materials agree vertex by vertex (matched through the edge key).
  std::map<std::uint64_t, std::tuple<OpenMesh::Vec3f, std::uint8_t>> expected;
  for (auto v : fm.vertices()) expected[fm.edge_key(v)] = {fm.normal(v), fm.material(v)};
  for (auto v : s.mesh().vertices()) {
    const auto it = expected.find(s.mesh().edge_key(v));
    ASSERT_NE(it, expected.end());
    EXPECT_LT((std::get<0>(it->second) - s.mesh().normal(v)).norm(), 1e-6f);
    EXPECT_EQ(std::get<1>(it->second), s.mesh().material(v));
  }
  // Compaction drops the deleted elements and keeps the surface.
  EXPECT_GT(s.deleted_faces(), 0u);
  s.compact();
  EXPECT_EQ(s.mesh().n_faces(), b.faces);
  EXPECT_EQ(face_set(s.mesh()), face_set(fm));
  // Updating after compaction still works (the edge map was rebuilt).
  auto d = drill_sphere(ph.volume, burr({-0.012, 0.0, 0.004}, 0.003), ph.material);
  ASSERT_TRUE(d.ok());
  ASSERT_TRUE(s.update(ph.volume, d.value().dirty, ph.material).ok());
  EXPECT_TRUE(mesh_stats(s.mesh()).closed());
}

TEST(LiveIsosurface, DrillingThroughTheVolumeEdgeStaysClosedWithPadding) {
  Volume v = block(24, 0.001, 1000, -1000, 0);  // touches every side: only padding closes it
  IsoOptions o = opts(0, true);
  o.pad_value = -1000;  // the default, the volume's minimum, would be inside here
  auto live = LiveIsosurface::create(v, o);
  ASSERT_TRUE(live.ok());
  auto& s = *live.value();
  EXPECT_TRUE(mesh_stats(s.mesh()).closed());
  for (const Vec3& c : {v.position(0, 12, 12), v.position(23, 23, 23), v.position(12, 0, 5)}) {
    auto d = drill_sphere(v, burr(c, 0.004));
    ASSERT_TRUE(d.ok());
    auto u = s.update(v, d.value().dirty);
    ASSERT_TRUE(u.ok());
    EXPECT_EQ(u.value().refused, 0u);
    const MeshStats st = mesh_stats(s.mesh());
    EXPECT_TRUE(st.closed());
    EXPECT_EQ(st.components, 1u);
  }
}

TEST(LiveIsosurface, RejectsAMismatchedVolume) {
  Volume v = block(12, 0.001, 1000, -1000, 2);
  auto live = LiveIsosurface::create(v, opts(0, false));
  ASSERT_TRUE(live.ok());
  Volume other = block(13, 0.001, 1000, -1000, 2);
  auto u = live.value()->update(other, VoxelBox{{0, 0, 0}, {5, 5, 5}});
  ASSERT_FALSE(u.ok());
  EXPECT_NE(u.error().message.find("13x13x13"), std::string::npos);
  std::vector<std::uint8_t> labels(v.voxel_count());
  EXPECT_FALSE(live.value()->update(v, VoxelBox{{0, 0, 0}, {5, 5, 5}}, labels).ok()) << "created without labels";
  auto nothing = live.value()->update(v, VoxelBox{{5, 5, 5}, {5, 9, 9}});
  ASSERT_TRUE(nothing.ok());
  EXPECT_EQ(nothing.value().cubes, 0u);
}

}  // namespace
}  // namespace lancet::volume
