#include "volume/marching_cubes.hpp"

#include "volume/halfedge_build.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <string>
#include <thread>

#include "volume/detail/mc_core.hpp"

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace lancet::volume {

// ---- case table ---------------------------------------------------------------------------------
// Generated, not transcribed: for each of the 256 inside/outside patterns the surface's trace on
// each of the six cube faces is a set of segments between crossing edges. A face with two
// crossings has one segment; an ambiguous face (four crossings, diagonal corners alike) gets two,
// each cutting off one inside corner. The rule looks at the face alone, so the two cubes sharing a
// face trace the same segments there: the surface is watertight. Each segment is directed so that
// the surface's normal points from inside to outside; every crossing edge then has one segment in
// and one out, and following them gives closed polygons, which are triangulated.

std::array<int, 2> mc_edge_corners(int edge) noexcept {
  const int axis = edge / 4, r = edge % 4;
  const int u = (axis + 1) % 3, w = (axis + 2) % 3;  // the two other axes
  const int base = ((r & 1) << std::min(u, w)) | (((r >> 1) & 1) << std::max(u, w));
  return {base, base | (1 << axis)};
}

namespace {

int edge_between(int c0, int c1) {
  for (int e = 0; e < 12; ++e) {
    const auto c = mc_edge_corners(e);
    if ((c[0] == c0 && c[1] == c1) || (c[0] == c1 && c[1] == c0)) return e;
  }
  throw std::logic_error("marching cubes: corners " + std::to_string(c0) + " and " + std::to_string(c1) + " share no edge");
}

struct P3 {
  double v[3];
};
P3 corner_pos(int c) { return P3{{double(c & 1), double((c >> 1) & 1), double((c >> 2) & 1)}}; }
P3 edge_mid(int e) {
  const auto c = mc_edge_corners(e);
  const P3 a = corner_pos(c[0]), b = corner_pos(c[1]);
  return P3{{(a.v[0] + b.v[0]) / 2, (a.v[1] + b.v[1]) / 2, (a.v[2] + b.v[2]) / 2}};
}
P3 sub(P3 a, P3 b) { return P3{{a.v[0] - b.v[0], a.v[1] - b.v[1], a.v[2] - b.v[2]}}; }
P3 crs(P3 a, P3 b) {
  return P3{{a.v[1] * b.v[2] - a.v[2] * b.v[1], a.v[2] * b.v[0] - a.v[0] * b.v[2], a.v[0] * b.v[1] - a.v[1] * b.v[0]}};
}
double dt(P3 a, P3 b) { return a.v[0] * b.v[0] + a.v[1] * b.v[1] + a.v[2] * b.v[2]; }

// The two faces (axis · 2 + side) an edge lies on.
std::array<int, 2> edge_faces(int e) {
  const auto c = mc_edge_corners(e)[0];
  const int axis = e / 4;
  std::array<int, 2> f{};
  int n = 0;
  for (int a = 0; a < 3; ++a)
    if (a != axis) f[static_cast<std::size_t>(n++)] = a * 2 + ((c >> a) & 1);
  return f;
}
bool share_face(int e0, int e1) {
  for (int a : edge_faces(e0))
    for (int b : edge_faces(e1))
      if (a == b) return true;
  return false;
}

// Triangulates polygon p (cube edges in order) with no diagonal between two edges on one cube face
// (such a diagonal could be shared with the neighbouring cube's triangulation: an edge with four
// faces). Interval dynamic programme over the polygon; false when impossible.
bool triangulate(const std::vector<int>& p, std::vector<std::array<int, 3>>& out) {
  const int m = static_cast<int>(p.size());
  const auto allowed = [&](int i, int j) {
    if (j == i + 1 || (i == 0 && j == m - 1)) return true;
    return !share_face(p[static_cast<std::size_t>(i)], p[static_cast<std::size_t>(j)]);
  };
  std::vector<int> split(static_cast<std::size_t>(m * m), -2);  // -2 unknown, -1 impossible
  const auto at = [&](int i, int j) -> int& { return split[static_cast<std::size_t>(i * m + j)]; };
  // solve(i, j): can polygon i..j (closed by chord i-j) be triangulated?
  const auto solve = [&](auto&& self, int i, int j) -> bool {
    if (j - i < 2) return true;
    int& s = at(i, j);
    if (s != -2) return s >= 0;
    s = -1;
    for (int k = i + 1; k < j; ++k)
      if (allowed(i, k) && allowed(k, j) && self(self, i, k) && self(self, k, j)) {
        s = k;
        break;
      }
    return s >= 0;
  };
  if (!solve(solve, 0, m - 1)) return false;
  const auto emit = [&](auto&& self, int i, int j) -> void {
    if (j - i < 2) return;
    const int k = at(i, j);
    out.push_back({p[static_cast<std::size_t>(i)], p[static_cast<std::size_t>(k)], p[static_cast<std::size_t>(j)]});
    self(self, i, k);
    self(self, k, j);
  };
  emit(emit, 0, m - 1);
  return true;
}

std::array<McCase, 256> build_table() {
  std::array<McCase, 256> table{};
  for (int cs = 0; cs < 256; ++cs) {
    const auto inside = [&](int c) { return ((cs >> c) & 1) != 0; };
    std::array<int, 12> next;
    next.fill(-1);
    const auto add_segment = [&](int e0, int e1, P3 toward_outside, P3 face_normal) {
      // Direct the segment along N × n (N: inside → outside within the face, n: the face's
      // outward normal); then the polygon winds counter-clockwise about the outward normal.
      const P3 d = crs(toward_outside, face_normal);
      if (dt(sub(edge_mid(e1), edge_mid(e0)), d) < 0) std::swap(e0, e1);
      if (next[static_cast<std::size_t>(e0)] != -1) throw std::logic_error("marching cubes: table generation: edge leaves twice");
      next[static_cast<std::size_t>(e0)] = e1;
    };
    for (int axis = 0; axis < 3; ++axis)
      for (int side = 0; side < 2; ++side) {
        const int u = (axis + 1) % 3, w = (axis + 2) % 3;
        const int lo = std::min(u, w), hi = std::max(u, w);
        const int s = side << axis;
        const std::array<int, 4> q = {s, s | (1 << lo), s | (1 << lo) | (1 << hi), s | (1 << hi)};  // cyclic
        P3 n{{0, 0, 0}};
        n.v[axis] = side != 0 ? 1.0 : -1.0;
        std::array<int, 4> e{};
        int crossings = 0;
        for (int t = 0; t < 4; ++t) {
          e[static_cast<std::size_t>(t)] = edge_between(q[static_cast<std::size_t>(t)], q[static_cast<std::size_t>((t + 1) % 4)]);
          crossings += inside(q[static_cast<std::size_t>(t)]) != inside(q[static_cast<std::size_t>((t + 1) % 4)]);
        }
        if (crossings == 2) {
          int found[2], nf = 0;
          P3 cin{{0, 0, 0}}, cout{{0, 0, 0}};
          int nin = 0, nout = 0;
          for (int t = 0; t < 4; ++t) {
            const int c = q[static_cast<std::size_t>(t)];
            const P3 cp = corner_pos(c);
            for (int a = 0; a < 3; ++a) (inside(c) ? cin : cout).v[a] += cp.v[a];
            (inside(c) ? nin : nout)++;
            if (inside(c) != inside(q[static_cast<std::size_t>((t + 1) % 4)])) found[nf++] = e[static_cast<std::size_t>(t)];
          }
          P3 toward{{0, 0, 0}};
          for (int a = 0; a < 3; ++a) toward.v[a] = cout.v[a] / nout - cin.v[a] / nin;
          add_segment(found[0], found[1], toward, n);
        } else if (crossings == 4) {
          // Ambiguous face: cut off each inside corner on its own.
          P3 centre{{0, 0, 0}};
          for (int c : q)
            for (int a = 0; a < 3; ++a) centre.v[a] += corner_pos(c).v[a] / 4;
          for (int t = 0; t < 4; ++t) {
            const int c = q[static_cast<std::size_t>(t)];
            if (!inside(c)) continue;
            const int e_after = e[static_cast<std::size_t>(t)], e_before = e[static_cast<std::size_t>((t + 3) % 4)];
            add_segment(e_before, e_after, sub(centre, corner_pos(c)), n);
          }
        }
      }
    // Follow the segments into polygons and triangulate them.
    std::array<bool, 12> used{};
    McCase& out = table[static_cast<std::size_t>(cs)];
    for (int start = 0; start < 12; ++start) {
      if (next[static_cast<std::size_t>(start)] == -1 || used[static_cast<std::size_t>(start)]) continue;
      std::vector<int> poly;
      for (int e = start; !used[static_cast<std::size_t>(e)]; e = next[static_cast<std::size_t>(e)]) {
        used[static_cast<std::size_t>(e)] = true;
        poly.push_back(e);
        if (next[static_cast<std::size_t>(e)] == -1) throw std::logic_error("marching cubes: table generation: open polygon");
      }
      if (poly.size() < 3) throw std::logic_error("marching cubes: table generation: polygon of " + std::to_string(poly.size()) + " edges");
      std::vector<std::array<int, 3>> tris;
      if (!triangulate(poly, tris)) throw std::logic_error("marching cubes: table generation: case " + std::to_string(cs) + " has no face-free triangulation");
      for (const auto& t : tris) {
        if (out.n_triangles >= kMaxCaseTriangles) throw std::logic_error("marching cubes: table generation: too many triangles");
        for (int v = 0; v < 3; ++v) out.edges[static_cast<std::size_t>(out.n_triangles * 3 + v)] = static_cast<std::uint8_t>(t[static_cast<std::size_t>(v)]);
        ++out.n_triangles;
      }
    }
  }
  return table;
}

}  // namespace

const std::array<McCase, 256>& mc_case_table() {
  static const std::array<McCase, 256> table = build_table();
  return table;
}

// ---- extraction ---------------------------------------------------------------------------------
// Four passes, the first three over bits:
//   0. classify: one bit per node (inside or not), rows of 64-bit words;
//   1. count, per node plane, the crossing edges (popcounts of xor-ed rows) and, per slab, the
//      triangles of its active cubes (a cube is active unless its 8 corner bits agree);
//   2. prefix sums give every plane its first vertex index and every slab its first triangle;
//   3. each slab numbers its planes' crossing edges, computes their vertices and emits the
//      triangles of its active cubes; the plane a slab ends on is numbered by both neighbours in
//      the same order, and only its owner writes the vertices.
namespace {

using detail::McField;

struct NodeBits {
  int nx = 0, ny = 0, nz = 0;
  std::size_t words = 0;  ///< words holding a row's bits
  std::size_t stride = 0; ///< words per row, one more than needed, zero: reads of word q + 1 are safe
  std::vector<std::uint64_t> w;
  std::vector<std::uint64_t> edge_mask;  ///< per word: bits of x-edges that exist (i < nx − 1)

  [[nodiscard]] std::size_t row_start(int j, int k) const {
    return (static_cast<std::size_t>(k) * static_cast<std::size_t>(ny) + static_cast<std::size_t>(j)) * stride;
  }
  const std::uint64_t* row(int j, int k) const { return w.data() + row_start(j, k); }
  std::uint64_t* row(int j, int k) { return w.data() + row_start(j, k); }
};

inline std::uint64_t shr1(const std::uint64_t* r, std::size_t q) { return (r[q] >> 1) | (r[q + 1] << 63); }
// The two bits i and i + 1 of a row.
inline unsigned two_bits(const std::uint64_t* r, int i) {
  const auto q = static_cast<std::size_t>(i) >> 6;
  const unsigned s = static_cast<unsigned>(i) & 63u;
  const std::uint64_t lo = r[q] >> s;
  const std::uint64_t hi = s == 63 ? r[q + 1] << 1 : 0;
  return static_cast<unsigned>((lo | hi) & 3u);
}

// The active cubes of cube row (j, k) in word q: cubes whose corners are not all alike.
inline std::uint64_t active_cubes(const NodeBits& b, int j, int k, std::size_t q) {
  const std::uint64_t* r0 = b.row(j, k);
  const std::uint64_t* r1 = b.row(j + 1, k);
  const std::uint64_t* r2 = b.row(j, k + 1);
  const std::uint64_t* r3 = b.row(j + 1, k + 1);
  const std::uint64_t any = r0[q] | r1[q] | r2[q] | r3[q];
  const std::uint64_t any_next = (any >> 1) | ((r0[q + 1] | r1[q + 1] | r2[q + 1] | r3[q + 1]) << 63);
  const std::uint64_t all = r0[q] & r1[q] & r2[q] & r3[q];
  const std::uint64_t all_next = (all >> 1) | ((r0[q + 1] & r1[q + 1] & r2[q + 1] & r3[q + 1]) << 63);
  return (any | any_next) & ~(all & all_next) & b.edge_mask[q];
}

inline unsigned cube_case_bits(const NodeBits& b, int i, int j, int k) {
  return two_bits(b.row(j, k), i) | two_bits(b.row(j + 1, k), i) << 2 | two_bits(b.row(j, k + 1), i) << 4 |
         two_bits(b.row(j + 1, k + 1), i) << 6;
}

// Edge-vertex indices of one node plane: x- and y-edges in the plane, z-edges up to the next.
struct PlaneIndex {
  std::vector<std::uint32_t> x, y, z;
  void resize(std::size_t n) {
    x.assign(n, 0);
    y.assign(n, 0);
    z.assign(n, 0);
  }
};

struct Extraction {
  const McField& f;
  IsoSurface& out;
  NodeBits bits;
  std::vector<std::uint64_t> plane_offset;  // first vertex index of each node plane

  void classify_planes(int k0, int k1) {
    const std::size_t nx = static_cast<std::size_t>(bits.nx);
    for (int k = k0; k < k1; ++k)
      for (int j = 0; j < bits.ny; ++j) {
        std::uint64_t* r = bits.row(j, k);
        const float* v = f.v + f.idx(0, j, k);
        for (std::size_t q = 0; q < bits.words; ++q) {
          const std::size_t begin = q * 64, end = std::min(nx, begin + 64);
          std::uint64_t word = 0;
          std::size_t i = begin;
#if defined(__SSE2__)
          // Four comparisons and one movemask per step: the classification is the only pass that
          // reads every voxel, so it sets the pace on a mostly empty volume.
          const __m128 iso4 = _mm_set1_ps(f.iso);
          for (; i + 4 <= end; i += 4) {
            const auto m = static_cast<unsigned>(_mm_movemask_ps(_mm_cmpge_ps(_mm_loadu_ps(v + i), iso4)));
            word |= static_cast<std::uint64_t>(m) << (i - begin);
          }
#endif
          for (; i < end; ++i) word |= static_cast<std::uint64_t>(v[i] >= f.iso) << (i - begin);
          r[q] = word;
        }
      }
  }

  // Vertices owned by plane k: crossing x- and y-edges in it and z-edges up to plane k + 1.
  std::uint64_t count_plane(int k) const {
    std::uint64_t c = 0;
    for (int j = 0; j < bits.ny; ++j) {
      const std::uint64_t* r = bits.row(j, k);
      for (std::size_t q = 0; q < bits.words; ++q) {
        c += static_cast<std::uint64_t>(std::popcount((r[q] ^ shr1(r, q)) & bits.edge_mask[q]));
        if (j + 1 < bits.ny) c += static_cast<std::uint64_t>(std::popcount(r[q] ^ bits.row(j + 1, k)[q]));
        if (k + 1 < bits.nz) c += static_cast<std::uint64_t>(std::popcount(r[q] ^ bits.row(j, k + 1)[q]));
      }
    }
    return c;
  }

  std::uint64_t count_layer_triangles(int k) const {
    const auto& table = mc_case_table();
    std::uint64_t c = 0;
    for (int j = 0; j + 1 < bits.ny; ++j)
      for (std::size_t q = 0; q < bits.words; ++q)
        for (std::uint64_t m = active_cubes(bits, j, k, q); m != 0; m &= m - 1) {
          const int i = static_cast<int>(q * 64) + std::countr_zero(m);
          c += table[cube_case_bits(bits, i, j, k)].n_triangles;
        }
    return c;
  }

  void emit_vertex(std::uint32_t index, int i, int j, int k, int axis) {
    const auto v = detail::edge_vertex(f, i, j, k, axis);
    out.positions[index] = v.position;
    if (f.normals) out.normals[index] = v.normal;
    out.material[index] = v.material;
    out.edge_key[index] = out.grid.edge_key(i, j, k, axis);
  }

  // Numbers plane k's crossing edges from plane_offset[k], row by row (x, then y, then z edges),
  // the one order both slabs sharing a plane use; writes the vertices when write is set. with_z:
  // also record the z-edges (needed on the plane a layer starts from, not the one it ends on).
  void index_plane(int k, PlaneIndex& p, bool write, bool with_z) {
    const int nx = bits.nx, ny = bits.ny, nz = bits.nz;
    auto next = static_cast<std::uint32_t>(plane_offset[static_cast<std::size_t>(k)]);
    const auto each = [&](std::uint64_t m, std::size_t q, auto&& fn) {
      for (; m != 0; m &= m - 1) fn(static_cast<int>(q * 64) + std::countr_zero(m));
    };
    for (int j = 0; j < ny; ++j) {
      const std::uint64_t* r = bits.row(j, k);
      const std::size_t l0 = static_cast<std::size_t>(j) * static_cast<std::size_t>(nx);
      for (std::size_t q = 0; q < bits.words; ++q)
        each((r[q] ^ shr1(r, q)) & bits.edge_mask[q], q, [&](int i) {
          if (write) emit_vertex(next, i, j, k, 0);
          p.x[l0 + static_cast<std::size_t>(i)] = next++;
        });
      if (j + 1 < ny) {
        const std::uint64_t* r1 = bits.row(j + 1, k);
        for (std::size_t q = 0; q < bits.words; ++q)
          each(r[q] ^ r1[q], q, [&](int i) {
            if (write) emit_vertex(next, i, j, k, 1);
            p.y[l0 + static_cast<std::size_t>(i)] = next++;
          });
      }
      if (k + 1 < nz) {
        const std::uint64_t* r1 = bits.row(j, k + 1);
        for (std::size_t q = 0; q < bits.words; ++q) {
          if (!with_z) {  // counted only, so the numbering matches count_plane
            next += static_cast<std::uint32_t>(std::popcount(r[q] ^ r1[q]));
            continue;
          }
          each(r[q] ^ r1[q], q, [&](int i) {
            if (write) emit_vertex(next, i, j, k, 2);
            p.z[l0 + static_cast<std::size_t>(i)] = next++;
          });
        }
      }
    }
  }

  // Slab [k0, k1) of cube layers; owns node planes k0 .. k1-1 (and the top plane if last).
  void run_slab(int k0, int k1, std::uint64_t tri_offset) {
    const int nx = bits.nx, nz = bits.nz;
    const std::size_t plane = static_cast<std::size_t>(nx) * static_cast<std::size_t>(bits.ny);
    PlaneIndex cur, nxt;
    cur.resize(plane);
    nxt.resize(plane);
    index_plane(k0, cur, true, true);
    const auto& table = mc_case_table();
    std::size_t t = tri_offset;
    for (int k = k0; k < k1; ++k) {
      const bool owned = k + 1 < k1 || k + 1 == nz - 1;
      index_plane(k + 1, nxt, owned, owned);
      for (int j = 0; j + 1 < bits.ny; ++j) {
        // Per cube edge, where its vertex index sits for cube i of this row: edge_index[e][i].
        const std::uint32_t* edge_index[12];
        for (int e = 0; e < 12; ++e) {
          const auto ce = detail::cube_edge(e);
          const PlaneIndex& p = ce.dk != 0 ? nxt : cur;
          const std::vector<std::uint32_t>& arr = ce.axis == 0 ? p.x : ce.axis == 1 ? p.y : cur.z;
          edge_index[e] = arr.data() + static_cast<std::size_t>(j + ce.dj) * static_cast<std::size_t>(nx) + static_cast<std::size_t>(ce.di);
        }
        for (std::size_t q = 0; q < bits.words; ++q)
          for (std::uint64_t m = active_cubes(bits, j, k, q); m != 0; m &= m - 1) {
            const int i = static_cast<int>(q * 64) + std::countr_zero(m);
            const McCase& c = table[cube_case_bits(bits, i, j, k)];
            const std::uint32_t cube = out.grid.cube(i, j, k);
            const auto vertex = [&](std::uint8_t e) { return edge_index[e][i]; };
            for (int n = 0; n < c.n_triangles; ++n) {
              const std::uint32_t a = vertex(c.edges[static_cast<std::size_t>(3 * n)]);
              const std::uint32_t b = vertex(c.edges[static_cast<std::size_t>(3 * n + 1)]);
              const std::uint32_t d = vertex(c.edges[static_cast<std::size_t>(3 * n + 2)]);
              out.triangles[t] = f.flip ? std::array<std::uint32_t, 3>{a, d, b} : std::array<std::uint32_t, 3>{a, b, d};
              out.triangle_cube[t] = cube;
              ++t;
            }
          }
      }
      std::swap(cur, nxt);
    }
  }
};

}  // namespace

namespace detail {

void extract_field(const McField& f, IsoSurface& out, int thread_count) {
  const auto& g = out.grid.dims;
  Extraction ex{f, out, {}, std::vector<std::uint64_t>(static_cast<std::size_t>(g[2]) + 1, 0)};
  NodeBits& b = ex.bits;
  b.nx = g[0];
  b.ny = g[1];
  b.nz = g[2];
  b.words = (static_cast<std::size_t>(g[0]) + 63) / 64;
  b.stride = b.words + 1;
  b.w.assign(b.stride * static_cast<std::size_t>(g[1]) * static_cast<std::size_t>(g[2]), 0);
  b.edge_mask.assign(b.stride, 0);
  for (int i = 0; i + 1 < g[0]; ++i) b.edge_mask[static_cast<std::size_t>(i) >> 6] |= std::uint64_t{1} << (i & 63);

  // Slabs of cube layers, one per thread.
  const int layers = g[2] - 1;
  int threads = thread_count > 0 ? thread_count : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  threads = std::clamp(threads, 1, layers);
  std::vector<int> slab_start(static_cast<std::size_t>(threads) + 1);
  for (int s = 0; s <= threads; ++s) slab_start[static_cast<std::size_t>(s)] = static_cast<int>(static_cast<long>(layers) * s / threads);
  const auto parallel = [&](auto&& body) {
    std::vector<std::thread> pool;
    for (int s = 1; s < threads; ++s) pool.emplace_back(body, s);
    body(0);
    for (auto& th : pool) th.join();
  };
  // A slab's node planes: k0 .. k1-1, and the top plane for the last slab.
  const auto plane_end = [&](int s) { return s + 1 == threads ? g[2] : slab_start[static_cast<std::size_t>(s) + 1]; };
  // Pass 0: classify.
  parallel([&](int s) { ex.classify_planes(slab_start[static_cast<std::size_t>(s)], plane_end(s)); });
  // Pass 1: count the vertices of each node plane and the triangles of each slab.
  std::vector<std::uint64_t> slab_tris(static_cast<std::size_t>(threads), 0);
  parallel([&](int s) {
    const int k0 = slab_start[static_cast<std::size_t>(s)], k1 = slab_start[static_cast<std::size_t>(s) + 1];
    for (int k = k0; k < plane_end(s); ++k) ex.plane_offset[static_cast<std::size_t>(k) + 1] = ex.count_plane(k);
    for (int k = k0; k < k1; ++k) slab_tris[static_cast<std::size_t>(s)] += ex.count_layer_triangles(k);
  });
  // Pass 2: offsets.
  std::partial_sum(ex.plane_offset.begin(), ex.plane_offset.end(), ex.plane_offset.begin());
  const std::uint64_t n_vertices = ex.plane_offset.back();
  const std::uint64_t n_triangles = std::accumulate(slab_tris.begin(), slab_tris.end(), std::uint64_t{0});
  if (n_vertices >= std::numeric_limits<std::uint32_t>::max() || n_triangles >= std::numeric_limits<std::uint32_t>::max())
    throw std::length_error("marching cubes: more than 2^32 vertices or triangles");
  out.positions.resize(n_vertices);
  if (f.normals) out.normals.resize(n_vertices);
  out.material.resize(n_vertices);
  out.edge_key.resize(n_vertices);
  out.triangles.resize(n_triangles);
  out.triangle_cube.resize(n_triangles);
  std::vector<std::uint64_t> tri_offset(static_cast<std::size_t>(threads), 0);
  std::exclusive_scan(slab_tris.begin(), slab_tris.end(), tri_offset.begin(), std::uint64_t{0});
  // Pass 3: vertices and triangles, each slab into its own ranges.
  parallel([&](int s) {
    ex.run_slab(slab_start[static_cast<std::size_t>(s)], slab_start[static_cast<std::size_t>(s) + 1], tri_offset[static_cast<std::size_t>(s)]);
  });
}

}  // namespace detail

namespace detail {

Result<FieldStorage> prepare_field(const Volume& volume, const IsoOptions& options, std::span<const std::uint8_t> labels, bool copy) {
  const auto& d = volume.dims;
  if (d[0] < 1 || d[1] < 1 || d[2] < 1 || volume.data.size() != volume.voxel_count())
    return Error{ErrorCode::kInvalid, "marching cubes: volume dims " + std::to_string(d[0]) + "x" + std::to_string(d[1]) + "x" +
                                          std::to_string(d[2]) + " hold " + std::to_string(volume.voxel_count()) + " voxels, data has " +
                                          std::to_string(volume.data.size())};
  if (!std::isfinite(options.iso)) return Error{ErrorCode::kInvalid, "marching cubes: isovalue must be finite, found " + std::to_string(options.iso)};
  // A zero, negative or NaN spacing (or a singular direction) would make every normal NaN.
  const double det = index_frame(volume).det;
  if (!(volume.spacing.x > 0 && volume.spacing.y > 0 && volume.spacing.z > 0) || !is_finite(volume.spacing) || !(std::abs(det) > 0) ||
      !std::isfinite(det))
    return Error{ErrorCode::kInvalid, "marching cubes: expected 3 positive finite spacings (m) and an invertible direction, found spacing " +
                                          std::to_string(volume.spacing.x) + " " + std::to_string(volume.spacing.y) + " " +
                                          std::to_string(volume.spacing.z)};
  if (!labels.empty() && labels.size() != volume.voxel_count())
    return Error{ErrorCode::kInvalid, "marching cubes: label volume has " + std::to_string(labels.size()) + " entries, expected " +
                                          std::to_string(volume.voxel_count()) + " (one per voxel)"};
  if (options.pad_value && !std::isfinite(*options.pad_value))
    return Error{ErrorCode::kInvalid, "marching cubes: pad_value must be finite"};
  if (!std::is_sorted(options.materials.begin(), options.materials.end(),
                      [](const MaterialThreshold& x, const MaterialThreshold& y) { return x.min_value < y.min_value; }))
    return Error{ErrorCode::kInvalid, "marching cubes: material thresholds must ascend by min_value"};

  FieldStorage st;
  const int pad = options.pad_border ? 1 : 0;
  st.grid.dims = {d[0] + 2 * pad, d[1] + 2 * pad, d[2] + 2 * pad};
  st.grid.pad = pad;
  const auto& g = st.grid.dims;
  if (g[0] < 2 || g[1] < 2 || g[2] < 2)
    return Error{ErrorCode::kInvalid, "marching cubes: need at least 2 nodes along each axis, grid is " + std::to_string(g[0]) + "x" +
                                          std::to_string(g[1]) + "x" + std::to_string(g[2]) + " (use pad_border for a thin volume)"};
  if (st.grid.node(g[0] - 1, g[1] - 1, g[2] - 1) >= std::numeric_limits<std::uint32_t>::max())
    return Error{ErrorCode::kInvalid, "marching cubes: grid has more than 2^32 nodes"};
  if (pad != 0 || copy) {
    float bg = 0;
    if (options.pad_value) {
      bg = *options.pad_value;
    } else {
      // The smallest finite value: a NaN or infinite voxel must not become the whole border.
      bool any = false;
      for (float x : volume.data) {
        if (std::isfinite(x) && (!any || x < bg)) bg = x, any = true;
      }
      if (!any) return Error{ErrorCode::kInvalid, "marching cubes: no voxel is finite (all NaN or infinite)"};
    }
    st.values.assign(static_cast<std::size_t>(st.grid.node(g[0] - 1, g[1] - 1, g[2] - 1)) + 1, bg);
    if (!labels.empty()) st.labels.assign(st.values.size(), 0);
    for (int k = 0; k < d[2]; ++k)
      for (int j = 0; j < d[1]; ++j) {
        const std::size_t src = volume.index(0, j, k), dst = st.grid.node(pad, j + pad, k + pad);
        std::copy_n(volume.data.begin() + static_cast<std::ptrdiff_t>(src), d[0], st.values.begin() + static_cast<std::ptrdiff_t>(dst));
        if (!labels.empty()) std::copy_n(labels.begin() + static_cast<std::ptrdiff_t>(src), d[0], st.labels.begin() + static_cast<std::ptrdiff_t>(dst));
      }
  }
  return st;
}

McField field_view(const FieldStorage& st, const Volume& volume, const IsoOptions& options, std::span<const std::uint8_t> labels) {
  McField f;
  f.n = st.grid.dims;
  f.iso = options.iso;
  f.normals = options.normals;
  f.thresholds = &options.materials;
  const bool own = !st.values.empty();
  f.v = own ? st.values.data() : volume.data.data();
  f.labels = labels.empty() ? nullptr : own ? st.labels.data() : labels.data();
  set_geometry(f, volume, st.grid.pad);
  return f;
}

Result<bool> check_finite_vertices(const IsoSurface& surface) {
  std::size_t bad = 0, first = 0;
  for (std::size_t v = 0; v < surface.positions.size(); ++v) {
    const Vec3f& p = surface.positions[v];
    bool ok = std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z);
    if (!surface.normals.empty()) {
      const Vec3f& n = surface.normals[v];
      ok = ok && std::isfinite(n.x) && std::isfinite(n.y) && std::isfinite(n.z);
    }
    if (!ok && bad++ == 0) first = v;
  }
  if (bad == 0) return true;
  const IsoGrid& g = surface.grid;
  const std::uint64_t node = surface.edge_key[first] / 3;
  const auto nx = static_cast<std::uint64_t>(g.dims[0]), ny = static_cast<std::uint64_t>(g.dims[1]);
  const long long i = static_cast<long long>(node % nx) - g.pad, j = static_cast<long long>((node / nx) % ny) - g.pad,
                  k = static_cast<long long>(node / (nx * ny)) - g.pad;
  return Error{ErrorCode::kInvalid, "marching cubes: the volume has NaN or infinite voxels on the surface: " + std::to_string(bad) +
                                        " vertices are not finite, the first on the grid edge from voxel (" + std::to_string(i) + ", " +
                                        std::to_string(j) + ", " + std::to_string(k) +
                                        "); replace those voxels first (replace_nonfinite in volume/nonfinite.hpp)"};
}

}  // namespace detail

Result<IsoSurface> extract_isosurface(const Volume& volume, const IsoOptions& options, std::span<const std::uint8_t> labels) {
  auto st = detail::prepare_field(volume, options, labels, false);
  if (!st.ok()) return st.error();
  IsoSurface out;
  out.grid = st.value().grid;
  try {
    detail::extract_field(detail::field_view(st.value(), volume, options, labels), out, options.threads);
  } catch (const std::length_error& e) {
    return Error{ErrorCode::kInvalid, e.what()};
  }
  if (auto finite = detail::check_finite_vertices(out); !finite) return finite.error();
  return out;
}

IsoMesh to_openmesh(const IsoSurface& surface, std::size_t* refused) {
  IsoMesh mesh;
  const std::size_t bad = fill_openmesh(surface, mesh);
  if (refused != nullptr) *refused = bad;
  return mesh;
}

std::size_t fill_openmesh(const IsoSurface& surface, IsoMesh& mesh) {
  mesh.reserve(surface.positions.size(), surface.positions.size() + surface.triangles.size(), surface.triangles.size());
  std::vector<IsoMesh::VertexHandle> vh(surface.positions.size());
  for (std::size_t v = 0; v < surface.positions.size(); ++v) {
    const Vec3f p = surface.positions[v];
    vh[v] = mesh.add_vertex(IsoMesh::Point(p.x, p.y, p.z));
    if (!surface.normals.empty()) mesh.set_normal(vh[v], IsoMesh::Normal(surface.normals[v].x, surface.normals[v].y, surface.normals[v].z));
    mesh.set_material(vh[v], surface.material[v]);
    mesh.set_edge_key(vh[v], surface.edge_key[v]);
  }
  // The connectivity at once (volume/halfedge_build.hpp); a surface that is not a manifold (it
  // cannot be, from our extractor, but an IsoSurface may come from elsewhere) goes face by face,
  // with add_face refusing what does not fit.
  if (build_triangle_mesh(mesh, std::span<const IsoMesh::VertexHandle>(vh),
                          std::span<const std::array<std::uint32_t, 3>>(surface.triangles))) {
    for (std::size_t t = 0; t < surface.triangles.size(); ++t) mesh.set_cube(IsoMesh::FaceHandle(static_cast<int>(t)), surface.triangle_cube[t]);
    return 0;
  }
  std::size_t bad = 0;
  for (std::size_t t = 0; t < surface.triangles.size(); ++t) {
    const auto& tri = surface.triangles[t];
    const auto fh = mesh.add_face(vh[tri[0]], vh[tri[1]], vh[tri[2]]);
    if (!fh.is_valid()) {
      ++bad;
      continue;
    }
    mesh.set_cube(fh, surface.triangle_cube[t]);
  }
  return bad;
}

}  // namespace lancet::volume
