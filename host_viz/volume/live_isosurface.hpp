#pragma once
// LiveIsosurface: an isosurface kept as an OpenMesh IsoMesh while the volume under it changes
// (drilling). After a change inside a voxel box only the cubes that touch the box are extracted
// again and stitched into the mesh:
//   1. faces of those cubes are deleted; vertices left without faces go with them;
//   2. the cubes are triangulated anew; a vertex on an edge shared with an untouched cube is
//      reused (its nodes did not change, so neither did it), so the seam stays watertight;
//   3. normals of vertices whose gradient reads a changed voxel are recomputed.
// Deleted elements stay in OpenMesh's arrays (flagged) until compact(), which renumbers handles.
// Allocating; viz frame time, never the real-time path.

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <unordered_map>
#include <vector>

#include "lancet/shared_model/result.hpp"
#include "volume/iso_mesh.hpp"
#include "volume/marching_cubes.hpp"
#include "volume/volume.hpp"

namespace lancet::volume {

/// A box of voxels, half-open: lo <= (i, j, k) < hi, in the source volume's indices.
struct VoxelBox {
  std::array<int, 3> lo{}, hi{};
  [[nodiscard]] bool empty() const noexcept { return hi[0] <= lo[0] || hi[1] <= lo[1] || hi[2] <= lo[2]; }
};

struct RegionUpdate {
  std::size_t cubes = 0;             ///< cubes re-extracted
  std::size_t faces_removed = 0, faces_added = 0;
  std::size_t vertices_removed = 0, vertices_added = 0, vertices_reused = 0;
  std::size_t refused = 0;           ///< faces OpenMesh refused as non-manifold (0 expected)
};

class LiveIsosurface {
 public:
  /// Extracts the whole surface (like extract_isosurface) and keeps a copy of the field.
  /// (A unique_ptr because OpenMesh meshes copy rather than move.)
  [[nodiscard]] static Result<std::unique_ptr<LiveIsosurface>> create(const Volume& volume, const IsoOptions& options,
                                                     std::span<const std::uint8_t> labels = {});

  [[nodiscard]] const IsoMesh& mesh() const noexcept { return mesh_; }
  [[nodiscard]] const IsoGrid& grid() const noexcept { return storage_grid_; }
  /// Faces OpenMesh refused at creation (0 expected).
  [[nodiscard]] std::size_t refused_at_creation() const noexcept { return refused_; }

  /// Takes the voxels of dirty (clipped to the volume) from volume, which must have the dims it
  /// was created from, and labels when it was created with labels; re-extracts locally.
  [[nodiscard]] Result<RegionUpdate> update(const Volume& volume, VoxelBox dirty, std::span<const std::uint8_t> labels = {});

  /// Removes the deleted elements from the mesh's arrays. Invalidates every handle.
  void compact();
  [[nodiscard]] std::size_t deleted_faces() const noexcept { return deleted_faces_; }

 private:
  LiveIsosurface() = default;

  IsoOptions options_;
  Volume geometry_;                 ///< the source's dims and geometry (no data)
  IsoGrid storage_grid_;
  std::vector<float> values_;       ///< the grid's values (padded copy)
  std::vector<std::uint8_t> labels_;
  bool has_labels_ = false;
  IsoMesh mesh_;
  std::unordered_map<std::uint64_t, IsoMesh::VertexHandle> vertex_of_edge_;
  std::size_t refused_ = 0;
  std::size_t deleted_faces_ = 0;
};

}  // namespace lancet::volume
