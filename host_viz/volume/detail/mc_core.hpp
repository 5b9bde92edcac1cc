#pragma once
// The per-cube and per-edge pieces of marching cubes, shared by the whole-volume extraction
// (marching_cubes.cpp) and the local re-extraction (live_isosurface.cpp). Internal.

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "volume/detail/index_frame.hpp"
#include "volume/marching_cubes.hpp"

namespace lancet::volume::detail {

/// A read-only view of the grid marching cubes runs on, with its world geometry.
struct McField {
  std::array<int, 3> n{};
  const float* v = nullptr;
  const std::uint8_t* labels = nullptr;         ///< may be null
  const std::vector<MaterialThreshold>* thresholds = nullptr;
  float iso = 0;
  bool normals = true;
  bool flip = false;                            ///< index→world mapping mirrors: reverse windings
  Vec3 origin{};                                ///< world position of grid node (0, 0, 0)
  std::array<Vec3, 3> step{};                   ///< world offset of one grid step along each axis
  std::array<Vec3, 3> grad{};                   ///< world gradient = Σ_a (∂v/∂index_a) · grad[a]

  [[nodiscard]] std::size_t idx(int i, int j, int k) const noexcept {
    return static_cast<std::size_t>(i) +
           static_cast<std::size_t>(n[0]) * (static_cast<std::size_t>(j) + static_cast<std::size_t>(n[1]) * static_cast<std::size_t>(k));
  }
  [[nodiscard]] float at(int i, int j, int k) const noexcept { return v[idx(i, j, k)]; }
};

/// Fills origin, step, grad and flip from a volume's geometry; pad shifts the grid origin by
/// pad voxels down every axis.
inline void set_geometry(McField& f, const Volume& vol, int pad) {
  const IndexFrame fr = index_frame(vol);
  for (int a = 0; a < 3; ++a) f.step[static_cast<std::size_t>(a)] = Vec3{fr.m[0][a], fr.m[1][a], fr.m[2][a]};
  f.flip = fr.det < 0;
  // ∇_world v = M^{-T} ∇_index v: grad[a] is row a of M^{-1} (as a world vector).
  for (int a = 0; a < 3; ++a) f.grad[static_cast<std::size_t>(a)] = Vec3{fr.inv[a][0], fr.inv[a][1], fr.inv[a][2]};
  f.origin = vol.position(-pad, -pad, -pad);
}

/// The case index of cube (i, j, k): bit c set when corner c is inside (value >= iso).
[[nodiscard]] inline unsigned cube_case(const McField& f, int i, int j, int k) noexcept {
  const std::size_t sx = 1, sy = static_cast<std::size_t>(f.n[0]), sz = sy * static_cast<std::size_t>(f.n[1]);
  const float* p = f.v + f.idx(i, j, k);
  const float t = f.iso;
  return static_cast<unsigned>(p[0] >= t) | static_cast<unsigned>(p[sx] >= t) << 1 | static_cast<unsigned>(p[sy] >= t) << 2 |
         static_cast<unsigned>(p[sx + sy] >= t) << 3 | static_cast<unsigned>(p[sz] >= t) << 4 |
         static_cast<unsigned>(p[sx + sz] >= t) << 5 | static_cast<unsigned>(p[sy + sz] >= t) << 6 |
         static_cast<unsigned>(p[sx + sy + sz] >= t) << 7;
}

/// Gradient of the field at a node in index units (central differences, one-sided at the edge).
[[nodiscard]] inline std::array<double, 3> node_gradient(const McField& f, int i, int j, int k) noexcept {
  std::array<double, 3> g{};
  const int c[3] = {i, j, k};
  for (int a = 0; a < 3; ++a) {
    int lo[3] = {i, j, k}, hi[3] = {i, j, k};
    lo[a] = std::max(c[a] - 1, 0);
    hi[a] = std::min(c[a] + 1, f.n[static_cast<std::size_t>(a)] - 1);
    const double span = hi[a] - lo[a];
    g[static_cast<std::size_t>(a)] = span > 0 ? (static_cast<double>(f.at(hi[0], hi[1], hi[2])) - f.at(lo[0], lo[1], lo[2])) / span : 0.0;
  }
  return g;
}

[[nodiscard]] inline std::uint8_t material_of(const McField& f, std::size_t node) noexcept {
  if (f.labels != nullptr) return f.labels[node];
  std::uint8_t m = 0;
  if (f.thresholds != nullptr)
    for (const auto& t : *f.thresholds)
      if (f.v[node] >= t.min_value) m = t.material;
  return m;
}

struct McVertex {
  Vec3f position;
  Vec3f normal;
  std::uint8_t material;
};

/// The vertex on the grid edge from node (i, j, k) along axis (which must cross the isovalue).
[[nodiscard]] inline McVertex edge_vertex(const McField& f, int i, int j, int k, int axis) noexcept {
  const int b[3] = {i + (axis == 0), j + (axis == 1), k + (axis == 2)};
  const std::size_t na = f.idx(i, j, k), nb = f.idx(b[0], b[1], b[2]);
  const float va = f.v[na], vb = f.v[nb];
  float t = (f.iso - va) / (vb - va);
  t = std::clamp(t, kEdgeClamp, 1.0f - kEdgeClamp);  // also catches va == vb (cannot cross) safely
  const auto ax = static_cast<std::size_t>(axis);
  const Vec3 p = f.origin + f.step[0] * static_cast<double>(i) + f.step[1] * static_cast<double>(j) +
                 f.step[2] * static_cast<double>(k) + f.step[ax] * static_cast<double>(t);
  McVertex out{Vec3f{static_cast<float>(p.x), static_cast<float>(p.y), static_cast<float>(p.z)}, Vec3f{}, 0};
  const bool a_inside = va >= f.iso;
  out.material = material_of(f, a_inside ? na : nb);
  if (f.normals) {
    const auto ga = node_gradient(f, i, j, k);
    const auto gb = node_gradient(f, b[0], b[1], b[2]);
    Vec3 g{};
    for (std::size_t a = 0; a < 3; ++a) g = g + f.grad[a] * ((1.0 - t) * ga[a] + t * gb[a]);
    double len = norm(g);
    if (!(len > 0)) {  // flat gradient: fall back to the edge direction, inside → outside
      g = f.step[ax] * (a_inside ? 1.0 : -1.0);
      len = norm(g);
    }
    const Vec3 nrm = g * (-1.0 / len);  // values fall outward
    out.normal = Vec3f{static_cast<float>(nrm.x), static_cast<float>(nrm.y), static_cast<float>(nrm.z)};
  }
  return out;
}

/// Cube edge e's lower node offset (di, dj, dk) and axis.
struct CubeEdge {
  int di, dj, dk, axis;
};
[[nodiscard]] inline CubeEdge cube_edge(int e) noexcept {
  const auto c = mc_edge_corners(e)[0];
  return CubeEdge{c & 1, (c >> 1) & 1, (c >> 2) & 1, e / 4};
}

/// The grid marching cubes runs on when it is not the volume itself: a padded (or plain) copy.
struct FieldStorage {
  IsoGrid grid;
  std::vector<float> values;          ///< empty: the field is the volume's own data
  std::vector<std::uint8_t> labels;   ///< per grid node when labels were given and values is a copy
};

/// Validates the inputs and makes the grid: a copy when padding or when copy is set.
[[nodiscard]] Result<FieldStorage> prepare_field(const Volume& volume, const IsoOptions& options,
                                                 std::span<const std::uint8_t> labels, bool copy);
/// A view of storage (or of volume itself when storage holds no copy). options must outlive it.
[[nodiscard]] McField field_view(const FieldStorage& storage, const Volume& volume, const IsoOptions& options,
                                 std::span<const std::uint8_t> labels);
/// Marching cubes over the whole field into out (whose grid is set), on thread_count slabs
/// (0: one per hardware thread). Throws std::length_error past 2^32 vertices or triangles.
void extract_field(const McField& f, IsoSurface& out, int thread_count);
/// An error when a vertex position or normal of `surface` is not finite (a NaN or infinite voxel
/// at a crossing edge), naming the voxel; checks the vertices, not the voxels, so it costs
/// O(vertices) after an extraction.
[[nodiscard]] Result<bool> check_finite_vertices(const IsoSurface& surface);

}  // namespace lancet::volume::detail
