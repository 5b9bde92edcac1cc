#pragma once
// TissuePatch export: the triangles of the surface near the tool, nearest first, up to the
// patch capacity, for lancet-rt's haptic step. (The surface-model issue adds the BVH query, cut
// state and blade frame; this version scans the placeholder mesh.)

#include <cstddef>
#include <cstdint>
#include <vector>

#include "lancet/shared_model/messages.hpp"
#include "surface/placeholder_mesh.hpp"

namespace lancet::hybrid {

struct PatchExportParams {
  double radius = 0.02;   ///< m, triangles whose bounding sphere reaches within this of the tool
};

/// Scratch reused across frames so export allocates only while it grows.
struct PatchExportScratch {
  std::vector<std::pair<double, std::uint32_t>> candidates;  ///< (distance², triangle index)
};

/// Fills out.triangles / n_triangles / centre / radius from mesh around centre; leaves seq, t_ns,
/// blade, cut and brick to the caller. Returns the number of triangles found within the radius
/// (may exceed kPatchCapacity; only the nearest kPatchCapacity are exported).
std::size_t export_patch(const surface::TriangleMesh& mesh, Vec3 centre, const PatchExportParams& params,
                         PatchExportScratch& scratch, TissuePatch& out);

}  // namespace lancet::hybrid
