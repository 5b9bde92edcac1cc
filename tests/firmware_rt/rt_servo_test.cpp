#include "app/rt_servo.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <array>
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

// A servo on a SharedState in ordinary memory, driven with synthetic time (no sleeping). One hand
// unless the model says two.
struct Rig {
  RtModel model;
  std::unique_ptr<SharedState> shared = std::make_unique<SharedState>();
  std::unique_ptr<RtServo> servo;
  std::array<std::unique_ptr<TissuePatch>, kHandCount> scratch{std::make_unique<TissuePatch>(),
                                                                std::make_unique<TissuePatch>()};  // the "viz" side's buffers
  std::int64_t t = 1'000'000'000;
  rt::Watchdog watchdog;
  rt::LoopLive live;
  std::uint64_t n = 0;
  std::array<bool, kHandCount> published{};

  explicit Rig(RtModel m = {}) : model(m) { servo = std::make_unique<RtServo>(model, *shared, t); }

  [[nodiscard]] const HandData& hand(Hand h) const { return servo->hand(h); }
  [[nodiscard]] const HandData& right() const { return hand(Hand::kRight); }
  [[nodiscard]] const HandData& left() const { return hand(Hand::kLeft); }

  /// A flat plane at height h under `hand`'s tool, in that hand's patch buffer.
  void publish_plane(float h = 0.0f, Hand hand = Hand::kRight) {
    TissuePatch* p = scratch[hand_index(hand)].get();
    const float s = 0.1f;
    p->n_triangles = 2;
    p->triangles[0] = {{{-s, -s, h}, {s, -s, h}, {s, s, h}}, 1, 0, 0};
    p->triangles[1] = {{{-s, -s, h}, {s, s, h}, {-s, s, h}}, 1, 0, 1};
    p->t_ns = t;
    p->hand = hand;
    shared->patch[hand_index(hand)].publish(*p);
    published[hand_index(hand)] = true;
  }
  /// `hand`'s stylus held still at p (the viz's mouse target, refreshed every tick).
  void hold_stylus(Vec3 p, Hand hand = Hand::kRight) {
    StylusTarget tg{};
    tg.seq = n + 1;
    tg.t_ns = t;
    tg.active = 1;
    tg.hand = hand;
    tg.target.position = p;
    shared->stylus_target[hand_index(hand)].write(tg);
  }
  /// One tick; the viz beats when `viz_beats` and republishes its patches every 16 ticks when
  /// `republish` (a live viz does both; the tests of each fade stop one of them).
  void tick(bool viz_beats, bool republish) {
    t += model.period_ns;
    if (viz_beats) shared->viz_heartbeat.beat(t, 1);
    for (std::size_t h = 0; h < kHandCount; ++h) {
      if (republish && published[h] && n % 16 == 0) {
        scratch[h]->t_ns = t;
        shared->patch[h].publish(*scratch[h]);
      }
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
  EXPECT_GT(rig.right().patches_received, 0u);
  EXPECT_GT(rig.right().servo.contact_ticks, 500u);
  EXPECT_GT(rig.right().servo.force.z, 0.5);               // pushed up, out of the tissue
  EXPECT_LE(norm(rig.right().servo.force), rig.model.hand[0].servo.haptic.safety.max_force);
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
  return norm(rig.right().servo.force);
}

TEST(RtServoFades, VizHeartbeatFadeAloneHoldsUntilTheTimeoutThenFallsMonotonically) {
  RtModel m;
  m.hand[0].servo.fade.timeout_ns = 150 * kMs;
  m.hand[0].servo.fade.fade_ns = 100 * kMs;
  m.hand[0].servo.fade.stale_after_ns = 10'000 * kMs;  // the stale-patch fade cannot act in this test
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
    const double f = norm(rig.right().servo.force);
    const std::int64_t age = rig.t - last_beat;
    if (age <= m.hand[0].servo.fade.timeout_ns) {
      ASSERT_NEAR(f, f0, 0.02 * f0) << "the force must hold until the timeout; " << age / kMs << " ms after the last beat";
    } else {
      ASSERT_LE(f, prev + 1e-9) << "the fade must fall monotonically; " << age / kMs << " ms after the last beat";
    }
    if (age > m.hand[0].servo.fade.timeout_ns + m.hand[0].servo.fade.fade_ns + m.period_ns) {
      ASSERT_EQ(f, 0.0) << "zero by timeout + fade + one tick";
      zero = true;
    }
    prev = f;
  }
  EXPECT_TRUE(zero);
  const RtData& d = rig.servo->data();
  EXPECT_EQ(d.viz_lost_at_beat_ns, last_beat);
  EXPECT_LE(d.force_zero_ns - last_beat, m.hand[0].servo.fade.timeout_ns + m.hand[0].servo.fade.fade_ns + m.period_ns);
  EXPECT_EQ(rig.right().servo.fade.scale(), 0.0);
}

TEST(RtServoFades, StalePatchFadeAloneHoldsUntilStaleThenFallsMonotonically) {
  RtModel m;
  m.hand[0].servo.fade.timeout_ns = 10'000 * kMs;  // the heartbeat fade cannot act in this test
  m.hand[0].servo.fade.stale_after_ns = 100 * kMs;
  m.hand[0].servo.fade.fade_ns = 100 * kMs;
  Rig rig(m);
  const double f0 = settle(rig);
  ASSERT_GT(f0, 0.5);
  const std::int64_t last_patch = rig.scratch[0]->t_ns;
  double prev = f0;
  bool zero = false;
  for (int i = 1; i <= 400; ++i) {
    rig.hold_stylus(kHeld);
    rig.tick(/*viz_beats=*/true, /*republish=*/false);  // the viz beats but publishes no new tissue
    rig.drain();
    const double f = norm(rig.right().servo.force);
    const std::int64_t age = rig.t - last_patch;
    if (age <= m.hand[0].servo.fade.stale_after_ns) {
      ASSERT_NEAR(f, f0, 0.02 * f0) << "the force must hold until the patch is stale; age " << age / kMs << " ms";
    } else {
      ASSERT_LE(f, prev + 1e-9) << "the fade must fall monotonically; age " << age / kMs << " ms";
    }
    if (age > m.hand[0].servo.fade.stale_after_ns + m.hand[0].servo.fade.fade_ns + m.period_ns) {
      ASSERT_EQ(f, 0.0) << "zero once stale_after + fade + one tick have passed";
      zero = true;
    }
    prev = f;
  }
  EXPECT_TRUE(zero);
  EXPECT_EQ(rig.right().servo.fade.scale(), 0.0) << "the viz was alive, but the patch went stale";
  EXPECT_GT(rig.right().servo.faded_ticks, 0u);
}

TEST(RtServo, ForceIsClampedAndNeverNaN) {
  RtModel m;
  for (auto& mat : m.hand[0].servo.haptic.materials) mat.stiffness = 1e6;  // absurdly stiff: the clamp must hold
  m.hand[0].servo.haptic.safety.max_force = 5.0;
  Rig rig(m);
  rig.publish_plane();
  for (int i = 0; i < 3000; ++i) {
    rig.tick(true);
    rig.drain();
    const Vec3 f = rig.right().servo.force;
    ASSERT_TRUE(is_finite(f));
    ASSERT_LE(norm(f), m.hand[0].servo.haptic.safety.max_force * (1 + 1e-12));
  }
  EXPECT_GT(rig.right().servo.haptic.safety.clamps, 0u);

  // A patch with NaN vertices is rejected (the one in use stays): forces stay finite.
  auto bad = std::make_unique<TissuePatch>();
  bad->n_triangles = 1;
  bad->t_ns = rig.t;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  bad->triangles[0] = {{{nan, 0, 0}, {0.1f, 0, 0}, {0, 0.1f, nan}}, 1, 0, 0};
  rig.shared->patch[0].publish(*bad);
  const std::uint64_t in_use = rig.right().patch_version;
  for (int i = 0; i < 10; ++i) {
    rig.tick(true, false);
    rig.drain();
    ASSERT_TRUE(is_finite(rig.right().servo.force));
  }
  EXPECT_EQ(rig.servo->data().health.patches_rejected, 1u);
  EXPECT_EQ(rig.right().patch_version, in_use);
  EXPECT_GT(norm(rig.right().servo.force), 0.5) << "the previous patch is still felt";
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
  EXPECT_EQ(rig.right().servo.mode, ToolMode::kScalpel);
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
  ASSERT_GT(norm(rig.right().servo.force), 0.5);
  rt::WatchdogParams wp;
  wp.tick_budget_ns = 1;
  ASSERT_TRUE(rig.watchdog.observe(wp, false, 10));  // one slow tick
  for (int i = 0; i < 500; ++i) {
    rig.tick(true);
    ASSERT_EQ(rig.right().servo.force, Vec3{}) << "tick " << i;
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
  EXPECT_GT(norm(rig.right().servo.force), 0.5);
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
    r.hands = 0b01;
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
  EXPECT_EQ(rig.right().servo.tick, 70u);
  // The ring works again from there: a sealed command from the viz is applied.
  Command c{};
  c.kind = CommandKind::kSetToolMode;
  c.mode = ToolMode::kRetractor;
  rig.push(c);
  rig.tick(true);
  EXPECT_EQ(rig.right().servo.mode, ToolMode::kRetractor);
  // A head just inside the ring's capacity: the stale slots (old sealed commands among them) are
  // drained at most a batch per tick and every one of them is rejected, replays included.
  std::uint64_t tail = 0;
  std::memcpy(&tail, ring + rig.shared->commands.tail_offset(), sizeof tail);
  const std::uint64_t near = tail + kCommandRingCapacity;
  std::memcpy(ring + rig.shared->commands.head_offset(), &near, sizeof near);
  const std::uint64_t applied = rig.right().servo.commands_applied;
  rig.tick(true);
  EXPECT_EQ(rig.servo->data().health.commands_rejected, rig.model.max_commands_per_tick) << "one bounded batch per tick";
  EXPECT_EQ(rig.servo->data().health.commands_deferred, 1u);
  for (int i = 0; i < 40; ++i) rig.tick(true);
  EXPECT_EQ(rig.right().servo.commands_applied, applied) << "stale slots are not commands";
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
    EXPECT_EQ(newest, rig.right().servo.tick) << "the newest sample arrives";
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
      rig.shared->patch[0].publish(*junk_patch);
    }
    if (i % 5 == 0) {
      fill(&junk_target, sizeof junk_target);
      rig.shared->stylus_target[0].write(junk_target);
      fill(&junk_request, sizeof junk_request);
      rig.shared->operator_request.write(junk_request);
    }
    rig.tick(true, false);
    rig.drain();
    const Vec3 f = rig.right().servo.force;
    ASSERT_TRUE(is_finite(f));
    ASSERT_LE(norm(f), rig.model.hand[0].servo.haptic.safety.max_force * (1 + 1e-12));
  }
  EXPECT_EQ(guard.count(), 0u);
  const SegmentHealth& h = rig.servo->data().health;
  EXPECT_EQ(h.commands_rejected, 3000u + 600u) << "every random command and request is rejected";
  EXPECT_GE(h.patches_rejected, 400u);
  EXPECT_GE(h.targets_rejected, 550u);
  EXPECT_EQ(rig.right().servo.commands_applied, 0u);
}

TEST(RtServoSegment, APatchOrTargetFromTheFutureIsRejected) {
  Rig rig;
  rig.publish_plane();
  rig.tick(true);
  const std::uint64_t v = rig.right().patch_version;
  rig.scratch[0]->t_ns = rig.t + 10'000 * kMs;  // would never go stale
  rig.shared->patch[0].publish(*rig.scratch[0]);
  StylusTarget tg{};
  tg.active = 1;
  tg.t_ns = rig.t + 10'000 * kMs;  // would never time out
  rig.shared->stylus_target[0].write(tg);
  rig.tick(true, false);
  EXPECT_EQ(rig.right().patch_version, v);
  EXPECT_EQ(rig.servo->data().health.patches_rejected, 1u);
  EXPECT_EQ(rig.servo->data().health.targets_rejected, 1u);
}

// ---- Two hands: one loop, each hand its own device, patch, target, model, commands and safety.

RtModel two_hands() {
  RtModel m;
  m.hands = 2;
  return m;
}

/// How far the tool's centre is inside the proxy's sphere resting on the plane at height `plane`
/// (m; > 0 pressing): the spring's stretch.
double depth_below(const HandData& h, const HandModel& m, double plane) { return plane + m.servo.haptic.proxy_radius - h.servo.tool.z; }

TEST(RtServoTwoHands, EachHandStepsItsOwnDeviceAgainstItsOwnPatchWithItsOwnStiffness) {
  RtModel m = two_hands();
  for (auto& mat : m.hand[0].servo.haptic.materials) mat.stiffness = 300;
  for (auto& mat : m.hand[1].servo.haptic.materials) mat.stiffness = 600;
  Rig rig(m);
  // The right hand's tissue at z = 0, the left's 2 mm higher: each is felt only by its hand.
  rig.publish_plane(0.0f, Hand::kRight);
  rig.publish_plane(0.002f, Hand::kLeft);
  const Vec3 right_at{0.01, 0.0, -0.003}, left_at{-0.01, 0.02, -0.003};
  for (int i = 0; i < 2000; ++i) {
    rig.hold_stylus(right_at, Hand::kRight);
    rig.hold_stylus(left_at, Hand::kLeft);
    rig.tick(true);
    rig.drain();
  }
  const HandData& r = rig.right();
  const HandData& l = rig.left();
  ASSERT_TRUE(r.servo.contact && l.servo.contact);
  // At rest each hand's force is its own stiffness times its own depth into its own patch.
  const double dr = depth_below(r, rig.model.hand[0], 0.0), dl = depth_below(l, rig.model.hand[1], 0.002);
  ASSERT_GT(dr, 0.0005);
  ASSERT_GT(dl, 0.0005);
  EXPECT_NEAR(r.servo.force.z, 300 * dr, 0.03 * 300 * dr);
  EXPECT_NEAR(l.servo.force.z, 600 * dl, 0.03 * 600 * dl);
  EXPECT_GT(dl, dr) << "the left tissue is higher: the left tool is deeper in its own";
  // Each stylus is where its own hand holds it.
  EXPECT_NEAR(r.servo.tool.x, right_at.x, 1e-3);
  EXPECT_NEAR(l.servo.tool.y, left_at.y, 1e-3);
  EXPECT_EQ(r.patches_received, l.patches_received);
  // The status says the same, hand by hand.
  RtStatus st{};
  ASSERT_EQ(rig.shared->rt_status.try_read(st), ReadStatus::kOk);
  EXPECT_EQ(wire::check(st), nullptr);
  EXPECT_EQ(st.hands, 2u);
  EXPECT_EQ(st.hand[0].force, r.servo.force);
  EXPECT_EQ(st.hand[1].force, l.servo.force);
  EXPECT_EQ(st.hand[0].contact, 1u);
  EXPECT_EQ(st.hand[1].patch_version, l.patch_version);
  EXPECT_EQ(st.hand[1].tool, l.servo.tool);
  // Each hand's model is published in its own slot.
  for (std::size_t h = 0; h < kHandCount; ++h) {
    ServoModelBlob blob{};
    ASSERT_EQ(rig.shared->servo_model[h].try_read(blob), ReadStatus::kOk);
    auto model = servo::model_from_blob(blob);
    ASSERT_TRUE(model.ok()) << model.error().message;
    EXPECT_EQ(model.value().haptic.materials[1].stiffness, h == 0 ? 300 : 600);
  }
}

TEST(RtServoTwoHands, OneHandWritesOnlyTheRightHandsModel) {
  Rig rig;
  ServoModelBlob blob{};
  EXPECT_EQ(rig.shared->servo_model[0].try_read(blob), ReadStatus::kOk);
  EXPECT_EQ(rig.shared->servo_model[1].try_read(blob), ReadStatus::kEmpty);
  rig.tick(false);
  RtStatus st{};
  ASSERT_EQ(rig.shared->rt_status.try_read(st), ReadStatus::kOk);
  EXPECT_EQ(st.hands, 1u);
  ToolSample s{};
  ASSERT_TRUE(rig.shared->samples.try_pop(s));
  EXPECT_EQ(s.hand, Hand::kRight);
  EXPECT_FALSE(rig.shared->samples.try_pop(s)) << "one sample a tick with one hand";
}

TEST(RtServoTwoHands, TheLeftHandsBuiltInScriptParksAboveTheTissue) {
  Rig rig(two_hands());
  rig.publish_plane(0.0f, Hand::kRight);
  rig.publish_plane(0.0f, Hand::kLeft);
  for (int i = 0; i < 2500; ++i) rig.tick(true), rig.drain();
  EXPECT_GT(rig.right().servo.contact_ticks, 500u) << "the right hand's script presses in";
  EXPECT_EQ(rig.left().servo.contact_ticks, 0u) << "the left hand's waits above the tissue";
  EXPECT_LT(norm(rig.left().servo.tool - device::kLeftParked), 1e-3);
  EXPECT_EQ(rig.left().servo.force, Vec3{});
}

TEST(RtServoTwoHands, EachTickPushesTheRightSampleThenTheLeftWithTheTicksSeq) {
  Rig rig(two_hands());
  for (int i = 0; i < 100; ++i) rig.tick(false);
  ToolSample s;
  std::uint64_t n = 0;
  while (rig.shared->samples.try_pop(s)) {
    EXPECT_EQ(s.seq, n / 2 + 1) << "sample " << n;
    EXPECT_EQ(s.hand, n % 2 == 0 ? Hand::kRight : Hand::kLeft) << "sample " << n;
    EXPECT_EQ(wire::check(s), nullptr);
    ++n;
  }
  EXPECT_EQ(n, 200u);
  RtStatus st{};
  ASSERT_EQ(rig.shared->rt_status.try_read(st), ReadStatus::kOk);
  EXPECT_EQ(st.tick, 100u);
  EXPECT_EQ(st.samples_pushed, 200u);
}

TEST(RtServoTwoHands, CommandsGoToTheHandTheyName) {
  Rig rig(two_hands());
  Command c{};
  c.kind = CommandKind::kSetToolMode;
  c.mode = ToolMode::kScalpel;
  c.hand = Hand::kLeft;
  rig.push(c);
  c.mode = ToolMode::kDrill;
  c.hand = Hand::kRight;
  rig.push(c);
  rig.tick(false);
  EXPECT_EQ(rig.left().servo.mode, ToolMode::kScalpel);
  EXPECT_EQ(rig.right().servo.mode, ToolMode::kDrill);
  ToolSample s[2];
  ASSERT_TRUE(rig.shared->samples.try_pop(s[0]));
  ASSERT_TRUE(rig.shared->samples.try_pop(s[1]));
  ASSERT_EQ(s[0].n_commands, 1u);
  ASSERT_EQ(s[1].n_commands, 1u);
  EXPECT_EQ(s[0].commands[0], servo::pack_command(CommandKind::kSetToolMode, ToolMode::kDrill));
  EXPECT_EQ(s[1].commands[0], servo::pack_command(CommandKind::kSetToolMode, ToolMode::kScalpel));
  // A reset for the left hand starts only the left hand's session.
  for (int i = 0; i < 50; ++i) rig.tick(false), rig.drain();
  const std::uint64_t right_applied = rig.right().servo.commands_applied;
  c = Command{};
  c.kind = CommandKind::kReset;
  c.hand = Hand::kLeft;
  rig.push(c);
  rig.tick(false);
  EXPECT_EQ(rig.left().servo.commands_applied, 0u) << "the left session restarted";
  EXPECT_EQ(rig.right().servo.commands_applied, right_applied);
  EXPECT_EQ(rig.left().servo.mode, ToolMode::kScalpel) << "the tool in hand is kept through a reset";
  EXPECT_EQ(rig.left().servo.tick, rig.right().servo.tick) << "the hands' ticks stay in step";
  // A command for a hand the loop does not drive is rejected.
  Rig one;
  c = Command{};
  c.kind = CommandKind::kSetToolMode;
  c.mode = ToolMode::kDrill;
  c.hand = Hand::kLeft;
  one.push(c);
  one.tick(false);
  EXPECT_EQ(one.servo->data().health.commands_rejected, 1u);
  EXPECT_EQ(one.right().servo.mode, ToolMode::kProbe);
}

TEST(RtServoTwoHands, ATargetOrPatchInTheOtherHandsSlotIsRejectedAndCounted) {
  Rig rig(two_hands());
  rig.publish_plane(0.0f, Hand::kLeft);
  rig.tick(true);
  const std::uint64_t left_version = rig.left().patch_version;
  ASSERT_NE(left_version, 0u);
  // A target saying "right" in the left hand's slot.
  StylusTarget tg{};
  tg.t_ns = rig.t;
  tg.active = 1;
  tg.hand = Hand::kRight;
  tg.target.position = {0, 0, -0.01};
  rig.shared->stylus_target[hand_index(Hand::kLeft)].write(tg);
  // A patch saying "right" in the left hand's buffer.
  rig.scratch[1]->hand = Hand::kRight;
  rig.scratch[1]->t_ns = rig.t;
  rig.shared->patch[hand_index(Hand::kLeft)].publish(*rig.scratch[1]);
  for (int i = 0; i < 200; ++i) rig.tick(true, false), rig.drain();
  const SegmentHealth& h = rig.servo->data().health;
  EXPECT_EQ(h.targets_rejected, 1u);
  EXPECT_EQ(h.patches_rejected, 1u);
  EXPECT_EQ(rig.left().patch_version, left_version) << "the left hand keeps its own patch";
  EXPECT_LT(norm(rig.left().servo.tool - device::kLeftParked), 2e-3) << "the left hand did not follow the stray target";
}

TEST(RtServoTwoHands, AKRearmForEitherHandReArmsTheLoopsWatchdogAndATripZeroesBoth) {
  Rig rig(two_hands());
  rig.publish_plane(0.0f, Hand::kRight);
  rig.publish_plane(0.0f, Hand::kLeft);
  for (int i = 0; i < 1500; ++i) {
    rig.hold_stylus({0, 0, -0.003}, Hand::kRight);
    rig.hold_stylus({0, 0.02, -0.003}, Hand::kLeft);
    rig.tick(true), rig.drain();
  }
  ASSERT_GT(norm(rig.right().servo.force), 0.5);
  ASSERT_GT(norm(rig.left().servo.force), 0.5);
  rt::WatchdogParams wp;
  wp.tick_budget_ns = 1;
  ASSERT_TRUE(rig.watchdog.observe(wp, false, 10));
  for (int i = 0; i < 50; ++i) {
    rig.hold_stylus({0, 0, -0.003}, Hand::kRight);
    rig.hold_stylus({0, 0.02, -0.003}, Hand::kLeft);
    rig.tick(true), rig.drain();
    ASSERT_EQ(rig.right().servo.force, Vec3{});
    ASSERT_EQ(rig.left().servo.force, Vec3{});
  }
  Command c{};
  c.kind = CommandKind::kRearm;
  c.hand = Hand::kLeft;
  rig.push(c);
  rig.hold_stylus({0, 0, -0.003}, Hand::kRight);
  rig.hold_stylus({0, 0.02, -0.003}, Hand::kLeft);
  rig.tick(true);
  EXPECT_FALSE(rig.watchdog.tripped());
  EXPECT_EQ(rig.servo->data().rearms, 1u);
  for (int i = 0; i < 5; ++i) rig.tick(true);
  EXPECT_GT(norm(rig.right().servo.force), 0.5) << "the loop's watchdog re-armed: both hands have their force back";
  EXPECT_GT(norm(rig.left().servo.force), 0.5);
}

TEST(RtServoTwoHands, AnOperatorRequestReArmsTheHandsItNames) {
  Rig rig(two_hands());
  for (int i = 0; i < 10; ++i) rig.tick(true), rig.drain();
  OperatorRequest r{};
  r.seq = 1;
  r.t_ns = rig.t;
  r.kind = kOperatorRearm;
  r.pid = 42;
  r.hands = 0b10;  // the left hand only
  wire::seal(r);
  rig.shared->operator_request.write(r);
  rig.tick(true);
  ToolSample s[2];
  ASSERT_TRUE(rig.shared->samples.try_pop(s[0]));
  ASSERT_TRUE(rig.shared->samples.try_pop(s[1]));
  EXPECT_EQ(s[0].inputs & input::kOperatorRearm, 0u) << "not for the right hand";
  EXPECT_NE(s[1].inputs & input::kOperatorRearm, 0u) << "for the left hand";
  EXPECT_EQ(rig.servo->data().operator_requests, 1u);
}

// The left hand goes through the same safety chain as the right: the clamp, the NaN guard (a
// patch with NaN vertices never reaches it), the slew limit.
TEST(RtServoTwoHands, TheLeftHandsForceIsClampedSlewLimitedAndNeverNaN) {
  RtModel m = two_hands();
  for (HandModel& hm : m.hand) {
    for (auto& mat : hm.servo.haptic.materials) mat.stiffness = 1e6;  // absurdly stiff: the clamp must hold
    hm.servo.haptic.safety.max_force = 5.0;
    hm.servo.haptic.safety.max_slew = 1000.0;  // N/s: 1 N a tick at most
  }
  Rig rig(m);
  rig.publish_plane(0.0f, Hand::kLeft);
  Vec3 prev{};
  const double max_step = m.hand[1].servo.haptic.safety.max_slew * 1e-3;
  for (int i = 0; i < 3000; ++i) {
    rig.hold_stylus({0, 0.02, -0.003}, Hand::kLeft);
    rig.tick(true);
    rig.drain();
    const Vec3 f = rig.left().servo.force;
    ASSERT_TRUE(is_finite(f));
    ASSERT_LE(norm(f), 5.0 * (1 + 1e-12)) << "tick " << i;
    ASSERT_LE(norm(f - prev), max_step * (1 + 1e-9)) << "tick " << i;
    prev = f;
  }
  EXPECT_GT(rig.left().servo.haptic.safety.clamps, 0u);
  EXPECT_GT(rig.left().servo.haptic.safety.slew_limits, 0u);
  EXPECT_EQ(rig.right().servo.haptic.safety.clamps, 0u) << "the right hand never touched its (absent) tissue";
  RtStatus st{};
  ASSERT_EQ(rig.shared->rt_status.try_read(st), ReadStatus::kOk);
  EXPECT_EQ(st.hand[1].clamped_ticks, rig.left().servo.haptic.safety.clamps);

  // A left patch with NaN vertices is rejected (the one in use stays): forces stay finite.
  auto bad = std::make_unique<TissuePatch>();
  bad->n_triangles = 1;
  bad->t_ns = rig.t;
  bad->hand = Hand::kLeft;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  bad->triangles[0] = {{{nan, 0, 0}, {0.1f, 0, 0}, {0, 0.1f, nan}}, 1, 0, 0};
  rig.shared->patch[1].publish(*bad);
  const std::uint64_t in_use = rig.left().patch_version;
  for (int i = 0; i < 10; ++i) {
    rig.hold_stylus({0, 0.02, -0.003}, Hand::kLeft);
    rig.tick(true, false);
    rig.drain();
    ASSERT_TRUE(is_finite(rig.left().servo.force));
  }
  EXPECT_EQ(rig.servo->data().health.patches_rejected, 1u);
  EXPECT_EQ(rig.left().patch_version, in_use);
  EXPECT_GT(norm(rig.left().servo.force), 0.5) << "the previous patch is still felt";
  EXPECT_EQ(rig.left().servo.haptic.safety.nan_guards, 0u) << "nothing NaN reached the left hand's step";
}

TEST(RtServoTwoHands, TickWithTwoHandsAllocatesNothing) {
  Rig rig(two_hands());
  rig.publish_plane(0.0f, Hand::kRight);
  rig.publish_plane(0.0f, Hand::kLeft);
  Command c{};
  c.kind = CommandKind::kSetToolMode;
  c.mode = ToolMode::kScalpel;
  c.hand = Hand::kLeft;
  rig.push(c);
  lancet::test::MallocGuard guard;
  for (int i = 0; i < 10'000; ++i) {
    rig.hold_stylus({0, 0.02, -0.003}, Hand::kLeft);
    rig.tick(true);
    if (i % 500 == 0) {
      rig.publish_plane(static_cast<float>(i) * 1e-7f, Hand::kRight);  // new patches arrive for both hands
      rig.publish_plane(static_cast<float>(i) * 1e-7f, Hand::kLeft);
    }
    rig.drain();
  }
  EXPECT_EQ(guard.count(), 0u);
  EXPECT_EQ(rig.left().servo.mode, ToolMode::kScalpel);
  EXPECT_GT(rig.left().servo.contact_ticks, 0u);
  EXPECT_GT(rig.right().servo.contact_ticks, 0u);
}

}  // namespace
}  // namespace lancet::app
