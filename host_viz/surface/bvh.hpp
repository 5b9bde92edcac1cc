#pragma once
// TriangleBvh: an axis-aligned bounding-box tree over a deforming triangle mesh, for the local
// surface operations of ALGORITHMS.md §3 (faces near the tool, closest point, where the blade
// path crosses the surface). Built once per topology (the faces sorted along a Morton curve and
// split where their octree cells part, at most 4 faces a leaf: tens of millions of faces a
// second, and the spatial-median tree that local queries on a surface want); after
// vertices move, refit() updates every box in O(n) and refit_faces() only the leaves of the given
// faces and their ancestors in O(k log n), so the cost of a local edit does not grow with the mesh.
//
// The mesh is not stored: every call takes a MeshView of the caller's arrays (OpenMesh's points()
// and a face-index array), so the tree never holds a stale copy.
//
// Allocation: build() allocates (and so does check(), a test helper). refit(), refit_faces() and
// the queries never allocate, except that faces_within() and segment_hits() grow the caller's
// `out` vector when it lacks capacity. Queries are const and may run on several threads at once;
// refits need exclusive access.
//
// Precision: boxes are floats (they hold the float vertices exactly); point–triangle and
// segment–triangle tests run in double. The segment test is watertight (Woop, Benthin & Wald,
// "Watertight ray/triangle intersection", JCGT 2013): a segment through a shared edge or vertex
// of a surface hits at least one of the faces around it. Zero-area triangles give no segment hits
// and a correct closest point (on their degenerate edges); nothing returns NaN for finite input.

#include <array>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <optional>
#include <span>
#include <vector>

#include "lancet/shared_model/geometry.hpp"

namespace lancet::surface {

/// A triangle mesh owned by the caller. Shapes: xyz is 3·n_vertices floats in metres (vertex v at
/// xyz[3v], xyz[3v+1], xyz[3v+2]; OpenMesh's points() array); faces is #F vertex-index triples,
/// each index < n_vertices. Positions may change between calls (then refit / refit_faces), and so
/// may a face's indices (a cut reconnects it to a duplicated vertex: refit_faces on it); the face
/// count may not change after build().
struct MeshView {
  const float* xyz = nullptr;
  std::size_t n_vertices = 0;
  std::span<const std::array<std::uint32_t, 3>> faces;
};

/// Closest point on a face. u, v: barycentric weights of corners 1 and 2 (point =
/// c0 + u·(c1 − c0) + v·(c2 − c0), u, v ≥ 0, u + v ≤ 1). distance in metres.
struct PointHit {
  std::uint32_t face = 0;
  Vec3f point;
  float distance = 0;
  float u = 0, v = 0;
};

/// A crossing of segment a→b with a face: t in [0, 1] along the segment; point on the face;
/// u, v barycentric weights of corners 1 and 2 as in PointHit.
struct SegmentHit {
  std::uint32_t face = 0;
  float t = 0;
  Vec3f point;
  float u = 0, v = 0;
};

class TriangleBvh {
 public:
  /// Builds the tree over all faces of m (≤ 4 faces a leaf): the faces sorted by the 30-bit Morton
  /// code of their box centre (stably, so equal codes keep face order), each range split where
  /// its codes' highest differing bit turns on, or at its middle where the codes are equal; depth
  /// stays below 30 + log2(#F) + 1. An empty mesh gives an empty tree. Allocates. A mesh of
  /// 65 536 faces or more computes its codes on two threads (`threads` false: one); the tree is
  /// the same either way, node for node.
  void build(const MeshView& m, bool threads = true);

  /// Recomputes every box bottom-up from the current positions and face indices. O(#F), no
  /// allocation. Precondition: m has the face count of the last build().
  void refit(const MeshView& m);

  /// Recomputes the boxes of the leaves holding `faces` and of their ancestors (stopping early
  /// where a box does not change). O(k log n), no allocation. The caller passes every face whose
  /// vertex positions or indices changed since the last refit; duplicates are harmless.
  void refit_faces(const MeshView& m, std::span<const std::uint32_t> faces);

  /// Every face whose exact distance to p is <= r (metres), in ascending face order, or, with
  /// `tree_order`, in the order of the tree's leaves (neighbours together; still the same for the
  /// same tree). out is cleared first; no allocation when it has capacity for the result.
  void faces_within(const MeshView& m, Vec3f p, float r, std::vector<std::uint32_t>& out, bool tree_order = false) const;

  /// Every face whose exact distance to at least one of `points` is <= r (metres), in ascending
  /// face order: the union of faces_within() over the points, each face once, found in one walk
  /// that carries down only the points still within r of a node's box. For many overlapping
  /// spheres (a cut's pairs) it visits each face once instead of once a sphere. out is cleared
  /// first; `scratch` holds the points' indices on the way down; no allocation when both have
  /// capacity.
  void faces_within_any(const MeshView& m, std::span<const Vec3f> points, float r, std::vector<std::uint32_t>& out,
                        std::vector<std::uint32_t>& scratch) const;

  /// Every face of a leaf whose box lies within r of p (metres), in the tree's leaf order: a
  /// superset of faces_within's answer, without a distance per face, for a caller that tests the
  /// faces its own way. out is cleared first; no allocation when it has capacity.
  void faces_in_boxes_within(Vec3f p, float r, std::vector<std::uint32_t>& out) const;

  /// The closest point of the mesh to p, if one lies within max_distance (metres); of faces
  /// equally near, the lowest index (so the answer does not depend on the tree). No allocation.
  [[nodiscard]] std::optional<PointHit> closest_point(
      const MeshView& m, Vec3f p, float max_distance = std::numeric_limits<float>::infinity()) const;

  /// The crossing of segment a→b with the surface nearest to a (both sides of each face count);
  /// of crossings equally near, the lowest face index. No allocation.
  [[nodiscard]] std::optional<SegmentHit> first_hit(const MeshView& m, Vec3f a, Vec3f b) const;

  /// All crossings of segment a→b, sorted by t (then face). A segment through a shared edge or
  /// vertex may report each face there. out is cleared first; no allocation when it has capacity.
  void segment_hits(const MeshView& m, Vec3f a, Vec3f b, std::vector<SegmentHit>& out) const;

  /// True when the tree is consistent with m: every face sits in exactly one leaf, the face → leaf
  /// and parent links agree, and every box encloses its children's boxes and its faces' vertices.
  /// For tests; allocates.
  [[nodiscard]] bool check(const MeshView& m) const;

  /// Bytes of the tree's arrays in use (build() leaves reserve past them, never touched).
  [[nodiscard]] std::size_t size_bytes() const;
  [[nodiscard]] std::size_t node_count() const { return nodes_.size(); }
  [[nodiscard]] std::size_t face_count() const { return order_.size(); }
  /// Longest root-to-leaf path in nodes (1 for a single leaf, 0 when empty).
  [[nodiscard]] std::size_t depth() const { return depth_; }
  /// Whether two trees are the same node for node (boxes, children, leaves, face order).
  [[nodiscard]] bool same_tree(const TriangleBvh& other) const;

  /// Deepest tree that build() makes; the queries' fixed traversal stacks are this deep.
  static constexpr std::size_t kMaxDepth = 96;
  static constexpr std::uint32_t kMaxLeafFaces = 4;

 private:
  // 32 bytes. Leaf: count ≥ 1 faces at order_[first .. first+count). Internal: count == 0,
  // children at first and first + 1.
  struct Node {
    Vec3f lo;
    std::uint32_t first = 0;
    Vec3f hi;
    std::uint32_t count = 0;
  };

  void refit_leaf(const MeshView& m, Node& node) const;
  template <class Leaf>
  void walk_boxes_within(Vec3 q, double r2, Leaf&& leaf) const;  // leaf(node) for every leaf within sqrt(r2) of q
  void refit_internal();  // every internal box from its children's, bottom up

  std::vector<Node> nodes_;             // #nodes, root at 0, children after their parent
  std::vector<std::uint32_t> parent_;   // #nodes, parent node (root: itself)
  std::vector<std::uint32_t> order_;    // #F, face indices grouped by leaf
  std::vector<std::uint32_t> leaf_of_;  // #F, the leaf node holding each face
  std::size_t depth_ = 0;
};

/// Closest point on triangle (a, b, c) to p, with barycentrics of b and c (exact in every Voronoi
/// region: 3 vertices, 3 edges, the face; computed in double). Zero-area triangles are handled as
/// their edges. face is left 0.
PointHit closest_point_on_triangle(Vec3f p, Vec3f a, Vec3f b, Vec3f c);

/// Squared distance (m²) from p to triangle (a, b, c), in double: the test faces_within uses.
double point_triangle_distance_squared(Vec3f p, Vec3f a, Vec3f b, Vec3f c);

/// Watertight segment–triangle test (both sides). On a crossing returns t in [0, 1] along a→b and
/// the barycentrics (u, v) of b and c; nothing for a miss, a zero-area triangle or a segment in
/// the triangle's plane.
std::optional<SegmentHit> segment_triangle(Vec3f a, Vec3f b, Vec3f p0, Vec3f p1, Vec3f p2);

}  // namespace lancet::surface
