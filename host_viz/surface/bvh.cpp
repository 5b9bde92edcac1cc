#include "surface/bvh.hpp"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <thread>
#include <utility>

namespace lancet::surface {
namespace {

constexpr std::uint32_t kNone = 0xffffffffu;
constexpr int kBins = 16;
// Below this depth build() stops using SAH and splits at the median, which halves the count each
// level: SAH alone can make a chain as deep as the mesh on adversarial input.
constexpr std::size_t kMedianDepth = TriangleBvh::kMaxDepth - 40;
// A mesh this large builds its root's two subtrees on two threads.
constexpr std::size_t kParallelFaces = 1u << 16;
// A triangle whose |ab × ac|² is below this fraction of (longest edge)⁴ is treated as its edges.
constexpr double kDegenerate = 1e-14;

double at(Vec3 v, int axis) { return axis == 0 ? v.x : (axis == 1 ? v.y : v.z); }
float at(Vec3f v, int axis) { return axis == 0 ? v.x : (axis == 1 ? v.y : v.z); }

Vec3f vertex(const MeshView& m, std::uint32_t i) {
  assert(i < m.n_vertices && "TriangleBvh: face refers to a vertex past n_vertices");
  const float* p = m.xyz + 3 * static_cast<std::size_t>(i);
  return {p[0], p[1], p[2]};
}

struct Box {
  Vec3f lo{std::numeric_limits<float>::infinity(), std::numeric_limits<float>::infinity(),
           std::numeric_limits<float>::infinity()};
  Vec3f hi{-std::numeric_limits<float>::infinity(), -std::numeric_limits<float>::infinity(),
           -std::numeric_limits<float>::infinity()};

  void grow(Vec3f p) {
    lo = {std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z)};
    hi = {std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z)};
  }
  void grow(const Box& b) {
    grow(b.lo);
    grow(b.hi);
  }
  [[nodiscard]] bool empty() const { return !(lo.x <= hi.x); }
  // Half the surface area (the SAH only compares them).
  [[nodiscard]] double half_area() const {
    if (empty()) return 0;
    const double dx = double{hi.x} - lo.x, dy = double{hi.y} - lo.y, dz = double{hi.z} - lo.z;
    return dx * dy + dy * dz + dz * dx;
  }
};

Box face_box(const MeshView& m, std::uint32_t f) {
  Box b;
  for (std::uint32_t vi : m.faces[f]) b.grow(vertex(m, vi));
  return b;
}

bool encloses(Vec3f lo, Vec3f hi, Vec3f p) {
  return lo.x <= p.x && p.x <= hi.x && lo.y <= p.y && p.y <= hi.y && lo.z <= p.z && p.z <= hi.z;
}

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

// A face of the mesh while the tree is built: its box and centroid, carried along as faces are
// sorted.
struct BuildRef {
  Box box;
  Vec3f centroid;
  std::uint32_t face;
};

struct Bin {
  Box box;
  std::uint32_t count = 0;
};

// The binned SAH split of [first, last) (centroids within cbox) over all three axes: partitions
// the range at the cheapest bin boundary and returns the split point; `last` when no axis
// separates the centroids.
std::vector<BuildRef>::iterator sah_partition(std::vector<BuildRef>::iterator first, std::vector<BuildRef>::iterator last,
                                              const Box& cbox) {
  int best_axis = -1;
  double lo[3], scale[3];
  bool live[3];
  for (int a = 0; a < 3; ++a) {
    lo[a] = at(cbox.lo, a);
    const double extent = double{at(cbox.hi, a)} - lo[a];
    live[a] = extent > 0;
    scale[a] = live[a] ? kBins * (1 - 1e-9) / extent : 0.0;
  }
  const auto bin_of = [&](const BuildRef& r, int a) {
    return std::clamp(static_cast<int>((at(r.centroid, a) - lo[a]) * scale[a]), 0, kBins - 1);
  };
  Bin bins[3][kBins];
  for (auto it = first; it != last; ++it)
    for (int a = 0; a < 3; ++a) {
      Bin& b = bins[a][bin_of(*it, a)];
      b.box.grow(it->box);
      ++b.count;
    }
  double best_cost = std::numeric_limits<double>::infinity();
  int best_bin = 0;
  for (int a = 0; a < 3; ++a) {
    if (!live[a]) continue;
    // Sweep: right-hand areas and counts, then left to right.
    double right_area[kBins];
    std::uint32_t right_count[kBins];
    Box acc;
    std::uint32_t cnt = 0;
    for (int i = kBins - 1; i > 0; --i) {
      acc.grow(bins[a][i].box);
      cnt += bins[a][i].count;
      right_area[i] = acc.half_area();
      right_count[i] = cnt;
    }
    acc = Box{};
    cnt = 0;
    for (int i = 0; i < kBins - 1; ++i) {
      acc.grow(bins[a][i].box);
      cnt += bins[a][i].count;
      if (cnt == 0 || right_count[i + 1] == 0) continue;
      const double cost = acc.half_area() * cnt + right_area[i + 1] * right_count[i + 1];
      if (cost < best_cost) best_cost = cost, best_axis = a, best_bin = i;
    }
  }
  if (best_axis < 0) return last;
  return std::partition(first, last, [&](const BuildRef& r) { return bin_of(r, best_axis) <= best_bin; });
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

void TriangleBvh::build(const MeshView& m, bool threads) {
  nodes_.clear();
  parent_.clear();
  depth_ = 0;
  const std::size_t n = m.faces.size();
  assert(n < kNone && "TriangleBvh::build: too many faces");
  order_.resize(n);
  leaf_of_.assign(n, kNone);
  if (n == 0) return;

  // Faces are sorted in place as references carrying their box and centroid, so that every pass
  // of the build reads memory in order; order_ is read off the leaves.
  std::vector<BuildRef> refs(n);
  for (std::uint32_t f = 0; f < n; ++f) {
    const Box b = face_box(m, f);
    refs[f] = {b, {0.5f * (b.lo.x + b.hi.x), 0.5f * (b.lo.y + b.hi.y), 0.5f * (b.lo.z + b.hi.z)}, f};
  }

  struct Task {
    std::uint32_t node, begin, end;
    std::size_t depth;
  };
  nodes_.reserve(n);
  parent_.reserve(n);
  nodes_.push_back({});
  parent_.push_back(0);

  // Splits the tasks' nodes until every range is a leaf, depth first (the left child first), each
  // node's children appended to `nodes` side by side.
  // (max_tasks > 0: stops once the stack holds that many, for the caller to share them out.)
  const auto grow = [&](std::vector<Task>& tasks, std::vector<Node>& nodes, std::vector<std::uint32_t>& parents, std::size_t& depth,
                        std::size_t max_tasks) {
    while (!tasks.empty() && (max_tasks == 0 || tasks.size() < max_tasks)) {
      const Task task = tasks.back();
      tasks.pop_back();
      depth = std::max(depth, task.depth);
      const auto first = refs.begin() + task.begin, last = refs.begin() + task.end;
      Box box, cbox;
      for (auto it = first; it != last; ++it) {
        box.grow(it->box);
        cbox.grow(it->centroid);
      }
      nodes[task.node].lo = box.lo;
      nodes[task.node].hi = box.hi;
      const std::uint32_t count = task.end - task.begin;
      if (count <= kMaxLeafFaces) {
        nodes[task.node].first = task.begin;
        nodes[task.node].count = count;
        for (std::uint32_t i = task.begin; i < task.end; ++i) {
          order_[i] = refs[i].face;
          leaf_of_[refs[i].face] = task.node;
        }
        continue;
      }

      // Choose the split: the binned SAH over all three axes, or the median deep in the tree or
      // when every centroid coincides.
      std::uint32_t mid = task.begin + count / 2;
      bool split_by_sah = false;
      if (task.depth < kMedianDepth) {
        const auto split = sah_partition(first, last, cbox);
        split_by_sah = split != first && split != last;
        if (split_by_sah) mid = static_cast<std::uint32_t>(split - refs.begin());
      }
      if (!split_by_sah) {
        // Median along the widest centroid axis (any order when all centroids coincide).
        const double ex = double{cbox.hi.x} - cbox.lo.x, ey = double{cbox.hi.y} - cbox.lo.y,
                     ez = double{cbox.hi.z} - cbox.lo.z;
        const int axis = ex >= ey ? (ex >= ez ? 0 : 2) : (ey >= ez ? 1 : 2);
        std::nth_element(first, refs.begin() + mid, last,
                         [&](const BuildRef& a, const BuildRef& b) { return at(a.centroid, axis) < at(b.centroid, axis); });
      }

      const auto child = static_cast<std::uint32_t>(nodes.size());
      nodes[task.node].first = child;
      nodes[task.node].count = 0;
      nodes.push_back({});
      nodes.push_back({});
      parents.push_back(task.node);
      parents.push_back(task.node);
      tasks.push_back({child + 1, mid, task.end, task.depth + 1});
      tasks.push_back({child, task.begin, mid, task.depth + 1});
    }
  };

  // The root's split here; then, for a large mesh, the right subtree on a second thread into its
  // own arrays while this one builds the left, spliced in after it with the indices a one-thread
  // build gives (the left subtree's nodes all come before the right's, but for its root): the
  // same tree, node for node, whatever the threads do.
  std::vector<Task> tasks{{0, 0, static_cast<std::uint32_t>(n), 1}};
  const bool two = threads && n >= kParallelFaces && std::thread::hardware_concurrency() > 1;
  grow(tasks, nodes_, parent_, depth_, two ? 2 : 0);
  if (!tasks.empty()) {
    // tasks = {right child, left child} of the root (the left on top).
    const Task right = tasks.front();
    std::vector<Task> right_tasks{{0, right.begin, right.end, right.depth}};
    std::vector<Node> right_nodes(1);
    std::vector<std::uint32_t> right_parents(1, 0);
    std::size_t right_depth = 0;
    std::thread worker([&] { grow(right_tasks, right_nodes, right_parents, right_depth, 0); });
    tasks.erase(tasks.begin());
    grow(tasks, nodes_, parent_, depth_, 0);
    worker.join();
    // Local index 0 is the right child (global right.node); local i >= 1 goes after the left's.
    const auto base = static_cast<std::uint32_t>(nodes_.size());
    const auto global = [&](std::uint32_t i) { return i == 0 ? right.node : base + i - 1; };
    nodes_.resize(base + right_nodes.size() - 1);
    parent_.resize(nodes_.size());
    for (std::uint32_t i = 0; i < right_nodes.size(); ++i) {
      Node node = right_nodes[i];
      if (node.count == 0) node.first = global(node.first);  // internal: its children
      nodes_[global(i)] = node;
      if (i > 0) parent_[global(i)] = global(right_parents[i]);
    }
    for (std::uint32_t i = right.begin; i < right.end; ++i) leaf_of_[order_[i]] = global(leaf_of_[order_[i]]);
    depth_ = std::max(depth_, right_depth);
  }
  assert(depth_ <= kMaxDepth && "TriangleBvh::build: tree deeper than the traversal stacks");
  nodes_.shrink_to_fit();
  parent_.shrink_to_fit();
}

bool TriangleBvh::same_tree(const TriangleBvh& o) const {
  if (nodes_.size() != o.nodes_.size() || order_ != o.order_ || leaf_of_ != o.leaf_of_ || parent_ != o.parent_ || depth_ != o.depth_)
    return false;
  for (std::size_t i = 0; i < nodes_.size(); ++i) {
    const Node &a = nodes_[i], &b = o.nodes_[i];
    if (!(a.lo == b.lo) || !(a.hi == b.hi) || a.first != b.first || a.count != b.count) return false;
  }
  return true;
}

void TriangleBvh::refit_leaf(const MeshView& m, Node& node) const {
  Box b;
  for (std::uint32_t i = node.first; i < node.first + node.count; ++i) b.grow(face_box(m, order_[i]));
  node.lo = b.lo;
  node.hi = b.hi;
}

void TriangleBvh::refit(const MeshView& m) {
  assert(m.faces.size() == order_.size() && "TriangleBvh::refit: face count changed since build");
  // Children always come after their parent, so one backward sweep is bottom-up.
  for (std::size_t i = nodes_.size(); i-- > 0;) {
    Node& node = nodes_[i];
    if (node.count > 0) {
      refit_leaf(m, node);
    } else {
      const Node& l = nodes_[node.first];
      const Node& r = nodes_[node.first + 1];
      node.lo = {std::min(l.lo.x, r.lo.x), std::min(l.lo.y, r.lo.y), std::min(l.lo.z, r.lo.z)};
      node.hi = {std::max(l.hi.x, r.hi.x), std::max(l.hi.y, r.hi.y), std::max(l.hi.z, r.hi.z)};
    }
  }
}

void TriangleBvh::refit_faces(const MeshView& m, std::span<const std::uint32_t> faces) {
  assert(m.faces.size() == order_.size() && "TriangleBvh::refit_faces: face count changed since build");
  for (std::uint32_t f : faces) {
    assert(f < leaf_of_.size() && "TriangleBvh::refit_faces: face index out of range");
    std::uint32_t i = leaf_of_[f];
    Node& leaf = nodes_[i];
    const Vec3f lo = leaf.lo, hi = leaf.hi;
    refit_leaf(m, leaf);
    if (leaf.lo == lo && leaf.hi == hi) continue;
    // Every internal box is the exact union of its children, so once a box comes out unchanged
    // its ancestors are unchanged too.
    while (i != 0) {
      i = parent_[i];
      Node& node = nodes_[i];
      const Node& l = nodes_[node.first];
      const Node& r = nodes_[node.first + 1];
      const Vec3f nlo{std::min(l.lo.x, r.lo.x), std::min(l.lo.y, r.lo.y), std::min(l.lo.z, r.lo.z)};
      const Vec3f nhi{std::max(l.hi.x, r.hi.x), std::max(l.hi.y, r.hi.y), std::max(l.hi.z, r.hi.z)};
      if (nlo == node.lo && nhi == node.hi) break;
      node.lo = nlo;
      node.hi = nhi;
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Queries. Each keeps a fixed stack on the C++ stack: a pop pushes at most two children, so it
// never holds more than depth + 1 entries.

void TriangleBvh::faces_within(const MeshView& m, Vec3f p, float r, std::vector<std::uint32_t>& out, bool tree_order) const {
  out.clear();
  if (nodes_.empty() || !(r >= 0)) return;
  const Vec3 q = to_vec3(p);
  const double r2 = double{r} * double{r};
  // Boxes are culled with a hair of slack; the exact test on each face decides.
  const double cull = r2 * (1 + 1e-9) + 1e-30;
  std::uint32_t stack[kMaxDepth + 2];
  std::size_t top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const Node& node = nodes_[stack[--top]];
    if (box_distance2(node.lo, node.hi, q) > cull) continue;
    if (node.count > 0) {
      for (std::uint32_t i = node.first; i < node.first + node.count; ++i) {
        const std::uint32_t f = order_[i];
        if (closest_on_face(m, f, q).d2 <= r2) out.push_back(f);
      }
    } else {
      stack[top++] = node.first + 1;
      stack[top++] = node.first;
    }
  }
  if (!tree_order) std::sort(out.begin(), out.end());
}

std::optional<PointHit> TriangleBvh::closest_point(const MeshView& m, Vec3f p, float max_distance) const {
  if (nodes_.empty() || !(max_distance >= 0)) return std::nullopt;
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
    if (node.count > 0) {
      for (std::uint32_t i = node.first; i < node.first + node.count; ++i) {
        const std::uint32_t f = order_[i];
        const Closest c = closest_on_face(m, f, q);
        if (c.d2 < best || (!hit && c.d2 <= best)) {
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
  if (nodes_.empty()) return std::nullopt;
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
    if (node.count > 0) {
      for (std::uint32_t i = node.first; i < node.first + node.count; ++i) {
        const std::uint32_t f = order_[i];
        const auto& tri = m.faces[f];
        const Vec3f p0 = vertex(m, tri[0]), p1 = vertex(m, tri[1]), p2 = vertex(m, tri[2]);
        double t = 0, u = 0, v = 0;
        if (s.triangle(p0, p1, p2, best, t, u, v) && (!hit || t < best)) {
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
  if (nodes_.empty()) return;
  const Segment s(a, b);
  if (!s.valid) return;
  std::uint32_t stack[kMaxDepth + 2];
  std::size_t top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const Node& node = nodes_[stack[--top]];
    double t_enter = 0;
    if (!s.box(node.lo, node.hi, 1.0, t_enter)) continue;
    if (node.count > 0) {
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

bool TriangleBvh::check(const MeshView& m) const {
  const std::size_t n = order_.size();
  if (m.faces.size() != n || leaf_of_.size() != n || parent_.size() != nodes_.size()) return false;
  if (n == 0) return nodes_.empty();
  if (nodes_.empty() || depth_ > kMaxDepth) return false;
  std::vector<std::uint8_t> seen(n, 0);
  for (std::size_t i = 0; i < nodes_.size(); ++i) {
    const Node& node = nodes_[i];
    if (!(node.lo.x <= node.hi.x && node.lo.y <= node.hi.y && node.lo.z <= node.hi.z)) return false;
    if (node.count > 0) {
      if (node.count > kMaxLeafFaces || std::size_t{node.first} + node.count > n) return false;
      for (std::uint32_t k = node.first; k < node.first + node.count; ++k) {
        const std::uint32_t f = order_[k];
        if (f >= n || seen[f]++ != 0 || leaf_of_[f] != i) return false;
        for (std::uint32_t vi : m.faces[f]) {
          if (vi >= m.n_vertices || !encloses(node.lo, node.hi, vertex(m, vi))) return false;
        }
      }
    } else {
      if (node.first <= i || std::size_t{node.first} + 1 >= nodes_.size()) return false;
      for (std::uint32_t c : {node.first, node.first + 1}) {
        if (parent_[c] != i) return false;
        if (!encloses(node.lo, node.hi, nodes_[c].lo) || !encloses(node.lo, node.hi, nodes_[c].hi)) return false;
      }
    }
  }
  return std::all_of(seen.begin(), seen.end(), [](std::uint8_t s) { return s == 1; });
}

std::size_t TriangleBvh::size_bytes() const {
  return nodes_.capacity() * sizeof(Node) + (parent_.capacity() + order_.capacity() + leaf_of_.capacity()) * sizeof(std::uint32_t);
}

}  // namespace lancet::surface
