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

#include "haptics/patch_bvh.hpp"
#include "lancet/shared_model/geometry.hpp"
#include "lancet/shared_model/messages.hpp"
#include "lancet/shared_model/word_hasher.hpp"

namespace lancet::haptics {

/// Half-space n·x ≥ d, from triangle `triangle` of the patch.
struct Plane {
  Vec3 n;
  double d;
  std::uint32_t triangle;
  /// Its place in the list collect_planes would build (the order the search meets the triangles):
  /// what breaks ties in the solve, so a list built in another order solves the same
  std::uint32_t rank = 0;
};

/// Most planes one proxy update takes. More triangles within reach (a step much longer than
/// the triangles are wide) and the step is shortened until they fit (update_proxy).
inline constexpr std::size_t kMaxPlanes = 1024;

/// Triangles [first, last) of the patch whose planes are not built yet, none nearer the proxy than
/// sqrt(distance2) (m; its leaf's box), the first of them rank `rank`.
struct PlaneGroup {
  std::uint32_t first = 0, last = 0, rank = 0;
  double distance2 = 0;
};
inline constexpr std::size_t kMaxPlaneGroups = kMaxPlanes / kPatchLeafSize + 1;

/// The planes of one proxy update. update_proxy builds them as the solve needs them (lazily): a
/// triangle whose plane cannot be violated where the solve looks (it lies further from the proxy's
/// start than that point plus a radius) waits in `pending`, and most never get built; what the
/// solve and the friction decide is the same as with every plane built (ProxyScratch::lazy false).
struct ProxyScratch {
  std::array<Plane, kMaxPlanes> planes;
  std::size_t n_planes = 0;
  bool overflow = false;      ///< the last collect_planes found more than kMaxPlanes
  std::uint64_t shortened = 0;  ///< updates whose step was shortened because of it (count)
  /// false: update_proxy builds every plane within reach up front (the reference the tests
  /// compare the lazy build against)
  bool lazy = true;
  std::array<PlaneGroup, kMaxPlaneGroups> pending;  ///< not built yet, any order
  std::size_t n_pending = 0;
  double nearest_pending = 0;  ///< least distance among them (m)
  const TissuePatch* patch = nullptr;  ///< what they are built from: the patch, the proxy's start,
  Vec3 from{};                         ///< its radius and the reach (squared)
  double radius = 0, reach2 = 0;
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

/// Builds the separating planes of every patch triangle within `reach` of the sphere at p,
/// through `bvh` (built for this patch) or, when null, by a scan of the whole patch. Stops with
/// s.overflow set when more than kMaxPlanes qualify. Builds them all (s.n_pending = 0).
std::size_t collect_planes(const TissuePatch& patch, const PatchBvh* bvh, Vec3 p, double radius, double reach,
                           ProxyScratch& s) noexcept;

/// The triangle of the patch nearest p within max_distance (its index; n_triangles when none),
/// with the nearest point in q. Through bvh when given, else a scan. Triangles with a non-finite
/// corner are skipped.
std::uint32_t nearest_triangle(const TissuePatch& patch, const PatchBvh* bvh, Vec3 p, double max_distance, Vec3& q) noexcept;

/// Where a free proxy whose centre p lies inside the tissue should start instead: just in front of
/// the nearest triangle (its centre `radius` above the face), when p is within `depth` of it,
/// behind its face and under the surface (the way to it within about 37° of the face normal: not
/// past the sheet's border) and the triangle is not on a cut's edge (p may be inside an opened
/// incision). Otherwise p.
/// This is how a stylus that is already below the surface when the tissue first appears around it
/// (the patch came after the hand, lancet-rt started with the stylus pressed in) is pushed out
/// instead of being ignored. Bounded: one pass over the patch at most.
Vec3 surface_entry(const TissuePatch& patch, const PatchBvh* bvh, Vec3 p, double radius, double depth) noexcept;

/// The point nearest goal that satisfies every plane, resting on at most three; p when none is
/// found (p must satisfy them all; *found, when given, says which). active_out receives the planes
/// it rests on.
Vec3 solve_constraints(const Plane* planes, std::size_t n, Vec3 p, Vec3 goal, std::array<std::uint32_t, 3>& active_out,
                       std::uint32_t& n_active, bool* found = nullptr) noexcept;

/// One proxy update without friction: from the previous centre p toward the device. Leaves the
/// planes it used in scratch for apply_friction. When more than kMaxPlanes triangles lie within
/// the step's reach, or the solve finds no point (a long step over a curved sheet), the step is
/// halved (the proxy goes part of the way this tick and on later), up to four times; then the
/// proxy stays at p (always feasible). Bounded: at most five queries and solves. Through a tree,
/// the planes are built as the solve needs them (ProxyScratch).
ProxyResult update_proxy(const TissuePatch& patch, const PatchBvh* bvh, Vec3 p, Vec3 device, double radius,
                         ProxyScratch& scratch) noexcept;

/// Where the proxy rests, in the frame of the triangle under it (the riding proxy, after CHAI3D's
/// adjustDynamicProxy): proxy = a + s·(b − a) + t·(c − a) + h·n̂ for its corners a, b, c and unit
/// normal n̂. When a newer patch moves that triangle (same PatchTriangle::id), the proxy moves with
/// it — a dent springing back, a retracted flap, a sliding sheet — instead of staying in world
/// space, where tissue moving toward the tool would leave it behind the surface (pop-through).
struct ProxyAnchor {
  bool valid = false;
  std::uint32_t id = 0;        ///< the triangle's surface id
  double s = 0, t = 0, h = 0;  ///< the proxy in its frame

  void hash(WordHasher& w) const noexcept { w.b(valid), w.word(id), w.f(s), w.f(t), w.f(h); }
};

/// The anchor of a proxy at `proxy` on triangle `i` of the patch (invalid for a degenerate one).
ProxyAnchor anchor_proxy(const TissuePatch& patch, std::uint32_t i, Vec3 proxy) noexcept;

/// Where an anchored proxy that was at `proxy` is on `patch`: its triangle (found by id among
/// those within `search` of proxy, through bvh when given) carried to its new place. false (and `out`
/// untouched) when the triangle is gone or degenerate, or the carry would move it further than
/// `max_move` (then the id no longer names the same piece of surface).
bool carry_proxy(const TissuePatch& patch, const PatchBvh* bvh, const ProxyAnchor& a, Vec3 proxy, double search,
                 double max_move, Vec3& out) noexcept;

/// Coulomb friction on a proxy in contact (r from update_proxy with the same p, device and
/// scratch), with static and dynamic coefficients mu_s, mu_d (tangential/normal spring
/// displacement). A proxy that was sliding last tick (`sliding`) keeps sliding unless it falls
/// inside the dynamic cone, so the force does not saw-tooth between the two coefficients. May
/// build more of the scratch's planes.
void apply_friction(ProxyResult& r, Vec3 p, Vec3 device, double mu_s, double mu_d, bool sliding,
                    ProxyScratch& scratch) noexcept;

}  // namespace lancet::haptics
