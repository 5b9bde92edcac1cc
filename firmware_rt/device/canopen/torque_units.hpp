#pragma once
// CiA 402 torque units for an arm's joints: the rated torque (0x6076, mN·m) of an actuator, and
// joint torque ↔ per mille of it (0x6071 target, 0x6077 actual) through the joint's gear,
// direction and lead. Real-time safe.

#include <cstdint>

#include "arm/arm_config.hpp"

namespace lancet::device::canopen {

/// The rated torque written to 0x6076: the actuator's continuous torque in mN·m, rounded (CiA 402
/// unit). 0 when it rounds below 1 mN·m (CanopenArm::create() rejects that).
[[nodiscard]] std::uint32_t rated_torque_mnm(const arm::ActuatorConfig& actuator) noexcept;

/// Target torque (0x6071, per mille of `rated_mnm`) for the joint torque tau (N·m, N for
/// prismatic) through the joint's gear, direction and lead; rounded, clamped to ± limit (and the
/// int16 range); 0 for a non-finite tau.
[[nodiscard]] std::int16_t torque_per_mille(const arm::JointConfig& joint, const arm::ActuatorConfig& actuator,
                                            std::uint32_t rated_mnm, std::int16_t limit, double tau) noexcept;

/// The joint torque (N·m, N for prismatic) a motor gives at `per_mille` of `rated_mnm`: the
/// inverse of torque_per_mille without its rounding; 0 for a transmission that passes no torque.
[[nodiscard]] double joint_torque_from_per_mille(const arm::JointConfig& joint, const arm::ActuatorConfig& actuator,
                                                 std::uint32_t rated_mnm, std::int16_t per_mille) noexcept;

}  // namespace lancet::device::canopen
