// Motor space ↔ joint space (the formulas in JointConfig, arm/arm_config.hpp). Real-time safe.

#include "arm/config/units.hpp"

#include <numbers>

#include "arm/arm_config.hpp"

namespace lancet::arm {

double joint_position_from_counts(const JointConfig& j, std::int64_t counts) noexcept {
  const double per_output_rev = static_cast<double>(j.counts_per_rev) * j.gear_ratio;
  const double travel = j.type == JointType::kRevolute ? 2.0 * std::numbers::pi : j.lead;
  return j.direction * travel * static_cast<double>(counts) / per_output_rev + j.offset;
}

double motor_current_for_joint_torque(const JointConfig& j, const ActuatorConfig& a, double tau) noexcept {
  // Output-side torque: tau itself (revolute) or force × lead / 2π (prismatic); the gear divides it.
  const double output = j.type == JointType::kRevolute ? tau : tau * j.lead / (2.0 * std::numbers::pi);
  return j.direction * output / (j.gear_ratio * a.torque_constant);
}

}  // namespace lancet::arm
