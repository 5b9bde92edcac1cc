// The 16k-triangle patch: lancet-rt's search tree (haptics/patch_bvh.hpp) gives the same proxy as
// a scan of the whole patch, whatever order the peer sends; and the proxy rides tissue that moves
// under it (haptics/proxy.hpp, carry_proxy).

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <cmath>
#include <memory>
#include <random>
#include <vector>

#include "haptics/haptic_step.hpp"
#include "haptics/patch_bvh.hpp"
#include "haptics/proxy.hpp"
#include "malloc_guard.hpp"
#include "patch_sheet.hpp"

namespace lancet::haptics {
namespace {

constexpr double kR = 0.001;

// A wavy sheet z = h + a·sin(x/λ)·cos(y/λ) of n×n cells of `cell` metres about the origin (2n²
// triangles, outward +z), row by row; ids are the index + 1000 (not the index: the carry must go
// by id).
std::unique_ptr<TissuePatch> wavy_sheet(int n, float cell, float h = 0, float amplitude = 0.002f, Vec3 shift = {}) {
  auto p = std::make_unique<TissuePatch>();
  const float half = cell * static_cast<float>(n) / 2;
  const auto z = [&](float x, float y) { return h + amplitude * std::sin(x / 0.007f) * std::cos(y / 0.009f); };
  const auto v = [&](float x, float y) {
    return Vec3f{x + static_cast<float>(shift.x), y + static_cast<float>(shift.y), z(x, y) + static_cast<float>(shift.z)};
  };
  test::add_sheet(*p, n, n, -half, -half, cell, cell, v, 1, 1000);
  return p;
}

void shuffle_triangles(TissuePatch& p, unsigned seed) {
  std::mt19937 rng(seed);
  std::shuffle(p.triangles, p.triangles + p.n_triangles, rng);
}

HapticModel model(double k = 500) {
  HapticModel m = HapticModel::defaults();
  m.proxy_radius = kR;
  for (auto& mat : m.materials) {
    mat.stiffness = k;
    mat.damping = 0;
  }
  m.safety.max_force = 40;
  m.safety.max_slew = 0;
  m.safety.passivity = false;
  return m;
}

std::vector<std::uint32_t> plane_triangles(const ProxyScratch& s) {
  std::vector<std::uint32_t> t;
  for (std::size_t i = 0; i < s.n_planes; ++i) t.push_back(s.planes[i].triangle);
  std::sort(t.begin(), t.end());
  return t;
}

TEST(PatchBvh, EveryTriangleLiesInItsLeafAndEveryLeafInItsParents) {
  auto p = wavy_sheet(90, 0.001f);  // 16 200 triangles
  shuffle_triangles(*p, 3);
  p->triangles[17].v[1].x = std::numeric_limits<float>::quiet_NaN();  // left out of every box
  auto bvh = std::make_unique<PatchBvh>();
  build_patch_bvh(*bvh, *p, 7);
  EXPECT_EQ(bvh->version, 7u);
  EXPECT_EQ(bvh->first_leaf, kPatchLeaves);  // 2025 leaves: the 2048 row
  const auto inside = [](const PatchBvh::Box& b, Vec3f v) {
    return v.x >= b.lo.x && v.x <= b.hi.x && v.y >= b.lo.y && v.y <= b.hi.y && v.z >= b.lo.z && v.z <= b.hi.z;
  };
  for (std::uint32_t i = 0; i < p->n_triangles; ++i) {
    if (i == 17) continue;
    for (std::uint32_t node = bvh->first_leaf + i / kPatchLeafSize; node >= 1; node /= 2)
      for (const Vec3f& v : p->triangles[i].v) ASSERT_TRUE(inside(bvh->nodes[node], v)) << "triangle " << i << " node " << node;
  }
  for (const float c : {bvh->nodes[1].lo.x, bvh->nodes[1].hi.x}) EXPECT_TRUE(std::isfinite(c));
}

// The tree finds exactly the planes and the nearest triangles a scan finds, in a sheet sent in a
// neighbourly order and in a shuffled one (slower then, never wrong).
TEST(PatchBvh, QueriesEqualTheScanOfTheWholePatch) {
  for (const bool shuffled : {false, true}) {
    auto p = wavy_sheet(90, 0.001f);
    if (shuffled) shuffle_triangles(*p, 11);
    auto bvh = std::make_unique<PatchBvh>();
    build_patch_bvh(*bvh, *p, 1);
    auto a = std::make_unique<ProxyScratch>(), b = std::make_unique<ProxyScratch>();
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> xy(-0.05, 0.05), z(-0.004, 0.006), reach(0.0005, 0.008);
    int with_planes = 0;
    for (int q = 0; q < 400; ++q) {
      const Vec3 at{xy(rng), xy(rng), z(rng)};
      const double r = reach(rng);
      collect_planes(*p, bvh.get(), at, kR, r, *a);
      collect_planes(*p, nullptr, at, kR, r, *b);
      ASSERT_EQ(plane_triangles(*a), plane_triangles(*b)) << "query " << q << (shuffled ? " shuffled" : "");
      with_planes += a->n_planes > 0;
      Vec3 qa{}, qb{};
      const std::uint32_t na = nearest_triangle(*p, bvh.get(), at, r, qa), nb = nearest_triangle(*p, nullptr, at, r, qb);
      ASSERT_EQ(na, nb) << "query " << q;
      if (na < p->n_triangles) {
        EXPECT_EQ(norm(qa - qb), 0.0);
      }
    }
    EXPECT_GT(with_planes, 100) << "the queries must reach the sheet";
  }
}

// A random walk over and into the 16k sheet: the step through the tree (a patch version) gives
// the proxy and force of the step that scans every triangle (no version), tick by tick.
TEST(PatchBvh, RandomWalkGivesTheProxyOfTheScan) {
  for (const bool shuffled : {false, true}) {
    auto p = wavy_sheet(90, 0.001f);
    if (shuffled) shuffle_triangles(*p, 2);
    const HapticModel m = model();
    auto tree = std::make_unique<HapticData>(), scan = std::make_unique<HapticData>();
    HapticInput in{};
    in.patch = p.get();
    HapticOutput ot{}, os{};
    std::mt19937 rng(9);
    std::normal_distribution<double> step(0, 0.0004);
    Vec3 dev{0, 0, 0.005};
    int contact = 0;
    for (int t = 0; t < 3000; ++t) {
      dev = dev + Vec3{step(rng), step(rng), step(rng) - 0.00002};
      dev.x = std::clamp(dev.x, -0.03, 0.03), dev.y = std::clamp(dev.y, -0.03, 0.03), dev.z = std::clamp(dev.z, -0.006, 0.008);
      in.device = dev;
      in.patch_version = 1;
      haptic_step(m, *tree, in, ot);
      in.patch_version = 0;
      haptic_step(m, *scan, in, os);
      ASSERT_LT(norm(ot.proxy - os.proxy), 1e-12) << "tick " << t << (shuffled ? " shuffled" : "");
      ASSERT_LT(norm(ot.force - os.force), 1e-9) << "tick " << t;
      ASSERT_EQ(ot.contact, os.contact) << "tick " << t;
      contact += ot.contact;
    }
    EXPECT_GT(contact, 300) << "the walk must press the sheet";
  }
}

// More triangles within the step's reach than the planes hold (a 9 cm jump over a sheet of
// 0.5 mm cells): the step is shortened, the proxy still never ends up under the sheet, and the
// work stays bounded.
TEST(PatchBvh, AStepOverMoreTrianglesThanThePlanesHoldIsShortened) {
  auto p = wavy_sheet(90, 0.0005f, 0, 0.0005f);
  HapticModel m = model();
  for (auto& mat : m.materials) mat.friction_static = mat.friction_dynamic = 0;
  auto d = std::make_unique<HapticData>();
  HapticInput in{};
  in.patch = p.get();
  in.patch_version = 1;
  HapticOutput out{};
  in.device = {-0.02, -0.02, 0.003};
  haptic_step(m, *d, in, out);
  in.device = {0.02, 0.02, -0.003};  // through the sheet and across it in one tick
  for (int t = 0; t < 200; ++t) {
    haptic_step(m, *d, in, out);
    ASSERT_GT(out.proxy.z, 0.0005) << "tick " << t << ": the proxy went under the sheet";
  }
  EXPECT_GT(d->probe.scratch.shortened, 0u);
  EXPECT_TRUE(out.contact) << "the proxy reaches the surface over the device in the end";
  EXPECT_NEAR(out.proxy.x, 0.02, 1e-3);
}

// Ticks that build the tree for a newly arrived 16k patch, and every tick after, allocate nothing.
TEST(PatchBvh, NoAllocationWhenA16kPatchArrivesOrIsSearched) {
  auto p1 = wavy_sheet(90, 0.001f);
  auto p2 = wavy_sheet(90, 0.001f, 0.0005f);
  const HapticModel m = model();
  auto d = std::make_unique<HapticData>();
  HapticInput in{};
  HapticOutput out{};
  in.device = {0.001, 0.002, 0.004};
  in.patch = p1.get(), in.patch_version = 1;
  haptic_step(m, *d, in, out);
  test::MallocGuard guard;
  for (int t = 0; t < 300; ++t) {
    const bool second = (t / 30) % 2 == 1;
    in.patch = second ? p2.get() : p1.get();
    in.patch_version = 1 + static_cast<std::uint64_t>(t / 30);
    in.device = {0.001 + 1e-5 * t, 0.002, 0.001 - 1e-5 * t};
    haptic_step(m, *d, in, out);
  }
  EXPECT_EQ(guard.count(), 0u);
  EXPECT_TRUE(out.contact);
}

// ---- The riding proxy ----

struct Pressed {
  HapticModel m;
  std::unique_ptr<HapticData> d = std::make_unique<HapticData>();
  HapticInput in{};
  HapticOutput out{};
  std::uint64_t version = 0;
  const HapticOutput& step(const TissuePatch& p, bool new_version) {
    if (new_version) ++version;
    in.patch = &p;
    in.patch_version = version;
    haptic_step(m, *d, in, out);
    return out;
  }
};

// The sheet under a pressing tool moves 1 mm toward it. Carried with its triangle, the proxy stays
// on the surface and the force grows by k·1 mm, as the tissue pushes harder; left in world space
// (ride_max_move 0: today's proxy), it ends up under the moved sheet and the force drops to zero:
// the pop-through.
TEST(RidingProxy, TissueMovingTowardTheToolPushesHarderInsteadOfPoppingThrough) {
  for (const bool ride : {true, false}) {
    Pressed r{model(500)};
    if (!ride) r.m.ride_max_move = 0;
    auto flat = wavy_sheet(40, 0.001f, 0, 0);
    auto moved = wavy_sheet(40, 0.001f, 0.001f, 0);
    r.in.device = {0.0003, 0.0004, 0.004};
    r.step(*flat, true);
    for (int t = 1; t <= 20; ++t) {
      r.in.device.z = 0.004 - 0.006 * t / 20;  // 2 mm into the sheet
      r.step(*flat, false);
    }
    const Vec3 before = r.out.force;
    ASSERT_NEAR(before.z, 500 * (0.002 + kR), 1e-6);
    r.step(*moved, true);
    if (ride) {
      EXPECT_NEAR(r.out.force.z - before.z, 500 * 0.001, 1e-6) << "the force steps by exactly k·(1 mm)";
      EXPECT_NEAR(r.out.proxy.z, 0.001 + kR, 1e-9) << "the proxy rests on the moved surface";
      EXPECT_EQ(r.d->probe.carried, 1u);
    } else {
      EXPECT_EQ(r.out.force.z, 0) << "without riding the proxy is left under the surface";
      EXPECT_FALSE(r.out.contact);
    }
  }
}

// A sheet sliding sideways 1 mm per visualizer frame (33 ticks) under a tool held still: no
// tick's force differs from the last by more than k·(1 mm), contact is never lost, and the
// proxy travels with the sheet while static friction holds it, then slides in the friction cone.
TEST(RidingProxy, ASlidingSheetDragsTheProxyWithoutForceJumps) {
  Pressed r{model(500)};
  for (auto& mat : r.m.materials) mat.friction_static = 0.5, mat.friction_dynamic = 0.4;
  std::vector<std::unique_ptr<TissuePatch>> frames;
  for (int f = 0; f <= 6; ++f) frames.push_back(wavy_sheet(40, 0.001f, 0, 0, {0.001 * f, 0, 0}));
  r.in.device = {0.0002, 0.0001, 0.004};
  r.step(*frames[0], true);
  for (int t = 1; t <= 20; ++t) {
    r.in.device.z = 0.004 - 0.0065 * t / 20;
    r.step(*frames[0], false);
  }
  Vec3 last = r.out.force;
  double largest = 0;
  for (int f = 1; f <= 6; ++f) {
    for (int t = 0; t < 33; ++t) {
      r.step(*frames[static_cast<std::size_t>(f)], t == 0);
      ASSERT_TRUE(r.out.contact) << "frame " << f << " tick " << t << " carried " << r.d->probe.carried << " lost "
                                 << r.d->probe.carry_lost << " stage " << static_cast<int>(r.out.stage);
      largest = std::max(largest, norm(r.out.force - last));
      last = r.out.force;
    }
  }
  EXPECT_LE(largest, 500 * 0.001 * 1.02) << "largest force step " << largest << " N";
  EXPECT_GT(r.out.force.x, 0.5 * 500 * 0.001) << "the sheet drags the tool along +x; carried " << r.d->probe.carried
                                              << " lost " << r.d->probe.carry_lost << " proxy x " << r.out.proxy.x;
  EXPECT_EQ(r.d->probe.carried, 6u);
}

// Tissue rising 5 mm toward a tool held still, 0.25 mm a frame: the proxy stays on the surface
// all the way and the force grows with it; it never passes through.
TEST(RidingProxy, TissueRisingUnderAStillToolNeverPassesThrough) {
  Pressed r{model(300)};
  for (auto& mat : r.m.materials) mat.friction_static = mat.friction_dynamic = 0;  // one answer: the device's projection
  r.in.device = {0.0004, -0.0003, 0.0};
  std::vector<std::unique_ptr<TissuePatch>> frames;
  for (int f = 0; f <= 20; ++f) frames.push_back(wavy_sheet(40, 0.001f, -0.0025f + 0.00025f * static_cast<float>(f), 0.0015f));
  r.in.device.z = 0.004;
  r.step(*frames[0], true);
  for (int t = 1; t <= 30; ++t) {
    r.in.device.z = 0.004 - 0.0085 * t / 30;  // to 4.5 mm below the sheet's mid-plane
    r.step(*frames[0], false);
  }
  ASSERT_TRUE(r.out.contact);
  double previous = r.out.force.z;
  for (int f = 1; f <= 20; ++f) {
    r.step(*frames[static_cast<std::size_t>(f)], true);
    ASSERT_TRUE(r.out.contact) << "frame " << f << " carried " << r.d->probe.carried << " lost " << r.d->probe.carry_lost
                               << " proxy " << r.out.proxy.x << " " << r.out.proxy.y << " " << r.out.proxy.z;
    EXPECT_GE(r.out.force.z, previous) << "frame " << f;
    previous = r.out.force.z;
  }
  EXPECT_EQ(r.d->probe.carried, 20u);
  // The same force as a tool pressed from above into the risen sheet to the same place.
  Pressed fresh{r.m};
  fresh.in.device = {r.in.device.x, r.in.device.y, 0.008};
  fresh.step(*frames.back(), true);
  for (int t = 1; t <= 60; ++t) {
    fresh.in.device.z = 0.008 - (0.008 - r.in.device.z) * t / 60;
    fresh.step(*frames.back(), false);
  }
  EXPECT_LT(norm(r.out.force - fresh.out.force), 5e-3) << r.out.force.z << " vs " << fresh.out.force.z;
}

// A patch whose face ids name other faces (the triangle under the proxy is now far away) does not
// carry it: the carry is refused beyond ride_max_move and counted.
TEST(RidingProxy, AnIdThatNowNamesAFarTriangleIsNotFollowed) {
  Pressed r{model(500)};
  auto flat = wavy_sheet(40, 0.001f, 0, 0);
  auto renumbered = wavy_sheet(40, 0.001f, 0, 0);
  // Each id now names the triangle ten rows (10 mm) further along y.
  const std::uint32_t n = renumbered->n_triangles, row = 2 * 40;
  for (std::uint32_t i = 0; i < n; ++i) renumbered->triangles[i].id = (i + n - 10 * row) % n + 1000;
  r.in.device = {0.0003, 0.0004, 0.004};
  r.step(*flat, true);
  for (int t = 1; t <= 20; ++t) {
    r.in.device.z = 0.004 - 0.006 * t / 20;
    r.step(*flat, false);
  }
  const Vec3 before = r.out.force;
  r.step(*renumbered, true);
  EXPECT_EQ(r.d->probe.carried, 0u);
  EXPECT_EQ(r.d->probe.carry_lost, 1u);
  EXPECT_LT(norm(r.out.force - before), 1e-9) << "the same surface, the proxy left where it was";
}

}  // namespace
}  // namespace lancet::haptics
