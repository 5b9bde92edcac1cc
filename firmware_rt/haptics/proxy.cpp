#include "haptics/proxy.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace lancet::haptics {
namespace {

constexpr double kEps = 1e-9;  // m: feasibility tolerance
constexpr int kMaxHalvings = 4;  // a proxy step is shortened at most this many times (update_proxy)

// Solves the equality projection x = goal + Σ λ_i n_i with n_i·x = d_i for the active planes.
// Returns false when the planes are (nearly) dependent.
bool project(const Plane* planes, const std::uint32_t* idx, std::uint32_t m, Vec3 goal, Vec3& x, double* lambda) {
  double g[3][3], b[3];
  for (std::uint32_t i = 0; i < m; ++i) {
    const Plane& pi = planes[idx[i]];
    b[i] = pi.d - dot(pi.n, goal);
    for (std::uint32_t j = 0; j < m; ++j) g[i][j] = dot(pi.n, planes[idx[j]].n);
  }
  if (m == 1) {
    lambda[0] = b[0] / g[0][0];
  } else if (m == 2) {
    const double det = g[0][0] * g[1][1] - g[0][1] * g[1][0];
    if (std::abs(det) < 1e-10) return false;
    lambda[0] = (b[0] * g[1][1] - g[0][1] * b[1]) / det;
    lambda[1] = (g[0][0] * b[1] - b[0] * g[1][0]) / det;
  } else {
    const double det = g[0][0] * (g[1][1] * g[2][2] - g[1][2] * g[2][1]) -
                       g[0][1] * (g[1][0] * g[2][2] - g[1][2] * g[2][0]) +
                       g[0][2] * (g[1][0] * g[2][1] - g[1][1] * g[2][0]);
    if (std::abs(det) < 1e-10) return false;
    // Cramer's rule.
    for (int k = 0; k < 3; ++k) {
      double mk[3][3];
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) mk[r][c] = c == k ? b[r] : g[r][c];
      lambda[k] = (mk[0][0] * (mk[1][1] * mk[2][2] - mk[1][2] * mk[2][1]) -
                   mk[0][1] * (mk[1][0] * mk[2][2] - mk[1][2] * mk[2][0]) +
                   mk[0][2] * (mk[1][0] * mk[2][1] - mk[1][1] * mk[2][0])) /
                  det;
    }
  }
  x = goal;
  for (std::uint32_t i = 0; i < m; ++i) x += lambda[i] * planes[idx[i]].n;
  return true;
}

bool feasible(const Plane* planes, std::size_t n, Vec3 x) {
  for (std::size_t i = 0; i < n; ++i) {
    if (dot(planes[i].n, x) < planes[i].d - kEps) return false;
  }
  return true;
}

}  // namespace

Vec3 closest_point_on_triangle(Vec3 p, Vec3 a, Vec3 b, Vec3 c) noexcept {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = dot(ab, ap), d2 = dot(ac, ap);
  if (d1 <= 0 && d2 <= 0) return a;
  const Vec3 bp = p - b;
  const double d3 = dot(ab, bp), d4 = dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) return b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + (d1 / (d1 - d3)) * ab;
  const Vec3 cp = p - c;
  const double d5 = dot(ab, cp), d6 = dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) return c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + (d2 / (d2 - d6)) * ac;
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) return b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * (c - b);
  const double denom = 1.0 / (va + vb + vc);
  return a + (vb * denom) * ab + (vc * denom) * ac;
}

namespace {

// Adds triangle i's separating plane (the rank-th triangle the search met) when it lies within
// reach of p; false when the scratch is full. Inlined into the loops that call it (it runs for
// every triangle met).
[[gnu::always_inline]] inline bool add_plane(const TissuePatch& patch, std::uint32_t i, std::uint32_t rank, Vec3 p, double radius, double reach2,
               ProxyScratch& s) {
  const PatchTriangle& t = patch.triangles[i];
  const Vec3 a = to_vec3(t.v[0]), b = to_vec3(t.v[1]), c = to_vec3(t.v[2]);
  const Vec3 face = cross(b - a, c - a);
  if (!is_finite(a) || !is_finite(b) || !is_finite(c) || dot(face, face) < 1e-24) return true;  // bad or degenerate
  const Vec3 q = closest_point_on_triangle(p, a, b, c);
  const Vec3 d = p - q;
  const double dist2 = dot(d, d);
  if (dist2 > reach2) return true;
  // Tissue surfaces are one-sided (outward normals): a proxy behind a triangle (a device that
  // started under the sheet, a patch that appeared around a pressed tool) is not held there,
  // which would pull the hand back in with a force spike when it leaves.
  if (dot(d, face) < 0) return true;
  if (s.n_planes == kMaxPlanes) {
    s.overflow = true;
    return false;
  }
  // The separating direction; when p lies on the triangle, its face normal.
  const Vec3 nrm = dist2 > 1e-20 ? (1.0 / std::sqrt(dist2)) * d : normalized(face);
  s.planes[s.n_planes++] = Plane{nrm, dot(nrm, q) + radius, i, rank};
  return true;
}

// add_plane for triangles [first, last) of the patch, ranks from `rank` on; false when the scratch is full.
bool add_planes(const TissuePatch& patch, std::uint32_t first, std::uint32_t last, std::uint32_t rank, Vec3 p, double radius,
                double reach2, ProxyScratch& s) {
  for (std::uint32_t i = first; i < last; ++i)
    if (!add_plane(patch, i, rank + (i - first), p, radius, reach2, s)) return false;
  return true;
}

// Calls visit(i) for the triangles that may lie within reach of p: through the tree, or all.
template <class Visit>
void for_each_candidate(const TissuePatch& patch, const PatchBvh* bvh, Vec3 p, double reach, Visit&& visit) {
  if (bvh != nullptr) {
    for_each_near(*bvh, p, reach, visit);
    return;
  }
  const std::uint32_t n = std::min(patch.n_triangles, kPatchCapacity);
  for (std::uint32_t i = 0; i < n; ++i)
    if (!visit(i)) return;
}

}  // namespace

std::size_t collect_planes(const TissuePatch& patch, const PatchBvh* bvh, Vec3 p, double radius, double reach,
                           ProxyScratch& s) noexcept {
  s.n_planes = 0;
  s.overflow = false;
  s.n_pending = 0;
  const double reach2 = reach * reach;
  std::uint32_t rank = 0;
  for_each_candidate(patch, bvh, p, reach, [&](std::uint32_t i) { return add_plane(patch, i, rank++, p, radius, reach2, s); });
  return s.n_planes;
}

std::uint32_t nearest_triangle(const TissuePatch& patch, const PatchBvh* bvh, Vec3 p, double max_distance, Vec3& q) noexcept {
  const std::uint32_t n = std::min(patch.n_triangles, kPatchCapacity);
  double best2 = max_distance * max_distance;
  std::uint32_t best = n;
  for_each_candidate(patch, bvh, p, max_distance, [&](std::uint32_t i) {
    const PatchTriangle& t = patch.triangles[i];
    const Vec3 a = to_vec3(t.v[0]), b = to_vec3(t.v[1]), c = to_vec3(t.v[2]);
    if (!is_finite(a) || !is_finite(b) || !is_finite(c)) return true;
    const Vec3 x = closest_point_on_triangle(p, a, b, c);
    const double d2 = dot(p - x, p - x);
    // Ties go to the lower index, whatever order the walk takes.
    if (d2 < best2 || (d2 == best2 && i < best)) {
      best2 = d2;
      best = i;
      q = x;
    }
    return true;
  });
  return best;
}

namespace {
constexpr double kUnderSurface = 0.8;  // cos of the widest angle off the normal counted as "under"
}  // namespace

Vec3 surface_entry(const TissuePatch& patch, const PatchBvh* bvh, Vec3 p, double radius, double depth) noexcept {
  Vec3 best_q{};
  const std::uint32_t best = nearest_triangle(patch, bvh, p, depth, best_q);
  if (best >= std::min(patch.n_triangles, kPatchCapacity)) return p;  // nothing within depth
  const double best2 = dot(p - best_q, p - best_q);
  const PatchTriangle& t = patch.triangles[best];
  if ((t.flags & kTriangleOnCutEdge) != 0) return p;
  const Vec3 a = to_vec3(t.v[0]), b = to_vec3(t.v[1]), c = to_vec3(t.v[2]);
  const Vec3 face = cross(b - a, c - a);
  if (dot(face, face) < 1e-24) return p;
  const Vec3 nrm = normalized(face);
  const double behind = -dot(p - best_q, nrm);
  // Behind the face and (nearly) straight under the surface: under a face the distance is all
  // along its normal; under a vertex or an edge of a gently curved sheet, nearly so; past the
  // border of the sheet it is mostly sideways.
  if (!(behind > 0) || behind < kUnderSurface * std::sqrt(best2)) return p;
  return best_q + (radius * (1 + 1e-9) + 1e-12) * nrm;
}

namespace {

constexpr std::size_t kNone = ~std::size_t{0};

// The active-set solve (solve_constraints) over planes that `most_violated(x, active, m)` (the
// index of the most violated plane at x not among the m active ones, kNone when none is violated
// by more than kEps; ties to the lower rank) and `satisfied(x)` (every plane holds at x) look
// through; planes[i] is plane i.
template <class MostViolated, class Satisfied>
Vec3 solve(const Plane* planes, Vec3 p, Vec3 goal, std::array<std::uint32_t, 3>& active, std::uint32_t& m, bool* found,
           MostViolated&& most_violated, Satisfied&& satisfied) {
  m = 0;
  if (found != nullptr) *found = true;
  Vec3 x = goal;
  double lambda[3];
  for (int iter = 0; iter < 12; ++iter) {
    const std::size_t worst = most_violated(x, active.data(), m);
    if (worst == kNone) return x;  // feasible
    if (m == 3) break;
    active[m++] = static_cast<std::uint32_t>(worst);
    // Solve on the active set; drop planes that pull (negative multiplier) and solve again.
    for (std::uint32_t tries = 0; tries < 3; ++tries) {
      if (!project(planes, active.data(), m, goal, x, lambda)) {
        m = 0;
        if (found != nullptr) *found = false;
        return p;
      }
      std::uint32_t drop = m;
      for (std::uint32_t i = 0; i < m; ++i) {
        if (lambda[i] < 0 && (drop == m || lambda[i] < lambda[drop])) drop = i;
      }
      if (drop == m) break;
      for (std::uint32_t i = drop; i + 1 < m; ++i) active[i] = active[i + 1];
      --m;
      if (m == 0) {
        x = goal;
        break;
      }
    }
  }
  if (satisfied(x)) return x;
  m = 0;
  if (found != nullptr) *found = false;
  return p;  // no feasible point found: stay (p satisfies every plane built from it)
}

bool is_active(const std::uint32_t* active, std::uint32_t m, std::size_t i) {
  return std::find(active, active + m, i) != active + m;
}

// ---- Planes built as the solve needs them (ProxyScratch::pending) ----
//
// Triangle i's plane, n = (p − q)/|p − q| from its closest point q to the start p, d = n·q + r, is
// violated at x by d − n·x = r − |p − q| − n·(x − p) ≤ r − |p − q| + |x − p|. Its leaf's box
// distance D ≤ |p − q| bounds that by r − D + |x − p|; where that bound (plus kSlack, far above the
// rounding of either side) is at most what the solve is looking for, no plane of the leaf can
// change its answer, and the leaf stays unbuilt. (A proxy on the triangle, |p − q| ≤ 1e-10, takes
// the face normal instead: the bound still holds within kSlack.) Leaves are built nearest first,
// so the first that stays unbuilt speaks for all the rest.
constexpr double kSlack = 1e-9;  // m

// The order of the heap of pending leaves: the nearest on top.
constexpr auto further = [](const PlaneGroup& a, const PlaneGroup& b) { return a.distance2 > b.distance2; };

// Puts the tree's leaves within reach of p into s.pending, ranked in the order collect_planes would
// meet their triangles. When they come to hold more triangles than kMaxPlanes, builds the planes
// of those met so far and of the rest of the walk, as collect_planes would (and finds whether
// they overflow).
void collect_pending(const TissuePatch& patch, const PatchBvh& bvh, Vec3 p, double radius, double reach, ProxyScratch& s) {
  s.n_planes = 0;
  s.overflow = false;
  s.n_pending = 0;
  s.patch = &patch, s.from = p, s.radius = radius, s.reach2 = reach * reach;
  std::uint32_t rank = 0;
  bool build_all = false;
  for_each_leaf_near(bvh, p, reach, [&](std::uint32_t first, std::uint32_t last, double d2) {
    if (!build_all && (s.n_pending == kMaxPlaneGroups || rank + (last - first) > kMaxPlanes)) {
      build_all = true;
      for (std::size_t j = 0; j < s.n_pending; ++j) {
        const PlaneGroup& g = s.pending[j];
        add_planes(patch, g.first, g.last, g.rank, p, radius, s.reach2, s);  // they fit: fewer than kMaxPlanes
      }
      s.n_pending = 0;
    }
    const std::uint32_t first_rank = rank;
    rank += last - first;
    if (build_all) return add_planes(patch, first, last, first_rank, p, radius, s.reach2, s);
    s.pending[s.n_pending++] = PlaneGroup{first, last, first_rank, d2};
    return true;
  });
  std::make_heap(s.pending.begin(), s.pending.begin() + static_cast<std::ptrdiff_t>(s.n_pending), further);
  s.nearest_pending = s.n_pending > 0 ? std::sqrt(s.pending[0].distance2) : std::numeric_limits<double>::infinity();
}

// Whether a pending plane may be violated by more than `violation` at x (NaN: yes).
bool pending_may_exceed(const ProxyScratch& s, Vec3 x, double violation) {
  return s.n_pending > 0 && !(s.radius - s.nearest_pending + norm(x - s.from) + kSlack <= violation);
}

// Builds the planes of the nearest pending leaf (appended to s.planes). s.pending is a heap,
// nearest on top.
void build_nearest_pending(ProxyScratch& s) {
  std::pop_heap(s.pending.begin(), s.pending.begin() + static_cast<std::ptrdiff_t>(s.n_pending), further);
  const PlaneGroup g = s.pending[--s.n_pending];
  add_planes(*s.patch, g.first, g.last, g.rank, s.from, s.radius, s.reach2, s);
  s.nearest_pending = s.n_pending > 0 ? std::sqrt(s.pending[0].distance2) : std::numeric_limits<double>::infinity();
}

// The most violated plane at x, building those that may be.
std::size_t most_violated_lazily(ProxyScratch& s, Vec3 x, const std::uint32_t* active, std::uint32_t m) {
  std::size_t worst = kNone;
  double worst_violation = kEps;
  const auto consider = [&](std::size_t from, std::size_t to) {
    for (std::size_t i = from; i < to; ++i) {
      const double v = s.planes[i].d - dot(s.planes[i].n, x);
      if (!(v >= worst_violation)) continue;
      if (v == worst_violation && (worst == kNone || s.planes[i].rank > s.planes[worst].rank)) continue;  // a tie: the lower rank
      if (is_active(active, m, i)) continue;
      worst = i;
      worst_violation = v;
    }
  };
  consider(0, s.n_planes);
  while (pending_may_exceed(s, x, worst_violation)) {
    const std::size_t built = s.n_planes;
    build_nearest_pending(s);
    consider(built, s.n_planes);
  }
  return worst;
}

// Whether every plane holds at x, building those that may not.
bool satisfied_lazily(ProxyScratch& s, Vec3 x) {
  if (!feasible(s.planes.data(), s.n_planes, x)) return false;
  while (pending_may_exceed(s, x, kEps)) {
    const std::size_t built = s.n_planes;
    build_nearest_pending(s);
    if (!feasible(s.planes.data() + built, s.n_planes - built, x)) return false;
  }
  return true;
}

}  // namespace

Vec3 solve_constraints(const Plane* planes, std::size_t n, Vec3 p, Vec3 goal, std::array<std::uint32_t, 3>& active,
                       std::uint32_t& m, bool* found) noexcept {
  const auto most_violated = [&](Vec3 x, const std::uint32_t* act, std::uint32_t n_act) {
    std::size_t worst = kNone;
    double worst_violation = kEps;
    for (std::size_t i = 0; i < n; ++i) {
      const double v = planes[i].d - dot(planes[i].n, x);
      if (v > worst_violation && !is_active(act, n_act, i)) {
        worst = i;
        worst_violation = v;
      }
    }
    return worst;
  };
  return solve(planes, p, goal, active, m, found, most_violated, [&](Vec3 x) { return feasible(planes, n, x); });
}

ProxyResult update_proxy(const TissuePatch& patch, const PatchBvh* bvh, Vec3 p, Vec3 device, double radius,
                         ProxyScratch& s) noexcept {
  ProxyResult r;
  Vec3 goal = device;
  std::array<std::uint32_t, 3> active{};
  std::uint32_t m = 0;
  // Lazily only from finite places (the bounds mean nothing otherwise).
  const bool lazy = s.lazy && bvh != nullptr && is_finite(p) && is_finite(device);
  for (int halvings = 0;; ++halvings) {
    const double reach = norm(goal - p) + 2.0 * radius;
    if (lazy) {
      collect_pending(patch, *bvh, p, radius, reach, s);
    } else {
      collect_planes(patch, bvh, p, radius, reach, s);
    }
    bool found = !s.overflow;
    if (found) {
      r.position = solve(
          s.planes.data(), p, goal, active, m, &found,
          [&](Vec3 x, const std::uint32_t* act, std::uint32_t n_act) { return most_violated_lazily(s, x, act, n_act); },
          [&](Vec3 x) { return satisfied_lazily(s, x); });
    }
    if (found) break;
    // Too many triangles within the step's reach, or no point found that rests on at most three
    // of their planes (a long step over a curved sheet): go part of the way this tick.
    ++s.shortened;
    if (halvings == kMaxHalvings) {  // not even a sixteenth of the step: stay
      s.n_planes = 0;
      s.n_pending = 0;
      r.position = p;
      return r;
    }
    goal = p + 0.5 * (goal - p);
  }
  r.n_active = m;
  if (m == 0) return r;
  Vec3 nsum{};
  for (std::uint32_t i = 0; i < m; ++i) nsum += s.planes[active[i]].n;
  r.normal = normalized(nsum);
  r.triangle = s.planes[active[0]].triangle;
  return r;
}

ProxyAnchor anchor_proxy(const TissuePatch& patch, std::uint32_t i, Vec3 proxy) noexcept {
  ProxyAnchor r;
  if (i >= std::min(patch.n_triangles, kPatchCapacity)) return r;
  const PatchTriangle& t = patch.triangles[i];
  const Vec3 a = to_vec3(t.v[0]), e1 = to_vec3(t.v[1]) - a, e2 = to_vec3(t.v[2]) - a;
  const Vec3 face = cross(e1, e2);
  const double g11 = dot(e1, e1), g12 = dot(e1, e2), g22 = dot(e2, e2);
  const double det = g11 * g22 - g12 * g12;
  if (!is_finite(a) || !is_finite(face) || dot(face, face) < 1e-24 || !(det > 0)) return r;
  const Vec3 n = normalized(face);
  const Vec3 w = proxy - a;
  r.h = dot(w, n);
  const Vec3 in_plane = w - r.h * n;
  const double b1 = dot(in_plane, e1), b2 = dot(in_plane, e2);
  r.s = (b1 * g22 - b2 * g12) / det;
  r.t = (g11 * b2 - g12 * b1) / det;
  r.id = t.id;
  r.valid = std::isfinite(r.s) && std::isfinite(r.t) && std::isfinite(r.h);
  return r;
}

bool carry_proxy(const TissuePatch& patch, const PatchBvh* bvh, const ProxyAnchor& an, Vec3 proxy, double search,
                 double max_move, Vec3& out) noexcept {
  if (!an.valid) return false;
  const std::uint32_t n = std::min(patch.n_triangles, kPatchCapacity);
  std::uint32_t found = n;
  const auto match = [&](std::uint32_t i) {
    if (patch.triangles[i].id != an.id) return true;
    found = i;
    return false;
  };
  for_each_candidate(patch, bvh, proxy, search, match);
  if (found == n) return false;
  const PatchTriangle& t = patch.triangles[found];
  const Vec3 a = to_vec3(t.v[0]), e1 = to_vec3(t.v[1]) - a, e2 = to_vec3(t.v[2]) - a;
  const Vec3 face = cross(e1, e2);
  if (!is_finite(a) || !is_finite(face) || dot(face, face) < 1e-24) return false;
  const Vec3 x = a + an.s * e1 + an.t * e2 + an.h * normalized(face);
  if (!is_finite(x) || !(norm(x - proxy) <= max_move)) return false;
  out = x;
  return true;
}

void apply_friction(ProxyResult& r, Vec3 p, Vec3 device, double mu_s, double mu_d, bool sliding,
                    ProxyScratch& s) noexcept {
  if (r.n_active == 0) return;
  // depth: how far the device is below the proxy along the normal; the tangential offset of the
  // previous proxy from the device decides stick or slide.
  const Vec3 x = r.position;
  const double depth = dot(x - device, r.normal);
  if (depth <= 0) return;
  const Vec3 off = p - device;
  const Vec3 tang = off - dot(off, r.normal) * r.normal;
  const double t = norm(tang);
  if (t < 1e-12) return;
  // Offsets count from the device's own place on the contact plane, which is x unless this
  // tick's step was held short of it (a long step, a carried proxy).
  const Vec3 base = device + depth * r.normal;
  Vec3 candidate;
  bool stuck = false;
  if (t <= (sliding ? mu_d : mu_s) * depth) {
    candidate = base + tang;  // stick: keep the old tangential place
    stuck = true;
  } else {
    candidate = base + (std::min(t, mu_d * depth) / t) * tang;  // slide to the edge of the cone
  }
  // Friction never moves the proxy into the tissue: keep it only where every plane holds.
  if (satisfied_lazily(s, candidate)) {
    r.position = candidate;
    r.stuck = stuck;
  }
}

}  // namespace lancet::haptics
