// The surface model: deformation and its elastic return, the progressive node-snapping cut and
// its invariants after every step on random paths, opening, wrinkle.

#include "surface/surface_model.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <set>

#include "surface/triangle_mesh.hpp"
#include "volume/marching_cubes.hpp"

namespace lancet::surface {
namespace {

// A wavy sheet 2·h across with `cells` cells a side (two materials: the vessel band is 2).
std::unique_ptr<SurfaceModel> sheet(int cells, double h = 0.03, SurfaceParams params = {}) {
  TissueBlockParams p;
  p.half_extent = h;
  p.cells = cells;
  p.wave_amplitude = 0.002;
  p.wave_length = 0.02;
  TriangleMesh m = make_tissue_block(p);
  // Two materials meeting at x = 3 mm, so that cuts cross a material boundary.
  for (std::size_t f = 0; f < m.triangles.size(); ++f) {
    const auto& t = m.triangles[f];
    const double cx = (m.vertices[t[0]].x + m.vertices[t[1]].x + m.vertices[t[2]].x) / 3;
    m.material[f] = cx < 0.003 ? 1 : 3;
  }
  auto r = SurfaceModel::create(m.vertices, m.triangles, m.material, params);
  EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().message);
  return std::move(r).value();
}

double height(double x, double y) {
  TissueBlockParams p;
  p.wave_amplitude = 0.002;
  p.wave_length = 0.02;
  return tissue_block_height(p, x, y);
}
Vec3 on_sheet(double x, double y) { return {x, y, height(x, y)}; }

void expect_invariants(const SurfaceModel& s, std::size_t faces, double rest_area0, bool opened, const std::string& where) {
  const SurfaceStats st = s.stats();
  EXPECT_EQ(st.faces, faces) << where;
  EXPECT_EQ(st.non_manifold_vertices, 0u) << where;
  EXPECT_EQ(st.degenerate_faces, 0u) << where;
  EXPECT_EQ(st.flipped_faces, 0u) << where;
  EXPECT_TRUE(st.boundary_loops_closed) << where;
  EXPECT_EQ(st.stale_haptic, 0u) << where << ": a kept haptic position is not rest + opening + wrinkle";
  EXPECT_EQ(st.stale_boundary_flags, 0u) << where << ": a kept boundary flag is not the mesh's";
  EXPECT_NEAR(st.rest_area, rest_area0, 0.01 * rest_area0) << where;
  if (!opened) {
    EXPECT_NEAR(st.area, rest_area0, 0.01 * rest_area0) << where;
  }
  EXPECT_TRUE(s.bvh().check(s.view())) << where;
  // Every face's stable index maps to a live OpenMesh face with the same corners.
  for (std::uint32_t f = 0; f < s.n_faces(); f += 97) {
    const auto fh = s.face_handle(f);
    ASSERT_TRUE(fh.is_valid()) << where;
    ASSERT_FALSE(s.mesh().status(fh).deleted()) << where;
    std::set<int> a, b;
    for (auto v : s.mesh().fv_range(fh)) a.insert(v.idx());
    for (auto v : s.faces()[f]) b.insert(static_cast<int>(v));
    EXPECT_EQ(a, b) << where << ", face " << f;
  }
}

TEST(SurfaceModel, CreateRejectsBadInput) {
  const std::vector<Vec3f> p = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 1, 1}};
  const std::vector<std::array<std::uint32_t, 3>> out_of_range = {{0, 1, 7}};
  EXPECT_FALSE(SurfaceModel::create(p, out_of_range).ok());
  // Three faces on one edge: not a manifold.
  const std::vector<std::array<std::uint32_t, 3>> fin = {{0, 1, 2}, {1, 0, 3}, {0, 1, 4}};
  auto r = SurfaceModel::create(p, fin);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("triangle 2"), std::string::npos);
  const std::vector<std::uint16_t> short_materials = {1};
  const std::vector<std::array<std::uint32_t, 3>> two = {{0, 1, 2}, {1, 0, 3}};
  EXPECT_FALSE(SurfaceModel::create(p, two, short_materials).ok());
  std::vector<Vec3f> nan = p;
  nan[2].y = std::nanf("");
  EXPECT_FALSE(SurfaceModel::create(nan, two).ok());
}

TEST(SurfaceModel, DeformationIsAGaussianDentThatReturnsElastically) {
  SurfaceParams params;
  params.deform_sigma = 0.005;
  auto s = sheet(60, 0.03, params);
  const Vec3 c = on_sheet(0.001, -0.002);
  const Vec3 down{0, 0, -1};
  s->update_contact(Contact{c, down, 0.004}, 0.001);
  ASSERT_GT(s->deformed_vertices(), 0u);
  double deepest = 0;
  for (auto v : s->mesh().vertices()) {
    const auto i = static_cast<std::uint32_t>(v.idx());
    const Vec3 d = s->position(i) - s->rest_position(i);
    const Vec3 rest = s->rest_position(i);
    const double r2 = dot(rest - c, rest - c);
    const double rim = std::exp(-4.5);  // the dent reaches zero at 3σ
    const double expected = norm(rest - c) <= 3 * params.deform_sigma ? 0.004 * (std::exp(-r2 / (2 * 0.005 * 0.005)) - rim) / (1 - rim) : 0.0;
    EXPECT_NEAR(-d.z, expected, 1e-6) << "vertex " << i;
    EXPECT_NEAR(d.x, 0, 1e-9);
    deepest = std::max(deepest, -d.z);
  }
  EXPECT_GT(deepest, 0.0035);
  EXPECT_TRUE(s->bvh().check(s->view()));
  // Released: back to rest within a few time constants, and the working set empties.
  for (int i = 0; i < 200; ++i) s->update_contact(std::nullopt, 0.01);
  for (auto v : s->mesh().vertices()) {
    const auto i = static_cast<std::uint32_t>(v.idx());
    EXPECT_LT(norm(s->position(i) - s->rest_position(i)), 1e-6);
  }
  EXPECT_EQ(s->deformed_vertices(), 0u);
  // A dent deeper than the limit is clamped.
  s->update_contact(Contact{c, down, 1.0}, 0.001);
  double max_d = 0;
  for (auto v : s->mesh().vertices()) max_d = std::max(max_d, norm(s->position(static_cast<std::uint32_t>(v.idx())) - s->rest_position(static_cast<std::uint32_t>(v.idx()))));
  EXPECT_LE(max_d, params.deform_max_depth + 1e-6);
}

TEST(SurfaceModel, StraightCutSplitsTheMeshAlongThePath) {
  auto s = sheet(40);
  const std::size_t faces = s->n_faces();
  const SurfaceStats before = s->stats();
  ASSERT_TRUE(s->begin_cut(on_sheet(-0.012, 0.0013)));
  for (int i = 1; i <= 24; ++i) {
    const auto r = s->cut_to(on_sheet(-0.012 + 0.001 * i, 0.0013 + 0.0002 * i));
    EXPECT_EQ(r.refused, 0u);
    expect_invariants(*s, faces, before.rest_area, false, "step " + std::to_string(i));
  }
  s->end_cut();
  const Cut& cut = s->cuts().front();
  EXPECT_GE(cut.chain.size(), 10u);
  EXPECT_EQ(cut.pairs.size(), cut.chain.size() - 2) << "every snapped vertex but start and end is split";
  const SurfaceStats after = s->stats();
  // The cut adds one boundary loop, whose edges run along the chain on both sides.
  EXPECT_EQ(after.boundary_loops, before.boundary_loops + 1);
  EXPECT_EQ(after.boundary_edges, before.boundary_edges + 2 * (cut.chain.size() - 1));
  EXPECT_EQ(after.vertices, before.vertices + cut.pairs.size());
  // Snapped vertices sit on the path (a straight line in x-y here).
  for (std::uint32_t v : cut.chain) {
    const Vec3 p = s->rest_position(v);
    const double along = (p.x + 0.012) / 0.001;
    EXPECT_NEAR(p.y, 0.0013 + 0.0002 * along, 2e-4) << "vertex " << v;
  }
}

TEST(SurfaceModel, ABladeTipUnderTheSkinCutsTheSurfaceOverIt) {
  // lancet-rt's blade is millimetres under the skin, and its path may run exactly along a row of
  // mesh edges; in fine steps (one per servo tick) the cut still follows it to the end. (It once
  // walked towards the deep point itself, ran downhill on the sloping faces and stalled.)
  auto s = sheet(40);  // 1.5 mm cells: y = 0 is a row of edges
  ASSERT_TRUE(s->begin_cut(on_sheet(-0.012, 0.0)));
  for (int i = 1; i <= 2400; ++i) {
    const double x = -0.012 + 0.024 * i / 2400.0;
    const double jitter = (i % 2 != 0 ? 1 : -1) * 2e-7;
    (void)s->cut_to(on_sheet(x, jitter) - Vec3{0, 0, 0.004});
  }
  s->end_cut();
  const Cut& cut = s->cuts().front();
  const Vec3 end = s->rest_position(cut.chain.back());
  EXPECT_NEAR(end.x, 0.012, 0.002) << "the cut reached the end of the line";
  EXPECT_NEAR(end.y, 0.0, 0.001);
  EXPECT_GE(cut.chain.size(), 14u);
}

TEST(SurfaceModel, RandomCutsKeepTheInvariantsAfterEveryStep) {
  for (std::uint32_t seed : {1u, 2u, 3u, 4u, 5u, 6u, 7u, 8u}) {
    auto s = sheet(36);
    const std::size_t faces = s->n_faces();
    const double area0 = s->stats().rest_area;
    std::vector<std::uint16_t> mat0;
    for (std::uint32_t f = 0; f < faces; ++f) mat0.push_back(s->face_material(f));
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> pos(-0.02, 0.02), turn(-0.8, 0.8), len(0.0005, 0.003);
    for (int c = 0; c < 3; ++c) {  // several cuts, which may cross one another
      double x = pos(rng), y = pos(rng), heading = std::uniform_real_distribution<double>(0, 6.28)(rng);
      ASSERT_TRUE(s->begin_cut(on_sheet(x, y)));
      for (int step = 0; step < 20; ++step) {
        heading += turn(rng);
        const double l = len(rng);
        x = std::clamp(x + l * std::cos(heading), -0.028, 0.028);
        y = std::clamp(y + l * std::sin(heading), -0.028, 0.028);
        const auto r = s->cut_to(on_sheet(x, y));
        EXPECT_EQ(r.refused, 0u);
        expect_invariants(*s, faces, area0, false, "seed " + std::to_string(seed) + " cut " + std::to_string(c) + " step " + std::to_string(step));
        if (HasFailure()) return;
      }
      s->end_cut();
      EXPECT_GE(s->cuts().back().chain.size(), 3u) << "seed " << seed << " cut " << c;
    }
    for (std::uint32_t f = 0; f < faces; ++f) ASSERT_EQ(s->face_material(f), mat0[f]) << "materials stay with their faces";
  }
}

TEST(SurfaceModel, OpeningWidensTheCutWithinTheElasticLimit) {
  SurfaceParams params;
  params.open_limit = 0.004;
  auto s = sheet(40, 0.03, params);
  ASSERT_TRUE(s->begin_cut(on_sheet(-0.01, 0.0011)));
  for (int i = 1; i <= 20; ++i) (void)s->cut_to(on_sheet(-0.01 + 0.001 * i, 0.0011));
  s->end_cut();
  const Cut& cut = s->cuts().front();
  ASSERT_GE(cut.pairs.size(), 5u);
  EXPECT_DOUBLE_EQ(s->set_opening(0, 0.002), 0.002);
  // In the middle of the lens the two sides are D apart, across the cut.
  const auto& mid = cut.pairs[cut.pairs.size() / 2];
  const double gap = norm(s->position(mid.right) - s->position(mid.left));
  const double taper = std::sin(3.14159265358979 * static_cast<double>(cut.pairs.size() / 2 + 1) / static_cast<double>(cut.pairs.size() + 1));
  EXPECT_NEAR(gap, 0.002 * taper, 1e-6);
  EXPECT_GT(std::abs(s->position(mid.right).y - s->position(mid.left).y), 0.0015 * taper) << "opens across the cut (y), not along it";
  const SurfaceStats st = s->stats();
  EXPECT_EQ(st.flipped_faces, 0u);
  EXPECT_EQ(st.degenerate_faces, 0u);
  EXPECT_TRUE(s->bvh().check(s->view()));
  // Pulling past the elastic limit stops at the limit.
  EXPECT_DOUBLE_EQ(s->pull(0, 0.05), 0.004);
  EXPECT_DOUBLE_EQ(s->set_opening(0, -1), 0.0);
}

TEST(SurfaceModel, WrinkleBesideACutDecays) {
  auto s = sheet(40);
  ASSERT_TRUE(s->begin_cut(on_sheet(-0.01, 0.0011)));
  for (int i = 1; i <= 20; ++i) (void)s->cut_to(on_sheet(-0.01 + 0.001 * i, 0.0011));
  s->end_cut();
  // The opening alone, then the same opening pulled: the difference is the wrinkle.
  ASSERT_DOUBLE_EQ(s->set_opening(0, 0.003), 0.003);
  std::vector<Vec3> opened;
  for (auto v : s->mesh().vertices()) opened.push_back(s->position(static_cast<std::uint32_t>(v.idx())));
  ASSERT_DOUBLE_EQ(s->pull(0, 0.003), 0.003);
  double max_dz = 0;
  for (auto v : s->mesh().vertices()) {
    const auto i = static_cast<std::uint32_t>(v.idx());
    const Vec3 d = s->position(i) - opened[i];
    max_dz = std::max(max_dz, norm(d));
    EXPECT_GT(std::abs(d.z) + 1e-12, 0.9 * norm(d)) << "the wrinkle moves along the normal (about z here)";
  }
  EXPECT_GT(max_dz, 1e-5);
  EXPECT_LE(max_dz, 0.25 * 0.003 + 1e-9);
  for (int i = 0; i < 100; ++i) s->relax(0.05);
  for (auto v : s->mesh().vertices()) {
    const auto i = static_cast<std::uint32_t>(v.idx());
    EXPECT_LT(norm(s->position(i) - opened[i]), 1e-6);
  }
  EXPECT_EQ(s->stats().flipped_faces, 0u);
}

// The patch export reads two things the model keeps rather than recomputes: each vertex's haptic
// position (rest + opening + wrinkle) and each face's boundary flag. Both stay the mesh's through
// cuts that cross and split fans, openings, pulls of one cut while another's wrinkle still lives
// (the wrinkle map made anew), relaxing, and a pressing contact.
TEST(SurfaceModel, KeptHapticPositionsAndBoundaryFlagsFollowEveryEdit) {
  auto s = sheet(40);
  const auto expect_kept = [&](const std::string& where) {
    const SurfaceStats st = s->stats();
    EXPECT_EQ(st.stale_haptic, 0u) << where;
    EXPECT_EQ(st.stale_boundary_flags, 0u) << where;
  };
  std::size_t on_boundary = 0;
  for (std::uint32_t f = 0; f < s->n_faces(); ++f) on_boundary += s->face_on_boundary(f) ? 1 : 0;
  EXPECT_GT(on_boundary, 0u) << "the sheet's border";
  expect_kept("made");
  ASSERT_TRUE(s->begin_cut(on_sheet(-0.01, 0.0011)));
  for (int i = 1; i <= 20; ++i) {
    (void)s->cut_to(on_sheet(-0.01 + 0.001 * i, 0.0011));
    expect_kept("cut step " + std::to_string(i));
  }
  s->end_cut();
  ASSERT_DOUBLE_EQ(s->pull(0, 0.003), 0.003);
  expect_kept("pulled");
  for (int i = 0; i < 3; ++i) s->relax(0.05);
  expect_kept("relaxing");
  // A second cut across the first (the fans at the crossing split), pulled while the first's
  // wrinkle is still dying away.
  ASSERT_TRUE(s->begin_cut(on_sheet(0.0, -0.008)));
  for (int i = 1; i <= 16; ++i) (void)s->cut_to(on_sheet(0.0003, -0.008 + 0.001 * i));
  s->end_cut();
  expect_kept("crossing cut");
  ASSERT_GE(s->cuts().size(), 2u);
  (void)s->pull(1, 0.002);
  expect_kept("second pull");
  s->update_contact(Contact{on_sheet(0.012, 0.006), {0, 0, -1}, 0.002}, 0.01);
  expect_kept("pressed");
  s->update_contact(std::nullopt, 0.5);
  for (int i = 0; i < 100; ++i) s->relax(0.05);
  expect_kept("relaxed");
  std::size_t lips = 0;
  for (std::uint32_t f = 0; f < s->n_faces(); ++f) lips += s->face_on_boundary(f) ? 1 : 0;
  EXPECT_GT(lips, on_boundary) << "the cuts' lips are boundary too";
}

// The wrinkle's extent follows from the cut alone: the same pull after the last one has died away
// gives the same skin, bit for bit (the map made at the first pull is kept, not gathered again
// around the opened cut); a longer cut makes it anew.
TEST(SurfaceModel, TheSamePullAfterTheWrinkleDiedGivesTheSameSkin) {
  auto s = sheet(40);
  ASSERT_TRUE(s->begin_cut(on_sheet(-0.01, 0.0011)));
  for (int i = 1; i <= 20; ++i) (void)s->cut_to(on_sheet(-0.01 + 0.001 * i, 0.0011));
  s->end_cut();
  const auto snapshot = [&] {
    std::vector<Vec3> p;
    for (auto v : s->mesh().vertices()) p.push_back(s->position(static_cast<std::uint32_t>(v.idx())));
    return p;
  };
  ASSERT_DOUBLE_EQ(s->pull(0, 0.0), 0.0);  // as lancet-rt's first report: pulled by nothing yet
  ASSERT_DOUBLE_EQ(s->pull(0, 0.003), 0.003);
  const std::vector<Vec3> first = snapshot();
  for (int i = 0; i < 100; ++i) s->relax(0.05);  // flat again
  ASSERT_DOUBLE_EQ(s->pull(0, 0.003), 0.003);
  const std::vector<Vec3> again = snapshot();
  ASSERT_EQ(first.size(), again.size());
  std::size_t moved = 0;
  for (std::size_t i = 0; i < first.size(); ++i) {
    EXPECT_EQ(first[i].x, again[i].x) << "vertex " << i;
    EXPECT_EQ(first[i].y, again[i].y) << "vertex " << i;
    EXPECT_EQ(first[i].z, again[i].z) << "vertex " << i;
  }
  for (int i = 0; i < 100; ++i) s->relax(0.05);
  ASSERT_DOUBLE_EQ(s->set_opening(0, 0.003), 0.003);
  const std::vector<Vec3> opened = snapshot();
  for (std::size_t i = 0; i < first.size(); ++i) moved += norm(first[i] - opened[i]) > 1e-6;
  EXPECT_GT(moved, 20u) << "the pull wrinkled the skin beside the cut";
  // A longer cut: its pull wrinkles the skin beside the new part too.
  ASSERT_TRUE(s->begin_cut(on_sheet(0.0105, 0.0011)));
  for (int i = 1; i <= 5; ++i) (void)s->cut_to(on_sheet(0.0105 + 0.001 * i, 0.0011));
  s->end_cut();
  ASSERT_EQ(s->cuts().size(), 2u);
  ASSERT_DOUBLE_EQ(s->set_opening(1, 0.002), 0.002);
  const std::vector<Vec3> second_opened = snapshot();
  ASSERT_DOUBLE_EQ(s->pull(1, 0.002), 0.002);
  const std::vector<Vec3> second = snapshot();
  std::size_t near_second = 0;
  for (std::size_t i = 0; i < second.size(); ++i)
    if (norm(second[i] - second_opened[i]) > 1e-6 && second_opened[i].x > 0.0105) ++near_second;
  EXPECT_GT(near_second, 5u) << "the second cut's pull wrinkles beside the second cut";
}

// On a closed, curved marching-cubes surface (a 20 mm sphere): random cuts over the top.
TEST(SurfaceModel, RandomCutsOnAMarchingCubesSphere) {
  volume::Volume v;
  const int n = 48;
  v.dims = {n, n, n};
  v.spacing = {0.001, 0.001, 0.001};
  v.origin = {-0.0235, -0.0235, -0.0235};
  v.data.resize(v.voxel_count());
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) v.data[v.index(i, j, k)] = static_cast<float>(0.02 - norm(v.position(i, j, k)));
  volume::IsoOptions o;
  o.iso = 0;
  auto iso = volume::extract_isosurface(v, o);
  ASSERT_TRUE(iso.ok());
  auto made = SurfaceModel::create(iso.value().positions, iso.value().triangles);
  ASSERT_TRUE(made.ok()) << made.error().message;
  auto& s = *made.value();
  const std::size_t faces = s.n_faces();
  const double area0 = s.stats().rest_area;
  EXPECT_EQ(s.stats().boundary_edges, 0u);
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> turn(-0.7, 0.7), len(0.0005, 0.002);
  const auto on_sphere = [](double az, double el) {
    return Vec3{0.02 * std::cos(el) * std::cos(az), 0.02 * std::cos(el) * std::sin(az), 0.02 * std::sin(el)};
  };
  for (int c = 0; c < 3; ++c) {
    double az = std::uniform_real_distribution<double>(0, 6.28)(rng), el = std::uniform_real_distribution<double>(0.3, 1.2)(rng);
    double heading = std::uniform_real_distribution<double>(0, 6.28)(rng);
    ASSERT_TRUE(s.begin_cut(on_sphere(az, el)));
    for (int step = 0; step < 16; ++step) {
      heading += turn(rng);
      const double l = len(rng) / 0.02;
      az += l * std::cos(heading);
      el = std::clamp(el + l * std::sin(heading), 0.2, 1.4);
      EXPECT_EQ(s.cut_to(on_sphere(az, el)).refused, 0u);
      expect_invariants(s, faces, area0, false, "sphere cut " + std::to_string(c) + " step " + std::to_string(step));
      if (HasFailure()) return;
    }
    s.end_cut();
    EXPECT_GE(s.cuts().back().pairs.size(), 3u) << "cut " << c;
  }
  EXPECT_GT(s.stats().boundary_edges, 0u) << "the cuts opened boundaries in the closed surface";
}

TEST(SurfaceModel, CrossingCutsJoinAndKeepTheInvariants) {
  auto s = sheet(40);
  const std::size_t faces = s->n_faces();
  const double area0 = s->stats().rest_area;
  ASSERT_TRUE(s->begin_cut(on_sheet(-0.015, 0.0007)));
  for (int i = 1; i <= 30; ++i) (void)s->cut_to(on_sheet(-0.015 + 0.001 * i, 0.0007));
  s->end_cut();
  ASSERT_TRUE(s->begin_cut(on_sheet(0.0013, -0.012)));
  for (int i = 1; i <= 24; ++i) {
    const auto r = s->cut_to(on_sheet(0.0013, -0.012 + 0.001 * i));
    EXPECT_EQ(r.refused, 0u);
    expect_invariants(*s, faces, area0, false, "crossing step " + std::to_string(i));
  }
  s->end_cut();
  expect_invariants(*s, faces, area0, false, "after both cuts");
  EXPECT_EQ(s->cuts().size(), 2u);
}

TEST(SurfaceModel, CutsThatOpenAsTheyGoKeepTheInvariants) {
  SurfaceParams params;
  params.open_rest = 0.0003;  // the blade leaves a 0.3 mm gap
  for (std::uint32_t seed : {11u, 12u}) {
    auto s = sheet(36, 0.03, params);
    const std::size_t faces = s->n_faces();
    const double area0 = s->stats().rest_area;
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> pos(-0.02, 0.02), turn(-0.6, 0.6), len(0.0005, 0.003);
    for (int c = 0; c < 2; ++c) {
      double x = pos(rng), y = pos(rng), heading = std::uniform_real_distribution<double>(0, 6.28)(rng);
      ASSERT_TRUE(s->begin_cut(on_sheet(x, y)));
      for (int step = 0; step < 16; ++step) {
        heading += turn(rng);
        const double l = len(rng);
        x = std::clamp(x + l * std::cos(heading), -0.028, 0.028);
        y = std::clamp(y + l * std::sin(heading), -0.028, 0.028);
        EXPECT_EQ(s->cut_to(on_sheet(x, y)).refused, 0u);
        expect_invariants(*s, faces, area0, true, "seed " + std::to_string(seed) + " cut " + std::to_string(c) + " step " + std::to_string(step));
        if (HasFailure()) return;
      }
      s->end_cut();
      EXPECT_GT(s->set_opening(s->cuts().size() - 1, 0.003), 0.0);
      expect_invariants(*s, faces, area0, true, "opened");
    }
  }
}

}  // namespace
}  // namespace lancet::surface
