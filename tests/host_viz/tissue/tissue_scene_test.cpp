// TissueScene: lancet-rt's ToolSample stream, scripted, drives the whole tissue — the dent, the
// rupture, a cut of the right length on the surface, a groove of the opening's width and the cut's
// depth in the volume, the drill's removals and the bone surface re-extracted closed — and the
// patch it exports carries the brick.

#include "tissue/tissue_scene.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "score/task_monitor.hpp"
#include "tissue/scenario_scene.hpp"
#include "tissue/scripted_sample.hpp"
#include "volume/marching_cubes.hpp"
#include "volume/mesh_tools.hpp"
#include "volume/phantom.hpp"

namespace lancet::tissue {
namespace {

std::unique_ptr<TissueScene> make(SceneDescription d) {
  auto s = TissueScene::create(std::move(d));
  EXPECT_TRUE(s.ok()) << (s.ok() ? "" : s.error().message);
  return s.ok() ? std::move(s).value() : nullptr;
}

// A scripted hand: samples one tick (1 ms) apart.
struct Script {
  std::vector<ToolSample> samples;
  std::uint64_t seq = 0;
  ToolSample& add(Stage stage, Vec3 proxy, Vec3 tool, std::uint32_t events = 0) {
    ++seq;
    samples.push_back(scripted_sample(seq, static_cast<std::int64_t>(seq) * 1'000'000, ToolMode::kProbe, stage, proxy, tool, events));
    return samples.back();
  }
  // Feeds the samples in frames of 16, as lancet-viz drains them.
  void play(TissueScene& s) {
    for (std::size_t i = 0; i < samples.size(); i += 16)
      (void)s.apply(std::span<const ToolSample>(samples).subspan(i, std::min<std::size_t>(16, samples.size() - i)));
    samples.clear();
  }
};

// Press, rupture, a straight cut of `length` along +x from `start` (the blade 1 mm below the
// proxy, cut progress every 0.5 mm), lift out, then the retractor pulls the incision open by D.
void cut_and_open(Script& sc, const std::function<double(double, double)>& height, Vec3 start, double length, double d) {
  const auto on = [&](double x, double y) { return Vec3{x, y, height(x, y)}; };
  const Vec3 p0 = on(start.x, start.y);
  for (int i = 0; i < 50; ++i) sc.add(Stage::kDeform, p0, p0 + Vec3{0, 0, -0.00005 * i});
  sc.add(Stage::kRupture, p0, p0 + Vec3{0, 0, -0.003}, event::kRupture).payload.magnitude = 4.0;
  const int steps = static_cast<int>(std::lround(length / 0.0001));
  for (int i = 1; i <= steps; ++i) {
    const Vec3 p = on(start.x + 0.0001 * i, start.y);
    sc.add(Stage::kCutting, p, p + Vec3{0, 0, -0.001}, i % 5 == 0 ? event::kCutProgress : 0u);
  }
  const Vec3 end = on(start.x + length, start.y);
  sc.add(Stage::kFree, end + Vec3{0, 0, 0.01}, end + Vec3{0, 0, 0.01});
  const Vec3 mid = on(start.x + 0.5 * length, start.y);
  sc.add(Stage::kFree, mid + Vec3{0, 0, 0.001}, mid + Vec3{0, 0, 0.001}, event::kContactBegin);
  sc.add(Stage::kPulling, mid, mid, event::kGrab);
  for (int i = 1; i <= 100; ++i) sc.add(Stage::kPulling, mid, mid, event::kPull).payload.magnitude = d * i / 100.0;
}

TEST(TissueScene, AScriptedStreamCutsTheSurfaceAndOpensAGrooveInTheVolume) {
  SceneDescription d;
  d.source = SceneSource::kBlock;
  d.cut_depth = 0.006;
  auto scene = make(d);
  ASSERT_TRUE(scene);
  Script sc;
  const surface::TissueBlockParams block{};
  const auto height = [&](double x, double y) { return surface::tissue_block_height(block, x, y); };
  cut_and_open(sc, height, {-0.015, 0.0011, 0}, 0.03, 0.004);
  sc.play(*scene);

  const SceneEvents& e = scene->events();
  EXPECT_EQ(e.ruptures, 1u);
  EXPECT_EQ(e.grabs, 1u);
  EXPECT_EQ(e.pulls, 100u);
  EXPECT_EQ(e.cut_steps, 60u);
  // On the surface: one cut, 30 mm long on the mesh, opened by D.
  const CutFigures cuts = scene->cut_figures();
  EXPECT_EQ(cuts.cuts, 1u);
  EXPECT_NEAR(cuts.longest, 0.03, 0.003);
  EXPECT_NEAR(cuts.opening, 0.004, 0.0005);
  // In the volume: a groove along the same 30 mm, its top walls D apart, as deep as the cut.
  const auto grooves = scene->grooves();
  ASSERT_EQ(grooves.size(), 1u);
  const GrooveFigures& g = grooves[0];
  EXPECT_NEAR(g.length, 0.03, 0.0015);
  EXPECT_DOUBLE_EQ(g.width, 0.004);
  EXPECT_NEAR(g.top_gap, 0.004, 0.0002);
  // The block's surface undulates by ±3 mm along the cut: the cut reaches 6 mm below its lowest
  // point, so its deepest face is 6 to 6 + 6 mm below the top of its column.
  EXPECT_GE(g.depth, 0.006 - 0.001);
  EXPECT_LE(g.depth, 0.012 + 0.001);
  EXPECT_GT(g.faces, 100u);

  // What is drawn: the surface plus the groove's walls, in the tissue's materials.
  surface::TriangleMesh drawn, skin;
  scene->draw_mesh(drawn);
  scene->surface().to_triangle_mesh(skin);
  EXPECT_GT(drawn.triangles.size(), skin.triangles.size() + 50);
  std::size_t fat = 0;
  for (std::size_t f = skin.triangles.size(); f < drawn.triangles.size(); ++f) fat += drawn.material[f] == volume::kFat;
  EXPECT_GT(fat, 0u) << "the walls show the fat under the skin";
  const auto st = scene->surface().stats();
  EXPECT_EQ(st.non_manifold_vertices, 0u);
  EXPECT_EQ(st.flipped_faces, 0u);
}

TEST(TissueScene, TheGrooveWidensWithTheOpening) {
  SceneDescription d;
  d.source = SceneSource::kBlock;
  auto scene = make(d);
  ASSERT_TRUE(scene);
  Script sc;
  const surface::TissueBlockParams block{};
  const auto height = [&](double x, double y) { return surface::tissue_block_height(block, x, y); };
  cut_and_open(sc, height, {-0.01, 0.0011, 0}, 0.02, 0.002);
  sc.play(*scene);
  const double narrow = scene->grooves().at(0).top_gap;
  const Vec3 mid{0, 0.0011, height(0, 0.0011)};
  for (int i = 1; i <= 50; ++i) sc.add(Stage::kPulling, mid, mid, event::kPull).payload.magnitude = 0.002 + 0.003 * i / 50.0;
  sc.play(*scene);
  EXPECT_NEAR(narrow, 0.002, 0.0002);
  EXPECT_NEAR(scene->grooves().at(0).top_gap, 0.005, 0.0003);
}

// Two hands, in tick order as lancet-rt sends them (each tick the right hand's sample, then the
// left's, with the tick's seq): the left hand's retractor grabs the first incision and holds it
// open while the right hand's scalpel makes a second one beside it. The held incision stays open,
// its groove with it; the left hand's pulls keep to the cut it grabbed, not the one being made; the
// right hand's cut is not ended by the left hand's samples.
TEST(TissueScene, TheHeldIncisionStaysOpenWhileTheOtherHandCuts) {
  SceneDescription d;
  d.source = SceneSource::kBlock;
  auto scene = make(d);
  ASSERT_TRUE(scene);
  const surface::TissueBlockParams block{};
  const auto on = [&](double x, double y) { return Vec3{x, y, surface::tissue_block_height(block, x, y)}; };
  // The first incision, one-handed (the right hand), 20 mm along x at y = 1.1 mm.
  Script right;
  cut_and_open(right, [&](double x, double y) { return surface::tissue_block_height(block, x, y); }, {-0.02, 0.0011, 0}, 0.02, 0.0);
  right.samples.resize(right.samples.size() - 101);  // up to the grab: the left hand holds it
  right.play(*scene);
  ASSERT_EQ(scene->cut_figures().cuts, 1u);
  // Whether the surface a patch around `at` gives the haptics covers `at` (seen from above): a
  // tool there rests on tissue, or falls into the opening.
  const auto patch_covers = [&](Vec3 at) {
    auto patch = std::make_unique<TissuePatch>();
    (void)scene->export_patch(at, *patch);
    for (std::uint32_t i = 0; i < patch->n_triangles; ++i) {
      const auto& v = patch->triangles[i].v;
      const auto side = [&](int a, int b) {
        return (v[b].x - v[a].x) * (at.y - v[a].y) - (v[b].y - v[a].y) * (at.x - v[a].x);
      };
      const double s0 = side(0, 1), s1 = side(1, 2), s2 = side(2, 0);
      if ((s0 >= 0 && s1 >= 0 && s2 >= 0) || (s0 <= 0 && s1 <= 0 && s2 <= 0)) return true;
    }
    return false;
  };
  const Vec3 on_the_cut = on(-0.012, 0.0011);
  EXPECT_TRUE(patch_covers(on_the_cut)) << "a closed incision: the tissue is felt across it";

  std::vector<ToolSample> ticks;
  std::uint64_t seq = 10'000;
  const auto tick = [&](ToolSample r, ToolSample l) {
    ++seq;
    r.seq = l.seq = seq;
    r.t_ns = l.t_ns = static_cast<std::int64_t>(seq) * 1'000'000;
    r.hand = Hand::kRight;
    l.hand = Hand::kLeft;
    ticks.push_back(r);
    ticks.push_back(l);
  };
  const Vec3 grip = on(-0.01, 0.0011), rest_r = on(0.005, -0.012) + Vec3{0, 0, 0.01};
  const auto sample = [](ToolMode m, Stage st, Vec3 proxy, Vec3 tool, std::uint32_t ev = 0) {
    return scripted_sample(0, 0, m, st, proxy, tool, ev);
  };
  // The left hand grabs and pulls the incision to 4 mm, the right hand hovers.
  tick(sample(ToolMode::kScalpel, Stage::kFree, rest_r, rest_r), sample(ToolMode::kRetractor, Stage::kPulling, grip, grip, event::kGrab));
  for (int i = 1; i <= 50; ++i) {
    ToolSample l = sample(ToolMode::kRetractor, Stage::kPulling, grip, grip, event::kPull);
    l.payload.magnitude = 0.004 * i / 50.0;
    tick(sample(ToolMode::kScalpel, Stage::kFree, rest_r, rest_r), l);
  }
  // The right hand presses, ruptures and cuts 20 mm along x at y = -12 mm, while the left hand
  // holds (and, its hand trembling, reports pulls of the same 4 mm).
  const auto holding = [&](int i) {
    ToolSample l = sample(ToolMode::kRetractor, Stage::kPulling, grip, grip, i % 7 == 0 ? event::kPull : 0u);
    l.payload.magnitude = 0.004;
    return l;
  };
  const Vec3 p0 = on(-0.005, -0.012);
  int i = 0;
  for (int k = 0; k < 50; ++k, ++i) tick(sample(ToolMode::kScalpel, Stage::kDeform, p0, p0 + Vec3{0, 0, -0.00005 * k}), holding(i));
  ToolSample rupture = sample(ToolMode::kScalpel, Stage::kRupture, p0, p0 + Vec3{0, 0, -0.003}, event::kRupture);
  rupture.payload.magnitude = 4.0;
  tick(rupture, holding(i++));
  for (int k = 1; k <= 200; ++k, ++i) {
    const Vec3 p = on(-0.005 + 0.0001 * k, -0.012);
    tick(sample(ToolMode::kScalpel, Stage::kCutting, p, p + Vec3{0, 0, -0.001}, k % 5 == 0 ? event::kCutProgress : 0u), holding(i));
  }
  const Vec3 end = on(0.015, -0.012) + Vec3{0, 0, 0.01};
  tick(sample(ToolMode::kScalpel, Stage::kFree, end, end), holding(i++));
  for (std::size_t f = 0; f < ticks.size(); f += 32)
    (void)scene->apply(std::span<const ToolSample>(ticks).subspan(f, std::min<std::size_t>(32, ticks.size() - f)));

  const auto& cuts = scene->surface().cuts();
  ASSERT_EQ(cuts.size(), 2u) << "the right hand's cut was made whole, not ended by the left hand's samples";
  EXPECT_NEAR(cuts[0].opening, 0.004, 1e-9) << "the held incision stays open";
  EXPECT_EQ(cuts[1].opening, 0.0) << "the left hand's pulls keep to the cut it grabbed";
  EXPECT_FALSE(cuts[1].active) << "the right hand lifted out: its cut ended";
  double second = 0;
  for (std::size_t k = 1; k < cuts[1].path.size(); ++k) second += norm(cuts[1].path[k] - cuts[1].path[k - 1]);
  EXPECT_NEAR(second, 0.02, 0.002);
  const auto grooves = scene->grooves();
  ASSERT_EQ(grooves.size(), 2u);
  EXPECT_NEAR(grooves[0].top_gap, 0.004, 0.0003) << "the groove opens under the held incision";
  // What the left hand holds, the right hand feels: the patch the right hand would get there has
  // the opening in it.
  EXPECT_FALSE(patch_covers(on_the_cut)) << "the held incision is open in the haptic surface too";
  EXPECT_LT(grooves[1].top_gap, 0.0005);
}

// The volume as drawn: the open groove is carved out of it (air where the incision gapes, down
// to the cut depth), the tissue's own volume is untouched, and a narrower opening restores what
// it no longer opens.
TEST(TissueScene, TheDrawnVolumeGapesWhereTheIncisionIsOpen) {
  SceneDescription d;
  d.source = SceneSource::kBlock;
  auto scene = make(d);
  ASSERT_TRUE(scene);
  const volume::Volume& drawn = scene->render_volume();
  const volume::Volume& tissue = scene->volume();
  const surface::TissueBlockParams block{};
  const auto height = [&](double x, double y) { return surface::tissue_block_height(block, x, y); };
  const auto hu = [&](const volume::Volume& v, Vec3 w) {
    const Vec3 q = scene->placement().to_volume(w);
    const int i = static_cast<int>(std::lround((q.x - v.origin.x) / v.spacing.x)), j = static_cast<int>(std::lround((q.y - v.origin.y) / v.spacing.y)),
              k = static_cast<int>(std::lround((q.z - v.origin.z) / v.spacing.z));
    return v.data[v.index(i, j, k)];
  };
  Script sc;
  cut_and_open(sc, height, {-0.015, 0.0, 0}, 0.03, 0.006);
  sc.play(*scene);
  (void)scene->take_volume_changes();
  const Vec3 under{0.0, 0.0, height(0.0, 0.0) - 0.002};
  EXPECT_EQ(hu(scene->render_volume(), under), -1000.0f) << "air in the gap, 2 mm down";
  EXPECT_GT(hu(tissue, under), -500.0f) << "the tissue itself is not cut away";
  EXPECT_GT(hu(drawn, under + Vec3{0, 0.008, 0}), -500.0f) << "8 mm beside the cut is tissue";
  // Closing the incision fills the gap again.
  const Vec3 mid{0, 0, height(0, 0)};
  sc.add(Stage::kPulling, mid, mid, event::kPull).payload.magnitude = 0.0;
  sc.play(*scene);
  EXPECT_GT(hu(scene->render_volume(), under), -500.0f);
  EXPECT_FALSE(scene->take_volume_changes().empty()) << "the change is reported for the ray caster";
}

TEST(TissueScene, ThePhantomIsPlacedAsItsSkinSaysAndItsPatchCarriesTheBrick) {
  auto scene = make({});
  ASSERT_TRUE(scene);
  // World (x, y, z) = volume (z, x, y): the limb along x, its front up, the skin's top at z = 0.
  EXPECT_EQ(scene->placement().axis, (std::array<int, 3>{2, 0, 1}));
  EXPECT_EQ(scene->placement().sign, (std::array<int, 3>{1, 1, 1}));
  EXPECT_NEAR(scene->placement().offset.x, 0, 1e-9);
  EXPECT_NEAR(scene->placement().offset.y, 0, 1e-9);
  surface::TriangleMesh skin;
  scene->surface().to_triangle_mesh(skin);
  float top = -1;
  for (const auto& v : skin.vertices) top = std::max(top, v.z);
  EXPECT_NEAR(top, 0.0f, 1e-6f);
  // Down from z = 0 at the limb's middle: air, then skin, fat and muscle in that order.
  std::vector<std::uint8_t> layers;
  for (double z = 0; z > -0.02; z -= 0.00025) {
    const std::uint8_t l = scene->label_at({0, 0, z});
    if (layers.empty() || layers.back() != l) layers.push_back(l);
  }
  EXPECT_EQ(layers, (std::vector<std::uint8_t>{volume::kAir, volume::kSkin, volume::kFat, volume::kMuscle}));
  auto patch = std::make_unique<TissuePatch>();
  EXPECT_GT(scene->export_patch({0, 0, 0}, *patch), 0u);
  EXPECT_GT(patch->n_triangles, 0u);
  EXPECT_EQ(patch->brick.valid, 1u);
}

// place_skin takes the isosurface and places it as the scene does: every vertex where the placement
// (with the offset it sets) sends it, the volume's centre at x = y = 0 and the top at z = 0, each
// triangle's winding kept or, where the axes change handedness, reversed so it still faces out.
TEST(TissueScene, PlaceSkinPutsTheSkinWhereThePlacementSaysAndKeepsItFacingOut) {
  const volume::Volume v = volume::make_phantom(volume::PhantomParams{}).volume;
  volume::IsoOptions o;
  o.iso = -300;
  o.normals = false;
  const volume::IsoSurface iso = volume::extract_isosurface(v, o).value();
  ASSERT_GT(iso.triangles.size(), 1000u);
  for (const int sign : {1, -1}) {
    VolumePlacement placement;
    placement.axis = {2, 0, 1};
    placement.sign = {1, sign, 1};
    volume::IsoSurface taken = iso;
    const surface::TriangleMesh m = place_skin(std::move(taken), v, placement);
    ASSERT_EQ(m.vertices.size(), iso.positions.size());
    ASSERT_EQ(m.triangles.size(), iso.triangles.size());
    EXPECT_TRUE(m.normals.empty());
    EXPECT_TRUE(std::all_of(m.material.begin(), m.material.end(), [](std::uint16_t x) { return x == volume::kSkin; }));
    float top = -1;
    for (std::size_t i = 0; i < m.vertices.size(); ++i) {
      const Vec3f want = to_vec3f(placement.to_world(to_vec3(iso.positions[i])));
      ASSERT_TRUE(m.vertices[i] == want) << "vertex " << i;
      top = std::max(top, m.vertices[i].z);
    }
    EXPECT_EQ(top, 0.0f);
    const Vec3 centre = placement.to_world(v.position(0.5 * (v.dims[0] - 1), 0.5 * (v.dims[1] - 1), 0.5 * (v.dims[2] - 1)));
    EXPECT_NEAR(centre.x, 0, 1e-12);
    EXPECT_NEAR(centre.y, 0, 1e-12);
    // Facing out: the signed volume the faces enclose (a closed skin's) stays positive.
    double volume6 = 0;
    for (std::size_t f = 0; f < m.triangles.size(); ++f) {
      const auto& t = m.triangles[f];
      const Vec3 a = to_vec3(m.vertices[t[0]]), b = to_vec3(m.vertices[t[1]]), c = to_vec3(m.vertices[t[2]]);
      volume6 += dot(a, cross(b, c));
      const auto& was = iso.triangles[f];
      if (sign > 0)
        EXPECT_EQ(t, was);
      else
        EXPECT_EQ(t, (std::array<std::uint32_t, 3>{was[0], was[2], was[1]}));
    }
    EXPECT_GT(volume6, 0) << "sign " << sign;
  }
}

// The drill: removals lancet-rt reports are carved into the volume, the labels follow, and the bone
// surface is re-extracted where they were and stays closed.
TEST(TissueScene, DrillRemovalsCarveTheVolumeAndKeepTheBoneSurfaceClosed) {
  auto scene = make({});
  ASSERT_TRUE(scene);
  const Vec3 bone_top{0, 0.006, -0.0325};  // the phantom's bone under the limb's front
  ASSERT_EQ(scene->label_at(bone_top + Vec3{0, 0, -0.001}), volume::kCorticalBone);
  Script sc;
  for (int i = 0; i < 40; ++i) {
    const Vec3 c = bone_top + Vec3{0, 0, -0.0001 * i};
    sc.add(Stage::kFree, c, c, event::kDrillRemove).payload.magnitude = 0.0025;
  }
  sc.play(*scene);
  EXPECT_EQ(scene->events().drill_removals, 40u);
  EXPECT_GT(scene->events().voxels_drilled, 60u);
  EXPECT_EQ(scene->label_at(bone_top + Vec3{0, 0, -0.002}), volume::kAir);
  EXPECT_EQ(scene->label_at(bone_top + Vec3{0, 0, -0.0055}), volume::kAir);
  ASSERT_NE(scene->bone(), nullptr);
  EXPECT_GE(scene->events().bone_updates, 1u);
  const auto st = volume::mesh_stats(scene->bone()->mesh());
  EXPECT_TRUE(st.closed()) << st.boundary_edges << " boundary edges, " << st.non_manifold_vertices << " non-manifold";
  // The next patch's brick has the hole.
  auto patch = std::make_unique<TissuePatch>();
  (void)scene->export_patch(bone_top, *patch);
  ASSERT_EQ(patch->brick.valid, 1u);
  const VoxelBrick& b = patch->brick;
  int inside = 0, air = 0;
  for (std::uint32_t k = 0; k < kBrickDim; ++k)
    for (std::uint32_t j = 0; j < kBrickDim; ++j)
      for (std::uint32_t i = 0; i < kBrickDim; ++i) {
        const Vec3 c = b.origin + Vec3{i * b.spacing.x, j * b.spacing.y, k * b.spacing.z};
        if (norm(c - (bone_top + Vec3{0, 0, -0.002})) > 0.002) continue;
        ++inside;
        air += b.hu[i + kBrickDim * (j + kBrickDim * k)] == -1000;
      }
  EXPECT_GT(inside, 10);
  EXPECT_EQ(air, inside);
}

// Exposed bone: the trainee touches the bone; the drilled hole shows in what is drawn at once and,
// once the drilling pauses (the drill put down), in the surface the haptics feel.
TEST(TissueScene, OnExposedBoneTheDrilledHoleIsDrawnAndFelt) {
  SceneDescription d;
  d.surface = SceneSurface::kBone;
  auto scene = make(d);
  ASSERT_TRUE(scene);
  ASSERT_NE(scene->bone(), nullptr);
  surface::TriangleMesh before;
  scene->draw_mesh(before);
  const std::uint64_t rev = scene->revision();
  const Vec3 bone_top{0, 0.006, -0.0325};
  Script sc;
  for (int i = 0; i < 300; ++i) {
    const Vec3 c = bone_top + Vec3{0, 0, -0.00001 * i};
    ToolSample& t = sc.add(Stage::kFree, c, c, i % 10 == 0 ? event::kDrillRemove : 0u);
    t.payload.magnitude = 0.002;
    t.mode = ToolMode::kDrill;
  }
  sc.play(*scene);
  EXPECT_NE(scene->revision(), rev);
  surface::TriangleMesh after;
  scene->draw_mesh(after);
  EXPECT_NE(after.triangles.size(), before.triangles.size());
  auto early = std::make_unique<TissuePatch>();
  ASSERT_GT(scene->export_patch(bone_top, *early), 0u);
  std::size_t inside = 0;
  for (std::uint32_t t = 0; t < early->n_triangles; ++t)
    for (const auto& v : early->triangles[t].v) inside += norm(to_vec3(v) - bone_top) <= 0.0015;
  EXPECT_GT(inside, 0u) << "while the drill is in use, the felt surface is not rebuilt";
  sc.add(Stage::kFree, bone_top + Vec3{0, 0, 0.01}, bone_top + Vec3{0, 0, 0.01});  // the probe again
  sc.play(*scene);
  // The felt surface has no triangle left inside the burr's first bite.
  auto patch = std::make_unique<TissuePatch>();
  ASSERT_GT(scene->export_patch(bone_top, *patch), 0u);
  for (std::uint32_t t = 0; t < patch->n_triangles; ++t)
    for (const auto& v : patch->triangles[t].v) EXPECT_GT(norm(to_vec3(v) - bone_top), 0.0015);
}

TEST(TissueScene, AVolumeWithoutLabelsGetsThemFromItsIsovalues) {
  SceneDescription d;
  d.source = SceneSource::kVolume;
  volume::Volume& v = d.volume.volume;
  v.dims = {40, 30, 20};
  v.spacing = {0.001, 0.001, 0.001};
  v.value_unit = "HU";
  v.data.assign(v.voxel_count(), -1000.0f);
  for (int k = 0; k < 14; ++k)  // tissue in the lower 14 layers, a bone slab in the lowest 4
    for (int j = 0; j < 30; ++j)
      for (int i = 0; i < 40; ++i) v.data[v.index(i, j, k)] = k < 4 ? 1200.0f : 40.0f;
  auto scene = make(std::move(d));
  ASSERT_TRUE(scene);
  EXPECT_EQ(scene->label_at({0, 0, -0.002}), volume::kMuscle);
  EXPECT_EQ(scene->label_at({0, 0, -0.0125}), volume::kCorticalBone);
  EXPECT_EQ(scene->label_at({0, 0, 0.002}), volume::kAir);
}

TEST(TissueScene, BadDescriptionsAreRefusedWithTheReason) {
  SceneDescription empty;
  empty.source = SceneSource::kVolume;
  auto r = TissueScene::create(std::move(empty));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("empty"), std::string::npos) << r.error().message;

  SceneDescription air;
  air.source = SceneSource::kVolume;
  air.volume.volume.dims = {8, 8, 8};
  air.volume.volume.spacing = {0.001, 0.001, 0.001};
  air.volume.volume.data.assign(512, -1000.0f);
  r = TissueScene::create(std::move(air));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("no skin at -300"), std::string::npos) << r.error().message;

  SceneDescription axes;
  axes.source = SceneSource::kVolume;
  axes.volume.volume.dims = {8, 8, 8};
  axes.volume.volume.spacing = {0.001, 0.001, 0.001};
  axes.volume.volume.data.assign(512, 40.0f);
  axes.axis = {0, 0, 2};
  r = TissueScene::create(std::move(axes));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("permutation"), std::string::npos) << r.error().message;

  SceneDescription iso;
  iso.skin_iso = 500;
  iso.bone_iso = 300;
  r = TissueScene::create(std::move(iso));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("skin < bone"), std::string::npos) << r.error().message;
}

}  // namespace
}  // namespace lancet::tissue

namespace lancet::tissue {
namespace {

// The task measured on the scene: an incision along the skin-incision scenario's line counts as
// progress, and drilling into the artery under it names the artery as damaged.
TEST(TaskMonitor, MeasuresTheIncisionAndNamesTheStructureReached) {
  auto sc = scenario::load_scenario(std::string(LANCET_SOURCE_DIR) + "/host_viz/scenarios/skin_incision.toml");
  ASSERT_TRUE(sc.ok()) << sc.error().message;
  auto d = scene_description(sc.value());
  ASSERT_TRUE(d.ok()) << d.error().message;
  auto scene = make(std::move(d).value());
  ASSERT_TRUE(scene);
  score::TaskMonitor task(sc.value(), *scene);
  EXPECT_EQ(task.status().progress, 0.0);
  // Cut along the line (x from -15 to 15 mm at y = -12 mm), on the skin.
  Script hand;
  const auto skin = [&](double x, double y) { return scene->surface_below(x, y).value_or(Vec3{x, y, 0}).z; };
  cut_and_open(hand, skin, {-0.015, -0.012, 0}, 0.03, 0.004);
  for (std::size_t i = 0; i < hand.samples.size(); i += 16) {
    const auto frame = std::span<const ToolSample>(hand.samples).subspan(i, std::min<std::size_t>(16, hand.samples.size() - i));
    (void)scene->apply(frame);
    (void)task.update(*scene, frame);
  }
  hand.samples.clear();
  EXPECT_GT(task.status().progress, 0.8) << task.status().line;
  EXPECT_TRUE(task.status().damaged.empty()) << "a 6 mm cut does not reach the artery 27 mm down";
  // The drill goes down to the artery.
  const Vec3 artery{0, -0.012, -0.027};
  ASSERT_EQ(scene->label_at(artery), volume::kVessel);
  ToolSample& t = hand.add(Stage::kFree, artery, artery, event::kDrillRemove);
  t.payload.magnitude = 0.002;
  (void)scene->apply(hand.samples);
  (void)task.update(*scene, hand.samples);
  ASSERT_EQ(task.status().damaged.size(), 1u) << task.status().line;
  EXPECT_EQ(task.status().damaged[0], "radial artery");
  EXPECT_NE(task.status().line.find("DAMAGED: radial artery"), std::string::npos);
}

}  // namespace
}  // namespace lancet::tissue
