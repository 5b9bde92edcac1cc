// The proxy builds its planes as the solve needs them (ProxyScratch::lazy): tick by tick, bit for
// bit, it steps as it did with every plane within reach built up front, over random walks into
// sheets flat, wavy and dense, convex and concave creases and corners, a closed box and a
// phantom-like sphere, with friction light and heavy, small steps and long jumps.

#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <functional>
#include <memory>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "haptics/haptic_step.hpp"
#include "haptics/proxy.hpp"
#include "lancet/shared_model/word_hasher.hpp"
#include "patch_sheet.hpp"

namespace lancet::haptics {
namespace {

constexpr double kR = 0.001;

// A sheet of n×n cells of `cell` metres about the origin, its height z(x, y).
std::unique_ptr<TissuePatch> sheet(int n, float cell, const std::function<float(float, float)>& z) {
  auto p = std::make_unique<TissuePatch>();
  const float half = cell * static_cast<float>(n) / 2;
  test::add_sheet(*p, n, n, -half, -half, cell, cell, [&](float x, float y) { return Vec3f{x, y, z(x, y)}; });
  return p;
}

// A UV sphere of radius `rad` about `centre`, outward normals, stacks × slices quads; its faces
// are no nearer the centre than inscribed_radius.
std::unique_ptr<TissuePatch> sphere(double rad, Vec3 centre, int stacks, int slices) {
  auto p = std::make_unique<TissuePatch>();
  const auto pt = [&](int i, int j) {
    const double th = std::numbers::pi * i / stacks, ph = 2 * std::numbers::pi * j / slices;
    return to_vec3f(centre + Vec3{rad * std::sin(th) * std::cos(ph), rad * std::sin(th) * std::sin(ph), rad * std::cos(th)});
  };
  const auto add = [&](Vec3f a, Vec3f b, Vec3f c) {
    p->triangles[p->n_triangles] = {{a, b, c}, 1, 0, p->n_triangles};
    ++p->n_triangles;
  };
  for (int i = 0; i < stacks; ++i)
    for (int j = 0; j < slices; ++j) {
      const Vec3f a = pt(i, j), b = pt(i + 1, j), c = pt(i + 1, j + 1), d = pt(i, j + 1);
      if (i != 0) add(a, b, d);
      if (i != stacks - 1) add(b, c, d);
    }
  return p;
}

// The least distance from `centre` to the planes of the patch's faces.
double inscribed_radius(const TissuePatch& p, Vec3 centre) {
  double r = 1e30;
  for (std::uint32_t i = 0; i < p.n_triangles; ++i) {
    const Vec3 a = to_vec3(p.triangles[i].v[0]), b = to_vec3(p.triangles[i].v[1]), c = to_vec3(p.triangles[i].v[2]);
    const Vec3 n = cross(b - a, c - a);
    if (dot(n, n) > 1e-30) r = std::min(r, std::abs(dot(normalized(n), a - centre)));
  }
  return r;
}

// A closed box [lo, hi] of quads split in two, outward normals, each face in k×k quads.
std::unique_ptr<TissuePatch> box(Vec3 lo, Vec3 hi, int k) {
  auto p = std::make_unique<TissuePatch>();
  // Face f: origin o, edges u, v (u × v outward).
  const Vec3 s = hi - lo;
  const Vec3 o[6] = {lo, lo, lo, {hi.x, lo.y, lo.z}, {lo.x, hi.y, lo.z}, {lo.x, lo.y, hi.z}};
  const Vec3 u[6] = {{0, s.y, 0}, {0, 0, s.z}, {s.x, 0, 0}, {0, s.y, 0}, {0, 0, s.z}, {s.x, 0, 0}};
  const Vec3 v[6] = {{s.x, 0, 0}, {0, s.y, 0}, {0, 0, s.z}, {0, 0, s.z}, {s.x, 0, 0}, {0, s.y, 0}};
  const auto f = [](Vec3 x) { return to_vec3f(x); };
  for (int face = 0; face < 6; ++face)
    for (int j = 0; j < k; ++j)
      for (int i = 0; i < k; ++i) {
        const auto at = [&](int a, int b) { return o[face] + (static_cast<double>(a) / k) * u[face] + (static_cast<double>(b) / k) * v[face]; };
        const Vec3f a = f(at(i, j)), b = f(at(i + 1, j)), c = f(at(i + 1, j + 1)), d = f(at(i, j + 1));
        p->triangles[p->n_triangles] = {{a, b, c}, 1, 0, p->n_triangles};
        p->triangles[p->n_triangles + 1] = {{a, c, d}, 1, 0, p->n_triangles + 1};
        p->n_triangles += 2;
      }
  return p;
}

HapticModel model(double mu_s, double mu_d) {
  HapticModel m = HapticModel::defaults();
  m.proxy_radius = kR;
  for (auto& mat : m.materials) {
    mat.stiffness = 500;
    mat.damping = 0;
    mat.friction_static = mu_s;
    mat.friction_dynamic = mu_d;
  }
  m.safety.max_force = 40;
  m.safety.max_slew = 0;
  m.safety.passivity = false;
  return m;
}

std::uint64_t state_hash(const HapticData& d) {
  WordHasher w;
  d.hash(w);
  return w.value();
}

bool same_bits(Vec3 a, Vec3 b) {
  return std::bit_cast<std::uint64_t>(a.x) == std::bit_cast<std::uint64_t>(b.x) &&
         std::bit_cast<std::uint64_t>(a.y) == std::bit_cast<std::uint64_t>(b.y) &&
         std::bit_cast<std::uint64_t>(a.z) == std::bit_cast<std::uint64_t>(b.z);
}

struct Walk {
  Vec3 start;       ///< where the device starts (outside the tissue)
  Vec3 toward;      ///< where it drifts to (inside)
  double step;      ///< m, the spread of a tick's step
  double jump;      ///< m, the spread of a jump every 40 ticks
  double box;       ///< m, it stays within ±box of `toward`
};

struct WalkResult {
  int contact = 0;
  std::uint64_t lazy_planes = 0, all_planes = 0;
};

// Steps a lazy and an eager proxy side by side (the tree's path: a patch version) and asserts
// that they agree to the bit; `outside` checks the proxy against the shape.
void walk_both(const TissuePatch& p, const HapticModel& m, const Walk& w, unsigned seed, int ticks, const std::string& what,
               WalkResult& r, const std::function<void(Vec3, int)>& outside = {}) {
  auto lazy = std::make_unique<HapticData>(), all = std::make_unique<HapticData>();
  all->probe.scratch.lazy = false;
  HapticInput in{};
  in.patch = &p;
  in.patch_version = 1;
  HapticOutput ol{}, oa{};
  std::mt19937 rng(seed);
  std::normal_distribution<double> step(0, w.step), jump(0, w.jump);
  Vec3 dev = w.start;
  r = WalkResult{};
  for (int t = 0; t < ticks; ++t) {
    const double spread = t % 40 == 39 ? 1 : 0;
    const Vec3 drift = 0.01 * (w.toward - dev);
    dev = dev + drift + Vec3{step(rng), step(rng), step(rng)} + spread * Vec3{jump(rng), jump(rng), jump(rng)};
    for (double* c : {&dev.x, &dev.y, &dev.z}) {
      const double centre = c == &dev.x ? w.toward.x : (c == &dev.y ? w.toward.y : w.toward.z);
      *c = std::clamp(*c, centre - w.box, centre + w.box);
    }
    in.device = dev;
    in.velocity = (1.0 / m.dt) * (drift);
    haptic_step(m, *lazy, in, ol);
    haptic_step(m, *all, in, oa);
    ASSERT_TRUE(same_bits(ol.proxy, oa.proxy)) << what << " tick " << t << ": proxy " << norm(ol.proxy - oa.proxy) << " m apart";
    ASSERT_TRUE(same_bits(ol.force, oa.force)) << what << " tick " << t;
    ASSERT_EQ(state_hash(*lazy), state_hash(*all)) << what << " tick " << t;
    ASSERT_EQ(ol.contact, oa.contact) << what << " tick " << t;
    ASSERT_TRUE(is_finite(ol.proxy) && is_finite(ol.force)) << what << " tick " << t;
    ASSERT_LE(norm(ol.force), m.safety.max_force * (1 + 1e-12)) << what << " tick " << t;
    if (outside) outside(ol.proxy, t);
    if (::testing::Test::HasFatalFailure()) return;
    r.contact += ol.contact;
    r.lazy_planes += lazy->probe.scratch.n_planes;
    r.all_planes += all->probe.scratch.n_planes;
  }
}

struct Mesh {
  std::string name;
  std::unique_ptr<TissuePatch> patch;
  Walk walk;
};

std::vector<Mesh> open_meshes() {
  std::vector<Mesh> m;
  const Walk down{{0, 0, 0.006}, {0, 0, -0.003}, 0.0003, 0.004, 0.012};
  m.push_back({"flat sheet, 1 mm cells", sheet(32, 0.001f, [](float, float) { return 0.0f; }), down});
  m.push_back({"wavy sheet", sheet(60, 0.001f, [](float x, float y) { return 0.002f * std::sin(x / 0.004f) * std::cos(y / 0.005f); }), down});
  m.push_back({"dense sheet, 0.5 mm cells, long jumps", sheet(90, 0.0005f, [](float x, float) { return 0.0005f * std::sin(x / 0.003f); }),
               Walk{{0, 0, 0.004}, {0, 0, -0.002}, 0.0003, 0.015, 0.02}});
  // Creases along x = 0 (a grid line) and corners at the origin (a grid point), steep and shallow.
  for (const float slope : {0.4f, 1.5f}) {
    const std::string s = slope > 1 ? " (steep)" : " (shallow)";
    m.push_back({"convex ridge" + s, sheet(40, 0.001f, [=](float x, float) { return -slope * std::abs(x); }), down});
    m.push_back({"concave valley" + s, sheet(40, 0.001f, [=](float x, float) { return slope * std::abs(x); }), down});
    m.push_back({"convex peak" + s, sheet(40, 0.001f, [=](float x, float y) { return -slope * std::max(std::abs(x), std::abs(y)); }), down});
    m.push_back({"concave pit" + s, sheet(40, 0.001f, [=](float x, float y) { return slope * std::max(std::abs(x), std::abs(y)); }), down});
  }
  return m;
}

TEST(ProxyPlanes, LazyPlanesStepLikeEveryPlaneOnSheetsCreasesAndCorners) {
  for (const auto& [mu_s, mu_d] : {std::pair{0.5, 0.3}, std::pair{0.0, 0.0}, std::pair{2.0, 1.5}}) {
    const HapticModel m = model(mu_s, mu_d);
    for (const Mesh& mesh : open_meshes()) {
      const std::string what = mesh.name + ", mu_s " + std::to_string(mu_s);
      for (unsigned seed : {1u, 2u}) {
        WalkResult r;
        walk_both(*mesh.patch, m, mesh.walk, seed, 1500, what, r);
        if (HasFatalFailure()) return;
        EXPECT_GT(r.contact, 300) << what << ": the walk must press the surface";
        EXPECT_LT(r.lazy_planes, r.all_planes) << what;
      }
    }
  }
}

// The flat sheet of the bench: the lazy proxy builds a small part of the planes within reach.
TEST(ProxyPlanes, OnAFlatSheetMostPlanesAreNeverBuilt) {
  auto p = sheet(32, 0.001f, [](float, float) { return 0.0f; });
  WalkResult r;
  walk_both(*p, model(0.5, 0.3), Walk{{0, 0, 0.005}, {0, 0, -0.002}, 0.0001, 0.0005, 0.01}, 3, 2000, "flat", r);
  ASSERT_FALSE(HasFatalFailure());
  EXPECT_GT(r.contact, 1500);
  EXPECT_LT(4 * r.lazy_planes, r.all_planes) << "lazy " << r.lazy_planes << ", all " << r.all_planes;
}

// Closed shapes, pressed from every side: a phantom-like sphere (5 cm across) and a box. The
// proxy also never gets into them (it stays a radius off every face, within 1 µm).
TEST(ProxyPlanes, LazyPlanesStepLikeEveryPlaneOnASphereAndABox) {
  const Vec3 c{0.01, -0.02, 0.005};
  auto ball = sphere(0.025, c, 32, 64);
  const double inner = inscribed_radius(*ball, c);
  auto cube = box(c - Vec3{0.01, 0.015, 0.008}, c + Vec3{0.01, 0.015, 0.008}, 8);
  const HapticModel m = model(0.5, 0.3);
  for (unsigned seed : {1u, 2u, 3u, 4u}) {
    // Start outside on a side the seed picks, drift to the centre.
    const double a = 1.7 * seed;
    const Vec3 out = c + 0.035 * Vec3{std::cos(a) * std::sin(1.1 * a), std::sin(a) * std::sin(1.1 * a), std::cos(1.1 * a)};
    const Walk w{out, c, 0.0004, 0.006, 0.04};
    WalkResult rb, rc;
    walk_both(*ball, m, w, seed, 1500, "sphere", rb, [&](Vec3 x, int t) {
      ASSERT_GE(norm(x - c), inner + kR - 1e-6) << "sphere tick " << t << ": the proxy got in";
    });
    ASSERT_FALSE(HasFatalFailure());
    EXPECT_GT(rb.contact, 300);
    const Vec3 lo = c - Vec3{0.01, 0.015, 0.008}, hi = c + Vec3{0.01, 0.015, 0.008};
    walk_both(*cube, m, w, seed, 1500, "box", rc, [&](Vec3 x, int t) {
      const Vec3 q{std::clamp(x.x, lo.x, hi.x), std::clamp(x.y, lo.y, hi.y), std::clamp(x.z, lo.z, hi.z)};
      ASSERT_GE(norm(x - q), kR - 1e-6) << "box tick " << t << ": the proxy got in";
    });
    ASSERT_FALSE(HasFatalFailure());
    EXPECT_GT(rc.contact, 300);
  }
}

}  // namespace
}  // namespace lancet::haptics
