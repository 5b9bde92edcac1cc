#pragma once
// build_triangle_mesh: OpenMesh half-edge connectivity for an indexed triangle mesh, built
// directly instead of one add_face() at a time.
//
// add_face() has to find, for every corner, where the new face fits among those already around
// the vertex (a search of the vertex's one-ring, and a re-linking of its boundary loops), which
// is most of the cost of turning marching cubes' output into a mesh. But the whole topology is
// known up front: every edge's two triangles can be paired at once. Here:
//   1. the 3·T directed edges are bucketed by their lower vertex (a counting sort, O(T)) and each
//      is paired with its reverse in its bucket; an edge used twice in the same direction, or by
//      more than two triangles, or a triangle that repeats a vertex, is not a manifold and the
//      build gives up (the caller then falls back to add_face, which refuses such faces one by
//      one); so does a vertex whose triangles are not one fan (walked across the paired edges);
//      all of this before the mesh is touched;
//   2. one OpenMesh edge per undirected edge, one face per triangle in input order (all made by
//      one resize of the mesh's arrays), the three half-edges of each face linked next → next;
//   3. the boundary half-edges (edges with one triangle) are linked around each hole: the one that
//      ends at vertex v is followed by the one that leaves v (one per vertex: one fan);
//   4. each vertex's outgoing half-edge is its boundary one when it has one (OpenMesh's rule).
// The passes over the corners and vertices run on two threads for a large mesh (all but the
// prefix sum and the boundary links); where a pass counts (the buckets, the corners leaving each
// vertex), each half counts its own and the counts are merged in corner order, so the result
// does not depend on the thread count.
// The result equals what add_face gives face for face (same faces, in the same order, with the
// same vertex cycles, the same one-rings in the same cyclic order); only the numbering of edges
// differs. Allocates O(T) scratch; not real-time.

#include <algorithm>
#include <array>
#include <cstdint>
#include <span>
#include <thread>
#include <utility>
#include <vector>

#include "volume/build_arrays.hpp"
#include "volume/in_two_halves.hpp"

namespace lancet::volume {

namespace detail {

/// The corner after c in its triangle (corner 3t + k of triangle t runs from t[k] to t[k+1]): it
/// leaves the vertex c runs to. prev_corner: the one before, which runs to the vertex c leaves.
constexpr std::uint32_t next_corner(std::uint32_t c) noexcept { return c - c % 3 + (c % 3 + 1) % 3; }
constexpr std::uint32_t prev_corner(std::uint32_t c) noexcept { return c - c % 3 + (c % 3 + 2) % 3; }

/// Steps 1 and the fan check, on the triangles' corners alone (corner 3t + k of triangle t runs
/// from t[k] to t[k+1]): each corner paired with its reverse, and each vertex's last corner. Its
/// arrays are reused by the mesh's build afterwards (bucket: each corner's half-edge).
struct CornerPairs {
  static constexpr std::uint32_t kNone = 0xffffffffu, kUp = 0x80000000u, kCorner = 0x7fffffffu;
  // An edge's bucket entry: its upper vertex, and which way the corner runs (bit 31 of the corner:
  // set when it runs from the lower vertex), so that pairing reads the bucket alone.
  struct Entry {
    std::uint32_t corner_dir, hi;
  };
  std::span<const std::array<std::uint32_t, 3>> triangles;
  std::size_t nv = 0, nt = 0;
  bool two = false;                        // large enough for two threads
  std::vector<std::uint32_t> start, fill;  // bucket offsets (spent after pairing)
  ScratchVector<Entry> bucket;             // filled in full by pair()
  ScratchVector<std::uint32_t> partner;    // per corner: its reverse's corner (or kNone)
  std::vector<std::uint32_t> last;         // per vertex: the last corner leaving it (or kNone)

  CornerPairs(std::size_t vertices, std::span<const std::array<std::uint32_t, 3>> tris)
      : triangles(tris), nv(vertices), nt(tris.size()), two(worth_two_threads(tris.size())) {}
  [[nodiscard]] std::uint32_t from(std::uint32_t c) const { return triangles[c / 3][c % 3]; }
  [[nodiscard]] std::uint32_t to(std::uint32_t c) const { return triangles[c / 3][(c % 3 + 1) % 3]; }

  /// Buckets the corners by their lower vertex (a counting sort) and pairs each with its reverse.
  /// False for an index out of range, a repeated vertex, an edge used twice the same way or by
  /// a third triangle.
  bool pair() {
    if (3 * nt > kCorner) return false;
    // Each half of the triangles counts its corners per bucket apart (fill: half 1's counts), so
    // that the halves then fill their buckets at once, half 1's corners after half 0's: the same
    // bucket order as one pass in corner order.
    start.assign(nv + 1, 0);
    fill.assign(nv + 1, 0);
    bool valid[2] = {true, true};
    in_two_halves(nt, two, [&](std::size_t begin, std::size_t end, int half) {
      std::uint32_t* count = (half == 0 ? start : fill).data();
      for (std::size_t t = begin; t < end && valid[half]; ++t)
        for (int k = 0; k < 3; ++k) {
          const std::uint32_t a = triangles[t][static_cast<std::size_t>(k)], b = triangles[t][static_cast<std::size_t>((k + 1) % 3)];
          if (a >= nv || b >= nv || a == b) {
            valid[half] = false;
            break;
          }
          ++count[std::min(a, b)];
        }
    });
    if (!valid[0] || !valid[1]) return false;
    // start[v]: bucket v's first entry; fill[v]: where half 1's entries of bucket v begin.
    std::uint32_t sum = 0;
    for (std::size_t v = 0; v <= nv; ++v) {
      const std::uint32_t c0 = start[v], c1 = fill[v];
      start[v] = sum;
      fill[v] = sum + c0;
      sum += c0 + c1;
    }
    bucket.resize(3 * nt);
    in_two_halves(nt, two, [&](std::size_t begin, std::size_t end, int half) {
      // Half 0 fills from each bucket's start (it moves start on; put back below), half 1 from fill.
      std::uint32_t* at = (half == 0 ? start : fill).data();
      for (std::size_t t = begin; t < end; ++t)
        for (std::uint32_t k = 0; k < 3; ++k) {
          const auto& tri = triangles[t];
          const std::uint32_t a = tri[k], b = tri[(k + 1) % 3];
          bucket[at[std::min(a, b)]++] = {static_cast<std::uint32_t>(3 * t + k) | (a < b ? kUp : 0u), std::max(a, b)};
        }
    });
    // Half 0 has moved each start to where half 1's entries begin, which half 1's count says
    // is where the bucket began: fill has moved to the bucket's end, the next bucket's start.
    for (std::size_t v = nv; v > 0; --v) start[v] = fill[v - 1];
    start[0] = 0;
    // A corner lies in one bucket only, so the buckets are shared between two threads.
    partner.resize(3 * nt);
    in_two_halves(3 * nt, two, [&](std::size_t begin, std::size_t end, int) { std::fill(partner.begin() + begin, partner.begin() + end, kNone); });
    bool paired[2] = {true, true};
    in_two_halves(nv, two, [&](std::size_t begin, std::size_t end, int half) {
      for (std::size_t v = begin; v < end && paired[half]; ++v) {
        for (std::uint32_t i = start[v]; i < start[v + 1]; ++i) {
          const Entry ei = bucket[i];
          const std::uint32_t c = ei.corner_dir & kCorner;
          for (std::uint32_t j = i + 1; j < start[v + 1]; ++j) {
            const Entry ej = bucket[j];
            if (ej.hi != ei.hi) continue;
            const std::uint32_t d = ej.corner_dir & kCorner;
            // The same direction twice (not oriented), or a third triangle on the edge.
            if ((ej.corner_dir ^ ei.corner_dir) < kUp || partner[c] != kNone || partner[d] != kNone) {
              paired[half] = false;
              break;
            }
            partner[c] = d;
            partner[d] = c;
          }
        }
      }
    });
    return paired[0] && paired[1];
  }

  /// A manifold vertex's triangles form one fan: walking from one of its corners across shared
  /// edges (both ways until a boundary) visits all of them. Two fans meeting at a vertex do not.
  /// Also finds each vertex's last corner. After pair().
  bool one_fan_each() {
    // The buckets' offsets are spent: their arrays (already touched) count the corners leaving
    // each vertex, each half of the corners its own (count: half 0's, other: half 1's), and each
    // half finds its last corner leaving each vertex (half 1's in last_of_half1); merged after.
    std::vector<std::uint32_t>& count = fill;
    std::vector<std::uint32_t>& other = start;
    std::fill(count.begin(), count.end(), 0u);
    std::fill(other.begin(), other.end(), 0u);
    last.assign(nv, kNone);
    std::vector<std::uint32_t> last_of_half1(nv, kNone);
    in_two_halves(3 * nt, two, [&](std::size_t begin, std::size_t end, int half) {
      std::uint32_t* n = (half == 0 ? count : other).data();
      std::uint32_t* l = (half == 0 ? last : last_of_half1).data();
      for (auto c = static_cast<std::uint32_t>(begin); c < end; ++c) {
        ++n[from(c)];
        l[from(c)] = c;
      }
    });
    in_two_halves(nv, two, [&](std::size_t begin, std::size_t end, int) {
      for (std::size_t v = begin; v < end; ++v) {
        count[v] += other[v];
        if (last_of_half1[v] != kNone) last[v] = last_of_half1[v];
      }
    });
    // One vertex's walk; false when its triangles are not one fan.
    const auto one_fan = [&](std::size_t v) {
      if (last[v] == kNone) return true;
      std::uint32_t seen = 1;
      // Forward: from the corner leaving v, across the edge arriving at v in its triangle.
      std::uint32_t c = last[v];
      bool closed = false;
      while (true) {
        const std::uint32_t n = partner[prev_corner(c)];
        if (n == kNone) break;
        if (n == last[v]) {
          closed = true;
          break;
        }
        if (++seen > count[v]) return false;
        c = n;
      }
      if (!closed) {  // backward from the start, across its own edge
        c = last[v];
        while (partner[c] != kNone) {
          c = next_corner(partner[c]);
          if (++seen > count[v]) return false;
        }
      }
      return seen == count[v];
    };
    // The walks read only; a large mesh shares them between two threads.
    bool fans[2] = {true, true};
    in_two_halves(nv, two, [&](std::size_t begin, std::size_t end, int half) {
      for (std::size_t v = begin; v < end && fans[half]; ++v) fans[half] = one_fan(v);
    });
    return fans[0] && fans[1];
  }
};

}  // namespace detail

/// The corners of the mesh build_triangle_mesh made, to walk its one-rings on compact arrays
/// rather than the mesh's: corner 3t + k of triangle t runs from t[k] to t[k+1] (vertex indices),
/// and triangle t is the mesh's face t.
struct TriangleCorners {
  static constexpr std::uint32_t kNone = detail::CornerPairs::kNone;
  ScratchVector<std::uint32_t> partner;  ///< per corner: the corner along its edge the other way, or kNone (a boundary edge)
  std::vector<std::uint32_t> first;      ///< per vertex: the corner leaving it whose triangle vf_range visits first (kNone: none)

  /// f(t) for every triangle t around vertex v, in the order of the mesh's vf_range(v): clockwise
  /// (next of opposite) from the vertex's half-edge, which for a boundary vertex is the boundary.
  template <class F>
  void for_each_triangle_around(std::uint32_t v, F&& f) const {
    const std::uint32_t s = first[v];
    if (s == kNone) return;
    std::uint32_t c = s;
    do {
      f(c / 3);
      const std::uint32_t p = partner[c];  // runs back to v
      if (p == kNone) return;              // the boundary: the fan's last triangle
      c = detail::next_corner(p);          // the corner after it leaves v
    } while (c != s);
  }
};

/// Appends the triangles to `mesh` (an OpenMesh mesh with those vertices already added, and no
/// faces yet): `vertices[i]` is the handle of index i. Returns false, leaving the mesh without
/// faces, when the triangles are not an oriented 2-manifold (with boundary); then use add_face.
/// With `on_boundary`, also sets it to one byte per triangle: 1 where an edge of the triangle is
/// on the boundary (no other triangle shares it), else 0. With `corners`, also hands over the
/// corners' pairing (see TriangleCorners).
template <class Mesh>
bool build_triangle_mesh(Mesh& mesh, std::span<const typename Mesh::VertexHandle> vertices,
                         std::span<const std::array<std::uint32_t, 3>> triangles, std::vector<std::uint8_t>* on_boundary = nullptr,
                         TriangleCorners* corners = nullptr) {
  using HH = typename Mesh::HalfedgeHandle;
  using FH = typename Mesh::FaceHandle;
  using VH = typename Mesh::VertexHandle;
  const std::size_t nv = vertices.size(), nt = triangles.size();
  if (mesh.n_faces() != 0) return false;
  detail::CornerPairs cp(nv, triangles);
  // Every edge has one or two corners, so a manifold has at least 3·nt/2 edges: that many, and the
  // faces, are made (their arrays filled with OpenMesh's defaults, mostly the first touch of fresh
  // pages, on one thread) while the corners pair up, and the few boundary edges added after.
  const std::size_t e0 = mesh.n_edges(), v0 = mesh.n_vertices();
  bool paired = false;
  {
    std::jthread sizer;
    if (cp.two)
      sizer = std::jthread([&] { mesh.resize(v0, e0 + 3 * nt / 2, nt); });
    else
      mesh.resize(v0, e0 + 3 * nt / 2, nt);
    paired = cp.pair() && cp.one_fan_each();
  }
  if (!paired) {
    mesh.resize(v0, e0, 0);  // as it came: no faces
    return false;
  }
  constexpr std::uint32_t kNone = detail::CornerPairs::kNone;
  const bool two = cp.two;
  const auto& partner = cp.partner;
  const std::vector<std::uint32_t>& last = cp.last;
  auto& bucket = cp.bucket;
  const auto from = [&](std::uint32_t c) { return cp.from(c); };
  const auto to = [&](std::uint32_t c) { return cp.to(c); };

  // 2. Edges, faces and their half-edge cycles.
  // Edge e is made by the first corner that has it (one without a partner, or the lower of the
  // two): its number counts such corners before it, in corner order, as new_edge one at a time
  // would number them. Each half of the corners counts its own, so the halves run at once, and
  // lists its boundary corners (no partner), for 3. and 4. below: the halves joined, corner order.
  const auto owns = [&](std::uint32_t c) { return partner[c] == kNone || partner[c] > c; };
  std::size_t owned[2] = {0, 0};
  std::vector<std::uint32_t> open[2];
  in_two_halves(3 * nt, two, [&](std::size_t begin, std::size_t end, int h) {
    for (auto c = static_cast<std::uint32_t>(begin); c < end; ++c) {
      owned[h] += owns(c) ? 1 : 0;
      if (partner[c] == kNone) open[h].push_back(c);
    }
  });
  open[0].insert(open[0].end(), open[1].begin(), open[1].end());
  const std::vector<std::uint32_t>& boundary = open[0];
  // All edges and faces are made at once (ArrayKernel::resize: one resize of each property array,
  // where new_edge and new_face grow every property by one element a call; here only the boundary
  // edges are left to add), then filled in: edge e's half-edge 2e runs its corner's way, 2e + 1
  // the partner's. Every corner's half-edge is written once (by its edge's corner), every
  // half-edge belongs to one face: the halves write apart. (A caller that reserved room for the
  // edges, 3·nt/2 on a closed surface and a little more with a boundary, never has its arrays
  // moved here; one that reserved fewer has them grown to the exact count by reserve() rather
  // than doubled by resize().)
  mesh.reserve(v0, e0 + owned[0] + owned[1], nt);
  mesh.resize(v0, e0 + owned[0] + owned[1], nt);
  // Corner → its half-edge (from → to): kept in the spent buckets, one entry a corner (their pages
  // are touched already, where a new array would fault in 4 bytes a corner again).
  const auto half = [&](std::size_t c) { return HH(static_cast<int>(bucket[c].corner_dir)); };
  const auto set_half = [&](std::size_t c, HH h) { bucket[c].corner_dir = static_cast<std::uint32_t>(h.idx()); };
  in_two_halves(3 * nt, two, [&](std::size_t begin, std::size_t end, int which) {
    std::size_t e = e0 + (which == 0 ? 0 : owned[0]);
    for (std::size_t i = begin; i < end; ++i) {
      const auto c = static_cast<std::uint32_t>(i);
      if (!owns(c)) continue;
      const HH h(static_cast<int>(2 * e));
      set_half(c, h);
      mesh.set_vertex_handle(h, vertices[to(c)]);
      mesh.set_vertex_handle(mesh.opposite_halfedge_handle(h), vertices[from(c)]);
      if (partner[c] != kNone) set_half(partner[c], mesh.opposite_halfedge_handle(h));
      ++e;
    }
  });
  in_two_halves(nt, two, [&](std::size_t begin, std::size_t end, int) {
    for (std::size_t t = begin; t < end; ++t) {
      const FH f(static_cast<int>(t));
      const HH h0 = half(3 * t), h1 = half(3 * t + 1), h2 = half(3 * t + 2);
      mesh.set_halfedge_handle(f, h0);
      for (const HH h : {h0, h1, h2}) mesh.set_face_handle(h, f);
      mesh.set_next_halfedge_handle(h0, h1);
      mesh.set_next_halfedge_handle(h1, h2);
      mesh.set_next_halfedge_handle(h2, h0);
    }
  });
  // Every vertex's outgoing half-edge is its last corner's (as setting it corner by corner leaves
  // it); 4. replaces it by the boundary one where there is one.
  in_two_halves(nv, two, [&](std::size_t begin, std::size_t end, int) {
    for (std::size_t v = begin; v < end; ++v)
      if (last[v] != kNone) mesh.set_halfedge_handle(vertices[v], half(last[v]));
  });
  // 3. Boundary loops: the boundary half-edge of corner c runs to → from; the one leaving each
  // vertex is unique on a manifold.
  std::vector<HH> boundary_out(nv);
  for (const std::uint32_t c : boundary) {
    const HH b = mesh.opposite_halfedge_handle(half(c));
    boundary_out[to(c)] = b;  // b leaves to(c); one per vertex (the fan check above)
  }
  for (const std::uint32_t c : boundary) {
    const HH b = mesh.opposite_halfedge_handle(half(c));  // runs to(c) → from(c)
    mesh.set_next_halfedge_handle(b, boundary_out[from(c)]);
  }
  // 4. Boundary vertices start their one-ring at the boundary.
  for (std::size_t v = 0; v < nv; ++v)
    if (boundary_out[v].is_valid()) mesh.set_halfedge_handle(VH(vertices[v]), boundary_out[v]);
  if (on_boundary != nullptr) {
    on_boundary->assign(nt, 0);
    for (const std::uint32_t c : boundary) (*on_boundary)[c / 3] = 1;
  }
  if (corners != nullptr) {
    // A vertex's half-edge is its last corner's (2.), or on a boundary the boundary half-edge
    // leaving it (4.), from whose clockwise turn the circulator starts: the corner after the
    // boundary corner arriving at the vertex.
    corners->first = std::move(cp.last);
    for (const std::uint32_t c : boundary) corners->first[to(c)] = detail::next_corner(c);
    corners->partner = std::move(cp.partner);
  }
  return true;
}

}  // namespace lancet::volume
