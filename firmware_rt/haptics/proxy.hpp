#pragma once
// Finite-radius god-object proxy (Zilles & Salisbury 1995; Ruspini et al. 1997) against the
// triangles of a TissuePatch.
//
// Constraints are separating planes built from the proxy's previous, feasible centre p: for each
// triangle near p, with c its closest point to p and n = (p − c)/|p − c|, the triangle lies in
// n·(y − c) ≤ 0 (it is convex), so any centre x with n·(x − c) ≥ r keeps the sphere off it. Faces,
// edges and vertices all give such planes, which is what keeps the proxy from popping through
// thin sheets or slipping through the seam between two triangles. The new centre is the point
// nearest the device satisfying every plane: an active-set solve with up to three planes at once
// (edges, corners, concave creases); when no such point is found the proxy stays at p, which is
// always feasible. Coulomb friction then lets it stick (static) or slide (dynamic). Triangles are
// one-sided: only those whose front (counter-clockwise) side faces the proxy constrain it.
// Real-time safe: bounded loops, no allocation (scratch lives in ProxyScratch).

#include <array>
#include <cstddef>
#include <cstdint>

#include "lancet/shared_model/geometry.hpp"
#include "lancet/shared_model/messages.hpp"

namespace lancet::haptics {

/// Half-space n·x ≥ d, from triangle `triangle` of the patch.
struct Plane {
  Vec3 n;
  double d;
  std::uint32_t triangle;
};

struct ProxyScratch {
  std::array<Plane, kPatchCapacity> planes;
  std::size_t n_planes = 0;
};

struct ProxyResult {
  Vec3 position;              ///< new proxy centre (m)
  Vec3 normal;                ///< unit contact normal (sum of active planes), zero when free
  std::uint32_t n_active = 0; ///< planes the proxy rests on (0: free)
  std::uint32_t triangle = 0; ///< a triangle it rests on (for its material)
  bool stuck = false;         ///< static friction held it
};

/// Closest point on triangle (a, b, c) to p (Ericson, Real-Time Collision Detection, 5.1.5).
Vec3 closest_point_on_triangle(Vec3 p, Vec3 a, Vec3 b, Vec3 c) noexcept;

/// Builds the separating planes of every patch triangle within `reach` of the sphere at p.
std::size_t collect_planes(const TissuePatch& patch, Vec3 p, double radius, double reach, ProxyScratch& s) noexcept;

/// Where a free proxy whose centre p lies inside the tissue should start instead: just in front of
/// the nearest triangle (its centre `radius` above the face), when p is within `depth` of it,
/// behind its face and under the surface (the way to it within about 37° of the face normal: not
/// past the sheet's border) and the triangle is not on a cut's edge (p may be inside an opened
/// incision). Otherwise p.
/// This is how a stylus that is already below the surface when the tissue first appears around it
/// (the patch came after the hand, lancet-rt started with the stylus pressed in) is pushed out
/// instead of being ignored. Bounded: one pass over the patch.
Vec3 surface_entry(const TissuePatch& patch, Vec3 p, double radius, double depth) noexcept;

/// The point nearest goal that satisfies every plane, resting on at most three; p when none is
/// found (p must satisfy them all). active_out receives the planes it rests on.
Vec3 solve_constraints(const Plane* planes, std::size_t n, Vec3 p, Vec3 goal, std::array<std::uint32_t, 3>& active_out,
                       std::uint32_t& n_active) noexcept;

/// One proxy update without friction: from the previous centre p toward the device. Leaves the
/// planes it used in scratch for apply_friction.
ProxyResult update_proxy(const TissuePatch& patch, Vec3 p, Vec3 device, double radius, ProxyScratch& scratch) noexcept;

/// Coulomb friction on a proxy in contact (r from update_proxy with the same p, device and
/// scratch), with static and dynamic coefficients mu_s, mu_d (tangential/normal spring
/// displacement). A proxy that was sliding last tick (`sliding`) keeps sliding unless it falls
/// inside the dynamic cone, so the force does not saw-tooth between the two coefficients.
void apply_friction(ProxyResult& r, Vec3 p, Vec3 device, double mu_s, double mu_d, bool sliding,
                    const ProxyScratch& scratch) noexcept;

}  // namespace lancet::haptics
