// lancet-rt's drill and lancet-viz's volume in one process, without the shared segment: the viz
// drains the samples and cuts a brick around the tool every 16 ticks (a frame), the brick reaches
// lancet-rt 6 ticks later (as a patch does), lancet-rt drills its copy meanwhile, and the viz
// carves each reported removal into its volume when it drains it. A removal made after the viz's
// drain is not in the brick that arrives next: lancet-rt must carve it again, or the bone it
// removed comes back under the burr.

#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <vector>

#include "haptics/haptic_step.hpp"
#include "tissue/block_volume.hpp"
#include "tissue/volume_brick.hpp"
#include "volume/drill.hpp"

namespace lancet {
namespace {

TEST(DrillReconcile, RemovedBoneNeverComesBackUnderTheBurr) {
  const surface::TissueBlockParams block{};
  volume::LabelledVolume tissue = tissue::make_block_volume(block);
  const tissue::VolumePlacement placement{};
  haptics::HapticModel m = haptics::HapticModel::defaults();
  auto d = std::make_unique<haptics::HapticData>();
  auto patch = std::make_unique<TissuePatch>(), next = std::make_unique<TissuePatch>();
  haptics::HapticInput in;
  haptics::HapticOutput out;
  in.mode = ToolMode::kDrill;
  in.patch = patch.get();
  std::uint64_t frame = 0, applied = 0;
  std::vector<std::pair<std::uint64_t, EventPayload>> pending;  // removals the viz has not drained yet
  std::vector<EventPayload> all_removals;
  int removals = 0, stale_voxels = 0;
  // Every voxel of lancet-rt's brick inside a removal it made must be air.
  const auto count_stale = [&](const VoxelBrick& b) {
    int n = 0;
    for (const auto& p : all_removals)
      for (std::uint32_t k = 0; k < kBrickDim; ++k)
        for (std::uint32_t j = 0; j < kBrickDim; ++j)
          for (std::uint32_t i = 0; i < kBrickDim; ++i) {
            const Vec3 c = b.origin + Vec3{i * b.spacing.x, j * b.spacing.y, k * b.spacing.z};
            if (norm(c - p.position) <= p.magnitude && b.hu[i + kBrickDim * (j + kBrickDim * k)] != -1000) ++n;
          }
    return n;
  };
  for (std::uint64_t tick = 1; tick <= 6000; ++tick) {
    const double t = static_cast<double>(tick) * 1e-3;
    // The hand: down from 10 mm above to 28 mm below the surface in 2 s, then held.
    const double a = t < 2.0 ? 0.5 - 0.5 * std::cos(M_PI * t / 2.0) : 1.0;
    in.device = {0, 0, 0.01 + a * (-0.028 - 0.01)};
    if (tick % 16 == 1) {  // a viz frame: drain, carve, cut the next brick around the tool
      for (const auto& [seq, p] : pending) {
        volume::DrillParams dp;
        dp.centre = placement.to_volume(p.position);
        dp.radius = p.magnitude;
        ASSERT_TRUE(volume::drill_sphere(tissue.volume, dp, tissue.material).ok());
      }
      pending.clear();
      applied = tick - 1;  // every sample up to the last tick was drained
      next->seq = ++frame;
      next->samples_applied = applied;
      tissue::fill_brick(tissue.volume, placement, in.device, next->brick);
    }
    if (tick % 16 == 7) std::swap(patch, next);  // the patch arrives
    in.patch = patch.get();
    in.tick = tick;
    haptics::haptic_step(m, *d, in, out);
    if ((out.events & event::kDrillRemove) != 0) {
      pending.emplace_back(tick, out.payload);
      all_removals.push_back(out.payload);
      ++removals;
    }
    if (tick % 16 == 7 && d->drill.brick.valid == 1) {
      const int stale = count_stale(d->drill.brick);
      EXPECT_EQ(stale, 0) << "tick " << tick << ": removed bone back in the brick";
      stale_voxels += stale;
      if (stale_voxels > 100) break;
    }
  }
  EXPECT_GT(removals, 3);
  EXPECT_GT(d->drill.reapplied, 0u) << "some removals came after the viz's drain and were carved again";
}

}  // namespace
}  // namespace lancet
