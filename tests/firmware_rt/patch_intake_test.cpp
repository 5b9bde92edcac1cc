// The patch intake (app/patch_intake.hpp): a published patch reaches the servo copied, checked and
// with its search tree, in the tick (without the helper thread) or from the helper thread; a bad
// patch is counted and never handed over; the servo's part allocates nothing; a writer that
// publishes flat out costs the helper at most one patch a servo period. With the thread, the tests
// wait for the patch to arrive (an event), never for a time.

#include "app/patch_intake.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <memory>
#include <thread>

#include "app/rt_servo.hpp"
#include "malloc_guard.hpp"
#include "patch_sheet.hpp"
#include "wait.hpp"

namespace lancet::app {
namespace {

constexpr std::int64_t kPeriod = 1'000'000;

// A wavy sheet of n_x × n_y cells (2 triangles each) around the origin, stamped at t_ns.
std::unique_ptr<TissuePatch> sheet(int nx, int ny, std::int64_t t_ns, float lift = 0.0f) {
  auto p = std::make_unique<TissuePatch>();
  p->n_triangles = 0;
  test::add_sheet(*p, nx, ny, -0.02f, -0.02f, 0.04f / static_cast<float>(nx), 0.04f / static_cast<float>(ny),
                  [lift](float x, float y) { return Vec3f{x, y, lift + 0.002f * std::sin(300.0f * x) * std::cos(200.0f * y)}; });
  p->t_ns = t_ns;
  return p;
}

bool same_tree(const haptics::PatchBvh& a, const haptics::PatchBvh& b) {
  if (a.version != b.version || a.n_triangles != b.n_triangles || a.first_leaf != b.first_leaf) return false;
  return std::memcmp(a.nodes.data(), b.nodes.data(), sizeof(a.nodes)) == 0;
}

TEST(PatchIntake, InTheTickAPublishedPatchIsHandedOverWithItsTree) {
  auto shared = std::make_unique<SharedState>();
  PatchIntake intake(*shared, kPeriod);
  EXPECT_FALSE(intake.poll(monotonic_ns())) << "nothing published yet";
  EXPECT_EQ(intake.take(), nullptr);
  const std::int64_t now = monotonic_ns();
  auto p = sheet(64, 64, now);  // 8192 triangles
  shared->patch[0].publish_prefix(*p, tissue_patch_bytes(*p));
  ASSERT_TRUE(intake.poll(now));
  const ReadyPatch* r = intake.take();
  ASSERT_NE(r, nullptr);
  EXPECT_EQ(r->version, 1u);
  EXPECT_EQ(r->patch.n_triangles, p->n_triangles);
  EXPECT_EQ(std::memcmp(r->patch.triangles, p->triangles, p->n_triangles * sizeof(PatchTriangle)), 0);
  auto expected = std::make_unique<haptics::PatchBvh>();
  haptics::build_patch_bvh(*expected, *p, 1);
  EXPECT_TRUE(same_tree(r->tree, *expected)) << "the tree is not the one the step would build";
  EXPECT_FALSE(intake.poll(now)) << "the same version is not taken twice";
  EXPECT_EQ(intake.take(), r) << "the patch in use stays until a newer one";
  EXPECT_EQ(intake.counters().taken.load(), 1u);
}

TEST(PatchIntake, OfTwoPatchesReadyBeforeTheServoLooksItGetsTheNewerAndKeepsItsOwnUntilThen) {
  auto shared = std::make_unique<SharedState>();
  PatchIntake intake(*shared, kPeriod);
  const std::int64_t now = monotonic_ns();
  auto a = sheet(4, 4, now, 0.0f), b = sheet(4, 4, now, 0.01f), c = sheet(4, 4, now, 0.02f);
  shared->patch[0].publish(*a);
  ASSERT_TRUE(intake.poll(now));
  const ReadyPatch* first = intake.take();
  ASSERT_NE(first, nullptr);
  shared->patch[0].publish(*b);
  ASSERT_TRUE(intake.poll(now));
  shared->patch[0].publish(*c);
  ASSERT_TRUE(intake.poll(now));
  // The servo's buffer was never written while it held it.
  EXPECT_EQ(first->version, 1u);
  EXPECT_FLOAT_EQ(first->patch.triangles[0].v[0].z, a->triangles[0].v[0].z);
  const ReadyPatch* newest = intake.take();
  ASSERT_NE(newest, nullptr);
  EXPECT_EQ(newest->version, 3u);
  EXPECT_FLOAT_EQ(newest->patch.triangles[0].v[0].z, c->triangles[0].v[0].z);
}

TEST(PatchIntake, ABadPatchIsCountedAndNeverHandedOver) {
  auto shared = std::make_unique<SharedState>();
  PatchIntake intake(*shared, kPeriod);
  const std::int64_t now = monotonic_ns();
  auto good = sheet(4, 4, now);
  shared->patch[0].publish(*good);
  ASSERT_TRUE(intake.poll(now));
  auto bad = sheet(4, 4, now);
  bad->triangles[5].v[1].y = std::nanf("");
  shared->patch[0].publish(*bad);
  EXPECT_FALSE(intake.poll(now));
  EXPECT_EQ(intake.counters().rejected.load(), 1u);
  ASSERT_NE(intake.counters().last_reject.load(), nullptr);
  EXPECT_NE(std::strstr(intake.counters().last_reject.load(), "patch.triangles[].v"), nullptr);
  const ReadyPatch* r = intake.take();
  ASSERT_NE(r, nullptr);
  EXPECT_EQ(r->version, 1u) << "the rejected patch replaced the good one";
  EXPECT_FALSE(intake.poll(now)) << "a rejected version is not read again";
}

TEST(PatchIntake, TheServosTakeAllocatesNothing) {
  auto shared = std::make_unique<SharedState>();
  PatchIntake intake(*shared, kPeriod);
  const std::int64_t now = monotonic_ns();
  auto p = sheet(32, 32, now);
  test::MallocGuard guard;
  for (int k = 0; k < 20; ++k) {
    p->t_ns = now;
    shared->patch[0].publish(*p);
    (void)intake.poll(now);
    (void)intake.take();
  }
  EXPECT_EQ(guard.count(), 0u) << "publish, poll or take allocated";
}

// With the helper thread: every patch the "viz" publishes reaches take(), checked, with its tree;
// the servo's side is O(1) and allocates nothing.
TEST(PatchIntakeThread, EveryPublishedPatchReachesTheServoFromTheHelperThread) {
  auto shared = std::make_unique<SharedState>();
  PatchIntake intake(*shared, kPeriod);
  const std::string said = intake.start_thread(false, 0, -1);
  ASSERT_TRUE(intake.threaded()) << said;
  for (std::uint64_t k = 1; k <= 20; ++k) {
    auto p = sheet(32, 32, monotonic_ns(), 0.001f * static_cast<float>(k));
    shared->patch[0].publish_prefix(*p, tissue_patch_bytes(*p));
    const ReadyPatch* r = nullptr;
    ASSERT_TRUE(test::eventually([&] {
      test::MallocGuard guard;
      r = intake.take();
      return guard.count() == 0 && r != nullptr && r->version == k;
    })) << "patch " << k << " never reached the servo (or take() allocated)";
    EXPECT_EQ(r->patch.n_triangles, p->n_triangles);
    EXPECT_FLOAT_EQ(r->patch.triangles[7].v[2].z, p->triangles[7].v[2].z);
    EXPECT_EQ(r->tree.version, k);
  }
  intake.stop_thread();
  EXPECT_FALSE(intake.threaded());
  EXPECT_EQ(intake.counters().rejected.load(), 0u);
  EXPECT_EQ(intake.counters().busy.load(), 0u);
}

// A writer flat out: the helper takes at most one patch a servo period (its sleep between takes
// guarantees it, on any machine), and the newest still gets through.
TEST(PatchIntakeThread, AWriterFlatOutCostsTheHelperAtMostOnePatchAPeriod) {
  auto shared = std::make_unique<SharedState>();
  constexpr std::int64_t kSlowPeriod = 100'000'000;  // 100 ms: many publishes within each, even under TSan
  PatchIntake intake(*shared, kSlowPeriod);
  ASSERT_TRUE(intake.threaded() || !intake.start_thread(false, 0, -1).empty());
  auto p = sheet(16, 16, monotonic_ns());
  const std::int64_t t0 = monotonic_ns();
  std::uint64_t published = 0;
  // Until the helper has taken a few and the writer has published several times as many.
  while (intake.counters().taken.load() < 5 || published < 3 * intake.counters().taken.load() + 100) {
    p->t_ns = monotonic_ns();
    shared->patch[0].publish(*p);
    ++published;
    ASSERT_LT(monotonic_ns() - t0, std::chrono::nanoseconds(test::kHangTimeout).count())
        << "the helper took fewer than 5 patches: taken " << intake.counters().taken.load() << ", busy "
        << intake.counters().busy.load() << ", rejected " << intake.counters().rejected.load() << ", wake-ups "
        << intake.counters().wakeups.load() << ", published " << published;
  }
  intake.stop_thread();  // no take after t1: each one began after t0, a period after the one before
  const std::int64_t t1 = monotonic_ns();
  const std::uint64_t taken = intake.counters().taken.load();
  EXPECT_LE(taken, static_cast<std::uint64_t>((t1 - t0) / kSlowPeriod) + 1)
      << taken << " patches taken in " << (t1 - t0) / 1e6 << " ms at one per " << kSlowPeriod / 1e6 << " ms";
  EXPECT_LT(taken, published);
}

// The servo with the intake on its thread: ticks see the patch once it is ready, use the intake's
// tree (the step builds none), and allocate nothing while patches arrive.
TEST(PatchIntakeThread, TheServoUsesTheIntakesTreeAndBuildsNoneInItsTick) {
  auto shared = std::make_unique<SharedState>();
  RtModel model;
  std::int64_t t = monotonic_ns();
  RtServo servo(model, *shared, t);
  ASSERT_FALSE(servo.start_patch_intake(false, 0, -1).empty());
  rt::Watchdog watchdog;
  rt::LoopLive live;
  std::uint64_t n = 0;
  ToolSample s{};
  auto p = sheet(64, 64, t, -0.003f);  // the scripted stylus presses into it
  for (std::uint64_t k = 1; k <= 5; ++k) {
    p->t_ns = monotonic_ns();
    shared->patch[0].publish_prefix(*p, tissue_patch_bytes(*p));
    ASSERT_TRUE(test::eventually([&] {
      t += model.period_ns;
      shared->viz_heartbeat.beat(t, 1);
      test::MallocGuard guard;
      servo.tick(rt::TickContext{t, t, ++n, watchdog, live});
      EXPECT_EQ(guard.count(), 0u) << "a tick allocated";
      while (shared->samples.try_pop(s)) {
      }
      return s.patch_version == k;
    })) << "patch " << k << " never reached the tick";
  }
  EXPECT_EQ(servo.hand(Hand::kRight).patch_version, 5u);
  EXPECT_EQ(servo.hand(Hand::kRight).servo.haptic.patch_version, 5u);
  EXPECT_EQ(servo.hand(Hand::kRight).servo.haptic.bvh.version, 0u) << "the step built a tree the intake had built";
}

TEST(PatchIntake, EachHandsIntakeTakesOnlyItsOwnBufferAndOnlyPatchesThatSayItsHand) {
  auto shared = std::make_unique<SharedState>();
  PatchIntake right(*shared, kPeriod, Hand::kRight);
  PatchIntake left(*shared, kPeriod, Hand::kLeft);
  const std::int64_t now = monotonic_ns();
  auto p = sheet(4, 4, now);
  p->hand = Hand::kLeft;
  shared->patch[hand_index(Hand::kLeft)].publish(*p);
  EXPECT_FALSE(right.poll(now)) << "the right hand's buffer is empty";
  ASSERT_TRUE(left.poll(now));
  ASSERT_NE(left.take(), nullptr);
  EXPECT_EQ(left.take()->patch.hand, Hand::kLeft);
  // A patch cut out for the right hand, published in the left hand's buffer, is rejected.
  p->hand = Hand::kRight;
  shared->patch[hand_index(Hand::kLeft)].publish(*p);
  EXPECT_FALSE(left.poll(now));
  EXPECT_EQ(left.counters().rejected.load(), 1u);
  EXPECT_STREQ(left.counters().last_reject.load(), "patch.hand: not the hand whose buffer it came in");
  EXPECT_EQ(left.take()->version, 1u) << "the patch in use stays";
  EXPECT_EQ(right.counters().rejected.load(), 0u);
}

}  // namespace
}  // namespace lancet::app
