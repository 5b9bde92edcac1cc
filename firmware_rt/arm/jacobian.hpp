#pragma once
// The Jacobian values every kinematic model returns (arm/kinematics.hpp, arm/delta_arm.hpp): flat,
// fixed-size, no allocation.

#include <array>

#include "lancet/shared_model/geometry.hpp"
#include "lancet/shared_model/messages.hpp"

namespace lancet::arm {

/// Most joints any model handles; sizes the fixed arrays of the real-time path.
using lancet::kMaxJoints;  // the one limit, shared with the wire (messages.hpp)

/// Joint-space values (rad or m, N·m or N), entries [0, joint_count) used, the rest zero.
using JointArray = std::array<double, kMaxJoints>;

/// Linear Jacobian of the tool point, 3 × n: column j = ∂p/∂q_j (m/rad for a revolute joint,
/// dimensionless for a prismatic one). What haptics needs: τ = Jᵀ F.
struct Jacobian {
  int n = 0;
  std::array<Vec3, kMaxJoints> column{};
};

/// Geometric Jacobian, 6 × n: linear (as Jacobian) over angular (rad/s of the tool frame per unit
/// joint rate, base frame) parts.
struct SpatialJacobian {
  int n = 0;
  std::array<Vec3, kMaxJoints> linear{};
  std::array<Vec3, kMaxJoints> angular{};
};

}  // namespace lancet::arm
