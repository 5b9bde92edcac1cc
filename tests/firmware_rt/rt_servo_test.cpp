#include "app/rt_servo.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <random>

#include "lancet/shared_model/validate.hpp"
#include "malloc_guard.hpp"

namespace lancet::app {
namespace {

constexpr std::int64_t kMs = 1'000'000;

Command sealed(Command c) {
  wire::seal(c);
  return c;
}

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
    p->triangles[0] = {{{-s, -s, h}, {s, -s, h}, {s, s, h}}, 1, 0, 0};
    p->triangles[1] = {{{-s, -s, h}, {s, s, h}, {-s, s, h}}, 1, 0, 1};
    p->t_ns = t;
    shared->patch.publish(*p);
    published = true;
  }
  /// The stylus held still at p (the viz's mouse target, refreshed every tick).
  void hold_stylus(Vec3 p) {
    StylusTarget tg{};
    tg.seq = n + 1;
    tg.t_ns = t;
    tg.active = 1;
    tg.target.position = p;
    shared->stylus_target.write(tg);
  }
  /// One tick; the viz beats when `viz_beats` and republishes its patch every 16 ticks when
  /// `republish` (a live viz does both; the tests of each fade stop one of them).
  void tick(bool viz_beats, bool republish) {
    t += model.servo.period_ns;
    if (viz_beats) shared->viz_heartbeat.beat(t, 1);
    if (republish && published && n % 16 == 0) {
      scratch->t_ns = t;
      shared->patch.publish(*scratch);
    }
    servo->tick(rt::TickContext{t, t, ++n, watchdog, live});
  }
  void tick(bool viz_beats) { tick(viz_beats, viz_beats); }
  void drain() {
    ToolSample s;
    while (shared->samples.try_pop(s)) {
    }
  }
  /// A command as the viz sends it: numbered, stamped now (later than the last), sealed.
  void push(Command c) {
    c.seq = ++command_seq;
    c.t_ns = t + static_cast<std::int64_t>(command_seq);
    ASSERT_TRUE(shared->commands.try_push(sealed(c)));
  }
  std::uint64_t command_seq = 0;
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
  EXPECT_GT(d.servo.contact_ticks, 500u);
  EXPECT_GT(d.servo.force.z, 0.5);               // pushed up, out of the tissue
  EXPECT_LE(norm(d.servo.force), rig.model.servo.haptic.safety.max_force);
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

// The one fade (haptics/force_fade.hpp), by each of its two inputs alone: the force holds while
// the input is fresh, holds until the timeout, then falls monotonically to zero within the fade
// time. Dropping either input from the fade fails its test (the force would stay at its held value).
constexpr Vec3 kHeld{0.0, 0.0, -0.003};  // 3 mm into the plane at z = 0

/// Brings the rig to a steady press: the stylus held 3 mm deep, viz and patch fresh.
double settle(Rig& rig) {
  rig.publish_plane();
  for (int i = 0; i < 1500; ++i) rig.hold_stylus(kHeld), rig.tick(true), rig.drain();
  return norm(rig.servo->data().servo.force);
}

TEST(RtServoFades, VizHeartbeatFadeAloneHoldsUntilTheTimeoutThenFallsMonotonically) {
  RtModel m;
  m.servo.fade.timeout_ns = 150 * kMs;
  m.servo.fade.fade_ns = 100 * kMs;
  m.servo.fade.stale_after_ns = 10'000 * kMs;  // the stale-patch fade cannot act in this test
  Rig rig(m);
  const double f0 = settle(rig);
  ASSERT_GT(f0, 0.5);
  const std::int64_t last_beat = rig.t;
  double prev = f0;
  bool zero = false;
  for (int i = 1; i <= 400; ++i) {
    rig.hold_stylus(kHeld);
    rig.tick(/*viz_beats=*/false, /*republish=*/true);  // the patch stays fresh; only the heartbeat stops
    rig.drain();
    const double f = norm(rig.servo->data().servo.force);
    const std::int64_t age = rig.t - last_beat;
    if (age <= m.servo.fade.timeout_ns) {
      ASSERT_NEAR(f, f0, 0.02 * f0) << "the force must hold until the timeout; " << age / kMs << " ms after the last beat";
    } else {
      ASSERT_LE(f, prev + 1e-9) << "the fade must fall monotonically; " << age / kMs << " ms after the last beat";
    }
    if (age > m.servo.fade.timeout_ns + m.servo.fade.fade_ns + m.servo.period_ns) {
      ASSERT_EQ(f, 0.0) << "zero by timeout + fade + one tick";
      zero = true;
    }
    prev = f;
  }
  EXPECT_TRUE(zero);
  const RtData& d = rig.servo->data();
  EXPECT_EQ(d.viz_lost_at_beat_ns, last_beat);
  EXPECT_LE(d.force_zero_ns - last_beat, m.servo.fade.timeout_ns + m.servo.fade.fade_ns + m.servo.period_ns);
  EXPECT_EQ(d.servo.fade.scale(), 0.0);
}

TEST(RtServoFades, StalePatchFadeAloneHoldsUntilStaleThenFallsMonotonically) {
  RtModel m;
  m.servo.fade.timeout_ns = 10'000 * kMs;  // the heartbeat fade cannot act in this test
  m.servo.fade.stale_after_ns = 100 * kMs;
  m.servo.fade.fade_ns = 100 * kMs;
  Rig rig(m);
  const double f0 = settle(rig);
  ASSERT_GT(f0, 0.5);
  const std::int64_t last_patch = rig.scratch->t_ns;
  double prev = f0;
  bool zero = false;
  for (int i = 1; i <= 400; ++i) {
    rig.hold_stylus(kHeld);
    rig.tick(/*viz_beats=*/true, /*republish=*/false);  // the viz beats but publishes no new tissue
    rig.drain();
    const double f = norm(rig.servo->data().servo.force);
    const std::int64_t age = rig.t - last_patch;
    if (age <= m.servo.fade.stale_after_ns) {
      ASSERT_NEAR(f, f0, 0.02 * f0) << "the force must hold until the patch is stale; age " << age / kMs << " ms";
    } else {
      ASSERT_LE(f, prev + 1e-9) << "the fade must fall monotonically; age " << age / kMs << " ms";
    }
    if (age > m.servo.fade.stale_after_ns + m.servo.fade.fade_ns + m.servo.period_ns) {
      ASSERT_EQ(f, 0.0) << "zero once stale_after + fade + one tick have passed";
      zero = true;
    }
    prev = f;
  }
  EXPECT_TRUE(zero);
  EXPECT_EQ(rig.servo->data().servo.fade.scale(), 0.0) << "the viz was alive, but the patch went stale";
  EXPECT_GT(rig.servo->data().servo.faded_ticks, 0u);
}

TEST(RtServo, ForceIsClampedAndNeverNaN) {
  RtModel m;
  for (auto& mat : m.servo.haptic.materials) mat.stiffness = 1e6;  // absurdly stiff: the clamp must hold
  m.servo.haptic.safety.max_force = 5.0;
  Rig rig(m);
  rig.publish_plane();
  for (int i = 0; i < 3000; ++i) {
    rig.tick(true);
    rig.drain();
    const Vec3 f = rig.servo->data().servo.force;
    ASSERT_TRUE(is_finite(f));
    ASSERT_LE(norm(f), m.servo.haptic.safety.max_force * (1 + 1e-12));
  }
  EXPECT_GT(rig.servo->data().servo.haptic.safety.clamps, 0u);

  // A patch with NaN vertices is rejected (the one in use stays): forces stay finite.
  auto bad = std::make_unique<TissuePatch>();
  bad->n_triangles = 1;
  bad->t_ns = rig.t;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  bad->triangles[0] = {{{nan, 0, 0}, {0.1f, 0, 0}, {0, 0.1f, nan}}, 1, 0, 0};
  rig.shared->patch.publish(*bad);
  const std::uint64_t in_use = rig.servo->data().patch_version;
  for (int i = 0; i < 10; ++i) {
    rig.tick(true, false);
    rig.drain();
    ASSERT_TRUE(is_finite(rig.servo->data().servo.force));
  }
  EXPECT_EQ(rig.servo->data().health.patches_rejected, 1u);
  EXPECT_EQ(rig.servo->data().patch_version, in_use);
  EXPECT_GT(norm(rig.servo->data().servo.force), 0.5) << "the previous patch is still felt";
}

TEST(RtServo, TickAllocatesNothing) {
  Rig rig;
  rig.publish_plane();
  Command c{};
  c.kind = CommandKind::kSetToolMode;
  c.mode = ToolMode::kScalpel;
  rig.push(c);
  lancet::test::MallocGuard guard;
  for (int i = 0; i < 10'000; ++i) {
    rig.tick(true);
    if (i % 500 == 0) rig.publish_plane(static_cast<float>(i) * 1e-7f);  // new patches arrive too
    rig.drain();
  }
  EXPECT_EQ(guard.count(), 0u);
  EXPECT_EQ(rig.servo->data().servo.mode, ToolMode::kScalpel);
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
  ASSERT_GT(norm(rig.servo->data().servo.force), 0.5);
  rt::WatchdogParams wp;
  wp.tick_budget_ns = 1;
  ASSERT_TRUE(rig.watchdog.observe(wp, false, 10));  // one slow tick
  for (int i = 0; i < 500; ++i) {
    rig.tick(true);
    ASSERT_EQ(rig.servo->data().servo.force, Vec3{}) << "tick " << i;
  }
  ToolSample s{};
  while (rig.shared->samples.try_pop(s)) {
  }
  EXPECT_NE(s.events & event::kFault, 0u);
  RtStatus st{};
  ASSERT_EQ(rig.shared->rt_status.try_read(st), ReadStatus::kOk);
  EXPECT_EQ(st.watchdog_tripped, 1u);
  EXPECT_EQ(st.watchdog_reason, rt::Watchdog::Reason::kTickOverBudget);
  // A command that is not sealed (garbage that looks like a re-arm) does nothing.
  Command forged{};
  forged.kind = CommandKind::kRearm;
  ASSERT_TRUE(rig.shared->commands.try_push(forged));
  rig.tick(true);
  EXPECT_TRUE(rig.watchdog.tripped());
  EXPECT_EQ(rig.servo->data().health.commands_rejected, 1u);
  // Only an explicit re-arm brings the force back.
  Command c{};
  c.kind = CommandKind::kRearm;
  rig.push(c);
  rig.tick(true);
  EXPECT_FALSE(rig.watchdog.tripped());
  EXPECT_GT(norm(rig.servo->data().servo.force), 0.5);
  EXPECT_EQ(rig.servo->data().rearms, 1u);
}

TEST(RtServo, AnOperatorRequestReArmsOnceAndOnlyWhenSealedAndRecent) {
  Rig rig;
  rig.publish_plane();
  for (int i = 0; i < 100; ++i) rig.tick(true), rig.drain();
  rt::WatchdogParams wp;
  wp.tick_budget_ns = 1;
  auto trip = [&] { ASSERT_TRUE(rig.watchdog.observe(wp, false, 10)); };
  auto request = [&](std::uint64_t seq, std::int64_t t_ns, bool seal) {
    OperatorRequest r{};
    r.seq = seq;
    r.t_ns = t_ns;
    r.kind = kOperatorRearm;
    r.pid = 42;
    if (seal) wire::seal(r);
    rig.shared->operator_request.write(r);
  };
  trip();
  request(1, rig.t, /*seal=*/false);
  rig.tick(true);
  EXPECT_TRUE(rig.watchdog.tripped()) << "an unsealed request is garbage";
  request(2, rig.t - 5'000 * kMs, true);
  rig.tick(true);
  EXPECT_TRUE(rig.watchdog.tripped()) << "a request older than 2 s is not acted on";
  request(3, rig.t, true);
  rig.tick(true);
  EXPECT_FALSE(rig.watchdog.tripped());
  EXPECT_EQ(rig.servo->data().operator_requests, 1u);
  trip();
  for (int i = 0; i < 10; ++i) rig.tick(true);
  EXPECT_TRUE(rig.watchdog.tripped()) << "the same request is taken once";
}

// The segment is untrusted: an index written by anyone never makes a tick loop or overrun.
TEST(RtServoSegment, ACorruptCommandRingIndexIsResetCountedAndNeverLoopedOn) {
  Rig rig;
  rig.publish_plane();
  for (int i = 0; i < 50; ++i) rig.tick(true), rig.drain();
  // Eight bytes into the producer's index, as the attacker did: head far past tail.
  auto* ring = reinterpret_cast<unsigned char*>(&rig.shared->commands);
  const std::uint64_t garbage = 0x7fffffffffff1234ull;
  std::memcpy(ring + rig.shared->commands.head_offset(), &garbage, sizeof garbage);
  for (int i = 0; i < 20; ++i) rig.tick(true), rig.drain();  // returns: the old code spun here for good
  const RtData& d = rig.servo->data();
  EXPECT_EQ(d.health.ring_resets, 1u);
  EXPECT_EQ(d.servo.tick, 70u);
  // The ring works again from there: a sealed command from the viz is applied.
  Command c{};
  c.kind = CommandKind::kSetToolMode;
  c.mode = ToolMode::kRetractor;
  rig.push(c);
  rig.tick(true);
  EXPECT_EQ(rig.servo->data().servo.mode, ToolMode::kRetractor);
  // A head just inside the ring's capacity: the stale slots (old sealed commands among them) are
  // drained at most a batch per tick and every one of them is rejected, replays included.
  std::uint64_t tail = 0;
  std::memcpy(&tail, ring + rig.shared->commands.tail_offset(), sizeof tail);
  const std::uint64_t near = tail + kCommandRingCapacity;
  std::memcpy(ring + rig.shared->commands.head_offset(), &near, sizeof near);
  const std::uint64_t applied = rig.servo->data().servo.commands_applied;
  rig.tick(true);
  EXPECT_EQ(rig.servo->data().health.commands_rejected, rig.model.max_commands_per_tick) << "one bounded batch per tick";
  EXPECT_EQ(rig.servo->data().health.commands_deferred, 1u);
  for (int i = 0; i < 40; ++i) rig.tick(true);
  EXPECT_EQ(rig.servo->data().servo.commands_applied, applied) << "stale slots are not commands";
}

TEST(RtServoSegment, ACorruptSampleRingIndexIsResetAndSamplesFlowAgain) {
  Rig rig;
  // The viz stops draining: the ring fills (overflows counted), then its consumer index is
  // overwritten with garbage. The producer finds it impossible when it next looks, restarts from
  // it and counts the reset.
  for (std::size_t i = 0; i < kSampleRingCapacity + 10; ++i) rig.tick(false);
  EXPECT_EQ(rig.shared->samples.overflow_count(), 10u);
  auto* ring = reinterpret_cast<unsigned char*>(&rig.shared->samples);
  const std::uint64_t garbage = ~0ull;  // ahead of everything the producer ever published
  std::memcpy(ring + rig.shared->samples.tail_offset(), &garbage, sizeof garbage);
  rig.tick(false);
  EXPECT_EQ(rig.servo->data().health.sample_ring_resets, 1u);
  ToolSample s{};
  ASSERT_TRUE(rig.shared->samples.try_pop(s)) << "the producer restarted from the consumer's index";
  EXPECT_EQ(s.seq, kSampleRingCapacity + 11);
  EXPECT_FALSE(rig.shared->samples.try_pop(s));
  // Garbage in either index while the ring is not full: whichever side looks first finds it and
  // restarts from the other's index; no garbage slot is read and samples flow on.
  for (const std::size_t offset : {rig.shared->samples.tail_offset(), rig.shared->samples.head_offset()}) {
    const std::uint64_t resets = rig.shared->samples.producer_resets() + rig.shared->samples.consumer_resets();
    const std::uint64_t far = 0x5555555555555555ull;  // nowhere near either index
    std::memcpy(ring + offset, &far, sizeof far);
    std::uint64_t newest = 0;
    for (int i = 0; i < 3; ++i) {
      rig.tick(false);
      while (rig.shared->samples.try_pop(s)) newest = s.seq;
    }
    EXPECT_EQ(newest, rig.servo->data().servo.tick) << "the newest sample arrives";
    EXPECT_EQ(rig.shared->samples.producer_resets() + rig.shared->samples.consumer_resets(), resets + 1);
  }
}

TEST(RtServoSegment, GarbageEverywhereIsRejectedCountedAndAllocatesNothing) {
  Rig rig;
  rig.publish_plane();
  for (int i = 0; i < 200; ++i) rig.tick(true), rig.drain();
  std::mt19937_64 rng(7);
  auto fill = [&](void* p, std::size_t n) {
    auto* b = static_cast<unsigned char*>(p);
    for (std::size_t i = 0; i < n; ++i) b[i] = static_cast<unsigned char>(rng());
  };
  auto junk_patch = std::make_unique<TissuePatch>();
  StylusTarget junk_target{};
  OperatorRequest junk_request{};
  lancet::test::MallocGuard guard;
  for (int i = 0; i < 3000; ++i) {
    // Random commands through the ring, and random bytes over the patch, target and request.
    Command c{};
    fill(&c, sizeof c);
    (void)rig.shared->commands.try_push(c);
    if (i % 7 == 0) {
      fill(junk_patch.get(), sizeof(TissuePatch));
      rig.shared->patch.publish(*junk_patch);
    }
    if (i % 5 == 0) {
      fill(&junk_target, sizeof junk_target);
      rig.shared->stylus_target.write(junk_target);
      fill(&junk_request, sizeof junk_request);
      rig.shared->operator_request.write(junk_request);
    }
    rig.tick(true, false);
    rig.drain();
    const Vec3 f = rig.servo->data().servo.force;
    ASSERT_TRUE(is_finite(f));
    ASSERT_LE(norm(f), rig.model.servo.haptic.safety.max_force * (1 + 1e-12));
  }
  EXPECT_EQ(guard.count(), 0u);
  const SegmentHealth& h = rig.servo->data().health;
  EXPECT_EQ(h.commands_rejected, 3000u + 600u) << "every random command and request is rejected";
  EXPECT_GE(h.patches_rejected, 400u);
  EXPECT_GE(h.targets_rejected, 550u);
  EXPECT_EQ(rig.servo->data().servo.commands_applied, 0u);
}

TEST(RtServoSegment, APatchOrTargetFromTheFutureIsRejected) {
  Rig rig;
  rig.publish_plane();
  rig.tick(true);
  const std::uint64_t v = rig.servo->data().patch_version;
  rig.scratch->t_ns = rig.t + 10'000 * kMs;  // would never go stale
  rig.shared->patch.publish(*rig.scratch);
  StylusTarget tg{};
  tg.active = 1;
  tg.t_ns = rig.t + 10'000 * kMs;  // would never time out
  rig.shared->stylus_target.write(tg);
  rig.tick(true, false);
  EXPECT_EQ(rig.servo->data().patch_version, v);
  EXPECT_EQ(rig.servo->data().health.patches_rejected, 1u);
  EXPECT_EQ(rig.servo->data().health.targets_rejected, 1u);
}

}  // namespace
}  // namespace lancet::app
