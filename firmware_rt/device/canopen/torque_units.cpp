#include "device/canopen/torque_units.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>

namespace lancet::device::canopen {

std::uint32_t rated_torque_mnm(const arm::ActuatorConfig& actuator) noexcept {
  const double mnm = actuator.continuous_torque() * 1e3;
  if (!(mnm >= 0.5) || !std::isfinite(mnm)) return 0;
  if (mnm >= 4.0e9) return std::numeric_limits<std::uint32_t>::max();
  return static_cast<std::uint32_t>(std::llround(mnm));
}

std::int16_t torque_per_mille(const arm::JointConfig& joint, const arm::ActuatorConfig& actuator, std::uint32_t rated_mnm,
                              std::int16_t limit, double tau) noexcept {
  if (!std::isfinite(tau) || rated_mnm == 0) return 0;
  // Motor-shaft torque (mN·m) through the gear, direction and lead, then per mille of the rated torque.
  const double motor_mnm = arm::motor_current_for_joint_torque(joint, actuator, tau) * actuator.torque_constant * 1e3;
  const double lim = std::min<double>(std::abs(static_cast<int>(limit)), 32767.0);
  const double pm = std::clamp(motor_mnm * 1e3 / static_cast<double>(rated_mnm), -lim, lim);
  return static_cast<std::int16_t>(std::lround(pm));
}

double joint_torque_from_per_mille(const arm::JointConfig& joint, const arm::ActuatorConfig& actuator, std::uint32_t rated_mnm,
                                   std::int16_t per_mille) noexcept {
  // ‰ of the rated torque → motor torque → current → joint torque through the transmission.
  const double motor_nm = per_mille * 1e-3 * static_cast<double>(rated_mnm) * 1e-3;
  const double amps = motor_nm / actuator.torque_constant;
  const double amps_per_unit = arm::motor_current_for_joint_torque(joint, actuator, 1.0);
  return amps_per_unit != 0 ? amps / amps_per_unit : 0.0;
}

}  // namespace lancet::device::canopen
