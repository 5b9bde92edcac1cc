#pragma once
// Boxes of TriangleBvh's faces, shared by its build (bvh_build.cpp) and its queries (bvh.cpp).
// Internal to the surface library.

#include <algorithm>
#include <cassert>
#include <cstdint>
#include <limits>

#include "surface/bvh.hpp"

namespace lancet::surface::bvh_detail {

inline Vec3f vertex(const MeshView& m, std::uint32_t i) {
  assert(i < m.n_vertices && "TriangleBvh: face refers to a vertex past n_vertices");
  const float* p = m.xyz + 3 * static_cast<std::size_t>(i);
  return {p[0], p[1], p[2]};
}

struct Box {
  Vec3f lo{std::numeric_limits<float>::infinity(), std::numeric_limits<float>::infinity(),
           std::numeric_limits<float>::infinity()};
  Vec3f hi{-std::numeric_limits<float>::infinity(), -std::numeric_limits<float>::infinity(),
           -std::numeric_limits<float>::infinity()};

  void grow(Vec3f p) {
    lo = {std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z)};
    hi = {std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z)};
  }
  void grow(const Box& b) {
    grow(b.lo);
    grow(b.hi);
  }
  [[nodiscard]] bool empty() const { return !(lo.x <= hi.x); }
};

inline Box face_box(const MeshView& m, std::uint32_t f) {
  Box b;
  for (std::uint32_t vi : m.faces[f]) b.grow(vertex(m, vi));
  return b;
}

inline bool encloses(Vec3f lo, Vec3f hi, Vec3f p) {
  return lo.x <= p.x && p.x <= hi.x && lo.y <= p.y && p.y <= hi.y && lo.z <= p.z && p.z <= hi.z;
}

}  // namespace lancet::surface::bvh_detail
