#include "penalty_contact.hpp"

#include <algorithm>
#include <limits>

namespace lancet::haptics {

Vec3 closest_point_on_triangle(Vec3 p, Vec3 a, Vec3 b, Vec3 c) noexcept {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = dot(ab, ap), d2 = dot(ac, ap);
  if (d1 <= 0 && d2 <= 0) return a;
  const Vec3 bp = p - b;
  const double d3 = dot(ab, bp), d4 = dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) return b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + (d1 / (d1 - d3)) * ab;
  const Vec3 cp = p - c;
  const double d5 = dot(ab, cp), d6 = dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) return c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + (d2 / (d2 - d6)) * ac;
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) return b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * (c - b);
  const double denom = 1.0 / (va + vb + vc);
  return a + (vb * denom) * ab + (vc * denom) * ac;
}

ContactResult penalty_contact(const PenaltyParams& params, const TissuePatch& patch, Vec3 p, Vec3 v) noexcept {
  ContactResult r{};
  const std::uint32_t n = std::min(patch.n_triangles, kPatchCapacity);
  double best = std::numeric_limits<double>::infinity();
  for (std::uint32_t i = 0; i < n; ++i) {
    const PatchTriangle& t = patch.triangles[i];
    const Vec3 a = to_vec3(t.v[0]), b = to_vec3(t.v[1]), c = to_vec3(t.v[2]);
    const Vec3 q = closest_point_on_triangle(p, a, b, c);
    const Vec3 d = p - q;
    const double dist2 = dot(d, d);
    if (dist2 < best) {
      const Vec3 nrm = normalized(cross(b - a, c - a));
      if (nrm == Vec3{}) continue;  // degenerate triangle: skip
      best = dist2;
      r.closest = q;
      r.normal = nrm;
      r.signed_distance = dot(d, nrm);
    }
  }
  if (best == std::numeric_limits<double>::infinity()) return r;
  const double depth = -r.signed_distance;
  if (depth > 0 && depth < params.max_depth) {
    r.contact = true;
    const double vn = dot(v, r.normal);
    const double fn = std::max(0.0, params.stiffness * depth - params.damping * vn);  // never pull
    r.force = fn * r.normal;
  }
  return r;
}

}  // namespace lancet::haptics
