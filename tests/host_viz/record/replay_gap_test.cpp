// Replay of a session whose ticks have a gap (the viz stalled longer than the sample ring holds):
// the servo is re-stepped and checked up to the gap, the scene is driven by the recorded ticks
// after it and still matches the live scene's hashes. The live session is emulated in process,
// exactly as lancet-rt and lancet-viz step it (servo_step a tick, sim::run_frame a frame, the patch
// published at the end of each frame), with the ticks of three frames never reaching the viz.

#include <gtest/gtest.h>

#include <cstdint>
#include <memory>
#include <vector>

#include "lancet/shared_model/shared_state.hpp"
#include "record/replay.hpp"
#include "servo/servo_step.hpp"
#include "sim/viz_frame.hpp"

namespace lancet::record {
namespace {

constexpr std::int64_t kT0 = 5'000'000'000;
constexpr int kTicksPerFrame = 16;

// The live viz's ends of a frame, scripted: the ticks delivered, the patch in use refilled in place.
struct ScriptedFrame final : sim::FrameIo {
  sim::FrameBatch next;
  Result<sim::FrameBatch> drain() override { return next; }
  void publish(const std::array<const TissuePatch*, kHandCount>&) override {}
};

struct Live {
  Recording rec;
  std::uint64_t lost = 0;
  std::uint64_t gap_seq = 0;  ///< the first tick delivered after the gap
  std::uint32_t last_patch_triangles = 0;  ///< in the last patch the live frames published
};

// 40 frames of a probe pressing into the block and sliding; the ticks of frames [gap_from,
// gap_from + 3) are stepped but never delivered (nor recorded). gap_from < 0: none lost.
// hold_from >= 0: the ticks of that frame reach the viz twelve frames later (a tick held in the
// device's I/O: it took its patch, then waited), the frames between get none and keep publishing.
Live run_live(int gap_from, int hold_from = -1, double patch_radius = sim::SceneSetup{}.patch_radius) {
  Live live;
  Recording& rec = live.rec;
  sim::SceneSetup setup;
  setup.tissue = "block";
  setup.patch_radius = patch_radius;
  auto made = sim::SceneSim::create(setup);
  EXPECT_TRUE(made.ok());
  auto sim = std::move(made).value();
  rec.tissue = "block";
  rec.layout_hash = kSharedLayoutHash;
  rec.protocol = kProtocolVersion;
  rec.patch_radius = setup.patch_radius;
  rec.servo_hash_every = servo::kServoHashEvery;
  rec.scene_hash_every = 1;
  const servo::ServoModel model{};
  rec.servo_model[0] = servo::to_blob(model);
  auto data = std::make_unique<servo::ServoData>();
  auto out = std::make_unique<servo::ServoOutput>();
  // The patch in use: the last one published (the first, before any frame, around the origin).
  auto patch = std::make_unique<TissuePatch>();
  patch->n_triangles = 0;
  patch->brick.valid = 0;
  (void)sim->export_patch({}, *patch);
  patch->seq = 0, patch->t_ns = kT0, patch->samples_applied = 0;
  std::uint64_t version = 1;
  rec.first_patch_versions = {version};
  rec.first_patches = {*patch};
  const std::uint8_t reset[] = {servo::pack_command(CommandKind::kReset, ToolMode::kProbe)};
  std::uint64_t tick = 0;
  Vec3 latest{};
  std::vector<ToolSample> held;
  for (int frame = 0; frame < 40; ++frame) {
    std::vector<ToolSample> batch;
    if (hold_from >= 0 && frame == hold_from + 12) batch.swap(held);
    const bool holding = hold_from >= 0 && frame >= hold_from && frame < hold_from + 12;
    for (int k = 0; k < (holding && frame > hold_from ? 0 : kTicksPerFrame); ++k, ++tick) {
      const double t = static_cast<double>(tick) * 1e-3;
      servo::ServoInput in;
      in.deadline_ns = kT0 + static_cast<std::int64_t>(tick) * 1'000'000;
      in.woke_ns = in.deadline_ns + 10'000;
      if (tick == 0) in.commands = reset;
      in.reading.n = 3;
      in.reading.q = {-0.01 + 0.03 * t, 0.0, 0.004 - 0.01 * t};  // down into the block, then along x
      in.patch = patch.get();
      in.patch_version = version;
      in.viz_alive = true;
      servo::servo_step(model, *data, in, *out);
      const bool lost = gap_from >= 0 && frame >= gap_from && frame < gap_from + 3;
      if (lost) {
        ++live.lost;
        continue;
      }
      if (gap_from >= 0 && frame >= gap_from + 3 && live.gap_seq == 0) live.gap_seq = out->sample.seq;
      (holding ? held : batch).push_back(out->sample);
    }
    // The viz's frame: the batch, the patch around the newest tool, then the blood.
    rec.samples.insert(rec.samples.end(), batch.begin(), batch.end());
    if (!batch.empty()) latest = batch.back().tool.position;
    FrameRecord f;
    f.frame = static_cast<std::uint64_t>(frame);
    f.t_ns = kT0 + static_cast<std::int64_t>(frame) * 16'000'000;
    f.last_seq = rec.samples.back().seq;
    f.ticks = batch.size();
    f.blood_dt = 0.016;
    ScriptedFrame io;
    io.next.samples = batch;
    io.next.blood_dt = f.blood_dt;
    io.next.patches[0] = {patch.get(), latest, {static_cast<std::uint64_t>(frame) + 1, f.t_ns, f.last_seq}};
    EXPECT_TRUE(sim::run_frame(*sim, io).ok());
    ++version;
    f.patch_version = version, f.patch_seq = patch->seq, f.patch_t_ns = patch->t_ns, f.patch_samples_applied = f.last_seq;
    sim->figures(f);
    f.scene_hash = sim->hash();
    rec.frames.push_back(f);
    live.last_patch_triangles = patch->n_triangles;
  }
  for (std::size_t i = 1; i < rec.samples.size(); ++i)
    if (rec.samples[i].seq != rec.samples[i - 1].seq + 1) ++rec.gaps, rec.samples_lost += rec.samples[i].seq - rec.samples[i - 1].seq - 1;
  return live;
}

TEST(ReplayGap, ASessionWithoutAGapReplaysExactlyThroughout) {
  const Live live = run_live(-1);
  auto replay = Replay::create(live.rec);
  ASSERT_TRUE(replay.ok()) << replay.error().message;
  auto ck = replay.value()->run();
  ASSERT_TRUE(ck.ok()) << ck.error().message;
  EXPECT_TRUE(ck.value().exact());
  EXPECT_EQ(ck.value().gap_seq, 0u);
  EXPECT_EQ(ck.value().ticks, live.rec.samples.size());
  EXPECT_EQ(ck.value().scene_hashes, 40u);
  EXPECT_GT(ck.value().servo_hashes, 5u);
}

TEST(ReplayGap, AfterAGapTheServoIsNoLongerSteppedAndTheSceneIsStillChecked) {
  const Live live = run_live(12);
  ASSERT_EQ(live.rec.gaps, 1u);
  ASSERT_EQ(live.rec.samples_lost, 3u * kTicksPerFrame);
  auto replay = Replay::create(live.rec);
  ASSERT_TRUE(replay.ok()) << replay.error().message << " (a recording with a gap must replay)";
  auto ck = replay.value()->run();
  ASSERT_TRUE(ck.ok()) << ck.error().message;
  const ReplayCheck& c = ck.value();
  EXPECT_TRUE(c.exact()) << "first bad tick " << c.first_bad_seq << ", frame " << c.first_bad_frame;
  EXPECT_EQ(c.gap_seq, live.gap_seq);
  EXPECT_EQ(c.ticks_lost, 3u * kTicksPerFrame);
  EXPECT_EQ(c.ticks + c.ticks_unchecked, live.rec.samples.size());
  EXPECT_EQ(c.ticks, 12u * kTicksPerFrame) << "the servo is re-stepped up to the gap";
  EXPECT_EQ(c.scene_hashes, 40u) << "every frame's scene is checked, after the gap too";
  EXPECT_EQ(c.scene_hash_mismatches, 0u);
}

// A tick held in the device's I/O for twelve frames uses a patch published long before the frame
// that applies it: the replay still has it (it keeps every patch a later tick may use, not the
// last few).
TEST(ReplayGap, ATickHeldForTwelveFramesStillFindsItsPatch) {
  const Live live = run_live(-1, 10);
  auto replay = Replay::create(live.rec);
  ASSERT_TRUE(replay.ok()) << replay.error().message;
  auto ck = replay.value()->run();
  ASSERT_TRUE(ck.ok()) << ck.error().message;
  EXPECT_TRUE(ck.value().exact());
  EXPECT_EQ(ck.value().ticks, live.rec.samples.size());
}

// A recording made at another patch radius than this build's default (the default grew from 30 to
// 40 mm) replays at its own: the same patches, the same servo, exactly.
TEST(ReplayGap, ARecordingReplaysAtItsOwnPatchRadiusNotTheDefault) {
  const double recorded = 0.03;
  ASSERT_NE(recorded, sim::SceneSetup{}.patch_radius);
  const Live live = run_live(-1, -1, recorded);
  ASSERT_EQ(live.rec.patch_radius, recorded);
  auto replay = Replay::create(live.rec);
  ASSERT_TRUE(replay.ok()) << replay.error().message;
  EXPECT_EQ(replay.value()->sim().setup().patch_radius, recorded);
  auto ck = replay.value()->run();
  ASSERT_TRUE(ck.ok()) << ck.error().message;
  EXPECT_TRUE(ck.value().exact());
  ASSERT_NE(replay.value()->patch(Hand::kRight), nullptr);
  EXPECT_EQ(replay.value()->patch(Hand::kRight)->n_triangles, live.last_patch_triangles);
  // And the default's patch would have been another (larger) one.
  const Live wider = run_live(-1);
  EXPECT_GT(wider.last_patch_triangles, live.last_patch_triangles);
}

// What the checks are worth: a scene that does not match after the gap is caught.
TEST(ReplayGap, ASceneThatDiffersAfterTheGapIsCaught) {
  Live live = run_live(12);
  live.rec.samples.back().events |= event::kRupture;  // the last recorded tick: not what the live scene applied
  live.rec.samples[live.rec.samples.size() - 40].tool.position.x += 0.002;
  auto replay = Replay::create(live.rec);
  ASSERT_TRUE(replay.ok()) << replay.error().message;
  auto ck = replay.value()->run();
  ASSERT_TRUE(ck.ok()) << ck.error().message;
  EXPECT_GT(ck.value().scene_hash_mismatches, 0u);
  EXPECT_FALSE(ck.value().exact());
}

}  // namespace
}  // namespace lancet::record
