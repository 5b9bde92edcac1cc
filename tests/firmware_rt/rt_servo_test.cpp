#include "app/rt_servo.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <memory>

#include "malloc_guard.hpp"

namespace lancet::app {
namespace {

constexpr std::int64_t kMs = 1'000'000;

// A servo on a SharedState in ordinary memory, driven with synthetic time (no sleeping).
struct Rig {
  RtModel model;
  std::unique_ptr<SharedState> shared = std::make_unique<SharedState>();
  std::unique_ptr<RtServo> servo;
  std::unique_ptr<TissuePatch> scratch = std::make_unique<TissuePatch>();  // the "viz" side's buffer
  std::int64_t t = 1'000'000'000;
  rt::Watchdog watchdog;
  rt::LoopLive live;
  std::uint64_t n = 0;
  bool published = false;

  explicit Rig(RtModel m = {}) : model(m) { servo = std::make_unique<RtServo>(model, *shared, t); }

  void publish_plane(float h = 0.0f) {
    TissuePatch* p = scratch.get();
    const float s = 0.1f;
    p->n_triangles = 2;
    p->triangles[0] = {{{-s, -s, h}, {s, -s, h}, {s, s, h}}, 1, 0};
    p->triangles[1] = {{{-s, -s, h}, {s, s, h}, {-s, s, h}}, 1, 0};
    p->t_ns = t;
    shared->patch.write(*p);
    published = true;
  }
  void tick(bool viz_beats) {
    t += model.period_ns;
    if (viz_beats) shared->viz_heartbeat.beat(t, 1);
    // A live viz republishes the patch every frame (about 16 ms); a stale one fades the force.
    if (viz_beats && published && n % 16 == 0) {
      scratch->t_ns = t;
      shared->patch.write(*scratch);
    }
    servo->tick(rt::TickContext{t, t, ++n, watchdog, live});
  }
  void drain() {
    ToolSample s;
    while (shared->samples.try_pop(s)) {
    }
  }
};

TEST(RtServo, ScriptedToolPressesIntoThePatchAndFeelsAForce) {
  Rig rig;
  rig.publish_plane();
  for (int i = 0; i < 2000; ++i) {
    rig.tick(true);
    rig.drain();
  }
  const RtData& d = rig.servo->data();
  EXPECT_GT(d.patches_received, 0u);
  EXPECT_GT(d.contact_ticks, 500u);
  EXPECT_GT(d.force.z, 0.5);               // pushed up, out of the tissue
  EXPECT_LE(norm(d.force), rig.model.haptic.safety.max_force);
  EXPECT_EQ(rig.shared->samples.overflow_count(), 0u);
}

TEST(RtServo, OneSamplePerTickInOrder) {
  Rig rig;
  for (int i = 0; i < 100; ++i) rig.tick(false);
  ToolSample s;
  std::uint64_t expect = 1;
  while (rig.shared->samples.try_pop(s)) {
    EXPECT_EQ(s.seq, expect);
    ++expect;
  }
  EXPECT_EQ(expect, 101u);
}

TEST(RtServo, ForceFadesToZeroWhenTheVizHeartbeatStops) {
  RtModel m;
  m.fade.timeout_ns = 150 * kMs;
  m.fade.fade_ns = 100 * kMs;
  Rig rig(m);
  rig.publish_plane();
  for (int i = 0; i < 2000; ++i) rig.tick(true), rig.drain();
  ASSERT_GT(norm(rig.servo->data().force), 0.5);
  const std::int64_t last_beat = rig.t;
  int ticks = 0;
  while (norm(rig.servo->data().force) > 0.0 && ticks < 5000) rig.tick(false), rig.drain(), ++ticks;
  const RtData& d = rig.servo->data();
  EXPECT_EQ(d.force, Vec3{});
  EXPECT_EQ(d.viz_lost_at_beat_ns, last_beat);
  EXPECT_GT(d.force_zero_ns, 0);
  EXPECT_LE(d.force_zero_ns - last_beat, m.fade.timeout_ns + m.fade.fade_ns + m.period_ns);
  // The scale falls monotonically: no step back up while the viz is gone.
  for (int i = 0; i < 100; ++i) {
    rig.tick(false);
    EXPECT_EQ(rig.servo->data().force, Vec3{});
  }
  // And the loop keeps running.
  EXPECT_GT(d.tick, 2000u + static_cast<std::uint64_t>(ticks));
}

TEST(RtServo, ForceIsClampedAndNeverNaN) {
  RtModel m;
  for (auto& mat : m.haptic.materials) mat.stiffness = 1e6;  // absurdly stiff: the clamp must hold
  m.haptic.safety.max_force = 5.0;
  Rig rig(m);
  rig.publish_plane();
  for (int i = 0; i < 3000; ++i) {
    rig.tick(true);
    rig.drain();
    const Vec3 f = rig.servo->data().force;
    ASSERT_TRUE(is_finite(f));
    ASSERT_LE(norm(f), m.haptic.safety.max_force * (1 + 1e-12));
  }
  EXPECT_GT(rig.servo->data().haptic.safety.clamps, 0u);

  // A patch with NaN vertices: forces stay finite.
  auto bad = std::make_unique<TissuePatch>();
  bad->n_triangles = 1;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  bad->triangles[0] = {{{nan, 0, 0}, {0.1f, 0, 0}, {0, 0.1f, nan}}, 1, 0};
  rig.shared->patch.write(*bad);
  for (int i = 0; i < 100; ++i) {
    rig.tick(true);
    rig.drain();
    ASSERT_TRUE(is_finite(rig.servo->data().force));
  }
}

TEST(RtServo, TickAllocatesNothing) {
  Rig rig;
  rig.publish_plane();
  Command c{};
  c.kind = CommandKind::kSetToolMode;
  c.mode = ToolMode::kScalpel;
  ASSERT_TRUE(rig.shared->commands.try_push(c));
  lancet::test::MallocGuard guard;
  for (int i = 0; i < 10'000; ++i) {
    rig.tick(true);
    if (i % 500 == 0) rig.publish_plane(static_cast<float>(i) * 1e-7f);  // new patches arrive too
    rig.drain();
  }
  EXPECT_EQ(guard.count(), 0u);
  EXPECT_EQ(rig.servo->data().mode, ToolMode::kScalpel);
}

TEST(RtServo, MallocGuardCanFail) {
  lancet::test::MallocGuard guard;
  auto p = std::make_unique<int>(3);
  EXPECT_GT(guard.count(), 0u);
}

TEST(RtServo, ATrippedWatchdogHoldsZeroForceUntilReArmed) {
  Rig rig;
  rig.publish_plane();
  for (int i = 0; i < 2000; ++i) rig.tick(true), rig.drain();
  ASSERT_GT(norm(rig.servo->data().force), 0.5);
  rt::WatchdogParams wp;
  wp.tick_budget_ns = 1;
  ASSERT_TRUE(rig.watchdog.observe(wp, false, 10));  // one slow tick
  for (int i = 0; i < 500; ++i) {
    rig.tick(true);
    ASSERT_EQ(rig.servo->data().force, Vec3{}) << "tick " << i;
  }
  ToolSample s{};
  while (rig.shared->samples.try_pop(s)) {
  }
  EXPECT_NE(s.events & event::kFault, 0u);
  RtStatus st{};
  ASSERT_EQ(rig.shared->rt_status.try_read(st), ReadStatus::kOk);
  EXPECT_EQ(st.watchdog_tripped, 1u);
  // Only an explicit re-arm brings the force back.
  Command c{};
  c.kind = CommandKind::kRearm;
  ASSERT_TRUE(rig.shared->commands.try_push(c));
  rig.tick(true);
  EXPECT_FALSE(rig.watchdog.tripped());
  EXPECT_GT(norm(rig.servo->data().force), 0.5);
}

}  // namespace
}  // namespace lancet::app
