// build_triangle_mesh against add_face: the same mesh face for face (same faces in the same order,
// the same vertex cycles, the same one-rings in the same cyclic order), consistent half-edge
// links, closed where the surface is closed, open where it is cut; the edge arrays reserved for
// exactly the edges made; and inputs that are not a manifold refused before the mesh is touched.
#include "volume/halfedge_build.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <vector>

#include "volume/iso_mesh.hpp"
#include "volume/marching_cubes.hpp"
#include "volume/phantom.hpp"

namespace lancet::volume {
namespace {

using Tri = std::array<std::uint32_t, 3>;

// The mesh's vertices (no faces) for n vertices.
std::vector<IsoMesh::VertexHandle> add_vertices(IsoMesh& m, std::size_t n) {
  std::vector<IsoMesh::VertexHandle> vh(n);
  for (std::size_t i = 0; i < n; ++i) vh[i] = m.add_vertex(IsoMesh::Point(static_cast<float>(i), 0, 0));
  return vh;
}

std::array<int, 3> face_cycle(const IsoMesh& m, IsoMesh::FaceHandle f) {
  std::array<int, 3> c{};
  int i = 0;
  for (auto v : m.fv_range(f)) c[static_cast<std::size_t>(i++)] = v.idx();
  std::rotate(c.begin(), std::min_element(c.begin(), c.end()), c.end());  // the same cycle from its least vertex
  return c;
}

// Neighbours of v counter-clockwise, from its outgoing half-edge; for an interior vertex rotated
// to start at the least (the start is arbitrary there), for a boundary one as it is (it starts at
// the boundary in both).
std::vector<int> one_ring(const IsoMesh& m, IsoMesh::VertexHandle v) {
  std::vector<int> r;
  for (auto w : m.vv_range(v)) r.push_back(w.idx());
  if (!m.is_boundary(v) && !r.empty()) std::rotate(r.begin(), std::min_element(r.begin(), r.end()), r.end());
  return r;
}

void expect_consistent(const IsoMesh& m) {
  for (auto h : m.halfedges()) {
    ASSERT_EQ(m.next_halfedge_handle(m.prev_halfedge_handle(h)), h);
    ASSERT_EQ(m.opposite_halfedge_handle(m.opposite_halfedge_handle(h)), h);
    ASSERT_EQ(m.to_vertex_handle(h), m.from_vertex_handle(m.next_halfedge_handle(h)));
    ASSERT_EQ(m.face_handle(h), m.face_handle(m.next_halfedge_handle(h)));
  }
  for (auto v : m.vertices()) {
    if (!m.halfedge_handle(v).is_valid()) continue;
    ASSERT_EQ(m.from_vertex_handle(m.halfedge_handle(v)), v);
    ASSERT_TRUE(m.is_manifold(v));
  }
}

// Returns how many boundary vertices the mesh has.
std::size_t expect_same_as_add_face(std::size_t n_vertices, const std::vector<Tri>& tris) {
  IsoMesh a, b;
  const auto va = add_vertices(a, n_vertices);
  for (const Tri& t : tris) {
    EXPECT_TRUE(a.add_face(va[t[0]], va[t[1]], va[t[2]]).is_valid());
  }
  const auto vb = add_vertices(b, n_vertices);
  TriangleCorners corners;
  EXPECT_TRUE(build_triangle_mesh(b, std::span<const IsoMesh::VertexHandle>(vb), std::span<const Tri>(tris), nullptr, &corners));
  expect_consistent(b);
  EXPECT_EQ(a.n_faces(), b.n_faces());
  EXPECT_EQ(a.n_edges(), b.n_edges());
  EXPECT_EQ(a.n_vertices(), b.n_vertices());
  if (a.n_faces() != b.n_faces() || a.n_vertices() != b.n_vertices()) return 0;
  for (std::size_t f = 0; f < a.n_faces(); ++f) {
    const IsoMesh::FaceHandle fh(static_cast<int>(f));
    EXPECT_EQ(face_cycle(a, fh), face_cycle(b, fh)) << "face " << f;
    if (face_cycle(a, fh) != face_cycle(b, fh)) return 0;
  }
  std::size_t boundary = 0;
  for (std::size_t v = 0; v < n_vertices; ++v) {
    const IsoMesh::VertexHandle vh(static_cast<int>(v));
    EXPECT_EQ(a.is_boundary(vh), b.is_boundary(vh)) << "vertex " << v;
    boundary += b.is_boundary(vh);
    EXPECT_EQ(one_ring(a, vh), one_ring(b, vh)) << "vertex " << v;
    if (one_ring(a, vh) != one_ring(b, vh)) return 0;
    // The corners' walk visits the triangles around v in vf_range's order, from the same start
    // (a sum over them then matches the circulator's bit for bit).
    std::vector<int> circulated, walked;
    for (auto f : b.vf_range(vh)) circulated.push_back(f.idx());
    corners.for_each_triangle_around(static_cast<std::uint32_t>(v), [&](std::uint32_t t) { walked.push_back(static_cast<int>(t)); });
    EXPECT_EQ(circulated, walked) << "vertex " << v;
    if (circulated != walked) return 0;
  }
  // Boundary loops: the same half-edges follow each other.
  for (auto h : b.halfedges()) {
    if (!b.is_boundary(h)) continue;
    const auto from = b.from_vertex_handle(h), to = b.to_vertex_handle(h);
    const auto ha = a.find_halfedge(from, to);
    EXPECT_TRUE(ha.is_valid() && a.is_boundary(ha));
    if (!ha.is_valid()) return 0;
    EXPECT_EQ(a.to_vertex_handle(a.next_halfedge_handle(ha)), b.to_vertex_handle(b.next_halfedge_handle(h)));
  }
  return boundary;
}

std::vector<Tri> triangles_of(const IsoSurface& s) { return {s.triangles.begin(), s.triangles.end()}; }

IsoSurface phantom_skin(bool pad, std::array<int, 3> dims = {80, 80, 40}) {
  PhantomParams params;
  params.dims = dims;
  const LabelledVolume ph = make_phantom(params);
  IsoOptions o;
  o.iso = -300;
  o.pad_border = pad;
  auto r = extract_isosurface(ph.volume, o, ph.material);
  EXPECT_TRUE(r.ok());
  return std::move(r).value();
}

TEST(HalfedgeBuild, ThePhantomsClosedSkinEqualsTheAddFaceBuild) {
  const IsoSurface s = phantom_skin(true);
  ASSERT_GT(s.triangles.size(), 1000u);
  EXPECT_EQ(expect_same_as_add_face(s.positions.size(), triangles_of(s)), 0u);
  IsoMesh b;
  const auto vb = add_vertices(b, s.positions.size());
  ASSERT_TRUE(build_triangle_mesh(b, std::span<const IsoMesh::VertexHandle>(vb), std::span<const Tri>(s.triangles)));
  for (auto h : b.halfedges()) ASSERT_FALSE(b.is_boundary(h)) << "closed: no boundary";
}

TEST(HalfedgeBuild, AnOpenSkinCutByTheVolumesSidesEqualsTheAddFaceBuild) {
  const IsoSurface s = phantom_skin(false);
  EXPECT_GT(expect_same_as_add_face(s.positions.size(), triangles_of(s)), 100u) << "open where the volume ends";
}

// Large enough that every pass runs its halves on two threads (where there are two cores): the
// counts, buckets and last corners each half finds apart, merged, still give add_face's mesh.
TEST(HalfedgeBuild, ASkinLargeEnoughForTwoThreadsEqualsTheAddFaceBuild) {
  const IsoSurface s = phantom_skin(false, {192, 192, 96});
  ASSERT_GE(s.triangles.size(), std::size_t{1} << 16) << "below the two-thread threshold";
  EXPECT_GT(expect_same_as_add_face(s.positions.size(), triangles_of(s)), 100u) << "open where the volume ends";
}

// The edge count is known before the first edge is made: the edge arrays (OpenMesh's and every
// edge property's) are reserved for exactly that many, even when the caller reserved too few (one
// edge at a time, they grew to twice what they hold).
TEST(HalfedgeBuild, TheEdgeArraysAreReservedForExactlyTheEdgesMade) {
  const IsoSurface s = phantom_skin(false);
  IsoMesh m;
  OpenMesh::EPropHandleT<std::uint8_t> per_edge;
  m.add_property(per_edge);
  m.reserve(s.positions.size(), s.triangles.size(), s.triangles.size());  // an edge per triangle: too few
  const auto vh = add_vertices(m, s.positions.size());
  ASSERT_TRUE(build_triangle_mesh(m, std::span<const IsoMesh::VertexHandle>(vh), std::span<const Tri>(s.triangles)));
  EXPECT_GT(m.n_edges(), s.triangles.size());
  EXPECT_EQ(m.property(per_edge).data_vector().capacity(), m.n_edges());
}

TEST(HalfedgeBuild, SmallMeshesWithBoundariesEqualTheAddFaceBuild) {
  // A fan of four triangles around vertex 0 (open), a strip, and a closed tetrahedron.
  expect_same_as_add_face(6, {{0, 1, 2}, {0, 2, 3}, {0, 3, 4}, {0, 4, 5}});
  expect_same_as_add_face(6, {{0, 1, 2}, {2, 1, 3}, {2, 3, 4}, {4, 3, 5}});
  expect_same_as_add_face(4, {{0, 1, 2}, {0, 2, 3}, {0, 3, 1}, {1, 3, 2}});
  // A grid with a hole.
  std::vector<Tri> grid;
  const auto id = [](std::uint32_t i, std::uint32_t j) { return j * 6 + i; };
  for (std::uint32_t j = 0; j < 5; ++j)
    for (std::uint32_t i = 0; i < 5; ++i) {
      if (i == 2 && j == 2) continue;
      grid.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
      grid.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
    }
  EXPECT_EQ(expect_same_as_add_face(36, grid), 24u) << "the rim (20) and the hole (4)";
}

TEST(HalfedgeBuild, WhatIsNotAManifoldIsRefusedBeforeTheMeshIsTouched) {
  const std::vector<std::vector<Tri>> bad = {
      {{0, 1, 2}, {0, 1, 3}},             // an edge twice in the same direction (flipped neighbour)
      {{0, 1, 2}, {1, 0, 3}, {1, 0, 4}},  // three triangles on one edge
      {{0, 1, 2}, {0, 3, 4}},             // two fans touching at vertex 0 (a bowtie)
      {{0, 1, 1}},                        // a repeated vertex
      {{0, 1, 9}},                        // a vertex that is not there
  };
  for (const auto& tris : bad) {
    IsoMesh m;
    const auto vh = add_vertices(m, 6);
    EXPECT_FALSE(build_triangle_mesh(m, std::span<const IsoMesh::VertexHandle>(vh), std::span<const Tri>(tris)));
    EXPECT_EQ(m.n_faces(), 0u);
    EXPECT_EQ(m.n_edges(), 0u);
    EXPECT_EQ(m.n_vertices(), 6u);
  }
  // Two closed fans sharing a vertex (two tetrahedra touching at a corner): refused too.
  IsoMesh m;
  const auto vh = add_vertices(m, 7);
  const std::vector<Tri> two{{0, 1, 2}, {0, 2, 3}, {0, 3, 1}, {1, 3, 2}, {0, 4, 5}, {0, 5, 6}, {0, 6, 4}, {4, 6, 5}};
  EXPECT_FALSE(build_triangle_mesh(m, std::span<const IsoMesh::VertexHandle>(vh), std::span<const Tri>(two)));
  EXPECT_EQ(m.n_faces(), 0u);
}

}  // namespace
}  // namespace lancet::volume
