#include "patch_export.hpp"

#include <algorithm>
#include <cmath>

#include "surface/bvh.hpp"

namespace lancet::tissue {
namespace {

// Keeps the nearest kPatchCapacity candidates (all when they fit) in the order they came — the
// order of the BVH's walk or of the mesh, which keeps neighbours together for lancet-rt's search
// tree (haptics/patch_bvh.hpp) — with ties at the cut-off going to the earlier ones.
void keep_nearest_in_order(std::vector<std::pair<double, std::uint32_t>>& cand, std::vector<double>& scratch) {
  if (cand.size() <= kPatchCapacity) return;
  scratch.clear();
  for (const auto& c : cand) scratch.push_back(c.first);
  const auto nth = scratch.begin() + static_cast<std::ptrdiff_t>(kPatchCapacity - 1);
  std::nth_element(scratch.begin(), nth, scratch.end());
  const double limit = *nth;
  std::size_t below = 0;
  for (const auto& c : cand) below += c.first < limit ? 1 : 0;
  std::size_t ties = kPatchCapacity - below, kept = 0;
  for (const auto& c : cand) {
    if (c.first < limit || (c.first == limit && ties > 0)) {
      if (c.first == limit) --ties;
      cand[kept++] = c;
    }
  }
  cand.resize(kept);
}

}  // namespace

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
  const std::size_t found = cand.size();
  keep_nearest_in_order(cand, scratch.distances);
  const std::size_t keep = cand.size();
  for (std::size_t i = 0; i < keep; ++i) {
    const auto& t = mesh.triangles[cand[i].second];
    PatchTriangle& pt = out.triangles[i];
    pt.v[0] = mesh.vertices[t[0]];
    pt.v[1] = mesh.vertices[t[1]];
    pt.v[2] = mesh.vertices[t[2]];
    pt.material = mesh.material[cand[i].second];
    pt.flags = 0;
    pt.id = cand[i].second;
  }
  out.n_triangles = static_cast<std::uint32_t>(keep);
  return found;
}

std::size_t export_patch(const surface::SurfaceModel& model, Vec3 centre, const PatchExportParams& params,
                         PatchExportScratch& scratch, TissuePatch& out, const BrickSource& brick) {
  const surface::MeshView view = model.view();
  auto& near = scratch.faces;
  // The BVH holds the drawn (dented) surface; the patch is the haptic one, without the tool's own
  // dent, which lies at most deform_max_depth from it: search that much wider, then keep by the
  // distance to the haptic triangles. The search takes every face of the leaves whose boxes reach
  // (no drawn distance per face: the haptic test below decides every face anyway, and a face
  // within the radius of the haptic surface is within the reach of the drawn one).
  const double reach = params.radius + model.params().deform_max_depth;
  const Vec3f at = to_vec3f(centre);
  model.bvh().faces_in_boxes_within(model.view(), at, static_cast<float>(reach), near);
  auto& cand = scratch.candidates;
  auto& corners = scratch.corners;
  cand.clear();
  corners.clear();
  const double r2 = params.radius * params.radius;
  // Only triangles near the rim need the exact point–triangle distance: one with a corner
  // within the radius is within it (its distance is at most that corner's), and one whose nearest
  // corner is farther than the radius by more than its longest edge is outside (every point of a
  // triangle lies within its longest edge of each corner). Both tests keep a hair (1e-9 of the
  // radius) to spare, far more than the exact test's rounding (about 1e-18 m² here), so neither
  // decides a triangle the other way from the exact test: the set is the exact test's. A
  // candidate admitted by a corner gets its exact distance only if the patch overflows and the
  // nearest must be chosen.
  const double surely = r2 * (1 - 1e-9), beyond = params.radius * (1 + 1e-9) + 1e-12;
  const Vec3 q = to_vec3(at);
  const auto dist2 = [](Vec3 a, Vec3 b) { return dot(a - b, a - b); };
  constexpr double kNotMeasured = -1;
  for (std::uint32_t f : near) {
    const auto& t = view.faces[f];
    const std::array<Vec3f, 3> c = {model.haptic_position_f(t[0]), model.haptic_position_f(t[1]), model.haptic_position_f(t[2])};
    const Vec3 a = to_vec3(c[0]), b = to_vec3(c[1]), e = to_vec3(c[2]);
    const double nearest = std::min({dist2(q, a), dist2(q, b), dist2(q, e)});
    double d2 = kNotMeasured;
    if (!(nearest <= surely)) {
      const double longest = std::max({dist2(a, b), dist2(b, e), dist2(e, a)});
      if (std::sqrt(nearest) - std::sqrt(longest) > beyond) continue;
      d2 = surface::point_triangle_distance_squared(at, c[0], c[1], c[2]);
      if (!(d2 <= r2)) continue;
    }
    cand.emplace_back(d2, static_cast<std::uint32_t>(corners.size()));
    corners.push_back({c, f});
  }
  const std::size_t found = cand.size();
  if (found > kPatchCapacity) {
    for (auto& [d2, i] : cand)
      if (d2 == kNotMeasured) d2 = surface::point_triangle_distance_squared(at, corners[i].v[0], corners[i].v[1], corners[i].v[2]);
    keep_nearest_in_order(cand, scratch.distances);
  }
  const std::size_t keep = cand.size();
  for (std::size_t i = 0; i < keep; ++i) {
    const PatchExportScratch::Corners& c = corners[cand[i].second];
    PatchTriangle& pt = out.triangles[i];
    for (int k = 0; k < 3; ++k) pt.v[k] = c.v[static_cast<std::size_t>(k)];
    pt.material = model.face_material(c.face);
    pt.flags = model.face_on_boundary(c.face) ? kTriangleOnCutEdge : 0;
    pt.id = c.face;
  }
  out.n_triangles = static_cast<std::uint32_t>(keep);
  out.brick.valid = 0;
  if (brick) brick(centre, out.brick);
  return found;
}

}  // namespace lancet::tissue
