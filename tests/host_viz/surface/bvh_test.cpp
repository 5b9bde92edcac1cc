// TriangleBvh (host_viz/surface/bvh.hpp): closest point on a triangle against dense sampling in
// all seven Voronoi regions; the watertight segment–triangle test; the tree's queries against
// brute force over every face on random meshes (a wavy grid, an overlapping triangle soup, a
// closed sphere) after build, after local refits of moved and reconnected faces and after full
// refits; segments through vertices and edges; zero-area triangles; empty meshes; and queries and
// refits that never allocate. Link lancet::test_support (MallocGuard).

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <map>
#include <random>
#include <set>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "malloc_guard.hpp"
#include "surface/bvh.hpp"

namespace lancet::surface {
namespace {

using Face = std::array<std::uint32_t, 3>;

struct Mesh {
  std::vector<float> xyz;
  std::vector<Face> faces;

  [[nodiscard]] MeshView view() const { return {xyz.data(), xyz.size() / 3, faces}; }
  [[nodiscard]] std::uint32_t n_vertices() const { return static_cast<std::uint32_t>(xyz.size() / 3); }
  [[nodiscard]] Vec3f v(std::uint32_t i) const { return {xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]}; }
  void set(std::uint32_t i, Vec3f p) {
    xyz[3 * i] = p.x;
    xyz[3 * i + 1] = p.y;
    xyz[3 * i + 2] = p.z;
  }
  std::uint32_t add(Vec3f p) {
    xyz.insert(xyz.end(), {p.x, p.y, p.z});
    return n_vertices() - 1;
  }
  [[nodiscard]] std::array<Vec3f, 3> corners(std::uint32_t f) const {
    return {v(faces[f][0]), v(faces[f][1]), v(faces[f][2])};
  }
  // Faces around each vertex.
  [[nodiscard]] std::vector<std::vector<std::uint32_t>> vertex_faces() const {
    std::vector<std::vector<std::uint32_t>> vf(n_vertices());
    for (std::uint32_t f = 0; f < faces.size(); ++f)
      for (std::uint32_t vi : faces[f]) vf[vi].push_back(f);
    return vf;
  }
};

Vec3f add(Vec3f a, Vec3f b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
Vec3f sub(Vec3f a, Vec3f b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
Vec3f scale(float s, Vec3f a) { return {s * a.x, s * a.y, s * a.z}; }
double dist(Vec3f a, Vec3f b) { return norm(to_vec3(a) - to_vec3(b)); }

// n × n cells, 2 triangles each, over [-h, h]² at z = a·sin(x/L)·cos(y/L), vertices jittered in
// the plane by up to `jitter` of a cell.
Mesh wavy_grid(int n, float h = 0.1f, float amplitude = 0.01f, float jitter = 0.3f, unsigned seed = 1) {
  Mesh m;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> j(-jitter, jitter);
  const float cell = 2 * h / static_cast<float>(n);
  for (int y = 0; y <= n; ++y)
    for (int x = 0; x <= n; ++x) {
      const bool inner = x > 0 && x < n && y > 0 && y < n;
      const float px = -h + cell * (static_cast<float>(x) + (inner ? j(rng) : 0.0f));
      const float py = -h + cell * (static_cast<float>(y) + (inner ? j(rng) : 0.0f));
      m.add({px, py, amplitude * std::sin(px / 0.03f) * std::cos(py / 0.02f)});
    }
  const auto id = [n](int x, int y) { return static_cast<std::uint32_t>(y * (n + 1) + x); };
  for (int y = 0; y < n; ++y)
    for (int x = 0; x < n; ++x) {
      m.faces.push_back({id(x, y), id(x + 1, y), id(x + 1, y + 1)});
      m.faces.push_back({id(x, y), id(x + 1, y + 1), id(x, y + 1)});
    }
  return m;
}

// Random triangles in a 20 cm cube: sizes from 0.1 mm to 3 cm, some slivers, overlapping.
Mesh soup(int n, unsigned seed) {
  Mesh m;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-0.1f, 0.1f), e(-1.0f, 1.0f);
  std::uniform_real_distribution<float> logsize(std::log(1e-4f), std::log(0.03f));
  for (int i = 0; i < n; ++i) {
    const Vec3f c{u(rng), u(rng), u(rng)};
    const float s = std::exp(logsize(rng));
    const auto a = m.add(add(c, Vec3f{s * e(rng), s * e(rng), s * e(rng)}));
    const auto b = m.add(add(c, Vec3f{s * e(rng), s * e(rng), s * e(rng)}));
    Vec3f pc{s * e(rng), s * e(rng), s * e(rng)};
    if (i % 10 == 0) pc = scale(0.5f, add(sub(m.v(a), c), sub(m.v(b), c)));  // nearly collinear
    const auto cc = m.add(add(c, pc));
    m.faces.push_back({a, b, cc});
  }
  return m;
}

// Icosahedron subdivided `levels` times, on a sphere of radius r (closed, outward faces).
Mesh icosphere(int levels, float r) {
  Mesh m;
  const float t = (1.0f + std::sqrt(5.0f)) / 2.0f;
  const std::vector<Vec3f> base{{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
                                {0, -1, -t}, {0, 1, -t}, {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  const auto push = [&](Vec3f p) {
    const float k = r / static_cast<float>(norm(to_vec3(p)));
    return m.add(scale(k, p));
  };
  for (Vec3f p : base) push(p);
  m.faces = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
             {11, 10, 2}, {10, 7, 6}, {7, 1, 8},  {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
             {3, 8, 9},  {4, 9, 5},  {2, 4, 11}, {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
  for (int l = 0; l < levels; ++l) {
    std::map<std::pair<std::uint32_t, std::uint32_t>, std::uint32_t> mid;
    const auto midpoint = [&](std::uint32_t a, std::uint32_t b) {
      const auto key = std::minmax(a, b);
      const auto it = mid.find(key);
      if (it != mid.end()) return it->second;
      const std::uint32_t v = push(scale(0.5f, add(m.v(a), m.v(b))));
      mid.emplace(key, v);
      return v;
    };
    std::vector<Face> next;
    for (const Face& f : m.faces) {
      const auto a = midpoint(f[0], f[1]), b = midpoint(f[1], f[2]), c = midpoint(f[2], f[0]);
      next.push_back({f[0], a, c});
      next.push_back({f[1], b, a});
      next.push_back({f[2], c, b});
      next.push_back({a, b, c});
    }
    m.faces = std::move(next);
  }
  return m;
}

// ---- brute force over all faces -------------------------------------------------------------

double brute_closest(const Mesh& m, Vec3f p) {
  double best = std::numeric_limits<double>::infinity();
  for (std::uint32_t f = 0; f < m.faces.size(); ++f) {
    const auto c = m.corners(f);
    best = std::min(best, point_triangle_distance_squared(p, c[0], c[1], c[2]));
  }
  return std::sqrt(best);
}

std::vector<std::uint32_t> brute_within(const Mesh& m, Vec3f p, float r) {
  std::vector<std::uint32_t> out;
  for (std::uint32_t f = 0; f < m.faces.size(); ++f) {
    const auto c = m.corners(f);
    if (point_triangle_distance_squared(p, c[0], c[1], c[2]) <= double{r} * double{r}) out.push_back(f);
  }
  return out;
}

std::vector<std::pair<std::uint32_t, float>> brute_hits(const Mesh& m, Vec3f a, Vec3f b) {
  std::vector<std::pair<std::uint32_t, float>> out;
  for (std::uint32_t f = 0; f < m.faces.size(); ++f) {
    const auto c = m.corners(f);
    if (const auto h = segment_triangle(a, b, c[0], c[1], c[2])) out.emplace_back(f, h->t);
  }
  std::sort(out.begin(), out.end());
  return out;
}

// Compares every query with brute force at `queries` random points and segments around the mesh.
void expect_queries_match(const TriangleBvh& bvh, const Mesh& m, unsigned seed, int queries = 150) {
  const MeshView mv = m.view();
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-0.13f, 0.13f), radius(0.0f, 0.015f);
  std::vector<std::uint32_t> within;
  std::vector<SegmentHit> hits;
  int nonempty_within = 0, nonempty_hits = 0;
  for (int q = 0; q < queries; ++q) {
    // Points near a vertex of the mesh (so they are near the surface) and anywhere in the box.
    Vec3f p{u(rng), u(rng), u(rng)};
    if (q % 2 == 0 && m.n_vertices() > 0)
      p = add(m.v(static_cast<std::uint32_t>(rng() % m.n_vertices())), scale(0.05f, p));

    const double want = brute_closest(m, p);
    const auto hit = bvh.closest_point(mv, p);
    ASSERT_TRUE(hit.has_value());
    EXPECT_NEAR(hit->distance, want, 1e-7) << "query " << q;
    const auto c = m.corners(hit->face);
    EXPECT_NEAR(std::sqrt(point_triangle_distance_squared(p, c[0], c[1], c[2])), want, 1e-7);
    EXPECT_NEAR(dist(hit->point, p), want, 1e-6);
    // A bound below the distance finds nothing; one above finds the same distance.
    EXPECT_FALSE(bvh.closest_point(mv, p, static_cast<float>(want * 0.99)).has_value());
    const auto bounded = bvh.closest_point(mv, p, static_cast<float>(want * 1.01 + 1e-9));
    ASSERT_TRUE(bounded.has_value());
    EXPECT_NEAR(bounded->distance, want, 1e-7);

    const float r = radius(rng);
    bvh.faces_within(mv, p, r, within);
    EXPECT_EQ(within, brute_within(m, p, r)) << "query " << q << " r " << r;
    nonempty_within += !within.empty();

    const Vec3f a{u(rng), u(rng), u(rng)};
    const Vec3f b = q % 3 == 0 ? add(p, sub(p, a)) : Vec3f{u(rng), u(rng), u(rng)};
    const auto want_hits = brute_hits(m, a, b);
    bvh.segment_hits(mv, a, b, hits);
    std::vector<std::pair<std::uint32_t, float>> got;
    for (const SegmentHit& h : hits) got.emplace_back(h.face, h.t);
    EXPECT_TRUE(std::is_sorted(hits.begin(), hits.end(), [](const SegmentHit& x, const SegmentHit& y) { return x.t < y.t; }));
    std::sort(got.begin(), got.end());
    EXPECT_EQ(got, want_hits) << "query " << q;
    nonempty_hits += !hits.empty();
    const auto first = bvh.first_hit(mv, a, b);
    ASSERT_EQ(first.has_value(), !want_hits.empty());
    if (first) {
      float tmin = 2;
      for (const auto& [f, t] : want_hits) tmin = std::min(tmin, t);
      EXPECT_EQ(first->t, tmin);
    }
  }
  // The queries must exercise the non-empty paths.
  EXPECT_GT(nonempty_within, queries / 10);
  EXPECT_GT(nonempty_hits, queries / 10);
}

// ---- closest point on a triangle --------------------------------------------------------------

enum Region { kVertexA, kVertexB, kVertexC, kEdgeAB, kEdgeAC, kEdgeBC, kFace };

Region region_of(const PointHit& h) {
  constexpr float e = 1e-6f;
  const bool u0 = h.u <= e, v0 = h.v <= e, w0 = h.u + h.v >= 1 - e;
  if (u0 && v0) return kVertexA;
  if (v0 && w0) return kVertexB;
  if (u0 && w0) return kVertexC;
  if (v0) return kEdgeAB;
  if (u0) return kEdgeAC;
  if (w0) return kEdgeBC;
  return kFace;
}

// Smallest distance from p to (a, b, c) over an n-step barycentric grid.
double sampled_distance(Vec3f p, Vec3f a, Vec3f b, Vec3f c, int n) {
  const Vec3 A = to_vec3(a), AB = to_vec3(b) - A, AC = to_vec3(c) - A, P = to_vec3(p);
  double best = std::numeric_limits<double>::infinity();
  for (int i = 0; i <= n; ++i)
    for (int j = 0; i + j <= n; ++j) {
      const Vec3 q = A + (i / static_cast<double>(n)) * AB + (j / static_cast<double>(n)) * AC;
      best = std::min(best, norm(P - q));
    }
  return best;
}

void expect_matches_sampling(Vec3f p, Vec3f a, Vec3f b, Vec3f c, const PointHit& h) {
  constexpr int kSteps = 120;
  const double longest = std::max({dist(a, b), dist(a, c), dist(b, c)});
  const double sampled = sampled_distance(p, a, b, c, kSteps);
  // The exact answer is no farther than any sample, and some sample lies within one grid step.
  EXPECT_LE(h.distance, sampled + 1e-6 * (sampled + longest));
  EXPECT_GE(h.distance, sampled - longest / kSteps - 1e-6 * sampled - 1e-9);
  ASSERT_TRUE(std::isfinite(h.distance) && std::isfinite(h.u) && std::isfinite(h.v));
  EXPECT_GE(h.u, 0.0f);
  EXPECT_GE(h.v, 0.0f);
  EXPECT_LE(h.u + h.v, 1.0f + 1e-6f);
  // The point is where the barycentrics say, at the distance reported.
  const Vec3 q = to_vec3(a) + double{h.u} * (to_vec3(b) - to_vec3(a)) + double{h.v} * (to_vec3(c) - to_vec3(a));
  EXPECT_LT(norm(q - to_vec3(h.point)), 1e-6 * (longest + 1e-3));
  EXPECT_NEAR(dist(p, h.point), h.distance, 1e-6 * (h.distance + longest));
}

TEST(ClosestPointOnTriangle, MatchesDenseSamplingInAllSevenRegions) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-0.05f, 0.05f);
  std::array<int, 7> regions{};
  for (int k = 0; k < 300; ++k) {
    const Vec3f a{u(rng), u(rng), u(rng)}, b{u(rng), u(rng), u(rng)}, c{u(rng), u(rng), u(rng)};
    for (int i = 0; i < 12; ++i) {
      const Vec3f p{2 * u(rng), 2 * u(rng), 2 * u(rng)};
      const PointHit h = closest_point_on_triangle(p, a, b, c);
      expect_matches_sampling(p, a, b, c, h);
      ++regions[region_of(h)];
    }
  }
  for (int r = 0; r < 7; ++r) EXPECT_GE(regions[static_cast<std::size_t>(r)], 20) << "region " << r;
}

TEST(ClosestPointOnTriangle, EachRegionExactly) {
  const Vec3f a{0, 0, 0}, b{1, 0, 0}, c{0, 1, 0};
  struct Case {
    Vec3f p;
    Region region;
    Vec3f point;
    float u, v;
  };
  const Case cases[] = {
      {{-1, -1, 0.5f}, kVertexA, {0, 0, 0}, 0, 0},         {{2, -0.5f, 0}, kVertexB, {1, 0, 0}, 1, 0},
      {{-0.5f, 2, 1}, kVertexC, {0, 1, 0}, 0, 1},          {{0.5f, -1, 0.3f}, kEdgeAB, {0.5f, 0, 0}, 0.5f, 0},
      {{-1, 0.25f, -2}, kEdgeAC, {0, 0.25f, 0}, 0, 0.25f}, {{1, 1, 0}, kEdgeBC, {0.5f, 0.5f, 0}, 0.5f, 0.5f},
      {{0.2f, 0.3f, 0.7f}, kFace, {0.2f, 0.3f, 0}, 0.2f, 0.3f},
  };
  for (const Case& k : cases) {
    const PointHit h = closest_point_on_triangle(k.p, a, b, c);
    EXPECT_EQ(region_of(h), k.region) << k.p.x << " " << k.p.y << " " << k.p.z;
    EXPECT_LT(dist(h.point, k.point), 1e-6);
    EXPECT_NEAR(h.u, k.u, 1e-6);
    EXPECT_NEAR(h.v, k.v, 1e-6);
    EXPECT_NEAR(h.distance, dist(k.p, k.point), 1e-6);
  }
}

TEST(ClosestPointOnTriangle, ZeroAreaTrianglesAreTheirEdges) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-0.05f, 0.05f), s(-0.5f, 1.5f);
  for (int k = 0; k < 200; ++k) {
    const Vec3f a{u(rng), u(rng), u(rng)}, b{u(rng), u(rng), u(rng)};
    const Vec3f on_line = add(a, scale(s(rng), sub(b, a)));  // collinear, inside or outside ab
    const std::array<std::array<Vec3f, 3>, 4> tris{{{a, b, on_line}, {a, a, b}, {a, b, b}, {a, a, a}}};
    for (const auto& t : tris) {
      const Vec3f p{2 * u(rng), 2 * u(rng), 2 * u(rng)};
      const PointHit h = closest_point_on_triangle(p, t[0], t[1], t[2]);
      expect_matches_sampling(p, t[0], t[1], t[2], h);
      EXPECT_TRUE(std::isfinite(point_triangle_distance_squared(p, t[0], t[1], t[2])));
    }
  }
}

// ---- segment–triangle ---------------------------------------------------------------------

TEST(SegmentTriangle, CrossingsFromBothSidesAndMisses) {
  const Vec3f a{0, 0, 0}, b{1, 0, 0}, c{0, 1, 0};
  const auto down = segment_triangle({0.25f, 0.5f, 1}, {0.25f, 0.5f, -3}, a, b, c);
  ASSERT_TRUE(down.has_value());
  EXPECT_NEAR(down->t, 0.25f, 1e-7);
  EXPECT_NEAR(down->u, 0.25f, 1e-7);
  EXPECT_NEAR(down->v, 0.5f, 1e-7);
  EXPECT_LT(dist(down->point, {0.25f, 0.5f, 0}), 1e-7);
  const auto up = segment_triangle({0.25f, 0.5f, -1}, {0.25f, 0.5f, 1}, a, b, c);
  ASSERT_TRUE(up.has_value());
  EXPECT_NEAR(up->t, 0.5f, 1e-7);
  // Outside the triangle, short of it, past it, in its plane, zero length, zero-area triangles.
  EXPECT_FALSE(segment_triangle({0.75f, 0.75f, 1}, {0.75f, 0.75f, -1}, a, b, c));
  EXPECT_FALSE(segment_triangle({0.25f, 0.25f, 1}, {0.25f, 0.25f, 0.1f}, a, b, c));
  EXPECT_FALSE(segment_triangle({0.25f, 0.25f, -0.1f}, {0.25f, 0.25f, -1}, a, b, c));
  EXPECT_FALSE(segment_triangle({-1, 0.25f, 0}, {2, 0.25f, 0}, a, b, c));
  EXPECT_FALSE(segment_triangle({0.25f, 0.25f, 0}, {0.25f, 0.25f, 0}, a, b, c));
  EXPECT_FALSE(segment_triangle({0.5f, 0, 1}, {0.5f, 0, -1}, a, b, Vec3f{2, 0, 0}));
  EXPECT_FALSE(segment_triangle({0, 0, 1}, {0, 0, -1}, a, a, a));
  EXPECT_FALSE(segment_triangle({0.25f, 0, 1}, {0.25f, 0, -1}, a, b, Vec3f{0.5f, 0, 0}));  // through its line
  // Endpoints on the plane count (t = 0 and t = 1).
  EXPECT_TRUE(segment_triangle({0.25f, 0.25f, 0}, {0.25f, 0.25f, 1}, a, b, c));
  EXPECT_TRUE(segment_triangle({0.25f, 0.25f, 1}, {0.25f, 0.25f, 0}, a, b, c));
}

// ---- the tree -----------------------------------------------------------------------------

TEST(TriangleBvh, EmptyMesh) {
  Mesh m;
  TriangleBvh bvh;
  bvh.build(m.view());
  EXPECT_TRUE(bvh.check(m.view()));
  EXPECT_EQ(bvh.node_count(), 0u);
  EXPECT_EQ(bvh.depth(), 0u);
  bvh.refit(m.view());
  bvh.refit_faces(m.view(), {});
  std::vector<std::uint32_t> within{1, 2};
  bvh.faces_within(m.view(), {0, 0, 0}, 1.0f, within);
  EXPECT_TRUE(within.empty());
  EXPECT_FALSE(bvh.closest_point(m.view(), {0, 0, 0}));
  EXPECT_FALSE(bvh.first_hit(m.view(), {0, 0, -1}, {0, 0, 1}));
  std::vector<SegmentHit> hits(3);
  bvh.segment_hits(m.view(), {0, 0, -1}, {0, 0, 1}, hits);
  EXPECT_TRUE(hits.empty());
  // A tree built once and rebuilt empty is empty too.
  const Mesh g = wavy_grid(4);
  bvh.build(g.view());
  EXPECT_GT(bvh.node_count(), 0u);
  bvh.build(m.view());
  EXPECT_TRUE(bvh.check(m.view()));
  EXPECT_FALSE(bvh.closest_point(m.view(), {0, 0, 0}));
}

TEST(TriangleBvh, SingleFace) {
  Mesh m;
  m.add({0, 0, 0});
  m.add({0.01f, 0, 0});
  m.add({0, 0.01f, 0});
  m.faces.push_back({0, 1, 2});
  TriangleBvh bvh;
  bvh.build(m.view());
  EXPECT_TRUE(bvh.check(m.view()));
  EXPECT_EQ(bvh.depth(), 1u);
  const auto h = bvh.closest_point(m.view(), {0.002f, 0.002f, 0.005f});
  ASSERT_TRUE(h.has_value());
  EXPECT_EQ(h->face, 0u);
  EXPECT_NEAR(h->distance, 0.005f, 1e-8);
  const auto s = bvh.first_hit(m.view(), {0.002f, 0.002f, 0.005f}, {0.002f, 0.002f, -0.005f});
  ASSERT_TRUE(s.has_value());
  EXPECT_NEAR(s->t, 0.5f, 1e-6);
}

TEST(TriangleBvh, BuildIsConsistentOnAwkwardInputs) {
  std::vector<Mesh> meshes{wavy_grid(30), soup(3000, 3), icosphere(3, 0.05f)};
  // Every face the same triangle (all centroids coincide).
  Mesh same;
  same.add({0, 0, 0});
  same.add({1e-3f, 0, 0});
  same.add({0, 1e-3f, 0});
  for (int i = 0; i < 1000; ++i) same.faces.push_back({0, 1, 2});
  meshes.push_back(same);
  // Centroids spaced geometrically along x: SAH alone would build a chain.
  Mesh chain;
  for (int i = 0; i < 2000; ++i) {
    const float x = std::ldexp(1.0f, -(i % 120)) * (1.0f + static_cast<float>(i / 120) * 1e-3f);
    const auto a = chain.add({x, 0, 0});
    chain.add({x, 1e-3f, 0});
    chain.add({x, 0, 1e-3f});
    chain.faces.push_back({a, a + 1, a + 2});
  }
  meshes.push_back(chain);
  for (std::size_t i = 0; i < meshes.size(); ++i) {
    TriangleBvh bvh;
    bvh.build(meshes[i].view());
    EXPECT_TRUE(bvh.check(meshes[i].view())) << "mesh " << i;
    EXPECT_EQ(bvh.face_count(), meshes[i].faces.size());
    EXPECT_LE(bvh.depth(), TriangleBvh::kMaxDepth);
    EXPECT_GE(bvh.node_count(), 2 * ((meshes[i].faces.size() + 3) / 4) - 1);  // leaves hold ≤ 4 faces
    EXPECT_GT(bvh.size_bytes(), 0u);
  }
  // A balanced-ish tree on the grid: depth near log2(#F / 4).
  TriangleBvh bvh;
  bvh.build(meshes[0].view());
  EXPECT_LE(bvh.depth(), 20u);
}

TEST(TriangleBvh, QueriesMatchBruteForceOnAGrid) {
  const Mesh m = wavy_grid(40);
  TriangleBvh bvh;
  bvh.build(m.view());
  ASSERT_TRUE(bvh.check(m.view()));
  expect_queries_match(bvh, m, 21);
}

// A large mesh computes its Morton codes and leaf boxes on two threads: the same tree as one thread
// builds, node for node, and correct (its checks and queries).
TEST(TriangleBvh, TwoThreadsBuildTheSameTreeAsOne) {
  const Mesh m = wavy_grid(200);  // 80 000 faces: above the two-thread threshold
  ASSERT_GE(m.faces.size(), 65536u);
  TriangleBvh one, two;
  one.build(m.view(), false);
  two.build(m.view(), true);
  EXPECT_TRUE(one.same_tree(two));
  ASSERT_TRUE(two.check(m.view()));
  expect_queries_match(two, m, 24);
  // same_tree can fail: another mesh gives another tree.
  Mesh moved = m;
  moved.set(7, add(moved.v(7), {0, 0, 0.01f}));
  TriangleBvh three;
  three.build(moved.view(), true);
  EXPECT_FALSE(one.same_tree(three));
}

// Every answer of a lazily built tree, against the eager tree's (lazy = false) on the same mesh:
// the same faces in the same order (faces_in_boxes_within and faces_within's tree order give the
// leaves' order, which the patch export hands the servo), the same closest points and crossings.
void expect_same_answers(const TriangleBvh& lazy, const TriangleBvh& eager, const Mesh& m, Vec3f p, float r, Vec3f a, Vec3f b,
                         const std::string& where) {
  const MeshView mv = m.view();
  std::vector<std::uint32_t> x, y, scratch;
  lazy.faces_in_boxes_within(mv, p, r, x);
  eager.faces_in_boxes_within(mv, p, r, y);
  EXPECT_EQ(x, y) << where;
  lazy.faces_within(mv, p, r, x, /*tree_order=*/true);
  eager.faces_within(mv, p, r, y, /*tree_order=*/true);
  EXPECT_EQ(x, y) << where;
  const Vec3f pair[2] = {p, b};
  lazy.faces_within_any(mv, pair, r, x, scratch);
  eager.faces_within_any(mv, pair, r, y, scratch);
  EXPECT_EQ(x, y) << where;
  const auto cx = lazy.closest_point(mv, p), cy = eager.closest_point(mv, p);
  ASSERT_EQ(cx.has_value(), cy.has_value()) << where;
  if (cx) {
    EXPECT_EQ(cx->face, cy->face) << where;
    EXPECT_EQ(cx->distance, cy->distance) << where;
  }
  const auto hx = lazy.first_hit(mv, a, b), hy = eager.first_hit(mv, a, b);
  ASSERT_EQ(hx.has_value(), hy.has_value()) << where;
  if (hx) {
    EXPECT_EQ(hx->face, hy->face) << where;
    EXPECT_EQ(hx->t, hy->t) << where;
  }
  std::vector<SegmentHit> sx, sy;
  lazy.segment_hits(mv, a, b, sx);
  eager.segment_hits(mv, a, b, sy);
  ASSERT_EQ(sx.size(), sy.size()) << where;
  for (std::size_t i = 0; i < sx.size(); ++i) EXPECT_TRUE(sx[i].face == sy[i].face && sx[i].t == sy[i].t) << where;
}

// A large mesh is built in blocks, made only where queries reach: the answers are the eager
// tree's, leaf order included, and once every block is made the tree is the eager one with a
// node more a block (the block's own, above its root), one level deeper.
TEST(TriangleBvh, ALazyTreeAnswersAsTheEagerOneAndMakesOnlyTheBlocksItReaches) {
  const Mesh m = wavy_grid(200);  // 80 000 faces, 20 cm square
  ASSERT_GE(m.faces.size(), TriangleBvh::kLazyFrom);
  TriangleBvh lazy, eager;
  lazy.build(m.view());
  eager.build(m.view(), true, /*lazy=*/false);
  EXPECT_EQ(eager.block_count(), 0u);
  ASSERT_GE(lazy.block_count(), m.faces.size() / TriangleBvh::kBlockFaces);
  EXPECT_EQ(lazy.blocks_made(), 0u);
  EXPECT_LT(lazy.node_count(), lazy.block_count() * 2);  // the top only
  // A tool working in one corner: a few blocks made.
  std::mt19937 rng(41);
  std::uniform_real_distribution<float> near(-0.095f, -0.08f), radius(0.0f, 0.006f), dz(-0.02f, 0.02f);
  for (int q = 0; q < 60; ++q) {
    const Vec3f p{near(rng), near(rng), dz(rng)};
    const Vec3f a{p.x, p.y, 0.03f}, b{near(rng), near(rng), -0.03f};
    expect_same_answers(lazy, eager, m, p, radius(rng), a, b, "corner query " + std::to_string(q));
  }
  EXPECT_GT(lazy.blocks_made(), 0u);
  EXPECT_LT(lazy.blocks_made() * 10, lazy.block_count());
  // Anywhere, with crossings through the whole sheet: still the eager answers, and brute force's.
  std::uniform_real_distribution<float> u(-0.11f, 0.11f);
  for (int q = 0; q < 100; ++q) {
    const Vec3f p{u(rng), u(rng), dz(rng)};
    expect_same_answers(lazy, eager, m, p, radius(rng), Vec3f{u(rng), u(rng), 0.03f}, Vec3f{u(rng), u(rng), -0.03f},
                        "query " + std::to_string(q));
  }
  expect_queries_match(lazy, m, 42, 60);
  const std::size_t eager_nodes = eager.node_count(), eager_depth = eager.depth();
  lazy.expand(m.view());
  EXPECT_EQ(lazy.blocks_made(), lazy.block_count());
  EXPECT_EQ(lazy.node_count(), eager_nodes + lazy.block_count());
  EXPECT_EQ(lazy.depth(), eager_depth + 1);
  EXPECT_TRUE(lazy.check(m.view()));
  // A copy keeps the blocks made, node for node.
  const TriangleBvh copy = lazy;
  EXPECT_TRUE(copy.same_tree(lazy));
}

// Faces of a block no query has reached move: refit_faces makes the block from where they are now
// and fits the boxes above it, so the queries find them there (as the eager tree, refitted the
// same way, and brute force do).
TEST(TriangleBvh, RefitFacesMakesTheBlocksOfFacesThatMoved) {
  Mesh m = wavy_grid(200);
  const auto vf = m.vertex_faces();
  TriangleBvh lazy, eager;
  lazy.build(m.view());
  eager.build(m.view(), true, false);
  // Lift a 1 cm patch by 4 cm, far above its blocks' cells.
  std::vector<std::uint32_t> touched;
  const Vec3f centre{0.05f, 0.05f, 0};
  for (std::uint32_t v = 0; v < m.n_vertices(); ++v) {
    const Vec3f p = m.v(v);
    if (std::hypot(p.x - centre.x, p.y - centre.y) > 0.01f) continue;
    m.set(v, add(p, Vec3f{0, 0, 0.04f}));
    touched.insert(touched.end(), vf[v].begin(), vf[v].end());
  }
  ASSERT_GT(touched.size(), 100u);
  lazy.refit_faces(m.view(), touched);
  eager.refit_faces(m.view(), touched);
  EXPECT_GT(lazy.blocks_made(), 0u);
  EXPECT_LT(lazy.blocks_made() * 10, lazy.block_count());
  const Vec3f above{0.05f, 0.05f, 0.045f};
  const auto hit = lazy.closest_point(m.view(), above);
  ASSERT_TRUE(hit.has_value());
  EXPECT_NEAR(hit->distance, brute_closest(m, above), 1e-7);
  EXPECT_LT(hit->distance, 0.02f);  // the lifted patch (its waves ±1 cm), not the sheet 3.5 cm or more below
  expect_same_answers(lazy, eager, m, above, 0.008f, Vec3f{0.05f, 0.05f, 0.1f}, Vec3f{0.05f, 0.05f, -0.1f}, "above the patch");
  expect_queries_match(lazy, m, 43, 60);
  EXPECT_TRUE(lazy.check(m.view()));
}

// Queries may run on several threads at once: the first to reach a block makes it while the other
// waits, and both get the eager tree's answers (tsan runs this too).
TEST(TriangleBvh, ThreadsQueryingALazyTreeAtOnceGetTheEagerAnswers) {
  const Mesh m = wavy_grid(200);
  TriangleBvh lazy, eager;
  lazy.build(m.view());
  eager.build(m.view(), true, false);
  constexpr int kQueries = 300;
  std::vector<Vec3f> points(kQueries);
  std::mt19937 rng(44);
  std::uniform_real_distribution<float> u(-0.1f, 0.1f);
  for (Vec3f& p : points) p = {u(rng), u(rng), 0.005f};
  // Both threads walk the same points, one forwards and one backwards, so they meet on blocks.
  std::vector<std::uint32_t> got[2][kQueries];
  const auto run = [&](int t) {
    std::vector<std::uint32_t> out;
    for (int i = 0; i < kQueries; ++i) {
      const int q = t == 0 ? i : kQueries - 1 - i;
      lazy.faces_in_boxes_within(m.view(), points[q], 0.004f, out);
      got[t][q] = out;
    }
  };
  std::thread other(run, 1);
  run(0);
  other.join();
  std::vector<std::uint32_t> want;
  for (int q = 0; q < kQueries; ++q) {
    eager.faces_in_boxes_within(m.view(), points[q], 0.004f, want);
    EXPECT_EQ(got[0][q], want) << "query " << q;
    EXPECT_EQ(got[1][q], want) << "query " << q;
  }
  EXPECT_TRUE(lazy.check(m.view()));
}

// At a vertex every face around it is at distance 0: closest_point must answer the lowest face
// index of those (what brute force picks), not whichever face the tree's traversal meets first,
// so that the cut does not depend on the tree's shape.
TEST(TriangleBvh, TiesGoToTheLowestFaceWhateverTheTree) {
  const Mesh m = wavy_grid(30, 0.1f, 0.01f, 0.0f);
  TriangleBvh bvh;
  bvh.build(m.view());
  const MeshView mv = m.view();
  int ties = 0;
  for (std::uint32_t v = 0; v < m.n_vertices(); v += 7) {
    const Vec3f p = m.v(v);
    double best = std::numeric_limits<double>::infinity();
    std::uint32_t want = 0;
    int at_best = 0;
    for (std::uint32_t f = 0; f < m.faces.size(); ++f) {
      const auto c = m.corners(f);
      const double d2 = point_triangle_distance_squared(p, c[0], c[1], c[2]);
      if (d2 < best) best = d2, want = f, at_best = 1;
      else if (d2 == best) ++at_best;
    }
    ties += at_best > 1;
    const auto hit = bvh.closest_point(mv, p);
    ASSERT_TRUE(hit.has_value());
    EXPECT_EQ(hit->face, want) << "vertex " << v;
    // A vertical segment through the vertex: the faces around it give the same t to within
    // rounding (first_hit decides in double; an exact tie goes to the lowest face), so the answer
    // is one of the faces at the least float t.
    const Vec3f a = add(p, {0, 0, 0.05f}), b = add(p, {0, 0, -0.05f});
    const auto brute = brute_hits(m, a, b);
    ASSERT_FALSE(brute.empty()) << "vertex " << v;
    float t_min = std::numeric_limits<float>::infinity();
    for (const auto& [f, t] : brute) t_min = std::min(t_min, t);
    const auto seg = bvh.first_hit(mv, a, b);
    ASSERT_TRUE(seg.has_value());
    EXPECT_EQ(seg->t, t_min) << "vertex " << v;
    EXPECT_TRUE(std::any_of(brute.begin(), brute.end(), [&](const auto& h) { return h.first == seg->face && h.second == t_min; }))
        << "vertex " << v;
  }
  EXPECT_GT(ties, 10);  // the test is about ties: there must be some
}

// faces_in_boxes_within: every face of the leaves whose boxes reach, so a superset of
// faces_within's answer, and in the same (leaf) order once filtered by the exact distance.
TEST(TriangleBvh, FacesInBoxesHoldEveryFaceWithinInTreeOrder) {
  const Mesh m = wavy_grid(60);
  TriangleBvh bvh;
  bvh.build(m.view());
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-0.1f, 0.1f), radius(0.0f, 0.03f);
  std::vector<std::uint32_t> within, boxes, filtered;
  for (int q = 0; q < 200; ++q) {
    const Vec3f p{u(rng), u(rng), 0.2f * u(rng)};
    const float r = radius(rng);
    bvh.faces_within(m.view(), p, r, within, /*tree_order=*/true);
    bvh.faces_in_boxes_within(m.view(), p, r, boxes);
    filtered.clear();
    for (std::uint32_t f : boxes) {
      const auto c = m.corners(f);
      if (point_triangle_distance_squared(p, c[0], c[1], c[2]) <= double{r} * double{r}) filtered.push_back(f);
    }
    EXPECT_EQ(filtered, within) << "query " << q;
    EXPECT_GE(boxes.size(), within.size());
    // Each face at most once (a face sits in one leaf).
    std::vector<std::uint32_t> sorted = boxes;
    std::sort(sorted.begin(), sorted.end());
    EXPECT_TRUE(std::adjacent_find(sorted.begin(), sorted.end()) == sorted.end()) << "query " << q;
  }
}

// faces_within_any: exactly the union of faces_within over its points, ascending, each face once;
// for a cut-like chain of close points (spheres overlapping almost entirely), scattered points, one
// point, none, and on a soup where boxes overlap.
TEST(TriangleBvh, FacesWithinAnyIsTheUnionOfFacesWithin) {
  const Mesh grid = wavy_grid(60), junk = soup(3000, 9);
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-0.1f, 0.1f), radius(0.0f, 0.03f);
  std::vector<std::uint32_t> any, one, scratch;
  std::vector<Vec3f> points;
  for (const Mesh* m : {&grid, &junk}) {
    TriangleBvh bvh;
    bvh.build(m->view());
    for (int q = 0; q < 120; ++q) {
      points.clear();
      const int n = q % 40;  // 0 .. 39 points
      const Vec3f start{u(rng), u(rng), 0.2f * u(rng)};
      for (int i = 0; i < n; ++i)
        points.push_back(q % 2 == 0 ? add(start, Vec3f{0.0005f * static_cast<float>(i), 0.0002f * static_cast<float>(i), 0})  // a chain
                                    : Vec3f{u(rng), u(rng), 0.2f * u(rng)});                                                  // scattered
      const float r = radius(rng);
      std::set<std::uint32_t> expected;
      for (const Vec3f& p : points) {
        bvh.faces_within(m->view(), p, r, one);
        expected.insert(one.begin(), one.end());
      }
      bvh.faces_within_any(m->view(), points, r, any, scratch);
      EXPECT_EQ(any, std::vector<std::uint32_t>(expected.begin(), expected.end())) << "query " << q << ", " << n << " points";
    }
  }
}

TEST(TriangleBvh, QueriesMatchBruteForceOnATriangleSoup) {
  const Mesh m = soup(3000, 5);
  TriangleBvh bvh;
  bvh.build(m.view());
  ASSERT_TRUE(bvh.check(m.view()));
  expect_queries_match(bvh, m, 22);
}

TEST(TriangleBvh, QueriesMatchBruteForceOnASphere) {
  const Mesh m = icosphere(4, 0.08f);
  TriangleBvh bvh;
  bvh.build(m.view());
  ASSERT_TRUE(bvh.check(m.view()));
  expect_queries_match(bvh, m, 23);
}

TEST(TriangleBvh, RefitFacesAfterLocalVertexMoves) {
  Mesh m = wavy_grid(40);
  const auto vf = m.vertex_faces();
  TriangleBvh bvh;
  bvh.build(m.view());
  std::mt19937 rng(31);
  std::uniform_real_distribution<float> d(-0.01f, 0.01f);
  std::vector<std::uint32_t> touched;
  for (int round = 0; round < 8; ++round) {
    // Push a patch of vertices around a random centre (tool contact), some by a lot.
    const Vec3f centre = m.v(static_cast<std::uint32_t>(rng() % m.n_vertices()));
    const float reach = round % 2 == 0 ? 0.02f : 0.005f;
    touched.clear();
    for (std::uint32_t v = 0; v < m.n_vertices(); ++v) {
      if (dist(m.v(v), centre) > reach) continue;
      m.set(v, add(m.v(v), Vec3f{d(rng), d(rng), 3 * d(rng)}));
      touched.insert(touched.end(), vf[v].begin(), vf[v].end());  // duplicates are fine
    }
    ASSERT_FALSE(touched.empty());
    if (round == 0) {
      // check() can fail: before the refit, the moved vertices stick out of their boxes.
      EXPECT_FALSE(bvh.check(m.view()));
    }
    bvh.refit_faces(m.view(), touched);
    ASSERT_TRUE(bvh.check(m.view())) << "round " << round;
    expect_queries_match(bvh, m, 100u + static_cast<unsigned>(round), 40);
  }
  // Boxes are tight after refit_faces: equal to a full refit's.
  TriangleBvh full = bvh;
  full.refit(m.view());
  for (int i = 0; i < 50; ++i) {
    const Vec3f p = m.v(static_cast<std::uint32_t>(rng() % m.n_vertices()));
    EXPECT_EQ(bvh.closest_point(m.view(), p)->distance, full.closest_point(m.view(), p)->distance);
  }
}

TEST(TriangleBvh, RefitFacesAfterACutReconnectsFaces) {
  // A cut duplicates vertices along a line and reconnects the faces on one side to the copies,
  // which then move apart: the face count stays, indices and positions change.
  Mesh m = wavy_grid(30, 0.1f, 0.01f, 0.0f);
  TriangleBvh bvh;
  bvh.build(m.view());
  const auto vf = m.vertex_faces();
  std::vector<std::uint32_t> touched;
  const int n = 30;
  for (int x = 5; x <= 25; ++x) {
    const auto v = static_cast<std::uint32_t>(15 * (n + 1) + x);  // row y = 15
    const Vec3f p = m.v(v);
    const std::uint32_t copy = m.add(add(p, Vec3f{0, 0.002f, 0}));
    m.set(v, add(p, Vec3f{0, -0.002f, 0}));
    for (std::uint32_t f : vf[v]) {
      const auto c = m.corners(f);
      const float cy = (c[0].y + c[1].y + c[2].y) / 3;
      if (cy > p.y)
        for (auto& idx : m.faces[f])
          if (idx == v) idx = copy;
      touched.push_back(f);
    }
  }
  bvh.refit_faces(m.view(), touched);
  ASSERT_TRUE(bvh.check(m.view()));
  expect_queries_match(bvh, m, 41);
  // The opening is a gap: a vertical segment through the middle of it misses.
  const Vec3f mid = m.v(static_cast<std::uint32_t>(15 * (n + 1) + 15));
  EXPECT_FALSE(bvh.first_hit(m.view(), {mid.x, mid.y + 0.002f, 1}, {mid.x, mid.y + 0.002f, -1}));
}

TEST(TriangleBvh, FullRefitAfterGlobalDeformation) {
  Mesh m = soup(2000, 9);
  TriangleBvh bvh;
  bvh.build(m.view());
  std::mt19937 rng(51);
  std::uniform_real_distribution<float> d(-0.02f, 0.02f);
  for (int round = 0; round < 3; ++round) {
    for (std::uint32_t v = 0; v < m.n_vertices(); ++v) {
      const Vec3f p = m.v(v);
      m.set(v, add(Vec3f{p.x * 1.3f, p.y, p.z + 0.05f * std::sin(p.x * 30)}, Vec3f{d(rng), d(rng), d(rng)}));
    }
    EXPECT_FALSE(bvh.check(m.view()));
    bvh.refit(m.view());
    ASSERT_TRUE(bvh.check(m.view()));
    expect_queries_match(bvh, m, 200u + static_cast<unsigned>(round), 60);
  }
}

TEST(TriangleBvh, SegmentsThroughVerticesAndEdgesHitTheSurface) {
  // A flat grid with axis-aligned segments exactly through vertices and edge midpoints, a wavy
  // jittered grid with oblique ones, and a closed sphere crossed from its centre.
  std::mt19937 rng(61);
  std::uniform_real_distribution<float> d(-0.6f, 0.6f);
  std::vector<SegmentHit> hits;
  for (const Mesh& m : {wavy_grid(24, 0.1f, 0.0f, 0.0f), wavy_grid(24, 0.1f, 0.01f, 0.4f)}) {
    TriangleBvh bvh;
    bvh.build(m.view());
    std::vector<Vec3f> targets;
    for (std::uint32_t v = 0; v < m.n_vertices(); ++v) targets.push_back(m.v(v));
    for (std::uint32_t f = 0; f < m.faces.size(); ++f) {
      const auto c = m.corners(f);
      targets.push_back(scale(0.5f, add(c[0], c[1])));
      targets.push_back(scale(0.5f, add(c[1], c[2])));
    }
    int misses = 0;
    for (const Vec3f& p : targets) {
      // Skip the border, where a tilted segment may pass outside the sheet.
      if (std::abs(p.x) > 0.095f || std::abs(p.y) > 0.095f) continue;
      for (int k = 0; k < 3; ++k) {
        const Vec3f dir = k == 0 ? Vec3f{0, 0, 0.01f} : Vec3f{0.01f * d(rng), 0.01f * d(rng), 0.01f};
        const Vec3f a = add(p, dir), b = sub(p, dir);
        bvh.segment_hits(m.view(), a, b, hits);
        misses += hits.empty();
        misses += !bvh.first_hit(m.view(), a, b).has_value();
        misses += !bvh.first_hit(m.view(), b, a).has_value();
      }
    }
    EXPECT_EQ(misses, 0);
  }
  const Mesh s = icosphere(3, 0.05f);
  TriangleBvh bvh;
  bvh.build(s.view());
  int misses = 0;
  for (std::uint32_t f = 0; f < s.faces.size(); ++f) {
    const auto c = s.corners(f);
    for (const Vec3f& p : {c[0], scale(0.5f, add(c[0], c[1])), scale(1.0f / 3, add(c[0], add(c[1], c[2])))}) {
      const Vec3f out = scale(2.0f, p);
      bvh.segment_hits(s.view(), {0, 0, 0}, out, hits);
      misses += hits.empty();
      misses += !bvh.first_hit(s.view(), out, {0, 0, 0}).has_value();
    }
  }
  EXPECT_EQ(misses, 0);
}

TEST(TriangleBvh, ZeroAreaFacesAreSafe) {
  Mesh m = wavy_grid(20);
  // Collapse some faces: a repeated vertex, three equal vertices, a collinear corner.
  const std::uint32_t v0 = m.faces[10][0];
  m.faces[10] = {v0, v0, m.faces[10][2]};
  m.faces[20] = {v0, v0, v0};
  const Vec3f a = m.v(m.faces[30][0]), b = m.v(m.faces[30][1]);
  m.set(m.faces[30][2], scale(0.5f, add(a, b)));
  TriangleBvh bvh;
  bvh.build(m.view());
  ASSERT_TRUE(bvh.check(m.view()));
  expect_queries_match(bvh, m, 71);
  // Queries aimed right at the degenerate faces stay finite.
  std::vector<std::uint32_t> within;
  for (std::uint32_t f : {10u, 20u, 30u}) {
    const auto c = m.corners(f);
    const auto h = bvh.closest_point(m.view(), add(c[0], Vec3f{1e-4f, 0, 1e-3f}));
    ASSERT_TRUE(h.has_value());
    EXPECT_TRUE(std::isfinite(h->distance) && std::isfinite(h->u) && std::isfinite(h->v) && std::isfinite(h->point.x));
    const auto s = bvh.first_hit(m.view(), add(c[0], Vec3f{0, 0, 0.01f}), add(c[0], Vec3f{0, 0, -0.01f}));
    ASSERT_TRUE(s.has_value());  // the neighbours around the vertex catch it
    EXPECT_TRUE(std::isfinite(s->t) && std::isfinite(s->u) && std::isfinite(s->point.z));
    bvh.faces_within(m.view(), c[0], 1e-3f, within);
    EXPECT_TRUE(std::find(within.begin(), within.end(), f) != within.end());
  }
  // A mesh of nothing but zero-area faces.
  Mesh flat;
  for (int i = 0; i < 50; ++i) {
    const auto v = flat.add({0.001f * static_cast<float>(i), 0, 0});
    flat.faces.push_back({v, v, v});
  }
  bvh.build(flat.view());
  ASSERT_TRUE(bvh.check(flat.view()));
  EXPECT_FALSE(bvh.first_hit(flat.view(), {0.01f, 0, 1}, {0.01f, 0, -1}));
  const auto h = bvh.closest_point(flat.view(), {0.0101f, 0.001f, 0});
  ASSERT_TRUE(h.has_value());
  EXPECT_EQ(h->face, 10u);
  EXPECT_NEAR(h->distance, std::hypot(0.0001, 0.001), 1e-8);
}

// On a small mesh, and on a large one whose blocks the queries and refits make as they go.
class TriangleBvhAllocation : public ::testing::TestWithParam<int> {};

TEST_P(TriangleBvhAllocation, QueriesAndRefitsDoNotAllocate) {
  Mesh m = wavy_grid(GetParam());
  const auto vf = m.vertex_faces();
  TriangleBvh bvh;
  bvh.build(m.view());
  EXPECT_EQ(bvh.block_count() > 0, m.faces.size() >= TriangleBvh::kLazyFrom);
  std::vector<std::uint32_t> within, touched;
  std::vector<SegmentHit> hits;
  within.reserve(m.faces.size());
  hits.reserve(1024);
  touched.reserve(m.faces.size());
  std::vector<std::uint32_t> scratch;
  scratch.reserve(3 * (TriangleBvh::kMaxDepth + 2));
  std::size_t found = 0;
  lancet::test::MallocGuard guard;
  for (int i = 0; i < 200; ++i) {
    const std::uint32_t v = static_cast<std::uint32_t>(i * 97) % m.n_vertices();
    const Vec3f p = m.v(v);
    m.set(v, add(p, Vec3f{0, 0, 0.001f}));
    touched.clear();
    touched.insert(touched.end(), vf[v].begin(), vf[v].end());
    bvh.refit_faces(m.view(), touched);
    bvh.faces_within(m.view(), p, 0.01f, within);
    found += within.size();
    const Vec3f chain[3] = {p, add(p, Vec3f{0.002f, 0, 0}), add(p, Vec3f{0.004f, 0, 0})};
    bvh.faces_within_any(m.view(), chain, 0.01f, within, scratch);
    found += within.size();
    found += bvh.closest_point(m.view(), add(p, Vec3f{0, 0, 0.003f})).has_value();
    found += bvh.first_hit(m.view(), add(p, Vec3f{0, 0, 0.02f}), add(p, Vec3f{0, 0, -0.02f})).has_value();
    bvh.segment_hits(m.view(), {-0.2f, p.y, 0}, {0.2f, p.y, 0.001f}, hits);
    found += hits.size();
  }
  bvh.refit(m.view());
  EXPECT_EQ(guard.count(), 0u);
  EXPECT_GT(found, 200u);
  EXPECT_TRUE(bvh.check(m.view()));
}

INSTANTIATE_TEST_SUITE_P(SmallAndLazy, TriangleBvhAllocation, ::testing::Values(60, 200));

}  // namespace
}  // namespace lancet::surface
