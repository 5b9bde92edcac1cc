#pragma once
// TissuePatch export: the triangles of the surface near the tool, the nearest up to the patch
// capacity, for lancet-rt's haptic step: from a plain triangle mesh by a scan, or from the
// surface model through its BVH, with the voxel brick of the scene's volume. The triangles keep
// the order they were found in (the mesh's, or the BVH walk's), which keeps neighbours together:
// lancet-rt's search tree groups runs of eight into its leaves. Each carries its face index as
// its id, which the proxy follows from patch to patch.

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "lancet/shared_model/messages.hpp"
#include "surface/triangle_mesh.hpp"
#include "surface/surface_model.hpp"

#include <functional>

namespace lancet::tissue {

struct PatchExportParams {
  double radius = 0.03;   ///< m, triangles whose bounding sphere reaches within this of the tool
};

/// Scratch reused across frames so export allocates only while it grows.
struct PatchExportScratch {
  /// (distance², triangle index; from a SurfaceModel: distance² or −1 when not measured, index into corners)
  std::vector<std::pair<double, std::uint32_t>> candidates;
  struct Corners {
    std::array<Vec3f, 3> v;  ///< haptic positions, m
    std::uint32_t face;
  };
  std::vector<Corners> corners;                              ///< SurfaceModel export: each candidate's triangle
  std::vector<std::uint32_t> faces;                          ///< BVH query result
  std::vector<double> distances;                             ///< for the cut-off when too many
};

/// Fills out.triangles / n_triangles (ids: the mesh's triangle indices) from mesh around centre; leaves seq, t_ns,
/// samples_applied and brick to the caller. Returns the number of triangles found within the radius
/// (may exceed kPatchCapacity; only the nearest kPatchCapacity are exported).
std::size_t export_patch(const surface::TriangleMesh& mesh, Vec3 centre, const PatchExportParams& params,
                         PatchExportScratch& scratch, TissuePatch& out);

/// Fills out.brick for the patch centre (a cube of the CT around it); empty: brick.valid = 0.
using BrickSource = std::function<void(Vec3 centre, VoxelBrick& brick)>;

/// The same from the surface model, through its BVH (cost follows the triangles near the tool,
/// not the mesh): triangles within params.radius of centre by exact point–triangle distance,
/// the nearest kPatchCapacity in BVH order, ids the face indices, at their haptic positions (SurfaceModel::haptic_position:
/// the cut opening and the wrinkle, not the tool's own dent), material ids, kTriangleOnCutEdge on
/// triangles with an open edge (lancet-rt's proxy does not push a tool found behind them out:
/// it may be inside the incision), and the brick from `brick` when given. Leaves seq, t_ns and
/// samples_applied to the caller.
std::size_t export_patch(const surface::SurfaceModel& model, Vec3 centre, const PatchExportParams& params,
                         PatchExportScratch& scratch, TissuePatch& out, const BrickSource& brick = {});

}  // namespace lancet::tissue
