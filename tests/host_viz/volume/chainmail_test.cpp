// Enhanced ChainMail (host_viz/volume/chainmail.hpp): 1-D chains against their analytic result
// (compression, stretch, shear, pushed at an end and in the middle), every link valid after every
// step (checked here from positions and the material table, not by the module), anisotropy, each
// element processed once per step, groove width and V profile, memory that follows the deformed
// region (64³ = 512³ = 4096³ lattices), bounded large pushes, reset, air, bad arguments, the same
// links valid, moved elements and displacements (to 1e-6 of the spacing) as a straightforward
// reference implementation (random steps, grooves), a recorded groove, and the same displacements,
// bit for bit, as a ChainMail whose step counter did not wrap (the same input, the same output).

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <limits>
#include <queue>
#include <utility>
#include <stdexcept>
#include <string>
#include <vector>

#include "volume/chainmail.hpp"
#include "chainmail_reference.hpp"

namespace lancet::volume {
namespace {

using Index = ChainMail::Index;
constexpr double kS = 1e-3;      // m, lattice spacing of most tests
constexpr double kTol = 1e-12;   // m

ChainMailLattice lattice(int nx, int ny, int nz, Vec3 spacing = {kS, kS, kS}) {
  return {{nx, ny, nz}, spacing, {-0.01, 0.02, -0.03}};
}

double axis_of(const Vec3& v, int a) { return a == 0 ? v.x : (a == 1 ? v.y : v.z); }

// The largest amount by which any link of the whole lattice breaks its limits (mean of both
// materials' limits), computed from positions alone. `where` names the worst link.
double worst_link(const ChainMail& cm, const std::vector<ChainMailMaterial>& mats, const std::vector<std::uint8_t>& ids,
                  std::string* where = nullptr) {
  const auto& d = cm.lattice().dims;
  const auto mat = [&](const Index& e) -> const ChainMailMaterial& {
    if (ids.empty()) return mats[0];
    return mats[ids[static_cast<std::size_t>(e[0] + d[0] * (e[1] + d[1] * e[2]))]];
  };
  double worst = 0;
  for (int k = 0; k < d[2]; ++k)
    for (int j = 0; j < d[1]; ++j)
      for (int i = 0; i < d[0]; ++i)
        for (int a = 0; a < 3; ++a) {
          const Index e{i, j, k};
          if (!cm.linked(e, a)) continue;
          Index n = e;
          ++n[static_cast<std::size_t>(a)];
          const ChainMailAxisLimits& A = mat(e).axis[static_cast<std::size_t>(a)];
          const ChainMailAxisLimits& B = mat(n).axis[static_cast<std::size_t>(a)];
          const double lo = 0.5 * (A.min_length + B.min_length), hi = 0.5 * (A.max_length + B.max_length);
          const double shear = 0.5 * (A.max_shear + B.max_shear);
          const Vec3 dv = cm.position(n) - cm.position(e);
          double excess = std::max(lo - axis_of(dv, a), axis_of(dv, a) - hi);
          for (int b = 0; b < 3; ++b)
            if (b != a) excess = std::max(excess, std::abs(axis_of(dv, b)) - shear);
          if (excess > worst) {
            worst = excess;
            if (where != nullptr)
              *where = "link (" + std::to_string(i) + "," + std::to_string(j) + "," + std::to_string(k) + ") axis " + std::to_string(a);
          }
        }
  return worst;
}

// ---------------------------------------------------------------------------------------------
// 1-D chains: element n moves by max(0, P − n·allowance), allowance = spacing − min (compression),
// max − spacing (stretch) or max_shear (shear).

struct Chain {
  std::vector<ChainMailMaterial> mats;
  ChainMail cm;
  explicit Chain(int n)
      : mats{ChainMailMaterial{true, {{{0.8 * kS, 1.3 * kS, 0.1 * kS}, {0.5 * kS, 1.5 * kS, 0.5 * kS}, {0.5 * kS, 1.5 * kS, 0.5 * kS}}}}},
        cm(lattice(n, 1, 1), mats) {}
};

TEST(ChainMail, ChainCompressionMatchesAnalytic) {
  Chain c(40);
  const double P = 2.5e-3, allowance = 0.2e-3;
  const ChainMailStepResult r = c.cm.move({0, 0, 0}, c.cm.rest_position({0, 0, 0}) + Vec3{P, 0, 0});
  int expected_moved = 0;
  for (int n = 0; n < 40; ++n) {
    const double expect = std::max(0.0, P - n * allowance);
    if (expect > 0) ++expected_moved;
    const Vec3 u = c.cm.displacement({n, 0, 0});
    EXPECT_NEAR(u.x, expect, kTol) << "element " << n;
    EXPECT_EQ(u.y, 0.0);
    EXPECT_EQ(u.z, 0.0);
  }
  EXPECT_EQ(expected_moved, 13);
  EXPECT_EQ(r.moved, 13u);
  EXPECT_EQ(r.processed, 13u);  // each element once; the first at rest is checked, never queued
  EXPECT_EQ(r.conflicts, 0u);
  EXPECT_LE(worst_link(c.cm, c.mats, {}), kTol);
}

TEST(ChainMail, ChainStretchMatchesAnalytic) {
  Chain c(40);
  const double P = 2.5e-3, allowance = 0.3e-3;
  const ChainMailStepResult r = c.cm.move({0, 0, 0}, c.cm.rest_position({0, 0, 0}) - Vec3{P, 0, 0});
  for (int n = 0; n < 40; ++n) EXPECT_NEAR(c.cm.displacement({n, 0, 0}).x, -std::max(0.0, P - n * allowance), kTol) << n;
  EXPECT_EQ(r.moved, 9u);  // 2.5 / 0.3 = 8.33: elements 0..8
  EXPECT_EQ(r.conflicts, 0u);
  EXPECT_LE(worst_link(c.cm, c.mats, {}), kTol);
}

TEST(ChainMail, ChainShearMatchesAnalytic) {
  Chain c(40);
  const double P = 1.05e-3, allowance = 0.1e-3;
  c.cm.move({0, 0, 0}, c.cm.rest_position({0, 0, 0}) + Vec3{0, P, -P});
  for (int n = 0; n < 40; ++n) {
    const Vec3 u = c.cm.displacement({n, 0, 0});
    EXPECT_NEAR(u.y, std::max(0.0, P - n * allowance), kTol) << n;
    EXPECT_NEAR(u.z, -std::max(0.0, P - n * allowance), kTol) << n;
    EXPECT_EQ(u.x, 0.0) << n;
  }
  EXPECT_LE(worst_link(c.cm, c.mats, {}), kTol);
}

TEST(ChainMail, ChainPushedInTheMiddleCompressesOneSideAndStretchesTheOther) {
  Chain c(41);
  const double P = 1.9e-3;
  const ChainMailStepResult r = c.cm.move({20, 0, 0}, c.cm.rest_position({20, 0, 0}) + Vec3{P, 0, 0});
  for (int n = 0; n < 41; ++n) {
    const double expect = n >= 20 ? std::max(0.0, P - (n - 20) * 0.2e-3) : std::max(0.0, P - (20 - n) * 0.3e-3);
    EXPECT_NEAR(c.cm.displacement({n, 0, 0}).x, expect, kTol) << n;
  }
  EXPECT_EQ(r.moved, 1u + 9u + 6u);
  EXPECT_EQ(r.conflicts, 0u);
}

// A second step continues from the first (ChainMail is plastic): pulling back the end element
// drags the chain by the stretch allowance.
TEST(ChainMail, SecondStepStartsFromTheFirst) {
  Chain c(40);
  c.cm.move({0, 0, 0}, c.cm.rest_position({0, 0, 0}) + Vec3{2.5e-3, 0, 0});
  c.cm.move({0, 0, 0}, c.cm.rest_position({0, 0, 0}));
  for (int n = 0; n < 40; ++n) {
    const double pushed = std::max(0.0, 2.5e-3 - n * 0.2e-3);
    const double expect = std::min(pushed, n * 0.3e-3);  // at most n stretch allowances behind element 0
    EXPECT_NEAR(c.cm.displacement({n, 0, 0}).x, expect, kTol) << n;
  }
  EXPECT_LE(worst_link(c.cm, c.mats, {}), kTol);
}

// The step counter wraps after 2^32 − 1 steps: every mark's step is cleared and counting starts
// again at 1. A ChainMail told it has made 2^32 − 2 steps makes the step tagged 2^32 − 1, then
// wraps; every step, before and after, gives the same displacements (bit for bit) and counts as a
// ChainMail that counted from 0. The first step moves two regions (around a and d) that nothing
// touches again until the wrap: its marks are still there then. The wrap's step (step 1 again)
// goes back to a, where marks left at step 1 would read as settled had the wrap not cleared them;
// the step after it goes back to d, where a counter that ran on past 2^32 − 1 instead of wrapping
// would tag its step like step 1 (the tag keeps the counter's low 32 bits).
TEST(ChainMail, AStepCounterThatWrapsGivesTheSameDisplacements) {
  const std::vector<ChainMailMaterial> mats{ChainMailMaterial::relative({kS, kS, kS}, 0.3, 0.3, 0.3)};
  ChainMail plain(lattice(32, 32, 32), mats), wrapped(lattice(32, 32, 32), mats);
  const Index a{6, 6, 6}, d{6, 25, 25}, b{25, 25, 25}, c{16, 14, 18};
  const std::vector<std::vector<ChainMailSponsor>> steps{
      {{a, Vec3{1.2e-3, -0.8e-3, 0.5e-3}}, {d, Vec3{0.9e-3, 1.0e-3, -0.7e-3}}},  // 1: around a and d
      {{b, Vec3{-1.0e-3, 0.7e-3, 0.9e-3}}},                                      // 2^32 − 1: around b only
      {{a, Vec3{-0.9e-3, 1.1e-3, -0.6e-3}}},                                     // the wrap, step 1 again: a
      {{d, Vec3{-0.5e-3, -1.2e-3, 0.8e-3}}},                                     // step 2: d
      {{b, Vec3{0.4e-3, -1.3e-3, 0.2e-3}}, {c, Vec3{0.8e-3, 0.8e-3, -1.5e-3}}},  // two sponsors
      {{a, Vec3{}}},                                                             // a back to rest
      {{c, Vec3{-2.5e-3, 0.3e-3, 1.0e-3}}},                                      // a large push
  };
  std::vector<std::pair<Index, Vec3>> first;  // what the first step displaced, and by how much
  for (std::size_t s = 0; s < steps.size(); ++s) {
    if (s == 1) wrapped.set_steps_made_for_testing(0xFFFFFFFEu);
    std::vector<ChainMailSponsor> sp = steps[s];
    for (ChainMailSponsor& x : sp) x.position += plain.rest_position(x.element);
    const ChainMailStepResult want = plain.move(sp), got = wrapped.move(sp);
    const std::string what = "step " + std::to_string(s);
    EXPECT_EQ(got.processed, want.processed) << what;
    EXPECT_EQ(got.moved, want.moved) << what;
    EXPECT_EQ(got.conflicts, want.conflicts) << what;
    EXPECT_EQ(got.materialised, want.materialised) << what;
    EXPECT_EQ(want.conflicts, 0u) << what;
    EXPECT_GT(want.moved, 0u) << what;
    std::size_t differ = 0;
    for (int k = 0; k < 32; ++k)
      for (int j = 0; j < 32; ++j)
        for (int i = 0; i < 32; ++i) {
          const Vec3 w = plain.displacement({i, j, k}), g = wrapped.displacement({i, j, k});
          if (!(w == g) && ++differ <= 3)
            ADD_FAILURE() << what << ": element (" << i << "," << j << "," << k << ") at (" << g.x << "," << g.y << "," << g.z
                          << "), without the wrap (" << w.x << "," << w.y << "," << w.z << ")";
        }
    EXPECT_EQ(differ, 0u) << what;
    if (s == 0)
      plain.for_each_materialised([&](const Index& e, const Vec3& u) {
        if (!(u == Vec3{})) first.emplace_back(e, u);
      });
    if (s == 1) {  // the test can fail: b's step left the first step's regions (and marks) alone
      for (const auto& [e, u] : first) ASSERT_EQ(plain.displacement(e), u) << "b's step reached a's or d's region";
    }
  }
}

// ---------------------------------------------------------------------------------------------
// 3-D: validity, anisotropy, once per step, bounds.

// Three materials in layers with a blob of the third, anisotropic, and an air pocket.
struct Block {
  std::vector<ChainMailMaterial> mats;
  std::vector<std::uint8_t> ids;
  ChainMail cm;
  static std::vector<std::uint8_t> layout(int n) {
    std::vector<std::uint8_t> v(static_cast<std::size_t>(n * n * n));
    for (int k = 0; k < n; ++k)
      for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
          std::uint8_t m = k > n - 4 ? 1 : 2;  // skin on top, muscle below
          const int di = i - n / 3, dj = j - n / 2, dk = k - n / 3;
          if (di * di + dj * dj + dk * dk < 16) m = 3;  // a stiff blob
          if (i >= n - 3 && j < 3) m = 0;             // an air pocket at an edge
          v[static_cast<std::size_t>(i + n * (j + n * k))] = m;
        }
    return v;
  }
  explicit Block(int n)
      : mats{ChainMailMaterial::air(),
             ChainMailMaterial::relative({kS, kS, kS}, 0.3, 0.4, 0.3),
             ChainMailMaterial{true, {{{0.9 * kS, 1.1 * kS, 0.15 * kS}, {0.6 * kS, 1.5 * kS, 0.3 * kS}, {0.7 * kS, 1.2 * kS, 0.2 * kS}}}},
             ChainMailMaterial::relative({kS, kS, kS}, 0.05, 0.05, 0.05)},
        ids(layout(n)),
        cm(lattice(n, n, n), mats, ids) {}
};

TEST(ChainMail, EveryLinkValidAfterEveryStep) {
  Block b(24);
  std::uint64_t state = 12345;
  const auto next = [&]() {  // deterministic LCG in [0, 1)
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    return static_cast<double>(state >> 11) * 0x1.0p-53;
  };
  int steps = 0;
  for (int s = 0; s < 40; ++s) {
    const Index e{1 + static_cast<int>(next() * 21), 1 + static_cast<int>(next() * 21), 1 + static_cast<int>(next() * 21)};
    if (!b.cm.present(e)) continue;
    const Vec3 d{(next() - 0.5) * 6e-3, (next() - 0.5) * 6e-3, (next() - 0.5) * 6e-3};
    const ChainMailStepResult r = b.cm.move(e, b.cm.rest_position(e) + d);
    std::string where;
    const double worst = worst_link(b.cm, b.mats, b.ids, &where);
    EXPECT_EQ(r.conflicts, 0u) << "step " << s;
    EXPECT_LE(worst, kTol) << "step " << s << ": " << where;
    EXPECT_GT(r.moved, 0u);
    ++steps;
  }
  EXPECT_GT(steps, 30);
  // Air never moves and is never linked.
  EXPECT_FALSE(b.cm.present({23, 0, 5}));
  EXPECT_EQ(b.cm.displacement({23, 0, 5}), Vec3{});
  EXPECT_FALSE(b.cm.linked({20, 0, 5}, 0));
}

TEST(ChainMail, SeveralSponsorsInOneStep) {
  Block b(24);
  std::vector<ChainMailSponsor> s;
  for (int i = 6; i < 18; ++i) s.push_back({{i, 12, 23}, b.cm.rest_position({i, 12, 23}) + Vec3{0, 0, -2e-3}});
  const ChainMailStepResult r = b.cm.move(s);
  EXPECT_EQ(r.conflicts, 0u);
  EXPECT_LE(worst_link(b.cm, b.mats, b.ids), kTol);
  for (const ChainMailSponsor& sp : s) EXPECT_EQ(b.cm.position(sp.element), sp.position);
}

TEST(ChainMail, AnisotropicMaterialPropagatesDifferentlyAlongXAndZ) {
  // Compression allowance 0.1 s along x, 0.4 s along z; shear 0.5 s everywhere.
  const std::vector<ChainMailMaterial> mats{
      ChainMailMaterial{true, {{{0.9 * kS, 1.1 * kS, 0.5 * kS}, {0.9 * kS, 1.1 * kS, 0.5 * kS}, {0.6 * kS, 1.4 * kS, 0.5 * kS}}}}};
  const double P = 2e-3;
  const Index c{20, 20, 20};
  ChainMail along_x(lattice(41, 41, 41), mats), along_z(lattice(41, 41, 41), mats);
  const ChainMailStepResult rx = along_x.move(c, along_x.rest_position(c) + Vec3{P, 0, 0});
  const ChainMailStepResult rz = along_z.move(c, along_z.rest_position(c) + Vec3{0, 0, P});
  for (int n = 0; n <= 20; ++n) {
    EXPECT_NEAR(along_x.displacement({20 + n, 20, 20}).x, std::max(0.0, P - n * 0.1e-3), kTol) << n;
    EXPECT_NEAR(along_z.displacement({20, 20, 20 + n}).z, std::max(0.0, P - n * 0.4e-3), kTol) << n;
  }
  EXPECT_GT(along_x.displacement({39, 20, 20}).x, 0.0);  // reaches 19 elements along x
  EXPECT_EQ(along_z.displacement({20, 20, 26}).z, 0.0);  // 5 along z
  EXPECT_NE(rx.moved, rz.moved);
  EXPECT_EQ(rx.conflicts + rz.conflicts, 0u);
  EXPECT_LE(worst_link(along_x, mats, {}), kTol);
  EXPECT_LE(worst_link(along_z, mats, {}), kTol);
}

TEST(ChainMail, EachElementIsProcessedOncePerStep) {
  Block b(24);
  const Index e{12, 12, 12};
  const ChainMailStepResult r = b.cm.move(e, b.cm.rest_position(e) + Vec3{2e-3, -1.5e-3, 1e-3});
  std::uint64_t displaced = 0, coordinates = 0;
  b.cm.for_each_materialised([&](const Index&, const Vec3& u) {
    if (!(u == Vec3{})) ++displaced;
    coordinates += (u.x != 0 ? 1u : 0u) + (u.y != 0 ? 1u : 0u) + (u.z != 0 ? 1u : 0u);
  });
  EXPECT_EQ(r.moved, displaced);  // an element counted twice would show here
  // Each coordinate of each element is settled once (the sponsor, placed whole, counts once):
  // from rest every queued coordinate moves, so a coordinate settled twice would be counted twice.
  EXPECT_EQ(r.processed, coordinates - 2);
  EXPECT_GT(r.moved, 100u);
  EXPECT_LT(r.processed, 24u * 24u * 24u);
}

TEST(ChainMail, LargePushStaysBounded) {
  const std::vector<ChainMailMaterial> mats{ChainMailMaterial::relative({kS, kS, kS}, 0.2, 0.2, 0.2)};
  ChainMail cm(lattice(32, 32, 32), mats);
  const Vec3 P{0.2, -0.15, 0.1};  // 200, 150, 100 spacings: the whole block follows
  const Index e{16, 16, 31};
  const ChainMailStepResult r = cm.move(e, cm.rest_position(e) + P);
  EXPECT_EQ(r.conflicts, 0u);
  double worst = 0;
  cm.for_each_materialised([&](const Index&, const Vec3& u) {
    worst = std::max({worst, u.x - P.x, -u.x, P.y - u.y, u.y, u.z - P.z, -u.z});
    EXPECT_TRUE(is_finite(u));
  });
  EXPECT_LE(worst, kTol);
  EXPECT_EQ(r.moved, 32u * 32u * 32u);
  EXPECT_LE(worst_link(cm, mats, {}), 1e-11);
}

// ---------------------------------------------------------------------------------------------
// Against a straightforward reference (chainmail_reference.hpp), run from the same state.
//
// These tests compared displacements bit for bit, which held the order in which ChainMail takes
// its candidates fixed (largest violation first, exact to 1e-9 of the spacing, ties first in,
// first out). That order is a means, not what Enhanced ChainMail promises, and it ruled out the
// faster ways to reach the same result (a bucketed queue, settling several candidates at once). So
// a step is compared by what ChainMail must guarantee:
// - conflicts reported when, and only when, the reference reports them;
// - without conflicts: every link within its materials' compression, stretch and shear bounds (to
//   kTol, 1e-9 of the spacing: the module's tolerance), the same set of moved elements (an
//   element that one of them moved by less than kNearRef may be missing from the other's), and
//   every displacement within kNearRef of the reference's;
// - with conflicts the result depends on the order (the middle of disagreeing bounds), so only the
//   conflict itself is required. The same holds for a step from the invalid state a conflict
//   leaves: the links it repairs besides those its moves reach depend on the order (the
//   reference clamps every coordinate it takes to all its final neighbours, this implementation
//   moves a coordinate only as far as the neighbours that moved require); so the tests compare
//   steps from valid states, and the random steps start again from rest after a conflict.
// The reference then takes over the state under test, so each step is compared from the same state.
// (A recorded summary of one groove, RecordedTissueGroove below, catches a change in both.)
constexpr double kNearRef = 1e-9;  // m: 1e-6 of the 1 mm spacing

double max_abs_diff(const Vec3& a, const Vec3& b) { return std::max({std::abs(a.x - b.x), std::abs(a.y - b.y), std::abs(a.z - b.z)}); }

// Returns the number of elements displaced from rest after the step (by the reference).
std::size_t expect_equivalent(const ChainMail& cm, ChainMailReference& ref, const std::vector<Vec3>& before,
                              const ChainMailStepResult& got, const ChainMailStepResult& want, const std::string& what) {
  EXPECT_EQ(got.conflicts > 0, want.conflicts > 0) << what << ": conflicts " << got.conflicts << ", reference " << want.conflicts;
  std::size_t displaced = 0, differ = 0, moved_differ = 0, moved = 0;
  double worst = 0;
  for (std::size_t i = 0; i < ref.count(); ++i) {
    const Index e = ref.index_of(i);
    const Vec3 d = cm.displacement(e);
    displaced += ref.u[i] == Vec3{} ? 0u : 1u;
    moved += d == before[i] ? 0u : 1u;
    if (want.conflicts > 0 || !ref.valid) continue;
    const double diff = max_abs_diff(d, ref.u[i]);
    worst = std::max(worst, diff);
    if (diff > kNearRef && ++differ <= 3)
      ADD_FAILURE() << what << ": element (" << e[0] << "," << e[1] << "," << e[2] << ") at (" << d.x << "," << d.y << "," << d.z
                    << "), reference (" << ref.u[i].x << "," << ref.u[i].y << "," << ref.u[i].z << ")";
    const bool moved_here = !(d == before[i]), moved_there = !(ref.u[i] == before[i]);
    const bool tiny = std::max(max_abs_diff(d, before[i]), max_abs_diff(ref.u[i], before[i])) <= kNearRef;
    if (moved_here != moved_there && !tiny && ++moved_differ <= 3)
      ADD_FAILURE() << what << ": element (" << e[0] << "," << e[1] << "," << e[2] << ") moved " << moved_here << ", reference "
                    << moved_there;
  }
  EXPECT_EQ(got.moved, moved) << what << ": the step's count of moved elements";
  if (want.conflicts == 0 && ref.valid) {
    EXPECT_EQ(differ, 0u) << what << ": worst difference " << worst << " m";
    EXPECT_EQ(moved_differ, 0u) << what;
    std::string where;
    EXPECT_LE(worst_link(cm, ref.mats, ref.ids, &where), kTol) << what << ": " << where;
  }
  ref.valid = ref.valid && want.conflicts == 0;  // a conflict leaves links invalid, and later steps start from them
  ref.sync(cm);
  return displaced;
}

// One step of both, from the same state: the reference moves `sponsors`, the ChainMail under
// test makes `step` (by default the same move; open_groove for a groove, whose sponsors are the
// reference's `groove`).
std::size_t step_both(ChainMail& cm, ChainMailReference& ref, const std::vector<ChainMailSponsor>& sponsors, const std::string& what,
                      const std::function<ChainMailStepResult()>& step = {}) {
  const std::vector<Vec3> before = ref.u;
  const ChainMailStepResult want = ref.move(sponsors, cm);
  const ChainMailStepResult got = step ? step() : cm.move(sponsors);
  return expect_equivalent(cm, ref, before, got, want, what);
}

// Layered tissue (air, skin, fat, an anisotropic muscle) cut along a bent line and opened 4 mm, as
// the tissue scene cuts it.
struct TissueGroove {
  static constexpr double kWidth = 4e-3;  // m
  std::vector<ChainMailMaterial> mats{
      ChainMailMaterial::air(), ChainMailMaterial::relative({kS, kS, kS}, 0.2, 0.3, 0.3),
      ChainMailMaterial::relative({kS, kS, kS}, 0.4, 0.4, 0.4),
      ChainMailMaterial{true, {{{0.9 * kS, 1.1 * kS, 0.25 * kS}, {0.7 * kS, 1.3 * kS, 0.3 * kS}, {0.7 * kS, 1.3 * kS, 0.3 * kS}}}}};
  std::vector<std::uint8_t> ids = layers();
  ChainMail cm{lattice(48, 48, 24), mats, ids};
  ChainMailCut cut = cm.cut(line(cm.rest_position({0, 0, 0})), 12 * kS);
  ChainMailRetractor held{8 * kS, cut.length - 8 * kS, 0};

  static std::vector<std::uint8_t> layers() {
    std::vector<std::uint8_t> v(48u * 48u * 24u);
    for (int k = 0; k < 24; ++k)
      for (std::size_t p = 0; p < 48u * 48u; ++p)
        v[static_cast<std::size_t>(k) * 48u * 48u + p] = static_cast<std::uint8_t>(k > 20 ? 0 : (k > 18 ? 1 : (k > 12 ? 2 : 3)));
    return v;
  }
  static std::vector<Vec3> line(Vec3 o) { return {o + Vec3{6.3e-3, 20.2e-3, 0}, o + Vec3{24.1e-3, 27.4e-3, 0}, o + Vec3{41.5e-3, 22.2e-3, 0}}; }
};

TEST(ChainMail, MatchesAStraightforwardReferenceOnRandomSteps) {
  for (int seed = 1; seed <= 4; ++seed) {
    const int n = seed % 2 == 1 ? 24 : 29;
    Block b(n);
    ChainMailReference ref(b.cm, b.mats, b.ids);
    std::uint64_t state = 977u * static_cast<std::uint64_t>(seed);
    const auto next = [&]() {
      state = state * 6364136223846793005ull + 1442695040888963407ull;
      return static_cast<double>(state >> 11) * 0x1.0p-53;
    };
    std::size_t displaced = 0;
    int compared = 0, conflicted = 0;
    for (int s = 0; s < 25; ++s) {
      std::vector<ChainMailSponsor> sponsors;
      const int count = s % 4 == 3 ? 4 : 1;  // some steps with several sponsors (which may conflict)
      for (int q = 0; q < count; ++q) {
        const Index e{1 + static_cast<int>(next() * (n - 2)), 1 + static_cast<int>(next() * (n - 2)), 1 + static_cast<int>(next() * (n - 2))};
        const double amp = seed > 2 ? 12e-3 : 5e-3;
        const Vec3 d{(next() - 0.5) * amp, (next() - 0.5) * amp, (next() - 0.5) * amp};
        const bool dup = std::any_of(sponsors.begin(), sponsors.end(), [&](const ChainMailSponsor& x) { return x.element == e; });
        if (b.cm.present(e) && !dup) sponsors.push_back({e, b.cm.rest_position(e) + d});
      }
      if (sponsors.empty()) continue;
      compared += ref.valid ? 1 : 0;
      displaced = step_both(b.cm, ref, sponsors, "seed " + std::to_string(seed) + " step " + std::to_string(s));
      if (HasFailure()) return;
      if (!ref.valid) {  // a conflict: start again from rest
        b.cm.reset();
        ref.sync(b.cm);
        ref.valid = true;
        ++conflicted;
      }
    }
    EXPECT_GT(displaced, 100u);
    EXPECT_GT(compared, 20) << "seed " << seed;
    EXPECT_GT(conflicted + compared, 0);
    std::printf("seed %d: %d compared, %d conflicts\n", seed, compared, conflicted);
  }
}

TEST(ChainMail, GroovesMatchAStraightforwardReference) {
  const std::vector<ChainMailMaterial> mats{ChainMailMaterial::relative({kS, kS, kS}, 0.3, 0.3, 0.3)};
  int conflicted = 0;
  for (int variant = 0; variant < 3; ++variant) {
    ChainMail cm(lattice(64, 64, 16), mats);
    const Vec3 o = cm.rest_position({0, 0, 0});
    std::vector<Vec3> line;
    if (variant == 0) line = {o + Vec3{8.5e-3, 20.5e-3, 0}, o + Vec3{30.5e-3, 24.3e-3, 0}, o + Vec3{52.5e-3, 40.1e-3, 0}};
    if (variant == 1) line = {o + Vec3{8.3e-3, 10.2e-3, 0}, o + Vec3{8.3e-3, 10.2e-3, 0} + 50 * kS * normalized(Vec3{std::cos(0.5), std::sin(0.5), 0})};
    if (variant == 2) line = {o + Vec3{8.5e-3, 50.5e-3, 0}, o + Vec3{30.5e-3, 10.3e-3, 0}, o + Vec3{52.5e-3, 40.1e-3, 0}, o + Vec3{40.2e-3, 60.1e-3, 0}};
    const ChainMailCut cut = cm.cut(line, 9 * kS);
    ChainMailReference ref(cm, mats, {});
    const std::string what = "variant " + std::to_string(variant);
    // Open, widen, a push, then hold deeper (a wider groove than the floor allows: conflicts, but
    // for the straight cut of variant 1).
    const ChainMailRetractor first{10 * kS, cut.length - 10 * kS, 0}, deeper{5 * kS, cut.length - 5 * kS, 3 * kS};
    const auto groove = [&](double width, const ChainMailRetractor& r, const std::string& name) {
      step_both(cm, ref, ref.groove(cm, cut, width, r), what + " " + name, [&] { return cm.open_groove(cut, width, r); });
    };
    groove(2e-3, first, "open");
    groove(3.5e-3, first, "widen");
    const std::vector<ChainMailSponsor> push{{{30, 30, 15}, cm.rest_position({30, 30, 15}) + Vec3{1e-3, -2e-3, -3e-3}}};
    step_both(cm, ref, push, what + " push");
    groove(5e-3, deeper, "deeper");
    conflicted += ref.valid ? 0 : 1;
  }
  EXPECT_EQ(conflicted, 2);
  TissueGroove t;
  ChainMailReference ref(t.cm, t.mats, t.ids);
  const std::size_t displaced = step_both(t.cm, ref, ref.groove(t.cm, t.cut, t.kWidth, t.held), "tissue groove",
                                          [&] { return t.cm.open_groove(t.cut, t.kWidth, t.held); });
  EXPECT_GT(displaced, 1000u);
}

// A recorded summary of the tissue groove (made with the exact-order implementation of
// 2026-11-26, which matched the reference bit for bit): a change that moves the groove shows here
// even when the reference changes with it. Sums are over every element of the lattice; each
// displacement may drift by kNearRef (the tolerance of the reference tests), the sums by that
// times the elements moved. Update these figures only for a deliberate change of the result, and
// say why in the commit.
TEST(ChainMail, RecordedTissueGroove) {
  TissueGroove t;
  const ChainMailStepResult r = t.cm.open_groove(t.cut, t.kWidth, t.held);
  Vec3 sum{};
  double l1 = 0;
  for (int k = 0; k < 24; ++k)
    for (int j = 0; j < 48; ++j)
      for (int i = 0; i < 48; ++i) {
        const Vec3 u = t.cm.displacement({i, j, k});
        sum = sum + u;
        l1 += std::abs(u.x) + std::abs(u.y) + std::abs(u.z);
      }
  EXPECT_EQ(r.conflicts, 0u);
  EXPECT_EQ(r.moved, 1689u);
  const double drift = static_cast<double>(r.moved) * kNearRef;
  EXPECT_NEAR(sum.x, -0.0024319286597655281, drift);  // m
  EXPECT_NEAR(sum.y, 0.045473076197679915, drift);
  EXPECT_EQ(sum.z, 0.0);  // the groove opens in x-y only
  EXPECT_NEAR(l1, 1.2490525014981413, drift);
  // A face at the top (the opening, 2 mm a side) and one in the fat five layers below it (the
  // groove narrowing with depth).
  EXPECT_LE(max_abs_diff(t.cm.displacement({24, 28, 20}), Vec3{-0.00010727747609580972, 0.0021140272724119377, 0}), kNearRef);
  EXPECT_LE(max_abs_diff(t.cm.displacement({24, 27, 15}), Vec3{0, -0.00025013652270698439, 0}), kNearRef);
}

// ---------------------------------------------------------------------------------------------
// Cut and groove

struct GrooveSetup {
  std::vector<ChainMailMaterial> mats{ChainMailMaterial::relative({kS, kS, kS}, 0.3, 0.3, 0.25)};
  ChainMail cm{lattice(48, 24, 24), mats};
  // Along +x between rows j = 11 and 12: left (+y) is j = 12.
  std::vector<Vec3> line() const {
    const double y = cm.rest_position({0, 11, 0}).y + 0.5 * kS;
    return {{cm.rest_position({4, 0, 0}).x + 0.5 * kS, y, 0}, {cm.rest_position({43, 0, 0}).x + 0.5 * kS, y, 0}};
  }
};

TEST(ChainMail, CutUnlinksOnlyAcrossTheCut) {
  GrooveSetup g;
  const std::vector<Vec3> line = g.line();
  const ChainMailCut cut = g.cm.cut(line, 10 * kS);
  // Rows 11|12, elements i = 5..43, layers 13..23: 39 × 11 links.
  EXPECT_EQ(cut.links_removed, 39u * 11u);
  EXPECT_EQ(cut.faces.size(), 2u * 39u * 11u);
  EXPECT_NEAR(cut.length, 39 * kS, 1e-12);
  for (int k = 0; k < 24; ++k)
    for (int i = 0; i < 47; ++i) {
      const bool inside = i >= 5 && i <= 43 && k >= 13;
      EXPECT_EQ(g.cm.linked({i, 11, k}, 1), !inside) << i << " " << k;
      EXPECT_TRUE(g.cm.linked({i, 11, k}, 0));
      EXPECT_TRUE(g.cm.linked({i, 11, k}, 2) || k == 23);
    }
  for (const ChainMailCutFace& f : cut.faces) {
    EXPECT_EQ(f.side, f.element[1] == 12 ? 1 : -1);
    EXPECT_NEAR(f.away.y, f.side, 1e-12);
    EXPECT_NEAR(f.depth, (23 - f.element[2]) * kS, 1e-12);
  }
  EXPECT_EQ(g.cm.materialised_elements(), 6u * 1u * 2u * 512u);  // bricks: i 0..5, j 1 (rows 11 and 12), k 1..2
}

TEST(ChainMail, GrooveWidthEqualsWidthAndClosesWithDepth) {
  GrooveSetup g;
  const ChainMailCut cut = g.cm.cut(g.line(), 14 * kS);
  const double D = 3e-3, shear = 0.25e-3;
  // Held between 10 mm and 29 mm of arc: the groove can taper to closed before the cut's ends.
  const ChainMailStepResult r = g.cm.open_groove(cut, D, {10 * kS, 29 * kS, 0});
  EXPECT_EQ(r.conflicts, 0u);
  std::string where;
  EXPECT_LE(worst_link(g.cm, g.mats, {}, &where), kTol) << where;
  int checked = 0;
  for (int i = 15; i <= 33; ++i) {
    const double arc = (i - 4.5) * kS;
    if (arc < 10 * kS || arc > 29 * kS) continue;
    for (int m = 0; m <= 8; ++m) {
      const int k = 23 - m;
      const double width = (g.cm.position({i, 12, k}) - g.cm.position({i, 11, k})).y - kS;  // face-to-face
      EXPECT_NEAR(width, std::max(0.0, D - 2 * m * shear), 1e-12) << "i " << i << " level " << m;
      ++checked;
    }
  }
  EXPECT_EQ(checked, 19 * 9);
  // Each side moved only away from the cut.
  g.cm.for_each_materialised([&](const Index& e, const Vec3& u) {
    if (e[1] >= 12) {
      EXPECT_GE(u.y, 0.0);
    } else {
      EXPECT_LE(u.y, 0.0);
    }
  });
  // Widening re-places the held faces; still valid.
  const ChainMailStepResult wider = g.cm.open_groove(cut, 4e-3, {10 * kS, 29 * kS, 0});
  EXPECT_EQ(wider.conflicts, 0u);
  EXPECT_NEAR((g.cm.position({20, 12, 23}) - g.cm.position({20, 11, 23})).y - kS, 4e-3, 1e-12);
  EXPECT_LE(worst_link(g.cm, g.mats, {}), kTol);
}

TEST(ChainMail, GrooveHeldOverTheWholeDepthIsRectangular) {
  // A stretchy, shear-tolerant material whose floor can open 2 mm: the retractor holds the faces
  // over the whole depth, so the width is the same on every layer of the cut.
  const std::vector<ChainMailMaterial> mats{ChainMailMaterial::relative({kS, kS, kS}, 0.5, 1.0, 0.6)};
  ChainMail cm(lattice(40, 20, 20), mats);
  const double y = cm.rest_position({0, 9, 0}).y + 0.5 * kS;
  const std::vector<Vec3> line{{cm.rest_position({3, 0, 0}).x + 0.5 * kS, y, 0}, {cm.rest_position({36, 0, 0}).x + 0.5 * kS, y, 0}};
  const ChainMailCut cut = cm.cut(line, 6 * kS);
  const double D = 2e-3;
  const ChainMailStepResult r = cm.open_groove(cut, D, {6 * kS, cut.length - 6 * kS, 6 * kS});
  EXPECT_EQ(r.conflicts, 0u);
  EXPECT_LE(worst_link(cm, mats, {}), kTol);
  for (int k = 13; k <= 19; ++k)
    EXPECT_NEAR((cm.position({20, 10, k}) - cm.position({20, 9, k})).y - kS, D, 1e-12) << k;
  // The floor (not cut) opens less.
  EXPECT_LT((cm.position({20, 10, 12}) - cm.position({20, 9, 12})).y - kS, D);
}

TEST(ChainMail, DiagonalGrooveWidthEqualsWidthAcrossEveryHeldLink) {
  const std::vector<ChainMailMaterial> mats{ChainMailMaterial::relative({kS, kS, kS}, 0.3, 0.3, 0.3)};
  ChainMail cm(lattice(64, 64, 16), mats);
  const Vec3 a = cm.rest_position({8, 10, 0}) + Vec3{0.3 * kS, 0.2 * kS, 0};
  const Vec3 dir = normalized(Vec3{std::cos(0.5), std::sin(0.5), 0});
  const Vec3 b = a + 50 * kS * dir;
  const std::vector<Vec3> line{a, b};
  const ChainMailCut cut = cm.cut(line, 8 * kS);
  const double D = 2.5e-3;
  const ChainMailStepResult r = cm.open_groove(cut, D, {12 * kS, 38 * kS, 0});
  EXPECT_EQ(r.conflicts, 0u);
  EXPECT_LE(worst_link(cm, mats, {}), kTol);
  const Vec3 left{-dir.y, dir.x, 0};
  int held_links = 0;
  for (const ChainMailCutFace& f : cut.faces) {
    if (f.side != 1 || f.element[2] != 15 || f.arc < 12 * kS || f.arc > 38 * kS) continue;
    // The right side is toward +x and −y: its removed links go to (i + 1, j) and (i, j − 1).
    for (int axis = 0; axis < 2; ++axis) {
      Index o = f.element;
      o[static_cast<std::size_t>(axis)] += axis == 0 ? 1 : -1;
      if (axis == 0 ? cm.linked(f.element, 0) : cm.linked(o, 1)) continue;
      const auto other = std::find_if(cut.faces.begin(), cut.faces.end(), [&](const ChainMailCutFace& x) { return x.element == o; });
      ASSERT_NE(other, cut.faces.end());
      if (other->arc < 12 * kS || other->arc > 38 * kS) continue;
      const double opening = dot(cm.displacement(f.element) - cm.displacement(o), left);
      EXPECT_NEAR(opening, D, 1e-12);
      ++held_links;
    }
  }
  EXPECT_GT(held_links, 20);
}

TEST(ChainMail, BentPolylineGrooveIsValid) {
  const std::vector<ChainMailMaterial> mats{ChainMailMaterial::relative({kS, kS, kS}, 0.3, 0.3, 0.3)};
  ChainMail cm(lattice(64, 64, 16), mats);
  const Vec3 o = cm.rest_position({0, 0, 0});
  const std::vector<Vec3> line{o + Vec3{8.5e-3, 20.5e-3, 0}, o + Vec3{30.5e-3, 24.3e-3, 0}, o + Vec3{52.5e-3, 40.1e-3, 0}};
  const ChainMailCut cut = cm.cut(line, 9 * kS);
  const double D = 2e-3;
  const ChainMailStepResult r = cm.open_groove(cut, D, {10 * kS, cut.length - 10 * kS, 0});
  EXPECT_GT(r.moved, 100u);
  EXPECT_EQ(r.conflicts, 0u);
  EXPECT_LE(worst_link(cm, mats, {}), kTol);
  // Across every removed top-layer link in the held range (but 2 mm around the corner, where an
  // element can face both segments), the opening along the normal of the segment it crosses is D,
  // the corner's blended directions included.
  const double corner_arc = std::hypot(22e-3, 3.8e-3);
  int measured = 0;
  for (int j = 1; j < 63; ++j)
    for (int i = 0; i < 63; ++i)
      for (int axis = 0; axis < 2; ++axis) {
        const Index e{i, j, 15};
        const Index n{i + (axis == 0 ? 1 : 0), j + (axis == 1 ? 1 : 0), 15};
        if (cm.linked(e, axis)) continue;
        for (std::size_t g = 0; g + 1 < line.size(); ++g) {
          const Vec3 a = line[g], t = line[g + 1] - line[g];
          const auto side = [&](const Index& x) { const Vec3 p = cm.rest_position(x) - a; return t.x * p.y - t.y * p.x; };
          const double se = side(e), sn = side(n);
          if ((se >= 0) == (sn >= 0)) continue;
          const Vec3 cross_point = cm.rest_position(e) + (se / (se - sn)) * (cm.rest_position(n) - cm.rest_position(e));
          const double u = dot(cross_point - a, t) / dot(t, t);
          if (u < 0 || u > 1) continue;
          const double arc = (g == 0 ? 0 : corner_arc) + u * norm(t);
          // (An element's own arc is the mean over its removed links: keep clear of the held range's ends.)
          if (arc < 11.5 * kS || arc > cut.length - 11.5 * kS || std::abs(arc - corner_arc) < 2 * kS) continue;
          const Vec3 left = normalized(Vec3{-t.y, t.x, 0});
          const Vec3 opening = se >= 0 ? cm.displacement(e) - cm.displacement(n) : cm.displacement(n) - cm.displacement(e);
          EXPECT_NEAR(dot(opening, left), D, 1e-12) << "link " << i << "," << j << " axis " << axis;
          ++measured;
        }
      }
  EXPECT_GT(measured, 20);
  // The faces at the bend get the miter of both normals (longer than 1).
  bool mitred = false;
  for (const ChainMailCutFace& f : cut.faces) mitred = mitred || norm(f.away) > 1.0 + 1e-9;
  EXPECT_TRUE(mitred);
}

TEST(ChainMail, TooWideAGrooveReportsConflicts) {
  GrooveSetup g;
  const ChainMailCut cut = g.cm.cut(g.line(), 3 * kS);  // shallow: the floor must open too
  const ChainMailStepResult r = g.cm.open_groove(cut, 6e-3);  // held to the very ends
  EXPECT_GT(r.conflicts, 0u);
}

// A groove held to the very ends of its cut cannot open there without tearing: the elements past
// each end are pulled both ways (conflicts). How a conflict is settled depends on the order (see
// the reference tests above), but it must stay where the bounds disagree: the rest of the groove is
// the reference's, and the two sides, mirror images, are treated alike.
TEST(ChainMail, ConflictsAtAGroovesEndsStayThere) {
  const std::vector<ChainMailMaterial> mats{ChainMailMaterial::relative({kS, kS, kS}, 0.6, 1.5, 0.6)};  // the tissue scene's
  ChainMail cm(lattice(64, 40, 20), mats);
  const double y = cm.rest_position({0, 19, 0}).y + 0.5 * kS;  // between rows 19 and 20: the mirror of row j is 39 − j
  const std::vector<Vec3> line{{cm.rest_position({10, 0, 0}).x + 0.5 * kS, y, 0}, {cm.rest_position({50, 0, 0}).x + 0.5 * kS, y, 0}};
  const ChainMailCut cut = cm.cut(line, 6 * kS);
  ChainMailReference ref(cm, mats, {});
  const ChainMailStepResult want = ref.move(ref.groove(cm, cut, 4e-3, {}), cm), got = cm.open_groove(cut, 4e-3);
  EXPECT_GT(want.conflicts, 0u);
  EXPECT_GT(got.conflicts, 0u);
  double asymmetry = 0;
  std::size_t differ = 0, differ_inside = 0;
  for (int k = 0; k < 20; ++k)
    for (int i = 0; i < 64; ++i)
      for (int j = 0; j < 20; ++j) {
        const Vec3 a = cm.displacement({i, j, k}), b = cm.displacement({i, 39 - j, k});
        asymmetry = std::max({asymmetry, std::abs(a.x - b.x), std::abs(a.y + b.y), std::abs(a.z - b.z)});
        for (const Index& e : {Index{i, j, k}, Index{i, 39 - j, k}}) {
          if (max_abs_diff(cm.displacement(e), ref.u[ref.at(e)]) <= kNearRef) continue;
          ++differ;
          if (i >= 15 && i <= 45) ++differ_inside;  // 5 elements in from either end of the cut
        }
      }
  EXPECT_LE(asymmetry, kTol);
  EXPECT_EQ(differ_inside, 0u);
  EXPECT_LT(differ, 100u);  // of 51 200 elements, ~3 200 displaced
}

// ---------------------------------------------------------------------------------------------
// Memory

struct MemoryRun {
  std::size_t bytes;
  std::uint64_t materialised, moved;
};

MemoryRun groove_in(int n, double length_mm) {
  const std::vector<ChainMailMaterial> mats{ChainMailMaterial::relative({kS, kS, kS}, 0.3, 0.3, 0.25)};
  ChainMail cm({{n, n, n}, {kS, kS, kS}, {}}, mats);
  const double y = 20.5 * kS;
  const std::vector<Vec3> line{{10.5 * kS, y, 0}, {(10.5 + length_mm) * kS, y, 0}};
  const ChainMailCut cut = cm.cut(line, 12 * kS);
  const ChainMailStepResult r = cm.open_groove(cut, 3e-3, {8 * kS, cut.length - 8 * kS, 0});
  EXPECT_EQ(r.conflicts, 0u);
  return {cm.bytes_used(), cm.materialised_elements(), r.moved};
}

TEST(ChainMail, MemoryFollowsTheDeformedRegionNotTheVolume) {
  const MemoryRun small = groove_in(64, 40), large = groove_in(512, 40), huge = groove_in(4096, 40);
  EXPECT_EQ(small.bytes, large.bytes);
  EXPECT_EQ(small.bytes, huge.bytes);
  EXPECT_EQ(small.materialised, huge.materialised);
  EXPECT_EQ(small.moved, huge.moved);
  // A dense 4096³ lattice would need 69 G elements; this one holds a few bricks.
  EXPECT_LT(huge.bytes, std::size_t{8} << 20);
  EXPECT_LE(huge.materialised, 4 * huge.moved + 32 * 512);
  // Twice the cut, about twice the memory.
  const MemoryRun longer = groove_in(512, 80);
  const double ratio = static_cast<double>(longer.bytes) / static_cast<double>(large.bytes);
  EXPECT_GT(ratio, 1.5);
  EXPECT_LT(ratio, 2.5);
}

TEST(ChainMail, ResetRestoresRestAndReusesMemory) {
  GrooveSetup g;
  const ChainMailCut cut = g.cm.cut(g.line(), 14 * kS);
  const ChainMailStepResult first = g.cm.open_groove(cut, 3e-3, {10 * kS, 29 * kS, 0});
  const Vec3 probe = g.cm.displacement({20, 14, 21});
  const std::size_t bytes = g.cm.bytes_used();
  g.cm.reset();
  EXPECT_TRUE(g.cm.linked({20, 11, 23}, 1));
  g.cm.for_each_materialised([](const Index&, const Vec3& u) { EXPECT_EQ(u, Vec3{}); });
  const ChainMailCut again = g.cm.cut(g.line(), 14 * kS);
  const ChainMailStepResult second = g.cm.open_groove(again, 3e-3, {10 * kS, 29 * kS, 0});
  EXPECT_EQ(second.moved, first.moved);
  EXPECT_EQ(second.processed, first.processed);
  EXPECT_EQ(second.materialised, 0u);
  EXPECT_EQ(g.cm.displacement({20, 14, 21}), probe);
  EXPECT_EQ(g.cm.bytes_used(), bytes);
}

// ---------------------------------------------------------------------------------------------
// Bad arguments

template <class F>
std::string error_of(F&& f) {
  try {
    f();
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "(no std::invalid_argument)";
}

void expect_contains(const std::string& msg, const std::vector<std::string>& parts) {
  for (const std::string& p : parts) EXPECT_NE(msg.find(p), std::string::npos) << "'" << p << "' not in: " << msg;
}

TEST(ChainMail, BadParametersThrowNamingTheFieldAndValue) {
  const std::vector<ChainMailMaterial> ok{ChainMailMaterial::relative({kS, kS, kS}, 0.2, 0.2, 0.2)};
  std::vector<ChainMailMaterial> min_gt_max = ok;
  min_gt_max[0].axis[1] = {1.5e-3, 1.2e-3, 0};
  expect_contains(error_of([&] { ChainMail cm(lattice(4, 4, 4), min_gt_max); }),
                  {"materials[0].axis[1] (y)", "min_length = 0.0015", "max_length = 0.0012"});
  std::vector<ChainMailMaterial> rest_outside = ok;
  rest_outside[0].axis[2] = {1.1e-3, 1.2e-3, 0};
  expect_contains(error_of([&] { ChainMail cm(lattice(4, 4, 4), rest_outside); }), {"axis[2] (z)", "rest spacing 0.001"});
  std::vector<ChainMailMaterial> neg_shear = ok;
  neg_shear[0].axis[0].max_shear = -1e-4;
  expect_contains(error_of([&] { ChainMail cm(lattice(4, 4, 4), neg_shear); }), {"max_shear = -0.0001"});
  expect_contains(error_of([&] { ChainMail cm(lattice(4, 4, 4, {kS, -kS, kS}), ok); }), {"lattice.spacing.y = -0.001"});
  expect_contains(error_of([&] { ChainMail cm(lattice(4, 0, 4), ok); }), {"lattice.dims[1] = 0"});
  expect_contains(error_of([&] { ChainMail cm(lattice(4, 4, 4), {}); }), {"materials has 0 entries"});
  const std::vector<std::uint8_t> short_ids(10, 0), bad_ids(64, 3);
  expect_contains(error_of([&] { ChainMail cm(lattice(4, 4, 4), ok, short_ids); }), {"material_ids has 10 entries", "64"});
  expect_contains(error_of([&] { ChainMail cm(lattice(4, 4, 4), ok, bad_ids); }), {"material_ids[0] = 3"});

  ChainMail cm(lattice(8, 8, 8), ok);
  const std::vector<Vec3> one{{0, 0, 0}}, two{{0, 0, 0}, {1e-3, 0, 0}}, same{{1e-3, 1e-3, 0}, {1e-3, 1e-3, 0}};
  expect_contains(error_of([&] { (void)cm.cut(one, 1e-3); }), {"polyline has 1 point"});
  expect_contains(error_of([&] { (void)cm.cut(same, 1e-3); }), {"zero length"});
  expect_contains(error_of([&] { (void)cm.cut(two, -2e-3); }), {"depth = -0.002"});
  const ChainMailCut cut = cm.cut(two, 2e-3);
  expect_contains(error_of([&] { (void)cm.open_groove(cut, 0); }), {"width = 0"});
  expect_contains(error_of([&] { (void)cm.open_groove(cut, -1e-3); }), {"width = -0.001"});
  expect_contains(error_of([&] { (void)cm.open_groove(cut, 1e-3, {0, 1, -1}); }), {"retractor.depth = -1"});
  expect_contains(error_of([&] { (void)cm.move({8, 0, 0}, Vec3{}); }), {"(8, 0, 0)", "outside the lattice"});
  expect_contains(error_of([&] { (void)cm.move({1, 1, 1}, Vec3{std::nan(""), 0, 0}); }), {"not finite"});
  const std::vector<ChainMailSponsor> dup{{{1, 2, 3}, {}}, {{1, 2, 3}, {}}};
  expect_contains(error_of([&] { (void)cm.move(dup); }), {"(1, 2, 3)", "more than once"});
  // Nothing moved by the refused calls.
  cm.for_each_materialised([](const Index&, const Vec3& u) { EXPECT_EQ(u, Vec3{}); });
}

TEST(ChainMail, AirIsNotAnElement) {
  const std::vector<ChainMailMaterial> mats{ChainMailMaterial::relative({kS, kS, kS}, 0.2, 0.2, 0.2), ChainMailMaterial::air()};
  std::vector<std::uint8_t> ids(10 * 10 * 10, 0);
  for (int k = 5; k < 10; ++k)
    for (int j = 0; j < 10; ++j)
      for (int i = 0; i < 10; ++i) ids[static_cast<std::size_t>(i + 10 * (j + 10 * k))] = 1;  // air above k = 4
  ChainMail cm(lattice(10, 10, 10), mats, ids);
  EXPECT_FALSE(cm.present({5, 5, 5}));
  EXPECT_FALSE(cm.linked({5, 5, 4}, 2));
  expect_contains(error_of([&] { (void)cm.move({5, 5, 5}, Vec3{}); }), {"not present"});
  cm.move({5, 5, 4}, cm.rest_position({5, 5, 4}) + Vec3{0, 0, 3e-3});  // pulled up into the air: nothing above follows
  for (int k = 5; k < 10; ++k) EXPECT_EQ(cm.displacement({5, 5, k}), Vec3{});
  EXPECT_GT(cm.displacement({5, 5, 3}).z, 0.0);
  EXPECT_LE(worst_link(cm, mats, ids), kTol);
}

}  // namespace
}  // namespace lancet::volume
