// SceneSim's reads of a frame (export_patches_and_prepare_blood): both hands' patches and the
// blood's preparation at once, on two threads, each coming out as it does alone. On the phantom,
// whose skin (about 130 000 triangles) has a lazily built BVH, so the two patches' queries make its
// blocks as they first reach them, from both threads; meanwhile the frames dent the skin (the
// refits make blocks too) and drill the bone (re-extracting it). Labelled threads: the tsan
// preset runs it, and the debug preset's AddressSanitizer.

#include <gtest/gtest.h>

#include <array>
#include <cstdio>
#include <cstring>
#include <memory>
#include <vector>

#include "sim/scene_sim.hpp"
#include "tissue/scripted_sample.hpp"

namespace lancet::sim {
namespace {

TEST(SceneSim, BothHandsPatchesMadeAtOnceAreEachTheOneMadeAlone) {
  SceneSetup setup;
  setup.tissue = "phantom";
  auto made_a = SceneSim::create(setup), made_b = SceneSim::create(setup);
  ASSERT_TRUE(made_a.ok() && made_b.ok());
  const std::unique_ptr<SceneSim> at_once = std::move(made_a).value(), alone = std::move(made_b).value();
  ASSERT_GE(at_once->scene().surface().n_faces(), surface::TriangleBvh::kLazyFrom) << "a skin large enough for the lazy tree";
  const auto top = at_once->scene().surface_below(0, 0.006), left_top = at_once->scene().surface_below(0.02, -0.012);
  ASSERT_TRUE(top && left_top);
  const Vec3 bone_top{0, 0.006, -0.0325};  // the phantom's bone under the limb's front

  std::array<std::unique_ptr<TissuePatch>, kHandCount> a, b;
  for (auto* p : {&a, &b})
    for (auto& q : *p) q = std::make_unique<TissuePatch>();
  std::uint64_t seq = 0;
  std::size_t removals = 0, triangles = 0;
  for (int frame = 0; frame < 40; ++frame) {
    // Eight ticks a frame, 320 in all: the right hand presses the skin down to 3 mm (120 ticks),
    // then drills 4 mm down from the bone's top; the left presses the skin 27 mm away, all along.
    std::vector<ToolSample> batch;
    Vec3 right{}, left{};
    for (int k = 0; k < 8; ++k) {
      ++seq;
      const auto t_ns = static_cast<std::int64_t>(seq) * 1'000'000;
      const Vec3 lift{0, 0, 0.001};  // a pressing hand's proxy, on the surface above its tool
      const int t = frame * 8 + k;
      if (t < 120) {
        right = *top + Vec3{0, 0, 0.0005 - 0.0035 * t / 120.0};
        batch.push_back(tissue::scripted_sample(seq, t_ns, ToolMode::kProbe, Stage::kDeform, right + lift, right, 0));
      } else {
        right = bone_top + Vec3{0, 0, -0.004 * (t - 120) / 200.0};
        const bool removes = k % 4 == 0;
        batch.push_back(tissue::scripted_sample(seq, t_ns, ToolMode::kDrill, Stage::kDrilling, right, right, removes ? event::kDrillRemove : 0u));
        batch.back().payload.magnitude = 0.0025;  // the burr's radius
        removals += removes ? 1 : 0;
      }
      left = *left_top + Vec3{0, 0, 0.0005 - 0.0025 * t / 320.0};
      batch.push_back(tissue::scripted_sample(seq, t_ns, ToolMode::kProbe, Stage::kDeform, left + lift, left, 0));
      batch.back().hand = Hand::kLeft;
    }
    at_once->apply(batch);
    alone->apply(batch);
    const std::array<Vec3, kHandCount> centres{right, left};
    const std::array<std::size_t, kHandCount> found =
        at_once->export_patches_and_prepare_blood({a[0].get(), a[1].get()}, centres, 0.016);
    at_once->step_blood();
    for (std::size_t h = 0; h < kHandCount; ++h) {
      // Alone: one patch at a time, on this thread, with the scene's own scratch.
      ASSERT_EQ(alone->export_patch(centres[h], *b[h]), found[h]) << "frame " << frame << ", hand " << h;
      ASSERT_EQ(a[h]->n_triangles, b[h]->n_triangles);
      ASSERT_EQ(std::memcmp(a[h].get(), b[h].get(), tissue_patch_bytes(*a[h])), 0) << "frame " << frame << ", hand " << h;
      triangles += found[h];
    }
  }
  const surface::TriangleBvh& bvh = at_once->scene().surface().bvh();
  std::printf("[ info     ] %zu faces, %zu removals, %llu voxels drilled, %zu patch triangles, %zu of %zu blocks made\n",
              at_once->scene().surface().n_faces(), removals, static_cast<unsigned long long>(at_once->scene().events().voxels_drilled),
              triangles, bvh.blocks_made(), bvh.block_count());
  EXPECT_EQ(at_once->scene().events().drill_removals, removals);
  EXPECT_GT(at_once->scene().events().voxels_drilled, 0u);
  EXPECT_GT(triangles, 0u);
  EXPECT_GT(bvh.blocks_made(), 0u);
  EXPECT_LT(bvh.blocks_made(), bvh.block_count())
      << "the blocks far from both hands are never made";
}

}  // namespace
}  // namespace lancet::sim
