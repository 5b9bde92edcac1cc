// The one frame function (sim::run_frame): its sequence, and that live and replay both go through
// it — a session driven live through the shared-memory link (VizSession, LiveFrame, the recording)
// replays, through Replay's side of the same function, to the same scene hash every frame and at
// the end.

#include "sim/viz_frame.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "app/live_frame.hpp"
#include "app/recorder_control.hpp"
#include "app/viz_session.hpp"
#include "lancet/shared_model/shared_state.hpp"
#include "recording/hdf5_io.hpp"
#include "record/replay.hpp"
#include "servo/servo_step.hpp"

namespace lancet::sim {
namespace {

std::unique_ptr<SceneSim> block_sim() {
  SceneSetup setup;
  setup.tissue = "block";
  auto made = SceneSim::create(setup);
  EXPECT_TRUE(made.ok()) << made.error().message;
  return std::move(made).value();
}

// A frame's ends, scripted: the batch given, and what the frame did in which order.
struct ScriptedFrame final : FrameIo {
  FrameBatch next;
  std::vector<std::string> calls;
  const TissuePatch* published = nullptr;       // the right hand's
  const TissuePatch* published_left = nullptr;
  bool fail = false;
  Result<FrameBatch> drain() override {
    calls.push_back("drain");
    if (fail) return Error{ErrorCode::kInvalid, "no such patch"};
    return next;
  }
  void publish(const std::array<const TissuePatch*, kHandCount>& patches) override {
    calls.push_back("publish");
    published = patches[0];
    published_left = patches[1];
  }
};

ToolSample pressing(std::uint64_t seq, Vec3 at) {
  ToolSample s{};
  s.seq = seq;
  s.t_ns = static_cast<std::int64_t>(seq) * 1'000'000;
  s.stage = Stage::kDeform;
  s.tool.position = at;
  s.proxy.position = at + Vec3{0, 0, 0.001};
  return s;
}

TEST(VizFrame, DrainsAppliesExportsWithTheHeaderAndPublishes) {
  auto sim = block_sim();
  const std::uint64_t before = sim->hash();
  std::vector<ToolSample> batch;
  for (std::uint64_t i = 1; i <= 5; ++i) batch.push_back(pressing(i, {0.0, 0.0, -0.001}));
  auto patch = std::make_unique<TissuePatch>();
  patch->n_triangles = 12345;  // whatever the buffer held: the frame starts the patch afresh
  ScriptedFrame io;
  io.next.samples = batch;
  io.next.blood_dt = 0.016;
  io.next.patches[0] = {patch.get(), {0.0, 0.0, -0.001}, {7, 123'000'000, 5}};
  auto r = run_frame(*sim, io);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(io.calls, (std::vector<std::string>{"drain", "publish"}));
  EXPECT_EQ(io.published, patch.get());
  EXPECT_EQ(r.value().samples, 5u);
  EXPECT_EQ(r.value().blood_dt, 0.016);
  EXPECT_TRUE(r.value().patch[0]);
  EXPECT_FALSE(r.value().patch[1]) << "no patch was asked for the left hand";
  EXPECT_EQ(io.published_left, nullptr);
  EXPECT_EQ(patch->hand, Hand::kRight);
  EXPECT_EQ(sim->scene().events().samples, 5u) << "the batch was applied to the scene";
  EXPECT_NE(sim->hash(), before);
  EXPECT_GT(patch->n_triangles, 0u);
  EXPECT_NE(patch->n_triangles, 12345u);
  EXPECT_EQ(r.value().triangles[0], patch->n_triangles);
  EXPECT_EQ(patch->seq, 7u);
  EXPECT_EQ(patch->t_ns, 123'000'000);
  EXPECT_EQ(patch->samples_applied, 5u);

  // No patch asked for: the scene still steps, publish() is told there is none.
  io.calls.clear();
  io.next.samples = {};
  io.next.patches[0].patch = nullptr;
  r = run_frame(*sim, io);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(io.calls, (std::vector<std::string>{"drain", "publish"}));
  EXPECT_EQ(io.published, nullptr);
  EXPECT_FALSE(r.value().patch[0]);
}

TEST(VizFrame, ADrainErrorStopsTheFrameBeforeTheScene) {
  auto sim = block_sim();
  const std::uint64_t before = sim->hash();
  const ToolSample s = pressing(1, {0.0, 0.0, -0.001});
  ScriptedFrame io;
  io.next.samples = {&s, 1};
  io.fail = true;
  auto r = run_frame(*sim, io);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().message, "no such patch");
  EXPECT_EQ(io.calls, (std::vector<std::string>{"drain"}));
  EXPECT_EQ(sim->hash(), before);
}

// The same batches through two SceneSims, one frame at a time: the frame function is all there is
// to a frame, so the scenes stay identical.
TEST(VizFrame, TheSameBatchesGiveTheSameScene) {
  auto a = block_sim(), b = block_sim();
  auto pa = std::make_unique<TissuePatch>(), pb = std::make_unique<TissuePatch>();
  std::uint64_t seq = 0;
  for (int frame = 0; frame < 20; ++frame) {
    std::vector<ToolSample> batch;
    for (int k = 0; k < 16; ++k, ++seq) batch.push_back(pressing(seq + 1, {0.0005 * frame, 0.0, -0.0002 * frame}));
    ScriptedFrame ia, ib;
    ia.next.samples = batch;
    ia.next.blood_dt = 0.016;
    ia.next.patches[0] = {pa.get(), batch.back().tool.position, {static_cast<std::uint64_t>(frame), 0, seq}};
    ib.next = ia.next;
    ib.next.patches[0].patch = pb.get();
    ASSERT_TRUE(run_frame(*a, ia).ok());
    ASSERT_TRUE(run_frame(*b, ib).ok());
    ASSERT_EQ(a->hash(), b->hash()) << "frame " << frame;
    ASSERT_EQ(pa->n_triangles, pb->n_triangles);
    ASSERT_EQ(std::memcmp(pa.get(), pb.get(), tissue_patch_bytes(*pa)), 0) << "frame " << frame;
  }
}

// lancet-rt, in process, with one or two hands: each tick pops its commands (each for its hand),
// takes each hand's newest patch the viz published, steps each hand's servo and pushes its sample
// (the right hand's first), as lancet-rt's loop does around servo_step; its status says how many
// hands.
class InProcessRt {
 public:
  explicit InProcessRt(const std::string& name, std::size_t hands = 1) : ch_(SharedChannel::create(name, {}).value()), hands_(hands) {
    for (std::size_t h = 0; h < hands_; ++h) ch_.state().servo_model[h].write(servo::to_blob(model_));
    RtStatus st{};
    st.period_ns = 1'000'000;
    st.hands = static_cast<std::uint32_t>(hands_);
    ch_.state().rt_status.write(st);
  }
  void tick(std::int64_t now) {
    SharedState& s = ch_.state();
    std::uint8_t commands[kHandCount][kSampleCommands];
    std::size_t n[kHandCount] = {};
    Command c{};
    while (s.commands.try_pop(c)) {
      const std::size_t h = hand_index(c.hand);
      if (n[h] < kSampleCommands) commands[h][n[h]++] = servo::pack_command(c.kind, c.mode);
    }
    const double t = static_cast<double>(ticks_++) * 1e-3;
    for (std::size_t h = 0; h < hands_; ++h) {
      Hand& hand = hand_[h];
      std::uint64_t seen = hand.version;
      if (s.patch[h].try_read_if_newer(*hand.scratch, seen) == ReadStatus::kOk) {
        *hand.patch = *hand.scratch;
        hand.version = seen;
      }
      servo::ServoInput in;
      in.deadline_ns = now;
      in.woke_ns = now + 10'000;
      in.commands = {commands[h], n[h]};
      in.reading.n = 3;
      // Down into the block, then along x; the left hand 15 mm beside the right and slower.
      const double y = h == 0 ? 0.0 : 0.015, speed = h == 0 ? 1.0 : 0.5;
      in.reading.q = {-0.01 + 0.02 * t * speed, y, 0.004 - 0.008 * t * speed};
      in.patch = hand.version != 0 ? hand.patch.get() : nullptr;
      in.patch_version = hand.version;
      in.viz_alive = true;
      servo::servo_step(model_, *hand.data, in, *hand.out);
      hand.out->sample.hand = static_cast<lancet::Hand>(h);
      ASSERT_TRUE(s.samples.try_push(hand.out->sample));
    }
    s.rt_heartbeat.beat(now, getpid());
  }

 private:
  struct Hand {
    std::unique_ptr<servo::ServoData> data = std::make_unique<servo::ServoData>();
    std::unique_ptr<servo::ServoOutput> out = std::make_unique<servo::ServoOutput>();
    std::unique_ptr<TissuePatch> patch = std::make_unique<TissuePatch>(), scratch = std::make_unique<TissuePatch>();
    std::uint64_t version = 0;
  };
  SharedChannel ch_;
  std::size_t hands_;
  servo::ServoModel model_{};
  Hand hand_[kHandCount];
  std::uint64_t ticks_ = 0;
};

void live_record_replay(std::size_t hands) {
  SCOPED_TRACE(std::to_string(hands) + " hand(s)");  const std::string name = "/lancet-frame-" + std::to_string(getpid());
  const std::filesystem::path file = std::filesystem::temp_directory_path() / ("lancet-frame-" + std::to_string(getpid()) + ".h5");
  InProcessRt rt(name, hands);
  viz::VizSessionParams p;
  p.shm_name = name;
  viz::VizSession session(p);
  auto live_sim = block_sim();
  // As `lancet-viz --record FILE`: armed on the fresh scene, the servo's reset sent once it uses a
  // patch of this viz, recorded from the tick that applied it.
  viz::RecorderControl recorder(file.string(), live_sim->setup(), "", "test");
  viz::LiveFrame live(session, recorder, nullptr);
  std::int64_t now = monotonic_ns();
  std::uint64_t last_hash = 0;
  for (int frame = 0; frame < 60; ++frame) {
    if (frame > 0) {
      for (int k = 0; k < 16; ++k) rt.tick(now + k * 1'000'000);
    }
    now += 16'000'000;
    live.begin(now, 0.016);
    auto r = run_frame(*live_sim, live);
    ASSERT_TRUE(r.ok());
    // Until the session begins, the scene armed for it stays as made: its blood does not flow (a
    // replay's starts at time 0; the blood's clock gates its network's rebuilds).
    if (recorder.state() != viz::RecorderControl::State::kOn) {
      EXPECT_EQ(r.value().blood_dt, 0.0) << "frame " << frame;
    }
    recorder.after_frame(session, *live_sim, r.value(), now);
    if (frame == 0) {
      ASSERT_EQ(session.link(), viz::Link::kConnected) << session.link_message();
    }
    if (recorder.state() == viz::RecorderControl::State::kOn) last_hash = live_sim->hash();
  }
  ASSERT_EQ(recorder.state(), viz::RecorderControl::State::kOn) << recorder.panel_line();
  recorder.stop();

  auto rec = record::read_recording(file.string());
  ASSERT_TRUE(rec.ok()) << rec.error().message;
  std::filesystem::remove(file);
  EXPECT_GT(rec.value().frames.size(), 50u);
  EXPECT_EQ(rec.value().samples_lost, 0u);
  auto replay = record::Replay::create(rec.value());
  ASSERT_TRUE(replay.ok()) << replay.error().message;
  auto ck = replay.value()->run();
  ASSERT_TRUE(ck.ok()) << ck.error().message;
  EXPECT_TRUE(ck.value().exact()) << "first bad tick " << ck.value().first_bad_seq << ", frame " << ck.value().first_bad_frame;
  EXPECT_EQ(ck.value().frames, rec.value().frames.size());
  EXPECT_EQ(ck.value().ticks, rec.value().samples.size());
  EXPECT_GE(ck.value().scene_hashes, 2u);
  EXPECT_EQ(ck.value().scene_hash_mismatches, 0u);
  EXPECT_GT(live_sim->scene().events().samples, 0u) << "the live scene was driven";
  EXPECT_EQ(replay.value()->sim().hash(), last_hash) << "the replayed scene ends where the live one did";
  // Every hand recorded, from its reset on, with its own patches.
  EXPECT_EQ(rec.value().hands, hands);
  std::size_t per_hand[kHandCount] = {};
  for (const ToolSample& t : rec.value().samples) ++per_hand[hand_index(t.hand)];
  EXPECT_GT(per_hand[0], 500u);
  if (hands == 2) {
    EXPECT_EQ(per_hand[1], per_hand[0]) << "a sample of each hand every tick";
    std::size_t left_patches = 0;
    for (const record::FrameRecord& f : rec.value().frames) left_patches += f.left_patch_version != 0 ? 1 : 0;
    EXPECT_GT(left_patches, 50u);
    ASSERT_NE(replay.value()->latest(Hand::kLeft), nullptr);
    EXPECT_NEAR(replay.value()->latest(Hand::kLeft)->tool.position.y, 0.015, 1e-6) << "the left hand's ticks were re-stepped as the left's";
  } else {
    EXPECT_EQ(per_hand[1], 0u);
  }
}

TEST(VizFrame, ALiveSessionThroughTheLinkReplaysThroughTheSameFrameToTheSameScene) { live_record_replay(1); }

// Two hands through the link: each hand's patch published around its own tool, the resets of both
// in one tick, both recorded, and the replay re-steps each hand's servo bit-exactly.
TEST(VizFrame, ATwoHandedLiveSessionReplaysBitExactly) { live_record_replay(2); }

}  // namespace
}  // namespace lancet::sim
