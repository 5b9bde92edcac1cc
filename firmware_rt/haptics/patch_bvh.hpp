#pragma once
// PatchBvh: lancet-rt's search tree over a TissuePatch, so that the proxy's queries cost what is
// near the tool, not the whole patch (16 384 triangles).
//
// The tree's shape is fixed: leaf j holds the patch's triangles [8j, 8j + 8) in the order the
// visualizer sent them, and the leaves are the bottom row of a complete binary tree stored as a
// heap (node 1 the root, children 2i and 2i + 1). lancet-rt computes every box itself, from the
// triangles, when a patch arrives (build: one pass over the triangles, one over the nodes, no
// allocation). So the peer decides only the order: one that keeps neighbours together (its own
// BVH's) gives tight leaves; any other order makes queries slower, never wrong — every triangle
// lies in its leaf's box, whatever the peer did. Non-finite coordinates never enter a box (the
// proxy ignores a triangle with one).
//
// Queries visit the leaves whose box comes within a distance of a point, nearest tree order
// first; the visitor may stop the walk. Real-time safe: bounded stack, no allocation.

#include <array>
#include <cstdint>

#include "lancet/shared_model/geometry.hpp"
#include "lancet/shared_model/messages.hpp"

namespace lancet::haptics {

inline constexpr std::uint32_t kPatchLeafSize = 8;
inline constexpr std::uint32_t kPatchLeaves = kPatchCapacity / kPatchLeafSize;
static_assert((kPatchLeaves & (kPatchLeaves - 1)) == 0, "the leaf row must be a power of two");

struct PatchBvh {
  struct Box {
    Vec3f lo{1e30f, 1e30f, 1e30f};  ///< empty: lo > hi
    Vec3f hi{-1e30f, -1e30f, -1e30f};
  };
  std::uint64_t version = 0;     ///< the patch version it was built for (0: none)
  std::uint32_t n_triangles = 0;
  std::uint32_t first_leaf = 1;  ///< heap index of leaf 0 (a power of two)
  std::array<Box, 2 * kPatchLeaves> nodes{};
};

/// Builds `bvh` for `patch` (as patch version `version`). O(n_triangles).
void build_patch_bvh(PatchBvh& bvh, const TissuePatch& patch, std::uint64_t version) noexcept;

/// Squared distance from p to the box (0 inside; huge for an empty box).
inline double box_distance2(const PatchBvh::Box& b, Vec3 p) noexcept {
  if (b.lo.x > b.hi.x) return 1e60;
  const auto axis = [](double v, float lo, float hi) {
    const double d = v < lo ? lo - v : (v > hi ? v - hi : 0.0);
    return d * d;
  };
  return axis(p.x, b.lo.x, b.hi.x) + axis(p.y, b.lo.y, b.hi.y) + axis(p.z, b.lo.z, b.hi.z);
}

/// Calls visit(first, last, d2) for every leaf whose box lies within `reach` of p, nearest tree
/// order first (left before right): its triangles [first, last) of the patch, none of them nearer
/// p than sqrt(d2) (the box's distance). visit returns false to stop the walk. Returns false when
/// stopped.
template <class VisitLeaf>
bool for_each_leaf_near(const PatchBvh& bvh, Vec3 p, double reach, VisitLeaf&& visit) noexcept {
  if (bvh.n_triangles == 0) return true;
  const double reach2 = reach * reach;
  std::uint32_t stack[64];
  int top = 0;
  stack[top++] = 1;
  while (top > 0) {
    const std::uint32_t node = stack[--top];
    const double d2 = box_distance2(bvh.nodes[node], p);
    if (d2 > reach2) continue;
    if (node >= bvh.first_leaf) {
      const std::uint32_t first = (node - bvh.first_leaf) * kPatchLeafSize;
      const std::uint32_t last = first + kPatchLeafSize < bvh.n_triangles ? first + kPatchLeafSize : bvh.n_triangles;
      if (first < last && !visit(first, last, d2)) return false;
      continue;
    }
    // Depth ≤ log2(kPatchLeaves) + 1, so the stack holds at most one sibling per level.
    stack[top++] = 2 * node + 1;
    stack[top++] = 2 * node;
  }
  return true;
}

/// Calls visit(i) for every triangle i of the patch in a leaf whose box lies within `reach` of p
/// (a superset of the triangles within reach; the caller tests them), in the order of
/// for_each_leaf_near. visit returns false to stop the walk. Returns false when stopped.
template <class Visit>
bool for_each_near(const PatchBvh& bvh, Vec3 p, double reach, Visit&& visit) noexcept {
  return for_each_leaf_near(bvh, p, reach, [&](std::uint32_t first, std::uint32_t last, double) {
    for (std::uint32_t i = first; i < last; ++i)
      if (!visit(i)) return false;
    return true;
  });
}

}  // namespace lancet::haptics
