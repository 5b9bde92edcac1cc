#include "volume/marching_cubes.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <numbers>
#include <optional>
#include <random>
#include <set>

#include "volume/mesh_tools.hpp"
#include "volume/phantom.hpp"

namespace lancet::volume {
namespace {

constexpr double kPi = std::numbers::pi;

// A volume of n³ voxels at h metres, centred on the origin, with value field(x, y, z) (metres).
template <class F>
Volume analytic(int n, double h, F field) {
  Volume v;
  v.dims = {n, n, n};
  v.spacing = {h, h, h};
  const double c = (n - 1) * h / 2;
  v.origin = {-c, -c, -c};
  v.data.resize(v.voxel_count());
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        const Vec3 p = v.position(i, j, k);
        v.data[v.index(i, j, k)] = static_cast<float>(field(p.x, p.y, p.z));
      }
  return v;
}

// IsoOptions with the fields the tests vary (designated initializers would trip
// -Wmissing-field-initializers).
IsoOptions opt(float iso, bool pad = false, std::optional<float> pad_value = {}, int threads = 0,
               std::vector<MaterialThreshold> materials = {}) {
  IsoOptions o;
  o.iso = iso;
  o.pad_border = pad;
  o.pad_value = pad_value;
  o.threads = threads;
  o.materials = std::move(materials);
  return o;
}

IsoSurface extract(const Volume& v, IsoOptions o, std::span<const std::uint8_t> labels = {}) {
  auto r = extract_isosurface(v, o, labels);
  EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().message);
  return std::move(r).value();
}

MeshStats checked_stats(const IsoSurface& s) {
  std::size_t refused = 0;
  const IsoMesh m = to_openmesh(s, &refused);
  EXPECT_EQ(refused, 0u) << "OpenMesh refused faces: the surface is not manifold";
  return mesh_stats(m);
}

PhantomParams small_phantom(int nx, int ny, int nz) {
  PhantomParams p;
  p.dims = {nx, ny, nz};
  return p;
}

TEST(McCaseTable, EveryCaseUsesExactlyItsCrossingEdges) {
  const auto& table = mc_case_table();
  for (int cs = 0; cs < 256; ++cs) {
    std::set<int> crossing, used;
    for (int e = 0; e < 12; ++e) {
      const auto c = mc_edge_corners(e);
      if (((cs >> c[0]) & 1) != ((cs >> c[1]) & 1)) crossing.insert(e);
    }
    for (int t = 0; t < table[static_cast<std::size_t>(cs)].n_triangles * 3; ++t) used.insert(table[static_cast<std::size_t>(cs)].edges[static_cast<std::size_t>(t)]);
    EXPECT_EQ(used, crossing) << "case " << cs;
    // A polygon of m crossings gives m − 2 triangles, so at least (crossings − 2·polygons).
    EXPECT_GE(table[static_cast<std::size_t>(cs)].n_triangles * 3, static_cast<int>(crossing.size())) << "case " << cs;
  }
  EXPECT_EQ(table[0].n_triangles, 0);
  EXPECT_EQ(table[255].n_triangles, 0);
  EXPECT_EQ(table[1].n_triangles, 1);
  // Twelve crossings is the most any cube can have; the table's worst case stays within the bound.
  int worst = 0;
  for (const auto& c : table) worst = std::max(worst, int{c.n_triangles});
  EXPECT_LE(worst, kMaxCaseTriangles);
}

TEST(McCaseTable, EdgesJoinCornersAlongTheirAxis) {
  for (int e = 0; e < 12; ++e) {
    const auto c = mc_edge_corners(e);
    EXPECT_EQ(c[1] - c[0], 1 << (e / 4)) << "edge " << e;
  }
}

TEST(MarchingCubes, SphereAreaAndVolumeWithinOnePercent) {
  const double r = 0.02;  // 20 mm sphere on a 1 mm grid
  const Volume v = analytic(56, 0.001, [&](double x, double y, double z) { return r - std::sqrt(x * x + y * y + z * z); });
  const IsoSurface s = extract(v, opt(0));
  const MeshStats st = checked_stats(s);
  EXPECT_NEAR(st.area, 4 * kPi * r * r, 0.01 * 4 * kPi * r * r);
  EXPECT_NEAR(st.volume, 4.0 / 3.0 * kPi * r * r * r, 0.01 * 4.0 / 3.0 * kPi * r * r * r);
  EXPECT_TRUE(st.closed());
  EXPECT_EQ(st.components, 1u);
  EXPECT_EQ(st.euler, 2);
  EXPECT_EQ(st.genus(), 0);
  EXPECT_EQ(st.degenerate_faces, 0u);
  EXPECT_EQ(st.isolated_vertices, 0u);
}

TEST(MarchingCubes, TorusAreaVolumeAndGenusOne) {
  const double big = 0.02, small = 0.007;
  const Volume v = analytic(64, 0.001, [&](double x, double y, double z) {
    const double q = std::sqrt(x * x + y * y) - big;
    return small - std::sqrt(q * q + z * z);
  });
  const MeshStats st = checked_stats(extract(v, opt(0)));
  const double area = 4 * kPi * kPi * big * small, vol = 2 * kPi * kPi * big * small * small;
  EXPECT_NEAR(st.area, area, 0.01 * area);
  EXPECT_NEAR(st.volume, vol, 0.01 * vol);
  EXPECT_TRUE(st.closed());
  EXPECT_EQ(st.components, 1u);
  EXPECT_EQ(st.euler, 0);
  EXPECT_EQ(st.genus(), 1);
}

TEST(MarchingCubes, NormalsPointOutwardAndAgreeWithTheWinding) {
  const double r = 0.015;
  const Volume v = analytic(40, 0.001, [&](double x, double y, double z) { return r - std::sqrt(x * x + y * y + z * z); });
  const IsoSurface s = extract(v, opt(0));
  ASSERT_EQ(s.normals.size(), s.positions.size());
  for (std::size_t i = 0; i < s.positions.size(); ++i) {
    const Vec3 p = to_vec3(s.positions[i]), n = to_vec3(s.normals[i]);
    EXPECT_NEAR(norm(n), 1.0, 1e-5);
    EXPECT_GT(dot(n, normalized(p)), 0.99) << "vertex " << i;
  }
  for (const auto& t : s.triangles) {
    const Vec3 a = to_vec3(s.positions[t[0]]), b = to_vec3(s.positions[t[1]]), c = to_vec3(s.positions[t[2]]);
    EXPECT_GT(dot(cross(b - a, c - a), a + b + c), 0) << "a face winds inward";
  }
}

TEST(MarchingCubes, MirroredDirectionMatrixKeepsTheSurfaceOutward) {
  Volume v = analytic(30, 0.001, [](double x, double y, double z) { return 0.01 - std::sqrt(x * x + y * y + z * z); });
  v.direction = {1, 0, 0, 0, -1, 0, 0, 0, 1};  // y flipped: a left-handed index frame
  v.origin.y = -v.origin.y;
  const MeshStats st = checked_stats(extract(v, opt(0)));
  EXPECT_GT(st.volume, 0);
  EXPECT_NEAR(st.volume, 4.0 / 3.0 * kPi * 1e-6, 0.02 * 4.0 / 3.0 * kPi * 1e-6);
}

TEST(MarchingCubes, ResultDoesNotDependOnTheThreadCount) {
  const Volume v = analytic(33, 0.001, [](double x, double y, double z) { return std::sin(300 * x) + std::cos(250 * y) * std::sin(200 * z); });
  const IsoSurface one = extract(v, opt(0.2f, false, {}, 1));
  for (int threads : {2, 3, 7, 64}) {
    const IsoSurface many = extract(v, opt(0.2f, false, {}, threads));
    EXPECT_EQ(many.triangles, one.triangles) << threads << " threads";
    EXPECT_EQ(many.positions, one.positions) << threads << " threads";
    EXPECT_EQ(many.edge_key, one.edge_key) << threads << " threads";
  }
}

// Random integer fields where many voxels equal the isovalue exactly: the hardest topology
// (every ambiguous case, saddles everywhere) and the degenerate-vertex trap.
TEST(MarchingCubes, RandomIntegerFieldsGiveClosedManifoldSurfacesWithoutDegenerateFaces) {
  std::mt19937 rng(7);
  for (int trial = 0; trial < 20; ++trial) {
    Volume v;
    v.dims = {9 + trial % 5, 7 + trial % 3, 8};
    v.spacing = {0.001, 0.0015, 0.002};
    v.data.resize(v.voxel_count());
    std::uniform_int_distribution<int> d(0, 2);
    for (auto& x : v.data) x = static_cast<float>(d(rng));
    const IsoSurface s = extract(v, opt(1, true, 0.0f, 2));
    const MeshStats st = checked_stats(s);
    EXPECT_TRUE(st.closed()) << "trial " << trial << ": " << st.boundary_edges << " boundary edges, " << st.non_manifold_vertices
                             << " non-manifold vertices";
    EXPECT_EQ(st.degenerate_faces, 0u) << "trial " << trial;
    EXPECT_EQ(st.euler % 2, 0) << "trial " << trial;
    EXPECT_GT(st.volume, 0) << "trial " << trial;
    // Every edge key names an edge that crosses the isovalue.
    EXPECT_EQ(std::set<std::uint64_t>(s.edge_key.begin(), s.edge_key.end()).size(), s.edge_key.size()) << "an edge got two vertices";
  }
}

TEST(MarchingCubes, PaddingClosesASurfaceThatTouchesTheVolumeEdge) {
  Volume v;
  v.dims = {10, 12, 14};
  v.spacing = {0.001, 0.001, 0.001};
  v.data.assign(v.voxel_count(), 100.0f);  // everything inside
  EXPECT_TRUE(extract(v, opt(50)).triangles.empty());
  const IsoSurface s = extract(v, opt(50, true, 0.0f));
  const MeshStats st = checked_stats(s);
  EXPECT_TRUE(st.closed());
  EXPECT_EQ(st.genus(), 0);
  // The box closes halfway into the padding, (9+1) × (11+1) × (13+1) mm, less the chamfers marching
  // cubes cuts along its 12 edges (a 0.5 × 0.5 mm right triangle in section: at most 18 mm³).
  const double box = 10e-3 * 12e-3 * 14e-3, chamfers = 0.125e-6 * 4 * (10e-3 + 12e-3 + 14e-3);
  EXPECT_LE(st.volume, box - 0.9 * chamfers);
  EXPECT_GE(st.volume, box - chamfers);
  EXPECT_EQ(s.grid.pad, 1);
  EXPECT_EQ(s.grid.dims, (std::array<int, 3>{12, 14, 16}));
}

TEST(MarchingCubes, MaterialsComeFromLabelsOrThresholdsOnTheInside) {
  const LabelledVolume ph = make_phantom(small_phantom(64, 64, 24));
  const IsoSurface skin = extract(ph.volume, opt(-300, true, -1000.0f), ph.material);
  std::set<int> seen(skin.material.begin(), skin.material.end());
  EXPECT_TRUE(seen.count(kSkin)) << "the skin surface should be labelled skin";
  EXPECT_FALSE(seen.count(kAir)) << "the inside of the edge is never air";
  const IsoSurface bone = extract(ph.volume, opt(400, false, {}, 0, {{-1000, 9}, {300, 4}}));
  ASSERT_FALSE(bone.material.empty());
  for (auto m : bone.material) EXPECT_EQ(m, 4);
}

// The built-in phantom is made slice by slice on two threads: the same voxels and materials as
// one thread makes, bit for bit.
TEST(Phantom, TwoThreadsMakeTheOneThreadPhantomBitForBit) {
  PhantomParams one;
  one.threads = 1;
  const LabelledVolume a = make_phantom(one), b = make_phantom(PhantomParams{});
  ASSERT_EQ(a.volume.data.size(), b.volume.data.size());
  EXPECT_EQ(std::memcmp(a.volume.data.data(), b.volume.data.data(), a.volume.data.size() * sizeof(float)), 0);
  EXPECT_EQ(a.material, b.material);
}

TEST(MarchingCubes, PhantomSkinIsClosedWithPadding) {
  const LabelledVolume ph = make_phantom(small_phantom(80, 80, 40));
  const MeshStats st = checked_stats(extract(ph.volume, opt(-300, true)));
  EXPECT_TRUE(st.closed());
  EXPECT_EQ(st.degenerate_faces, 0u);
}

TEST(MarchingCubes, BadInputIsAClearError) {
  Volume v;
  v.dims = {4, 4, 4};
  v.data.assign(64, 0.0f);
  v.spacing = {1, 1, 1};
  auto nan_iso = extract_isosurface(v, opt(std::nanf("")));
  ASSERT_FALSE(nan_iso.ok());
  EXPECT_NE(nan_iso.error().message.find("isovalue"), std::string::npos);
  const std::vector<std::uint8_t> short_labels(10);
  auto labels = extract_isosurface(v, IsoOptions{}, short_labels);
  ASSERT_FALSE(labels.ok());
  EXPECT_NE(labels.error().message.find("expected 64"), std::string::npos);
  v.data.assign(10, 0.0f);
  auto sized = extract_isosurface(v, IsoOptions{});
  ASSERT_FALSE(sized.ok());
  EXPECT_NE(sized.error().message.find("data has 10"), std::string::npos);
  Volume thin;
  thin.dims = {1, 5, 5};
  thin.data.assign(25, 1.0f);
  // No spacing (all zero) would give NaN normals: refused.
  auto flat = extract_isosurface(thin, opt(0.5f, true, 0.0f));
  ASSERT_FALSE(flat.ok());
  EXPECT_NE(flat.error().message.find("positive finite spacings"), std::string::npos) << flat.error().message;
  thin.spacing = {1e-3, 1e-3, 1e-3};
  EXPECT_FALSE(extract_isosurface(thin, IsoOptions{}).ok());
  EXPECT_TRUE(extract_isosurface(thin, opt(0.5f, true, 0.0f)).ok());
  auto unsorted = extract_isosurface(thin, opt(0, true, {}, 0, {{5, 1}, {1, 2}}));
  EXPECT_FALSE(unsorted.ok());
}

}  // namespace
}  // namespace lancet::volume
