#pragma once
// Marching cubes (Lorensen & Cline; thesis 3.4.2, eq. 3.11–3.12): the isosurface of a Volume as
// an indexed triangle mesh, and as an OpenMesh IsoMesh.
//
// - Inside is value >= iso; faces wind counter-clockwise seen from outside and normals point out
//   (towards lower values), in world space, whatever the volume's direction matrix.
// - Each crossing grid edge gets exactly one vertex, shared by the up to four cubes around it; the
//   case table is generated from the cube's faces with one rule per face (an ambiguous face keeps
//   its two inside corners apart), so neighbouring cubes always agree and the surface is
//   watertight and 2-manifold. Polygons are triangulated without any diagonal lying in a cube
//   face, so no edge is shared by more than two triangles.
// - Vertices are kept a hair (kEdgeClamp of the edge) off the grid nodes, so a node whose value
//   equals the isovalue never collapses several vertices into one point: no degenerate faces.
// - pad_border surrounds the volume with one voxel of background, so that a surface touching the
//   scan's edge still closes. The extraction grid is then (nx+2)·(ny+2)·(nz+2) and its node
//   (i, j, k) is voxel (i-1, j-1, k-1).
// - Runs on slabs of z in parallel; the result does not depend on the thread count.
// Allocating; configure/frame time, never the real-time path.

#include <array>
#include <cstdint>
#include <optional>
#include <span>
#include <vector>

#include "lancet/shared_model/geometry.hpp"
#include "lancet/shared_model/result.hpp"
#include "volume/iso_mesh.hpp"
#include "volume/volume.hpp"

namespace lancet::volume {

/// The material of a vertex when no label volume is given: the last entry whose min_value is <=
/// the value on the inside of the vertex's edge (entries ascending by min_value); 0 below all.
struct MaterialThreshold {
  float min_value;
  std::uint8_t material;
};

struct IsoOptions {
  float iso = 0;
  bool pad_border = false;         ///< close the surface at the volume's edge (see above)
  std::optional<float> pad_value;  ///< background for pad_border; default: the volume's smallest finite value
  int threads = 0;                 ///< 0: one per hardware thread
  bool normals = true;             ///< per-vertex normals from the volume's gradient
  std::vector<MaterialThreshold> materials;
};

/// The fraction of an edge by which a vertex is kept off the grid nodes.
inline constexpr float kEdgeClamp = 1e-3f;

/// The grid an extraction ran on (padded when pad_border) and how to decode edge keys.
struct IsoGrid {
  std::array<int, 3> dims{};  ///< nodes along x, y, z
  int pad = 0;                ///< 1 when the border was padded: grid node i is voxel i - pad

  [[nodiscard]] std::uint64_t node(int i, int j, int k) const noexcept {
    return static_cast<std::uint64_t>(i) +
           static_cast<std::uint64_t>(dims[0]) * (static_cast<std::uint64_t>(j) + static_cast<std::uint64_t>(dims[1]) * static_cast<std::uint64_t>(k));
  }
  [[nodiscard]] std::uint64_t edge_key(int i, int j, int k, int axis) const noexcept {
    return node(i, j, k) * 3 + static_cast<std::uint64_t>(axis);
  }
  [[nodiscard]] std::uint32_t cube(int i, int j, int k) const noexcept { return static_cast<std::uint32_t>(node(i, j, k)); }
};

/// An indexed triangle mesh: vertex arrays in step, triangles as index triples.
struct IsoSurface {
  IsoGrid grid;
  std::vector<Vec3f> positions;              ///< m, world
  std::vector<Vec3f> normals;                ///< unit, outward; empty when options.normals is false
  std::vector<std::uint8_t> material;        ///< per vertex
  std::vector<std::uint64_t> edge_key;       ///< per vertex, IsoGrid::edge_key of its edge
  std::vector<std::array<std::uint32_t, 3>> triangles;
  std::vector<std::uint32_t> triangle_cube;  ///< per triangle, IsoGrid::cube of the cube it came from
};

/// Extracts the isosurface. labels (optional): a material id per voxel, laid out like
/// volume.data; it overrides options.materials. Errors: an empty or too small volume, a label
/// array of the wrong size, a non-finite isovalue, more than 2^32 vertices or cubes, or NaN or
/// infinite voxels where the surface passes (a vertex or normal that would not be finite; the
/// message names the voxel; volume/nonfinite.hpp counts and replaces them). The default pad_value
/// is the smallest finite value.
[[nodiscard]] Result<IsoSurface> extract_isosurface(const Volume& volume, const IsoOptions& options,
                                                    std::span<const std::uint8_t> labels = {});

/// The IsoSurface as an OpenMesh mesh (vertex order kept). Returns the number of faces OpenMesh
/// refused as non-manifold (zero for anything extract_isosurface produced) through refused.
IsoMesh to_openmesh(const IsoSurface& surface, std::size_t* refused = nullptr);
/// The same into an existing, empty mesh (OpenMesh meshes copy rather than move); returns the
/// number of refused faces.
std::size_t fill_openmesh(const IsoSurface& surface, IsoMesh& mesh);

// ---- the case table, exposed for tests -------------------------------------------------------
// Cube corner c sits at (c & 1, (c >> 1) & 1, (c >> 2) & 1). Edge e runs along axis e / 4 from
// corner mc_edge_corners(e)[0] to [1]. Case bit c is set when corner c is inside.
inline constexpr int kMaxCaseTriangles = 12;
struct McCase {
  std::uint8_t n_triangles = 0;
  std::array<std::uint8_t, 3 * kMaxCaseTriangles> edges{};  ///< cube edges, three per triangle
};
[[nodiscard]] const std::array<McCase, 256>& mc_case_table();
[[nodiscard]] std::array<int, 2> mc_edge_corners(int edge) noexcept;

}  // namespace lancet::volume
