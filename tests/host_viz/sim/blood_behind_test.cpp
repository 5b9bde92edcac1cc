// SceneSim's blood behind (sim/blood_behind.hpp, what a replay runs): the blood prepared and
// stepped on a thread of its own while the next frame's samples are applied. The same frames with
// it on and off give the same scene and blood, bit for bit. Labelled threads: the tsan preset runs
// it too.

#include "sim/blood_behind.hpp"

#include <gtest/gtest.h>

#include <cstring>
#include <fstream>
#include <memory>
#include <span>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "sim/viz_frame.hpp"
#include "tissue/scripted_sample.hpp"

namespace lancet::sim {
namespace {

// A frame's ends: the batch given; the patch stays in the caller's buffer.
struct Frame final : FrameIo {
  FrameBatch next;
  Result<FrameBatch> drain() override { return next; }
  void publish(const std::array<const TissuePatch*, kHandCount>&) override {}
};

// The blood behind (SceneSim::set_blood_behind, what a replay runs): prepared and stepped on a
// thread of its own while the next frame's samples are applied. The same cut and pull on the skin
// incision's phantom, frame by frame, with it on and off: the same scene and blood, bit for bit,
// in every frame's hash and figures.
TEST(BloodBehind, GivesTheSameSceneAndBloodAsSteppingInTheFrame) {
  std::ifstream in(std::string(LANCET_SOURCE_DIR) + "/host_viz/scenarios/skin_incision.toml");
  std::stringstream text;
  text << in.rdbuf();
  SceneSetup setup;
  setup.scenario_toml = text.str();
  setup.scenario_file = std::string(LANCET_SOURCE_DIR) + "/host_viz/scenarios/skin_incision.toml";
  auto a = SceneSim::create(setup), b = SceneSim::create(setup);
  ASSERT_TRUE(a.ok() && b.ok()) << (a.ok() ? b.error().message : a.error().message);
  ASSERT_NE(a.value()->bleeding(), nullptr);
  b.value()->set_blood_behind(true);
  // The script: press, rupture, cut 24 mm along the scenario's line, then pull the cut open with
  // the retractor and let it bleed; 16 samples a frame.
  std::vector<ToolSample> script;
  std::uint64_t seq = 0;
  const auto add = [&](ToolMode mode, Stage stage, Vec3 proxy, Vec3 tool, std::uint32_t events = 0, double magnitude = 0) {
    ++seq;
    script.push_back(tissue::scripted_sample(seq, static_cast<std::int64_t>(seq) * 1'000'000, mode, stage, proxy, tool, events));
    script.back().payload.magnitude = magnitude;
  };
  const tissue::TissueScene& scene = std::as_const(*a.value()).scene();
  const auto on = [&](double x, double y) { return scene.surface_below(x, y).value_or(Vec3{x, y, 0}); };
  const Vec3 p0 = on(-0.012, -0.012);
  for (int i = 0; i < 50; ++i) add(ToolMode::kScalpel, Stage::kDeform, p0, p0 + Vec3{0, 0, -0.00005 * i});
  add(ToolMode::kScalpel, Stage::kRupture, p0, p0 + Vec3{0, 0, -0.003}, event::kRupture, 4.0);
  for (int i = 1; i <= 240; ++i) {
    const Vec3 p = on(-0.012 + 0.0001 * i, -0.012);
    add(ToolMode::kScalpel, Stage::kCutting, p, p + Vec3{0, 0, -0.001}, i % 5 == 0 ? event::kCutProgress : 0u);
  }
  const Vec3 mid = on(0.0, -0.012);
  add(ToolMode::kRetractor, Stage::kFree, mid + Vec3{0, 0, 0.001}, mid + Vec3{0, 0, 0.001}, event::kContactBegin);
  add(ToolMode::kRetractor, Stage::kPulling, mid, mid, event::kGrab);
  for (int i = 1; i <= 100; ++i) add(ToolMode::kRetractor, Stage::kPulling, mid, mid, event::kPull, 0.004 * i / 100.0);
  for (int i = 0; i < 600; ++i) add(ToolMode::kRetractor, Stage::kFree, mid + Vec3{0, 0, 0.02}, mid + Vec3{0, 0, 0.02});
  auto pa = std::make_unique<TissuePatch>(), pb = std::make_unique<TissuePatch>();
  for (std::size_t from = 0, frame = 0; from < script.size(); from += 16, ++frame) {
    const std::span<const ToolSample> batch(script.data() + from, std::min<std::size_t>(16, script.size() - from));
    Frame ia, ib;
    ia.next.samples = batch;
    ia.next.blood_dt = 0.016;
    ia.next.patches[0] = {pa.get(), batch.back().tool.position, {frame, 0, batch.back().seq}};
    ib.next = ia.next;
    ib.next.patches[0].patch = pb.get();
    ASSERT_TRUE(run_frame(*a.value(), ia).ok());
    ASSERT_TRUE(run_frame(*b.value(), ib).ok());
    ASSERT_EQ(std::memcmp(pa.get(), pb.get(), tissue_patch_bytes(*pa)), 0) << "frame " << frame;
    if (frame % 8 == 0) {
      ASSERT_EQ(a.value()->hash(), b.value()->hash()) << "frame " << frame;  // waits for b's blood
    }
  }
  record::FrameRecord fa{}, fb{};
  a.value()->figures(fa);
  b.value()->figures(fb);
  EXPECT_GT(fa.blood_lost_ml, 0.0) << "the cut bled";
  EXPECT_EQ(fa.blood_lost_ml, fb.blood_lost_ml);
  EXPECT_EQ(fa.blood_on_tissue_ml, fb.blood_on_tissue_ml);
  EXPECT_EQ(a.value()->hash(), b.value()->hash());
  b.value()->set_blood_behind(false);  // waits for the last step; steps on this thread from here
  EXPECT_EQ(a.value()->hash(), b.value()->hash());
}

}  // namespace
}  // namespace lancet::sim
