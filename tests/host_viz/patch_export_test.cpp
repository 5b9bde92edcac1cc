#include "hybrid/patch_export.hpp"

#include <gtest/gtest.h>

#include <memory>

namespace lancet::hybrid {
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

TEST(PatchExport, NearestFirstAndAllWithinRadius) {
  const auto mesh = surface::make_tissue_block({});
  auto patch = std::make_unique<TissuePatch>();
  PatchExportScratch scratch;
  const Vec3 centre{0.01, -0.005, 0.0};
  const PatchExportParams params{0.01};
  const std::size_t found = export_patch(mesh, centre, params, scratch, *patch);
  ASSERT_GT(patch->n_triangles, 10u);
  EXPECT_EQ(found, patch->n_triangles);  // well under capacity
  EXPECT_EQ(patch->centre, centre);
  EXPECT_EQ(patch->radius, params.radius);
  double prev = 0;
  for (std::uint32_t i = 0; i < patch->n_triangles; ++i) {
    const double d = centroid_distance(patch->triangles[i], centre);
    EXPECT_GE(d, prev - 1e-12) << "triangle " << i << " out of order";
    EXPECT_LE(d, params.radius + 0.003);  // centroid within radius + the triangle's own size
    prev = d;
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
  const auto mesh = surface::make_tissue_block({});
  auto patch = std::make_unique<TissuePatch>();
  PatchExportScratch scratch;
  const std::size_t found = export_patch(mesh, {}, PatchExportParams{0.2}, scratch, *patch);
  EXPECT_EQ(found, mesh.triangles.size());
  EXPECT_EQ(patch->n_triangles, kPatchCapacity);
  const double farthest_kept = centroid_distance(patch->triangles[kPatchCapacity - 1], {});
  EXPECT_LT(farthest_kept, 0.03);  // 1024 triangles of 2 mm cells cover a disc of ~2.6 cm radius
}

TEST(PatchExport, NothingNearGivesAnEmptyPatch) {
  const auto mesh = surface::make_tissue_block({});
  auto patch = std::make_unique<TissuePatch>();
  PatchExportScratch scratch;
  EXPECT_EQ(export_patch(mesh, {0, 0, 0.5}, PatchExportParams{0.01}, scratch, *patch), 0u);
  EXPECT_EQ(patch->n_triangles, 0u);
}

}  // namespace
}  // namespace lancet::hybrid
