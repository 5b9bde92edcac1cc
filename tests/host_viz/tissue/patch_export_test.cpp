#include "tissue/patch_export.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <string>
#include <memory>
#include <vector>

namespace lancet::tissue {
namespace {

double centroid_distance(const PatchTriangle& t, Vec3 c) {
  const Vec3 m = (1.0 / 3.0) * (to_vec3(t.v[0]) + to_vec3(t.v[1]) + to_vec3(t.v[2]));
  return norm(m - c);
}

TEST(PlaceholderMesh, GridCountsNormalsAndMaterials) {
  surface::TissueBlockParams p;
  p.cells = 20;
  const auto m = surface::make_tissue_block(p);
  EXPECT_EQ(m.vertices.size(), 21u * 21u);
  EXPECT_EQ(m.triangles.size(), 2u * 20u * 20u);
  EXPECT_EQ(m.material.size(), m.triangles.size());
  for (const auto& n : m.normals) EXPECT_GT(n.z, 0.9f);  // a gentle height field faces up
  bool has_skin = false, has_vessel = false;
  for (auto id : m.material) has_skin |= id == 1, has_vessel |= id == 2;
  EXPECT_TRUE(has_skin && has_vessel);
  // Counter-clockwise seen from +z: every face normal points up.
  for (const auto& t : m.triangles) {
    const Vec3 a = to_vec3(m.vertices[t[0]]), b = to_vec3(m.vertices[t[1]]), c = to_vec3(m.vertices[t[2]]);
    EXPECT_GT(cross(b - a, c - a).z, 0.0);
  }
}

// The triangles keep the mesh's order (neighbours together, for lancet-rt's search tree) and carry
// their mesh index as their id.
TEST(PatchExport, AllWithinRadiusInMeshOrderWithTheirIds) {
  const auto mesh = surface::make_tissue_block({});
  auto patch = std::make_unique<TissuePatch>();
  PatchExportScratch scratch;
  const Vec3 centre{0.01, -0.005, 0.0};
  const PatchExportParams params{0.01};
  const std::size_t found = export_patch(mesh, centre, params, scratch, *patch);
  ASSERT_GT(patch->n_triangles, 10u);
  EXPECT_EQ(found, patch->n_triangles);  // well under capacity
  for (std::uint32_t i = 0; i < patch->n_triangles; ++i) {
    const PatchTriangle& pt = patch->triangles[i];
    EXPECT_LE(centroid_distance(pt, centre), params.radius + 0.003);  // centroid within radius + the triangle's own size
    if (i > 0) {
      EXPECT_GT(pt.id, patch->triangles[i - 1].id) << "triangle " << i << " out of the mesh's order";
    }
    ASSERT_LT(pt.id, mesh.triangles.size());
    EXPECT_EQ(pt.v[2], mesh.vertices[mesh.triangles[pt.id][2]]) << "the id names the triangle";
  }
  // Every triangle of the mesh whose centroid is well inside the radius was exported.
  std::size_t inside = 0;
  for (const auto& t : mesh.triangles) {
    const Vec3 c = (1.0 / 3.0) * (to_vec3(mesh.vertices[t[0]]) + to_vec3(mesh.vertices[t[1]]) + to_vec3(mesh.vertices[t[2]]));
    inside += norm(c - centre) <= params.radius ? 1 : 0;
  }
  EXPECT_GE(patch->n_triangles, inside);
}

TEST(PatchExport, LargeRadiusIsCutToCapacityKeepingTheNearest) {
  surface::TissueBlockParams bp;
  bp.cells = 120;  // 28 800 triangles on top: more than a patch holds
  const auto mesh = surface::make_tissue_block(bp);
  ASSERT_GT(mesh.triangles.size(), kPatchCapacity);
  auto patch = std::make_unique<TissuePatch>();
  PatchExportScratch scratch;
  const std::size_t found = export_patch(mesh, {}, PatchExportParams{0.5}, scratch, *patch);
  EXPECT_EQ(found, mesh.triangles.size());
  ASSERT_EQ(patch->n_triangles, kPatchCapacity);
  // The kept ones are the nearest: none farther than any left out; in mesh order.
  std::vector<bool> kept(mesh.triangles.size());
  double farthest_kept = 0;
  for (std::uint32_t i = 0; i < kPatchCapacity; ++i) {
    kept[patch->triangles[i].id] = true;
    farthest_kept = std::max(farthest_kept, centroid_distance(patch->triangles[i], {}));
    if (i > 0) {
      EXPECT_GT(patch->triangles[i].id, patch->triangles[i - 1].id);
    }
  }
  const auto centroid = [&](std::size_t f) {
    const auto& t = mesh.triangles[f];
    return (1.0 / 3.0) * (to_vec3(mesh.vertices[t[0]]) + to_vec3(mesh.vertices[t[1]]) + to_vec3(mesh.vertices[t[2]]));
  };
  for (std::size_t f = 0; f < mesh.triangles.size(); ++f)
    if (!kept[f]) {
      ASSERT_GE(norm(centroid(f)), farthest_kept - 1e-12) << "face " << f << " was left out for a farther one";
    }
}

TEST(PatchExport, NothingNearGivesAnEmptyPatch) {
  const auto mesh = surface::make_tissue_block({});
  auto patch = std::make_unique<TissuePatch>();
  PatchExportScratch scratch;
  EXPECT_EQ(export_patch(mesh, {0, 0, 0.5}, PatchExportParams{0.01}, scratch, *patch), 0u);
  EXPECT_EQ(patch->n_triangles, 0u);
}

std::unique_ptr<surface::SurfaceModel> model(int cells) {
  surface::TissueBlockParams p;
  p.cells = cells;
  p.half_extent = 0.03;
  const auto m = surface::make_tissue_block(p);
  return std::move(surface::SurfaceModel::create(m.vertices, m.triangles, m.material).value());
}

TEST(SurfacePatchExport, EqualsABruteForceSelection) {
  auto s = model(60);
  auto patch = std::make_unique<TissuePatch>();
  PatchExportScratch scratch;
  for (const Vec3 centre : {Vec3{0.001, -0.002, 0.001}, Vec3{0.02, 0.02, -0.004}, Vec3{-0.029, 0.0, 0.002}}) {
    const std::size_t found = export_patch(*s, centre, PatchExportParams{0.006}, scratch, *patch);
    // Brute force: every face by exact distance.
    std::vector<std::pair<double, std::uint32_t>> all;
    const auto view = s->view();
    const auto corner = [&](std::uint32_t v) { return Vec3f{view.xyz[3 * v], view.xyz[3 * v + 1], view.xyz[3 * v + 2]}; };
    for (std::uint32_t f = 0; f < s->n_faces(); ++f) {
      const auto& t = s->faces()[f];
      const double d2 = surface::point_triangle_distance_squared(to_vec3f(centre), corner(t[0]), corner(t[1]), corner(t[2]));
      if (d2 <= 0.006 * 0.006) all.emplace_back(d2, f);
    }
    ASSERT_EQ(found, all.size());
    ASSERT_EQ(patch->n_triangles, all.size()) << "well under capacity: all of them";
    // The same faces (by id), each the face its id names.
    std::vector<std::uint32_t> ids;
    for (std::size_t i = 0; i < patch->n_triangles; ++i) {
      const std::uint32_t f = patch->triangles[i].id;
      ids.push_back(f);
      ASSERT_LT(f, s->n_faces());
      const auto& t = s->faces()[f];
      EXPECT_EQ(patch->triangles[i].v[0], corner(t[0])) << i;
      EXPECT_EQ(patch->triangles[i].material, s->face_material(f));
    }
    std::sort(ids.begin(), ids.end());
    std::vector<std::uint32_t> expected;
    for (const auto& a : all) expected.push_back(a.second);
    EXPECT_EQ(ids, expected);
  }
}

TEST(SurfacePatchExport, TheHapticsGetTheSurfaceWithoutTheToolsOwnDent) {
  // The drawn surface dents under the tool; the patch lancet-rt pushes against must not, or the
  // surface (and the proxy on it) would follow the tool down and the force would fade.
  auto s = model(60);
  const Vec3 contact{0.001, 0.0, surface::tissue_block_height({}, 0.001, 0.0)};
  for (int i = 0; i < 20; ++i) s->update_contact(surface::Contact{contact, {0, 0, -1}, 0.004}, 0.016);
  ASSERT_GT(s->deformed_vertices(), 0u);
  double deepest = 0;
  for (std::uint32_t v = 0; v < s->mesh().n_vertices(); ++v) deepest = std::max(deepest, s->haptic_position(v).z - s->position(v).z);
  ASSERT_GT(deepest, 0.003) << "the drawn surface is dented";
  auto patch = std::make_unique<TissuePatch>();
  PatchExportScratch scratch;
  const Vec3 tool = contact - Vec3{0, 0, 0.004};
  const std::size_t found = export_patch(*s, tool, PatchExportParams{0.006}, scratch, *patch);
  ASSERT_GT(found, 0u);
  for (std::size_t i = 0; i < patch->n_triangles; ++i) {
    const auto& t = patch->triangles[i];
    for (const auto& v : t.v) {
      // Every corner lies on the undented block (rest: no cut, no wrinkle here).
      const double h = surface::tissue_block_height({}, v.x, v.y);
      ASSERT_NEAR(v.z, h, 2e-6) << "triangle " << i;
    }
  }
  // And the nearest triangle is the one over the tool, ~4 mm above it, not the dent around it.
  const auto& t0 = patch->triangles[0];
  EXPECT_NEAR((t0.v[0].z + t0.v[1].z + t0.v[2].z) / 3.0, contact.z, 0.0005);
}

TEST(SurfacePatchExport, FlagsTheTrianglesOnACutsLipsAndCarriesTheBrick) {
  auto s = model(40);
  const auto h = [](double x, double y) {
    surface::TissueBlockParams p;
    return surface::tissue_block_height(p, x, y);
  };
  ASSERT_TRUE(s->begin_cut({-0.01, 0.0012, h(-0.01, 0.0012)}));
  for (int i = 1; i <= 10; ++i) (void)s->cut_to({-0.01 + 0.001 * i, 0.0012, h(-0.01 + 0.001 * i, 0.0012)});
  auto patch = std::make_unique<TissuePatch>();
  PatchExportScratch scratch;
  int brick_calls = 0;
  const Vec3 tip{0.0, 0.0012, h(0.0, 0.0012)};
  export_patch(*s, tip, PatchExportParams{0.005}, scratch, *patch, [&](Vec3 c, VoxelBrick& b) {
    ++brick_calls;
    b.valid = 1;
    b.origin = c;
  });
  EXPECT_EQ(brick_calls, 1);
  EXPECT_EQ(patch->brick.valid, 1u);
  std::size_t on_cut = 0;
  for (std::size_t i = 0; i < patch->n_triangles; ++i) on_cut += (patch->triangles[i].flags & kTriangleOnCutEdge) != 0;
  EXPECT_GT(on_cut, 0u) << "triangles along the open cut are flagged";
  s->end_cut();
  export_patch(*s, tip, PatchExportParams{0.005}, scratch, *patch);
  EXPECT_EQ(patch->brick.valid, 0u);
}

// The export as it was before it skipped the exact distance for triangles with a corner inside
// the radius: the BVH's faces within the radius plus the dent's depth (drawn surface), each kept
// by its exact distance to its haptic triangle, the nearest kPatchCapacity in BVH order (ties at
// the cut-off to the earlier ones), the cut-edge flag from the half-edges.
struct Reference {
  std::size_t found = 0;
  std::vector<PatchTriangle> triangles;
};
Reference two_distance_export(const surface::SurfaceModel& s, Vec3 centre, double radius) {
  std::vector<std::uint32_t> near;
  s.bvh().faces_within(s.view(), to_vec3f(centre), static_cast<float>(radius + s.params().deform_max_depth), near, true);
  const auto corner = [&](std::uint32_t v) { return to_vec3f(s.haptic_position(v)); };
  std::vector<std::pair<double, std::uint32_t>> cand;
  for (std::uint32_t f : near) {
    const auto& t = s.faces()[f];
    const double d2 = surface::point_triangle_distance_squared(to_vec3f(centre), corner(t[0]), corner(t[1]), corner(t[2]));
    if (d2 <= radius * radius) cand.emplace_back(d2, f);
  }
  Reference r;
  r.found = cand.size();
  if (cand.size() > kPatchCapacity) {
    std::vector<double> d;
    for (const auto& c : cand) d.push_back(c.first);
    std::nth_element(d.begin(), d.begin() + (kPatchCapacity - 1), d.end());
    const double limit = d[kPatchCapacity - 1];
    std::size_t ties = kPatchCapacity;
    for (const auto& c : cand) ties -= c.first < limit ? 1 : 0;
    std::vector<std::pair<double, std::uint32_t>> kept;
    for (const auto& c : cand)
      if (c.first < limit || (c.first == limit && ties > 0 && ties--)) kept.push_back(c);
    cand = kept;
  }
  const auto& mesh = s.mesh();
  for (const auto& [d2, f] : cand) {
    PatchTriangle pt{};
    const auto& t = s.faces()[f];
    for (int k = 0; k < 3; ++k) pt.v[k] = corner(t[static_cast<std::size_t>(k)]);
    pt.material = s.face_material(f);
    pt.id = f;
    for (auto h : mesh.fh_range(s.face_handle(f)))
      if (mesh.is_boundary(mesh.opposite_halfedge_handle(h))) pt.flags |= kTriangleOnCutEdge;
    r.triangles.push_back(pt);
  }
  return r;
}

void expect_same_patch(const Reference& want, std::size_t found, const TissuePatch& got) {
  ASSERT_EQ(found, want.found);
  ASSERT_EQ(got.n_triangles, want.triangles.size());
  for (std::size_t i = 0; i < want.triangles.size(); ++i) {
    const PatchTriangle &a = want.triangles[i], &b = got.triangles[i];
    ASSERT_EQ(b.id, a.id) << "triangle " << i;
    ASSERT_EQ(b.flags, a.flags) << "triangle " << i;
    ASSERT_EQ(b.material, a.material) << "triangle " << i;
    for (int k = 0; k < 3; ++k) ASSERT_EQ(std::memcmp(&b.v[k], &a.v[k], sizeof a.v[k]), 0) << "triangle " << i << " corner " << k;
  }
}

TEST(SurfacePatchExport, IsTheTwoDistanceExportOnADentedCutSurfaceAndWhenItOverflows) {
  // 2·200² = 80 000 triangles 6 cm across: a 30 mm radius finds far more than the capacity.
  auto s = model(200);
  const auto h = [](double x, double y) { return surface::tissue_block_height({}, x, y); };
  const Vec3 contact{0.004, -0.003, h(0.004, -0.003)};
  for (int i = 0; i < 10; ++i) s->update_contact(surface::Contact{contact, {0, 0, -1}, 0.003}, 0.016);
  ASSERT_TRUE(s->begin_cut({-0.012, 0.0011, h(-0.012, 0.0011)}));
  for (int i = 1; i <= 16; ++i) (void)s->cut_to({-0.012 + 0.001 * i, 0.0011, h(-0.012 + 0.001 * i, 0.0011)});
  auto patch = std::make_unique<TissuePatch>();
  PatchExportScratch scratch;
  const Vec3 tool = contact - Vec3{0, 0, 0.002};
  bool overflowed = false, flagged = false;
  for (const double radius : {0.004, 0.0125, 0.03}) {
    for (const Vec3 at : {tool, Vec3{0.0, 0.0011, h(0.0, 0.0011)}, Vec3{-0.027, 0.02, 0.003}}) {
      SCOPED_TRACE("radius " + std::to_string(radius));
      const std::size_t found = export_patch(*s, at, PatchExportParams{radius}, scratch, *patch);
      const Reference want = two_distance_export(*s, at, radius);
      expect_same_patch(want, found, *patch);
      overflowed = overflowed || found > kPatchCapacity;
      for (const auto& t : want.triangles) flagged = flagged || t.flags != 0;
    }
  }
  EXPECT_TRUE(overflowed) << "a patch past the capacity was chosen from";
  EXPECT_TRUE(flagged) << "triangles on the cut were flagged";
}

}  // namespace
}  // namespace lancet::tissue
