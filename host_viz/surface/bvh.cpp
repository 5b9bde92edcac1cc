#include "surface/bvh.hpp"

#include "surface/bvh_box.hpp"

#include <algorithm>
#include <bit>
#include <cassert>
#include <cmath>
#include <thread>
#include <utility>

namespace lancet::surface {
namespace {

using bvh_detail::vertex;

// A triangle whose |ab × ac|² is below this fraction of (longest edge)⁴ is treated as its edges.
constexpr double kDegenerate = 1e-14;

double at(Vec3 v, int axis) { return axis == 0 ? v.x : (axis == 1 ? v.y : v.z); }
float at(Vec3f v, int axis) { return axis == 0 ? v.x : (axis == 1 ? v.y : v.z); }

// Squared distance from p to the box (0 inside), in double.
double box_distance2(Vec3f lo, Vec3f hi, Vec3 p) {
  const auto axis = [](double q, double l, double h) {
    const double d = q < l ? l - q : (q > h ? q - h : 0.0);
    return d * d;
  };
  return axis(p.x, lo.x, hi.x) + axis(p.y, lo.y, hi.y) + axis(p.z, lo.z, hi.z);
}

// ---------------------------------------------------------------------------------------------
// Closest point on a triangle (Ericson, Real-Time Collision Detection §5.1.5, region by region),
// in double. u, v: weights of b and c.
struct Closest {
  Vec3 point;
  double d2 = 0;
  double u = 0, v = 0;
};

// Clamped ratio for a parameter in [0, 1]; 0 when the denominator vanishes.
double ratio(double num, double den) { return den > 0 ? std::clamp(num / den, 0.0, 1.0) : 0.0; }

Closest on_segment(Vec3 p, Vec3 a, Vec3 b) {
  const Vec3 d = b - a;
  const double s = ratio(dot(p - a, d), dot(d, d));
  Closest c;
  c.point = a + s * d;
  const Vec3 e = p - c.point;
  c.d2 = dot(e, e);
  c.u = s;  // the caller maps s to the triangle's barycentrics
  return c;
}

Closest closest_on_triangle(Vec3 p, Vec3 a, Vec3 b, Vec3 c) {
  const Vec3 ab = b - a, ac = c - a, bc = c - b;
  const Vec3 n = cross(ab, ac);
  const double longest = std::max({dot(ab, ab), dot(ac, ac), dot(bc, bc)});
  Closest r;
  if (!(dot(n, n) > kDegenerate * longest * longest)) {
    // Zero (or nearly zero) area: the closest point lies on one of the edges.
    Closest e_ab = on_segment(p, a, b), e_ac = on_segment(p, a, c), e_bc = on_segment(p, b, c);
    e_ab.v = 0;                                  // a + s·ab: (s, 0)
    e_ac.v = e_ac.u, e_ac.u = 0;                 // a + s·ac: (0, s)
    e_bc.v = e_bc.u, e_bc.u = 1.0 - e_bc.u;      // b + s·bc: (1 − s, s)
    r = e_ab;
    if (e_ac.d2 < r.d2) r = e_ac;
    if (e_bc.d2 < r.d2) r = e_bc;
    return r;
  }
  const auto finish = [&](Vec3 q, double u, double v) {
    r.point = q;
    r.u = u;
    r.v = v;
    const Vec3 e = p - q;
    r.d2 = dot(e, e);
    return r;
  };
  const Vec3 ap = p - a;
  const double d1 = dot(ab, ap), d2 = dot(ac, ap);
  if (d1 <= 0 && d2 <= 0) return finish(a, 0, 0);
  const Vec3 bp = p - b;
  const double d3 = dot(ab, bp), d4 = dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) return finish(b, 1, 0);
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) {
    const double s = ratio(d1, d1 - d3);
    return finish(a + s * ab, s, 0);
  }
  const Vec3 cp = p - c;
  const double d5 = dot(ab, cp), d6 = dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) return finish(c, 0, 1);
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) {
    const double s = ratio(d2, d2 - d6);
    return finish(a + s * ac, 0, s);
  }
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && d4 - d3 >= 0 && d5 - d6 >= 0) {
    const double s = ratio(d4 - d3, (d4 - d3) + (d5 - d6));
    return finish(b + s * bc, 1.0 - s, s);
  }
  // Inside the face region va, vb, vc > 0 and their sum is |ab × ac|² > 0.
  const double sum = va + vb + vc;
  const double v = ratio(vb, sum), w = ratio(vc, sum);
  return finish(a + v * ab + w * ac, v, w);
}

Closest closest_on_face(const MeshView& m, std::uint32_t f, Vec3 p) {
  const auto& t = m.faces[f];
  return closest_on_triangle(p, to_vec3(vertex(m, t[0])), to_vec3(vertex(m, t[1])), to_vec3(vertex(m, t[2])));
}

PointHit to_hit(std::uint32_t face, const Closest& c) {
  return {face, to_vec3f(c.point), static_cast<float>(std::sqrt(c.d2)), static_cast<float>(c.u),
          static_cast<float>(c.v)};
}

// ---------------------------------------------------------------------------------------------
// Segment setup shared by the box and triangle tests. The triangle test is Woop, Benthin & Wald's
// watertight ray/triangle test in double: vertices are moved to the segment start and sheared so
// that the segment runs along +z; the 2-D edge functions of a shared edge are then computed from
// the same two transformed vertices in the same order by both faces (see edge()), so they are
// exact negatives and a crossing on the edge is inside at least one of the two faces.
struct Segment {
  Vec3 org, dir;
  double inv[3]{};
  bool flat[3]{};  // dir is zero along this axis
  int kx = 0, ky = 1, kz = 2;
  double sx = 0, sy = 0, sz = 0;
  bool valid = false;  // false for a zero-length segment

  Segment(Vec3f a, Vec3f b) : org(to_vec3(a)), dir(to_vec3(b) - to_vec3(a)) {
    for (int i = 0; i < 3; ++i) {
      const double d = at(dir, i);
      flat[i] = d == 0;
      inv[i] = flat[i] ? 0.0 : 1.0 / d;
    }
    const double ax = std::abs(dir.x), ay = std::abs(dir.y), az = std::abs(dir.z);
    kz = ax > ay ? (ax > az ? 0 : 2) : (ay > az ? 1 : 2);
    kx = (kz + 1) % 3;
    ky = (kx + 1) % 3;
    const double dz = at(dir, kz);
    if (dz < 0) std::swap(kx, ky);  // keep the winding, so the edge-function signs mean one thing
    valid = dz != 0;
    if (valid) {
      sx = at(dir, kx) / dz;
      sy = at(dir, ky) / dz;
      sz = 1.0 / dz;
    }
  }

  // Parameter range [t0, t1] of the segment inside the box, intersected with [0, t_max]; false
  // when empty. The box is padded by a relative 1e-6 so that rounding never drops a crossing
  // that lies on a box face (vertices always do).
  bool box(Vec3f lo, Vec3f hi, double t_max, double& t_enter) const {
    double t0 = 0, t1 = t_max;
    for (int i = 0; i < 3; ++i) {
      const double l = at(lo, i), h = at(hi, i);
      const double pad = 1e-6 * std::max({std::abs(l), std::abs(h), h - l}) + 1e-30;
      const double o = at(org, i);
      if (flat[i]) {
        if (o < l - pad || o > h + pad) return false;
        continue;
      }
      double a = (l - pad - o) * inv[i], b = (h + pad - o) * inv[i];
      if (a > b) std::swap(a, b);
      t0 = std::max(t0, a);
      t1 = std::min(t1, b);
      if (t0 > t1) return false;
    }
    t_enter = t0;
    return true;
  }

  struct Projected {
    double x, y, z;
    Vec3f key;  // the original position: orders the two ends of an edge the same way for all faces
  };
  [[nodiscard]] Projected project(Vec3f v) const {
    const Vec3 p = to_vec3(v) - org;
    const double pz = at(p, kz);
    return {at(p, kx) - sx * pz, at(p, ky) - sy * pz, sz * pz, v};
  }

  // 2-D edge function of (p, q), computed with the ends in a fixed order (by position) and then
  // negated as needed, so that edge(p, q) == −edge(q, p) exactly even where the compiler fuses
  // multiply–adds.
  static double edge(const Projected& p, const Projected& q) {
    const auto less = [](Vec3f a, Vec3f b) {
      if (a.x != b.x) return a.x < b.x;
      if (a.y != b.y) return a.y < b.y;
      return a.z < b.z;
    };
    if (p.key == q.key) return 0;  // (x·y − y·x need not be 0 when fused)
    if (less(q.key, p.key)) return -(q.x * p.y - q.y * p.x);
    return p.x * q.y - p.y * q.x;
  }

  // Crossing with triangle (a, b, c) at t in [0, t_max]: fills t, u, v (weights of b and c).
  bool triangle(Vec3f a, Vec3f b, Vec3f c, double t_max, double& t, double& u, double& v) const {
    if (!valid) return false;
    // Zero area. For float corners of similar magnitude this cross product is exact in double
    // (so are the differences and their products): it is 0 exactly when the corners are collinear.
    const Vec3 n = cross(to_vec3(b) - to_vec3(a), to_vec3(c) - to_vec3(a));
    if (n.x == 0 && n.y == 0 && n.z == 0) return false;
    const Projected A = project(a), B = project(b), C = project(c);
    const double eu = edge(B, C), ev = edge(C, A), ew = edge(A, B);
    if ((eu < 0 || ev < 0 || ew < 0) && (eu > 0 || ev > 0 || ew > 0)) return false;
    const double det = eu + ev + ew;
    if (det == 0 || !std::isfinite(det)) return false;  // zero area seen along the segment
    // t·det, with the sign of det: inside [0, t_max] when tn/det is.
    const double tn = eu * A.z + ev * B.z + ew * C.z;
    if (det > 0 ? (tn < 0 || tn > t_max * det) : (tn > 0 || tn < t_max * det)) return false;
    const double rdet = 1.0 / det;
    t = std::clamp(tn * rdet, 0.0, t_max);
    u = std::clamp(ev * rdet, 0.0, 1.0);
    v = std::clamp(ew * rdet, 0.0, 1.0);
    return true;
  }
};

SegmentHit make_segment_hit(std::uint32_t face, double t, double u, double v, Vec3f a, Vec3f b, Vec3f c) {
  const Vec3 A = to_vec3(a);
  const Vec3 q = A + u * (to_vec3(b) - A) + v * (to_vec3(c) - A);
  return {face, static_cast<float>(t), to_vec3f(q), static_cast<float>(u), static_cast<float>(v)};
}

}  // namespace

// =============================================================================================

PointHit closest_point_on_triangle(Vec3f p, Vec3f a, Vec3f b, Vec3f c) {
  return to_hit(0, closest_on_triangle(to_vec3(p), to_vec3(a), to_vec3(b), to_vec3(c)));
}

double point_triangle_distance_squared(Vec3f p, Vec3f a, Vec3f b, Vec3f c) {
  return closest_on_triangle(to_vec3(p), to_vec3(a), to_vec3(b), to_vec3(c)).d2;
}

std::optional<SegmentHit> segment_triangle(Vec3f a, Vec3f b, Vec3f p0, Vec3f p1, Vec3f p2) {
  const Segment s(a, b);
  double t = 0, u = 0, v = 0;
  if (!s.triangle(p0, p1, p2, 1.0, t, u, v)) return std::nullopt;
  return make_segment_hit(0, t, u, v, p0, p1, p2);
}

// ---------------------------------------------------------------------------------------------

// ---------------------------------------------------------------------------------------------
// Queries. Each keeps a fixed stack on the C++ stack: a pop pushes at most two children, so it
// never holds more than depth + 1 entries.

template <class Leaf>
void TriangleBvh::walk_boxes_within(const MeshView& m, Vec3 q, double r2, Leaf&& leaf) const {
  // Boxes are culled with a hair of slack; the caller's test on each face decides.
  const double cull = r2 * (1 + 1e-9) + 1e-30;
  std::uint32_t stack[kMaxDepth + 2];
  std::size_t top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const Node& node = nodes_[stack[--top]];
    if (box_distance2(node.lo, node.hi, q) > cull) continue;
    if (is_leaf(node)) {
      leaf(node);
    } else if (node.count == kBlockNode) {
      stack[top++] = open(m, node.first);
    } else {
      stack[top++] = node.first + 1;
      stack[top++] = node.first;
    }
  }
}

void TriangleBvh::faces_within(const MeshView& m, Vec3f p, float r, std::vector<std::uint32_t>& out, bool tree_order) const {
  out.clear();
  if (!nodes_ || !(r >= 0)) return;
  const Vec3 q = to_vec3(p);
  const double r2 = double{r} * double{r};
  walk_boxes_within(m, q, r2, [&](const Node& node) {
    for (std::uint32_t i = node.first; i < node.first + node.count; ++i) {
      const std::uint32_t f = order_[i];
      if (closest_on_face(m, f, q).d2 <= r2) out.push_back(f);
    }
  });
  if (!tree_order) std::sort(out.begin(), out.end());
}

void TriangleBvh::faces_in_boxes_within(const MeshView& m, Vec3f p, float r, std::vector<std::uint32_t>& out) const {
  out.clear();
  if (!nodes_ || !(r >= 0)) return;
  walk_boxes_within(m, to_vec3(p), double{r} * double{r}, [&](const Node& node) {
    out.insert(out.end(), order_.begin() + node.first, order_.begin() + node.first + node.count);
  });
}

void TriangleBvh::faces_within_any(const MeshView& m, std::span<const Vec3f> points, float r,
                                   std::vector<std::uint32_t>& out, std::vector<std::uint32_t>& scratch) const {
  out.clear();
  scratch.clear();
  if (!nodes_ || !(r >= 0) || points.empty()) return;
  const double r2 = double{r} * double{r};
  const double cull = r2 * (1 + 1e-9) + 1e-30;  // as walk_boxes_within: the face test decides
  for (std::uint32_t i = 0; i < points.size(); ++i) scratch.push_back(i);
  // Each level appends the points of its range that reach the node's box, visits with them, and
  // drops them again: scratch stays within depth × #points.
  const auto visit = [&](const auto& self, std::uint32_t at, std::size_t begin, std::size_t end) -> void {
    const Node& node = nodes_[at];
    const std::size_t mine = scratch.size();
    for (std::size_t k = begin; k < end; ++k)
      if (box_distance2(node.lo, node.hi, to_vec3(points[scratch[k]])) <= cull) scratch.push_back(scratch[k]);
    const std::size_t mine_end = scratch.size();
    if (mine_end > mine) {
      if (node.count == kBlockNode) {
        self(self, open(m, node.first), mine, mine_end);
      } else if (node.count == 0) {
        self(self, node.first, mine, mine_end);
        self(self, node.first + 1, mine, mine_end);
      } else {
        for (std::uint32_t i = node.first; i < node.first + node.count; ++i) {
          const std::uint32_t f = order_[i];
          for (std::size_t k = mine; k < mine_end; ++k)
            if (closest_on_face(m, f, to_vec3(points[scratch[k]])).d2 <= r2) {
              out.push_back(f);
              break;
            }
        }
      }
    }
    scratch.resize(mine);
  };
  visit(visit, 0, 0, points.size());
  std::sort(out.begin(), out.end());
}

std::optional<PointHit> TriangleBvh::closest_point(const MeshView& m, Vec3f p, float max_distance) const {
  if (!nodes_ || !(max_distance >= 0)) return std::nullopt;
  const Vec3 q = to_vec3(p);
  double best = double{max_distance} * double{max_distance};
  std::optional<PointHit> hit;
  struct Entry {
    std::uint32_t node;
    double d2;
  };
  Entry stack[kMaxDepth + 2];
  std::size_t top = 0;
  stack[top++] = {0, box_distance2(nodes_[0].lo, nodes_[0].hi, q)};
  while (top > 0) {
    const Entry e = stack[--top];
    if (e.d2 > best) continue;
    const Node& node = nodes_[e.node];
    if (node.count == kBlockNode) {  // its one child: no nearer-first to choose
      const std::uint32_t root = open(m, node.first);
      const double d = box_distance2(nodes_[root].lo, nodes_[root].hi, q);
      if (d <= best) stack[top++] = {root, d};
    } else if (is_leaf(node)) {
      for (std::uint32_t i = node.first; i < node.first + node.count; ++i) {
        const std::uint32_t f = order_[i];
        const Closest c = closest_on_face(m, f, q);
        // Ties go to the lower face index, so the answer does not depend on the tree's shape.
        if (c.d2 < best || (c.d2 == best && (!hit || f < hit->face))) {
          best = c.d2;
          hit = to_hit(f, c);
        }
      }
    } else {
      // Nearer child on top, so it is searched first and tightens `best` for the other.
      const std::uint32_t a = node.first, b = node.first + 1;
      const double da = box_distance2(nodes_[a].lo, nodes_[a].hi, q);
      const double db = box_distance2(nodes_[b].lo, nodes_[b].hi, q);
      const bool a_first = da <= db;
      const Entry closer{a_first ? a : b, a_first ? da : db}, farther{a_first ? b : a, a_first ? db : da};
      if (farther.d2 <= best) stack[top++] = farther;
      if (closer.d2 <= best) stack[top++] = closer;
    }
  }
  return hit;
}

std::optional<SegmentHit> TriangleBvh::first_hit(const MeshView& m, Vec3f a, Vec3f b) const {
  if (!nodes_) return std::nullopt;
  const Segment s(a, b);
  if (!s.valid) return std::nullopt;
  double best = 1.0;
  std::optional<SegmentHit> hit;
  struct Entry {
    std::uint32_t node;
    double t;
  };
  Entry stack[kMaxDepth + 2];
  std::size_t top = 0;
  double t_enter = 0;
  if (!s.box(nodes_[0].lo, nodes_[0].hi, best, t_enter)) return std::nullopt;
  stack[top++] = {0, t_enter};
  while (top > 0) {
    const Entry e = stack[--top];
    if (e.t > best) continue;
    const Node& node = nodes_[e.node];
    if (node.count == kBlockNode) {
      const std::uint32_t root = open(m, node.first);
      double t = 0;
      if (s.box(nodes_[root].lo, nodes_[root].hi, best, t)) stack[top++] = {root, t};
    } else if (is_leaf(node)) {
      for (std::uint32_t i = node.first; i < node.first + node.count; ++i) {
        const std::uint32_t f = order_[i];
        const auto& tri = m.faces[f];
        const Vec3f p0 = vertex(m, tri[0]), p1 = vertex(m, tri[1]), p2 = vertex(m, tri[2]);
        double t = 0, u = 0, v = 0;
        // Ties (a segment through a shared edge) go to the lower face index, whatever the tree.
        if (s.triangle(p0, p1, p2, best, t, u, v) && (!hit || t < best || (t == best && f < hit->face))) {
          best = t;
          hit = make_segment_hit(f, t, u, v, p0, p1, p2);
        }
      }
    } else {
      const std::uint32_t c0 = node.first, c1 = node.first + 1;
      double t0 = 0, t1 = 0;
      const bool h0 = s.box(nodes_[c0].lo, nodes_[c0].hi, best, t0);
      const bool h1 = s.box(nodes_[c1].lo, nodes_[c1].hi, best, t1);
      if (h0 && h1) {
        const bool first0 = t0 <= t1;
        stack[top++] = first0 ? Entry{c1, t1} : Entry{c0, t0};
        stack[top++] = first0 ? Entry{c0, t0} : Entry{c1, t1};
      } else if (h0) {
        stack[top++] = {c0, t0};
      } else if (h1) {
        stack[top++] = {c1, t1};
      }
    }
  }
  return hit;
}

void TriangleBvh::segment_hits(const MeshView& m, Vec3f a, Vec3f b, std::vector<SegmentHit>& out) const {
  out.clear();
  if (!nodes_) return;
  const Segment s(a, b);
  if (!s.valid) return;
  std::uint32_t stack[kMaxDepth + 2];
  std::size_t top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const Node& node = nodes_[stack[--top]];
    double t_enter = 0;
    if (!s.box(node.lo, node.hi, 1.0, t_enter)) continue;
    if (node.count == kBlockNode) {
      stack[top++] = open(m, node.first);
    } else if (is_leaf(node)) {
      for (std::uint32_t i = node.first; i < node.first + node.count; ++i) {
        const std::uint32_t f = order_[i];
        const auto& tri = m.faces[f];
        const Vec3f p0 = vertex(m, tri[0]), p1 = vertex(m, tri[1]), p2 = vertex(m, tri[2]);
        double t = 0, u = 0, v = 0;
        if (s.triangle(p0, p1, p2, 1.0, t, u, v)) out.push_back(make_segment_hit(f, t, u, v, p0, p1, p2));
      }
    } else {
      stack[top++] = node.first + 1;
      stack[top++] = node.first;
    }
  }
  std::sort(out.begin(), out.end(), [](const SegmentHit& x, const SegmentHit& y) {
    return x.t != y.t ? x.t < y.t : x.face < y.face;
  });
}

// ---------------------------------------------------------------------------------------------

}  // namespace lancet::surface
