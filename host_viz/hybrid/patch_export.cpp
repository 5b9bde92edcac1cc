#include "patch_export.hpp"

#include <algorithm>
#include <cmath>

namespace lancet::hybrid {

std::size_t export_patch(const surface::TriangleMesh& mesh, Vec3 centre, const PatchExportParams& params,
                         PatchExportScratch& scratch, TissuePatch& out) {
  auto& cand = scratch.candidates;
  cand.clear();
  for (std::uint32_t f = 0; f < mesh.triangles.size(); ++f) {
    const auto& t = mesh.triangles[f];
    const Vec3 a = to_vec3(mesh.vertices[t[0]]), b = to_vec3(mesh.vertices[t[1]]), c = to_vec3(mesh.vertices[t[2]]);
    const Vec3 centroid = (1.0 / 3.0) * (a + b + c);
    const double r = std::max({norm(a - centroid), norm(b - centroid), norm(c - centroid)});
    const double d = norm(centre - centroid);
    if (d - r <= params.radius) cand.emplace_back(d * d, f);
  }
  const std::size_t keep = std::min<std::size_t>(cand.size(), kPatchCapacity);
  std::partial_sort(cand.begin(), cand.begin() + static_cast<std::ptrdiff_t>(keep), cand.end());
  for (std::size_t i = 0; i < keep; ++i) {
    const auto& t = mesh.triangles[cand[i].second];
    PatchTriangle& pt = out.triangles[i];
    pt.v[0] = mesh.vertices[t[0]];
    pt.v[1] = mesh.vertices[t[1]];
    pt.v[2] = mesh.vertices[t[2]];
    pt.material = mesh.material[cand[i].second];
    pt.flags = 0;
  }
  out.n_triangles = static_cast<std::uint32_t>(keep);
  out.centre = centre;
  out.radius = params.radius;
  return cand.size();
}

}  // namespace lancet::hybrid
