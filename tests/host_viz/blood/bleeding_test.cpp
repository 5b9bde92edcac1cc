// Bleeding on the tissue scene (the phantom of the incision scenario): a fresh incision oozes
// from its lips into the groove and blood runs down the limb; cutting across the superficial vein
// bleeds strongly until the probe presses on it for 3 s without letting go; the swab takes blood
// away; every millilitre is accounted for.

#include "blood/bleeding.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "tissue/scenario_scene.hpp"
#include "tissue/scripted_sample.hpp"
#include "volume/phantom.hpp"

namespace lancet::tissue {

using blood::Bleeding;
using blood::BleedingParams;
using blood::BloodFigures;
using blood::BloodSource;
namespace {

std::unique_ptr<TissueScene> phantom_scene() {
  auto sc = scenario::load_scenario(std::string(LANCET_SOURCE_DIR) + "/host_viz/scenarios/skin_incision.toml");
  EXPECT_TRUE(sc.ok());
  auto d = scene_description(sc.value());
  EXPECT_TRUE(d.ok());
  auto s = TissueScene::create(std::move(d).value());
  EXPECT_TRUE(s.ok());
  return s.ok() ? std::move(s).value() : nullptr;
}

// A scripted hand, a sample a millisecond; played in frames of 16 samples (16 ms) into the
// scene and the bleeding, which advances by the frame's time.
struct Hand {
  Hand(TissueScene& s, Bleeding& b) : scene(s), blood(b) {}
  TissueScene& scene;
  Bleeding& blood;
  std::vector<ToolSample> samples;
  std::uint64_t seq = 0;
  ToolMode mode = ToolMode::kScalpel;
  // The returned sample may be changed until the next add (a full frame is played first).
  ToolSample& add(Stage stage, Vec3 proxy, Vec3 tool, std::uint32_t events = 0) {
    if (samples.size() == 16) play();
    ++seq;
    samples.push_back(scripted_sample(seq, static_cast<std::int64_t>(seq) * 1'000'000, mode, stage, proxy, tool, events));
    return samples.back();
  }
  void play() {
    if (samples.empty()) return;
    (void)scene.apply(samples);
    blood.observe(samples);
    blood.advance(scene, 1e-3 * static_cast<double>(samples.size()));
    samples.clear();
  }
  Vec3 on(double x, double y) const { return scene.surface_below(x, y).value_or(Vec3{x, y, 0}); }
  // Press, rupture and cut a straight line from a to b (x-y), cut progress every 0.5 mm; lift.
  void cut(Vec3 a, Vec3 b) {
    const Vec3 p0 = on(a.x, a.y);
    for (int i = 0; i < 50; ++i) add(Stage::kDeform, p0, p0 + Vec3{0, 0, -0.00005 * i});
    add(Stage::kRupture, p0, p0 + Vec3{0, 0, -0.003}, event::kRupture).payload.magnitude = 4.0;
    const double len = std::hypot(b.x - a.x, b.y - a.y);
    const int steps = static_cast<int>(std::lround(len / 0.0001));
    for (int i = 1; i <= steps; ++i) {
      const double f = static_cast<double>(i) / steps;
      const Vec3 p = on(a.x + f * (b.x - a.x), a.y + f * (b.y - a.y));
      add(Stage::kCutting, p, p + Vec3{0, 0, -0.001}, i % 5 == 0 ? event::kCutProgress : 0u);
    }
    const Vec3 end = on(b.x, b.y);
    add(Stage::kFree, end + Vec3{0, 0, 0.01}, end + Vec3{0, 0, 0.01});
  }
  // The tool held away from the tissue (or pressing at p) for `seconds`.
  void wait(double seconds) {
    for (int i = 0; i < static_cast<int>(seconds * 1000); ++i) add(Stage::kFree, {0, 0, 0.05}, {0, 0, 0.05});
    play();
  }
  void press(Vec3 p, double seconds) {
    for (int i = 0; i < static_cast<int>(seconds * 1000); ++i) add(Stage::kDeform, p, p + Vec3{0, 0, -0.002});
    play();
  }
};

TEST(Bleeding, AFreshIncisionOozesIntoItsGrooveAndBloodRunsDownTheLimb) {
  auto scene = phantom_scene();
  ASSERT_TRUE(scene);
  Bleeding blood(*scene);
  Hand hand(*scene, blood);
  hand.cut({-0.015, -0.012, 0}, {0.015, -0.012, 0});  // the scenario's line: no vessel under it
  // Open it with the retractor.
  const Vec3 mid = hand.on(0, -0.012);
  hand.mode = ToolMode::kRetractor;
  hand.add(Stage::kFree, mid + Vec3{0, 0, 0.001}, mid + Vec3{0, 0, 0.001}, event::kContactBegin);
  hand.add(Stage::kPulling, mid, mid, event::kGrab);
  for (int i = 1; i <= 100; ++i) hand.add(Stage::kPulling, mid, mid, event::kPull).payload.magnitude = 0.004 * i / 100.0;
  hand.add(Stage::kFree, mid + Vec3{0, 0, 0.02}, mid + Vec3{0, 0, 0.02}, event::kRelease);
  hand.wait(20.0);
  const BloodFigures f = blood.figures();
  EXPECT_FALSE(f.vessel_bleeding) << "nothing under the line but fat";
  ASSERT_GT(blood.groove_cells(), 25u) << "a groove cell per pair of split vertices (about one a mm)";
  // 20 s of ooze from a 30 mm incision opened 4 mm, 6 mm deep, at most at the fresh rates (it
  // clots, and it was open for less than all of it): not less than half that.
  const BleedingParams bp;
  const double most = (bp.ooze_per_m * 0.03 * (1 + 4) + bp.wall_ooze_per_m2 * 2 * 0.03 * 0.006) * 20.5 * 1e6;
  EXPECT_GT(f.lost_ml, 0.5 * most);
  EXPECT_LT(f.lost_ml, most);
  EXPECT_NEAR(f.on_tissue_ml, f.lost_ml, 1e-3 * f.lost_ml + 1e-6) << "nothing swabbed, nothing lost";
  EXPECT_LT(f.ledger_error, 1e-5);
  bool ooze = false, walls = false;
  for (const BloodSource& s : blood.sources()) {
    ooze |= s.kind == BloodSource::Kind::kCutOoze && s.loss_ml > 0;
    walls |= s.kind == BloodSource::Kind::kGrooveWall && s.loss_ml > 0;
  }
  EXPECT_TRUE(ooze && walls);
  // Blood fills the groove and wells onto the skin, and some of it has run down the limb's side:
  // wet skin well below the cut (the line lies on the limb's flank, the skin falls away from it).
  const auto& a = blood.automaton();
  double in_groove = 0, lowest_wet = 0;
  const std::size_t skin = scene->surface().mesh().n_vertices();
  for (std::uint32_t c = 0; c < a.network().cells(); ++c) {
    if (c >= skin) {
      in_groove += a.state().volume[c];
    } else if (a.depth(c) > 1e-4) {
      lowest_wet = std::min(lowest_wet, scene->surface().position(c).z);
    }
  }
  std::printf("[ info     ] lost %.3f mL, %.3f mL in the groove\n", f.lost_ml, in_groove * 1e6);
  for (const BloodSource& s : blood.sources()) std::printf("[ info     ]   %s: %.3f mL\n", s.name.c_str(), s.loss_ml);
  EXPECT_GT(in_groove * 1e6, 0.2) << "mL in the groove (it holds about 0.4 mL opened 4 mm)";
  EXPECT_LT(lowest_wet, mid.z - 0.003) << "blood ran down from the cut";
  // What is drawn: the skin's vertices and the groove's walls carry blood.
  surface::TriangleMesh drawn;
  scene->draw_mesh(drawn);
  std::vector<float> depth, age;
  blood.vertex_blood(drawn, depth, age);
  ASSERT_EQ(depth.size(), drawn.vertices.size());
  std::size_t wet_walls = 0;
  for (std::size_t v = skin; v < depth.size(); ++v) wet_walls += depth[v] > 0;
  EXPECT_GT(wet_walls, 10u);
}

TEST(Bleeding, ACutVesselBleedsUntilPressedForThreeSecondsAndTheSwabTakesBloodAway) {
  auto scene = phantom_scene();
  ASSERT_TRUE(scene);
  // The superficial vein runs along the limb about 12 mm to the side of the top, 4 to 7 mm deep.
  const Vec3 over_vein = scene->surface_below(0.0, 0.012).value();
  ASSERT_EQ(scene->label_at(over_vein + Vec3{0, 0, -0.0055}), volume::kVein);
  Bleeding blood(*scene);
  Hand hand(*scene, blood);
  hand.cut({0.0, 0.004, 0}, {0.0, 0.020, 0});  // across it, 6 mm deep
  hand.wait(2.0);
  BloodFigures f = blood.figures();
  ASSERT_TRUE(f.vessel_bleeding) << "the cut opened the vein";
  const BloodSource* vein = nullptr;
  for (const BloodSource& s : blood.sources())
    if (s.kind == BloodSource::Kind::kVessel) vein = &s;
  ASSERT_NE(vein, nullptr);
  const Vec3 at = vein->position;
  EXPECT_LT(std::hypot(at.x, at.y - 0.012), 0.004) << "where the cut crosses the vein";
  // Untouched it does not stop.
  hand.wait(5.0);
  const double after_7s = blood.figures().lost_ml;
  EXPECT_GT(after_7s, 5 * 0.25) << "about 0.3 mL/s";
  EXPECT_TRUE(blood.figures().vessel_bleeding);
  // Pressed for 2 s, let go: still bleeding (the timer starts again).
  hand.mode = ToolMode::kProbe;
  const Vec3 top = hand.on(at.x, at.y);
  hand.press(top, 2.0);
  hand.wait(0.5);
  EXPECT_TRUE(blood.figures().vessel_bleeding);
  // Pressed for 3.5 s: it stops, and bleeds no more.
  hand.press(top, 3.5);
  EXPECT_FALSE(blood.figures().vessel_bleeding);
  hand.wait(1.0);
  double vessel_loss = 0;
  for (const BloodSource& s : blood.sources()) {
    if (s.kind != BloodSource::Kind::kVessel) continue;
    vessel_loss = s.loss_ml;
    EXPECT_TRUE(s.stopped);
  }
  hand.wait(3.0);
  for (const BloodSource& s : blood.sources()) {
    if (s.kind == BloodSource::Kind::kVessel) {
      EXPECT_EQ(s.loss_ml, vessel_loss);
    }
  }
  // The swab over the wound takes the blood under it away (blood around runs back in, slowly),
  // counted as swabbed.
  const auto near_swab = [&] {
    double v = 0;
    const std::size_t skin = scene->surface().mesh().n_vertices();
    for (std::uint32_t c = 0; c < skin; ++c)
      if (norm(scene->surface().position(c) - top) < 0.003) v += blood.automaton().state().volume[c];
    return v;
  };
  const double before = blood.figures().on_tissue_ml, under_before = near_swab();
  ASSERT_GT(under_before, 0.0);
  hand.mode = ToolMode::kSwab;
  hand.press(top, 2.0);
  f = blood.figures();
  EXPECT_LT(near_swab(), 0.2 * under_before);
  EXPECT_GT(f.swabbed_ml, 0.01);
  EXPECT_LT(f.on_tissue_ml, before);
  EXPECT_NEAR(f.on_tissue_ml, f.lost_ml - f.swabbed_ml, 1e-3 * f.lost_ml);
  EXPECT_LT(f.ledger_error, 1e-5);
}

}  // namespace
// Two hands, their samples interleaved tick by tick as lancet-rt sends them (the right hand's, then
// the left's): the right hand's probe stops the vessel and its swab takes the blood while the left
// hand works elsewhere. (The left hand's sample comes last in every tick and frame: it does not
// stand for the right hand's.)
TEST(Bleeding, EitherHandPressesAndSwabsWhileTheOtherWorksElsewhere) {
  auto scene = phantom_scene();
  ASSERT_TRUE(scene);
  Bleeding blood(*scene);
  Hand hand(*scene, blood);
  hand.cut({0.0, 0.004, 0}, {0.0, 0.020, 0});  // across the superficial vein
  hand.wait(2.0);
  ASSERT_TRUE(blood.figures().vessel_bleeding);
  const BloodSource* vein = nullptr;
  for (const BloodSource& src : blood.sources())
    if (src.kind == BloodSource::Kind::kVessel) vein = &src;
  ASSERT_NE(vein, nullptr);
  const Vec3 top = hand.on(vein->position.x, vein->position.y);
  std::uint64_t seq = hand.seq;
  // seconds of ticks: the right hand's `mode` at `top`, the left hand probing 30 mm away.
  const auto both = [&](ToolMode right_mode, double seconds) {
    std::vector<ToolSample> frame;
    const Vec3 far = hand.on(0.03, -0.01);
    for (int i = 0; i < static_cast<int>(seconds * 1000); ++i) {
      ++seq;
      const auto t = static_cast<std::int64_t>(seq) * 1'000'000;
      ToolSample r = scripted_sample(seq, t, right_mode, Stage::kDeform, top, top + Vec3{0, 0, -0.002}, 0);
      ToolSample l = scripted_sample(seq, t, ToolMode::kProbe, Stage::kDeform, far, far + Vec3{0, 0, -0.001}, 0);
      r.hand = lancet::Hand::kRight;
      l.hand = lancet::Hand::kLeft;
      frame.push_back(r);
      frame.push_back(l);
      if (frame.size() == 32) {
        (void)scene->apply(frame);
        blood.observe(frame);
        blood.advance(*scene, 0.016);
        frame.clear();
      }
    }
  };
  both(ToolMode::kProbe, 3.5);
  EXPECT_FALSE(blood.figures().vessel_bleeding) << "the right hand's press stopped it, the left hand's samples between";
  const double swabbed = blood.figures().swabbed_ml;
  both(ToolMode::kSwab, 2.0);
  EXPECT_GT(blood.figures().swabbed_ml, swabbed + 0.01) << "the right hand's swab takes blood";
  EXPECT_LT(blood.figures().ledger_error, 1e-5);
}

}  // namespace lancet::tissue
