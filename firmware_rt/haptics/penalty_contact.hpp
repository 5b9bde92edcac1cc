#pragma once
// Simple penalty contact against a TissuePatch (the Foundation's placeholder; the proxy-based
// haptic core replaces it). The tool tip is a point; the patch triangles carry outward normals
// (counter-clockwise winding). The nearest triangle decides: when the tip is below it (negative
// signed distance, shallower than max_depth), f = k·depth·n − D·(v·n)·n.

#include <cstdint>

#include "lancet/shared_model/geometry.hpp"
#include "lancet/shared_model/messages.hpp"

namespace lancet::haptics {

struct PenaltyParams {
  double stiffness = 500.0;   ///< N/m
  double damping = 2.0;       ///< N·s/m, along the normal, only while in contact
  double max_depth = 0.02;    ///< m; deeper than this counts as being on the far side: no force
};

struct ContactResult {
  Vec3 force;            ///< N, on the tool
  Vec3 closest;          ///< closest surface point (m); meaningful when n_triangles > 0
  Vec3 normal;           ///< outward unit normal there
  double signed_distance = 0;  ///< m, negative inside
  bool contact = false;
};

/// Closest point on triangle (a, b, c) to p (Ericson, Real-Time Collision Detection, 5.1.5).
Vec3 closest_point_on_triangle(Vec3 p, Vec3 a, Vec3 b, Vec3 c) noexcept;

/// Penalty force of the patch on a tool tip at position p moving with velocity v.
/// Real-time safe: O(n_triangles), no allocation.
ContactResult penalty_contact(const PenaltyParams& params, const TissuePatch& patch, Vec3 p, Vec3 v) noexcept;

}  // namespace lancet::haptics
