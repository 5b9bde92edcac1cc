#pragma once
// TriangleBvh: an axis-aligned bounding-box tree over a deforming triangle mesh, for the local
// surface operations of ALGORITHMS.md §3 (faces near the tool, closest point, where the blade
// path crosses the surface). Built once per topology (the faces sorted along a Morton curve and
// split where their octree cells part, at most 4 faces a leaf: the spatial-median tree that local
// queries on a surface want); after vertices move, refit() updates every box in O(n) and
// refit_faces() only the leaves of the given faces and their ancestors in O(k log n), so the cost
// of a local edit does not grow with the mesh.
//
// Lazily, where the tool goes: on a mesh of kLazyFrom faces or more, build() sorts the faces and
// splits only down to blocks of at most kBlockFaces faces, each boxed by its octree cell grown by
// the largest face's half size (it encloses the block's faces without reading them). A block's
// own nodes, leaves and exact boxes are made the first time a query reaches its box, or
// refit_faces() names one of its faces. The blocks split by the same rule at the same places, so
// the tree is the one an eager build makes, leaf for leaf and in the same order, and every query
// answers the same (a face's box test decides from exact leaf boxes; the looser boxes above them
// only cull less). A 3-million-face skin then costs its sort, not its tree, until the tool comes.
//
// The mesh is not stored: every call takes a MeshView of the caller's arrays (OpenMesh's points()
// and a face-index array), so the tree never holds a stale copy.
//
// Allocation: build() allocates (and so do check(), expand() and the copy, test helpers); the
// node array is mapped at its largest size once and its pages are touched only where a block is
// made. refit(), refit_faces() and the queries never allocate, except that faces_within() and
// segment_hits() grow the caller's `out` vector when it lacks capacity. Queries are const and may
// run on several threads at once (the first to reach a block makes it, under a lock, while the
// others wait for it); refits need exclusive access.
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
#include <memory>
#include <optional>
#include <span>
#include <vector>

#include "lancet/shared_model/geometry.hpp"
#include "volume/build_arrays.hpp"

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
  TriangleBvh();
  ~TriangleBvh();
  TriangleBvh(const TriangleBvh& other);  // the blocks made so far, copied; allocates
  TriangleBvh& operator=(const TriangleBvh& other);
  TriangleBvh(TriangleBvh&&) noexcept;
  TriangleBvh& operator=(TriangleBvh&&) noexcept;

  /// Builds the tree over all faces of m (≤ 4 faces a leaf): the faces sorted by the 30-bit Morton
  /// code of their box centre (stably, so equal codes keep face order), each range split where
  /// its codes' highest differing bit turns on, or at its middle where the codes are equal; depth
  /// stays below 30 + log2(#F) + 2. An empty mesh gives an empty tree. Allocates. A mesh of
  /// kLazyFrom faces or more computes its codes on two threads (`threads` false: one; the tree is
  /// the same either way, node for node) and is built in blocks, each made where a query first
  /// reaches (`lazy` false: the whole tree now, without blocks; the same leaves in the same order,
  /// so every query answers the same, in other nodes).
  void build(const MeshView& m, bool threads = true, bool lazy = true);

  /// Makes every block not yet made (a lazily built tree becomes the eager one). For tests and
  /// benchmarks; thread-safe as a query is. Precondition: m has the positions the tree's boxes
  /// were last fitted to.
  void expand(const MeshView& m) const;

  /// Recomputes every box bottom-up from the current positions and face indices (making every
  /// block). O(#F), no allocation. Precondition: m has the face count of the last build().
  void refit(const MeshView& m);

  /// Recomputes the boxes of the leaves holding `faces` and of their ancestors (stopping early
  /// where a box does not change). O(k log n), no allocation (a face's block is made first where
  /// it was not). The caller passes every face whose vertex positions or indices changed since the
  /// last refit; duplicates are harmless.
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
  void faces_in_boxes_within(const MeshView& m, Vec3f p, float r, std::vector<std::uint32_t>& out) const;

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
  /// Makes every block first. For tests; allocates.
  [[nodiscard]] bool check(const MeshView& m) const;

  /// Bytes of the tree's arrays in use (the nodes made so far; the node array's pages past them
  /// are never touched).
  [[nodiscard]] std::size_t size_bytes() const;
  /// Nodes made so far (every node once expand() or check() has run).
  [[nodiscard]] std::size_t node_count() const;
  [[nodiscard]] std::size_t face_count() const { return order_.size(); }
  /// Blocks of a lazy build, and how many of them are made (0 and 0 for an eager build).
  [[nodiscard]] std::size_t block_count() const { return blocks_.size(); }
  [[nodiscard]] std::size_t blocks_made() const;
  /// Longest root-to-leaf path in nodes among those made (1 for a single leaf, 0 when empty).
  [[nodiscard]] std::size_t depth() const;
  /// Whether two trees are the same node for node (boxes, children, leaves, face order, the
  /// blocks made).
  [[nodiscard]] bool same_tree(const TriangleBvh& other) const;

  /// Deepest tree that build() makes; the queries' fixed traversal stacks are this deep.
  static constexpr std::size_t kMaxDepth = 96;
  static constexpr std::uint32_t kMaxLeafFaces = 4;
  /// Faces from which build() goes lazily, and the most faces a block holds.
  static constexpr std::size_t kLazyFrom = 65536;
  static constexpr std::uint32_t kBlockFaces = 512;

 private:
  // 32 bytes. Leaf: 1 ≤ count ≤ 4 faces at order_[first .. first+count). Internal: count == 0,
  // children at first and first + 1. Block: count == kBlockNode, first = the block's index; its
  // one child is the block's root, made on first use. Zero memory reads as an internal node.
  struct Node {
    Vec3f lo;
    std::uint32_t first = 0;
    Vec3f hi;
    std::uint32_t count = 0;
  };
  static constexpr std::uint32_t kBlockNode = 0xffffffffu;
  // A block: faces order_[begin, end); its placeholder node; its nodes from root (2·#F + 2·begin,
  // room for 2·(end − begin)) on, `used` of them once made; the placeholder's depth.
  struct Block {
    std::uint32_t begin = 0, end = 0, node = 0, root = 0, used = 0, depth = 0;
  };
  struct NodeFree {
    NodeFree() noexcept : capacity(0) {}
    explicit NodeFree(std::size_t n) noexcept : capacity(n) {}
    std::size_t capacity;
    void operator()(Node* p) const noexcept;
  };
  struct Lazy;  // the lock that makes blocks and each block's made flag (bvh_build.cpp)

  [[nodiscard]] static bool is_leaf(const Node& n) { return n.count - 1u < kMaxLeafFaces; }
  void allocate_nodes(std::size_t capacity);
  // Splits order_[begin, end) top down from node `root` (children from `next` on), making block
  // placeholders for ranges of ≤ block_faces faces when block_faces > 0; returns the depth reached.
  std::size_t split(std::uint32_t root, std::uint32_t begin, std::uint32_t end, std::size_t depth, std::uint32_t block_faces,
                    std::uint32_t& next, const std::uint32_t* code) const;
  // The boxes of nodes [begin, end) from their faces and children (and each leaf's faces' leaf).
  void fit_nodes(const MeshView& m, std::uint32_t begin, std::uint32_t end, bool two) const;
  std::uint32_t open(const MeshView& m, std::uint32_t block) const;  // makes it if need be; its root
  void make_block(const MeshView& m, std::uint32_t block) const;     // under the lock or exclusive access
  void refit_leaf(const MeshView& m, Node& node) const;
  void refit_up(std::uint32_t i, bool stop_when_unchanged);  // the boxes of i's ancestors
  // Sets the box of an internal node to its two children's union, of a made block's node to its
  // root's box.
  void fit_to_children(Node& node) const;
  template <class Leaf>
  void walk_boxes_within(const MeshView& m, Vec3 q, double r2, Leaf&& leaf) const;  // leaf(node) for every leaf within sqrt(r2) of q
  template <class Fn>
  void for_each_made_range(Fn&& fn) const;  // fn(begin, end) over the node ranges made

  std::unique_ptr<Node[], NodeFree> nodes_;    // capacity 2·#F (eager) or 4·#F (lazy); zero till made
  mutable volume::ZeroedVector<std::uint32_t> parent_;   // as nodes_: parent node (root: itself)
  std::vector<std::uint32_t> order_;           // #F, face indices grouped by leaf
  mutable volume::ZeroedVector<std::uint32_t> leaf_of_;  // #F, the leaf holding each face (0: not made)
  volume::ScratchVector<std::uint32_t> rank_;  // lazy: #F, each face's place in order_
  volume::ScratchVector<std::uint32_t> code_;  // lazy: #F, the sorted Morton codes, for the blocks
  mutable std::vector<Block> blocks_;          // lazy: in order_'s order
  std::unique_ptr<Lazy> lazy_;
  std::uint32_t top_ = 0;                      // nodes made by build() (the eager tree, or the top)
  mutable std::size_t made_ = 0;               // nodes made (top_ + the blocks'), under the lock
  mutable std::size_t depth_ = 0;              // under the lock
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
