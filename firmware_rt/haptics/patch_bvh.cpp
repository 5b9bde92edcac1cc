#include "haptics/patch_bvh.hpp"

#include <algorithm>

namespace lancet::haptics {
namespace {

// v < lo ? v : lo — NaN never wins, either way round.
float lower(float lo, float v) { return v < lo ? v : lo; }
float upper(float hi, float v) { return v > hi ? v : hi; }

void grow(PatchBvh::Box& b, Vec3f v) {
  b.lo = {lower(b.lo.x, v.x), lower(b.lo.y, v.y), lower(b.lo.z, v.z)};
  b.hi = {upper(b.hi.x, v.x), upper(b.hi.y, v.y), upper(b.hi.z, v.z)};
}

}  // namespace

void build_patch_bvh(PatchBvh& bvh, const TissuePatch& patch, std::uint64_t version) noexcept {
  const std::uint32_t n = std::min(patch.n_triangles, kPatchCapacity);
  const std::uint32_t leaves = (n + kPatchLeafSize - 1) / kPatchLeafSize;
  std::uint32_t first = 1;
  while (first < leaves) first *= 2;
  bvh.version = version;
  bvh.n_triangles = n;
  bvh.first_leaf = first;
  for (std::uint32_t j = 0; j < first; ++j) {
    PatchBvh::Box box;
    const std::uint32_t end = std::min(n, (j + 1) * kPatchLeafSize);
    for (std::uint32_t i = j * kPatchLeafSize; i < end; ++i) {
      // No finiteness test: min and max keep the box's side on a NaN (every comparison with it is
      // false), and an infinite corner only makes the box infinite. Either way the box holds every
      // finite corner, and the proxy skips a triangle with a non-finite one.
      const PatchTriangle& t = patch.triangles[i];
      grow(box, t.v[0]), grow(box, t.v[1]), grow(box, t.v[2]);
    }
    bvh.nodes[first + j] = box;
  }
  for (std::uint32_t i = first - 1; i >= 1; --i) {
    PatchBvh::Box box = bvh.nodes[2 * i];
    const PatchBvh::Box& r = bvh.nodes[2 * i + 1];
    if (r.lo.x <= r.hi.x) grow(box, r.lo), grow(box, r.hi);
    bvh.nodes[i] = box;
  }
}

}  // namespace lancet::haptics
