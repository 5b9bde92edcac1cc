#pragma once
// ArmPhysics: a simulated haptic arm built from its config (hw_configs/*.toml), for the in-process
// `sim` backend and for lancet-armsim, which serves the same arm over a bus.
//
// Joint-space rigid-body dynamics with the stylus and hand as a point mass m at the tool point:
//   M(q) q̈ = τ_motor + Jᵀ F_hand − b q̇,   M(q) = m JᵀJ + diag(rotor inertia),
// τ_motor = the commanded joint torques clamped to what the motors can give (torque constant ×
// peak current × gear ratio), F_hand = a spring-damper from the tool toward the hand's target
// (stiffness and damping from [bus.sim], or defaults), hard stops at the joint limits, and
// encoders that quantise each joint through its gear and counts per revolution (plus optional
// noise). Semi-implicit Euler; no allocation after construction: real-time safe.

#include <array>
#include <cstdint>
#include <memory>

#include "arm/arm_config.hpp"
#include "arm/kinematics.hpp"
#include "device/device.hpp"
#include "lancet/shared_model/geometry.hpp"
#include "lancet/shared_model/result.hpp"

namespace lancet::device {

struct ArmPhysicsParams {
  double mass = 0.15;            ///< kg at the tool point (stylus and hand)
  double hand_stiffness = 1500;  ///< N/m toward the target
  double hand_damping = 21;      ///< N·s/m
  double rotor_inertia = 2e-4;   ///< kg·m² (kg for prismatic) reflected at each joint
  double joint_damping = 0.01;   ///< N·m·s/rad at each joint
  std::int64_t encoder_noise_counts = 0;
};

class ArmPhysics {
 public:
  /// From a loaded config: its kinematics, joints, actuators and [bus.sim] (when present). The arm
  /// starts at rest at q = 0 (each joint clamped to its limits); a delta arm with the tool at the
  /// device-frame origin (its centre() when the origin is out of reach).
  [[nodiscard]] static Result<std::unique_ptr<ArmPhysics>> create(const arm::ArmConfig& config);

  /// Advances by dt (s) under the commanded joint torques (N·m, N for prismatic). RT-safe.
  void step(const JointCommand& cmd, double dt) noexcept;
  /// Where the hand pulls the tool (m, device frame).
  void set_hand_target(Vec3 target) noexcept { target_ = target; }
  /// Lets go of the stylus (no hand force) or takes it again.
  void set_hand_holding(bool holding) noexcept { holding_ = holding; }
  /// Puts the arm at q with zero velocity (joint limits applied).
  void reset(std::span<const double> q) noexcept;

  [[nodiscard]] int joint_count() const noexcept { return n_; }
  [[nodiscard]] double q(int j) const noexcept { return q_[static_cast<std::size_t>(j)]; }
  [[nodiscard]] double qd(int j) const noexcept { return qd_[static_cast<std::size_t>(j)]; }
  /// The encoder's count for joint j (quantised, with noise when configured).
  [[nodiscard]] std::int64_t encoder_counts(int j) noexcept;
  /// The tool point and its velocity (m, m/s, device frame).
  [[nodiscard]] Vec3 tool_position() const noexcept;
  [[nodiscard]] Vec3 tool_velocity() const noexcept;
  /// The torque the motors actually gave last step (after their limits).
  [[nodiscard]] double motor_torque(int j) const noexcept { return tau_[static_cast<std::size_t>(j)]; }
  /// The force the motors put on the tool last step: J⁻ᵀ τ for a square, non-singular J (N).
  [[nodiscard]] Vec3 rendered_force() const noexcept { return rendered_; }
  [[nodiscard]] const arm::ArmConfig& config() const noexcept { return config_; }
  [[nodiscard]] const arm::Kinematics& kinematics() const noexcept { return kin_; }
  [[nodiscard]] double peak_torque(int j) const noexcept { return peak_[static_cast<std::size_t>(j)]; }

 private:
  ArmPhysics(const arm::ArmConfig& config, const arm::Kinematics& kin) : config_(config), kin_(kin) {}

  arm::ArmConfig config_;
  arm::Kinematics kin_;
  ArmPhysicsParams params_{};
  int n_ = 0;
  std::array<double, kMaxJoints> q_{}, qd_{}, tau_{}, peak_{};
  Vec3 target_{};
  bool holding_ = true;
  Vec3 rendered_{};
  std::uint64_t noise_state_ = 0x9E3779B97F4A7C15ull;
};

}  // namespace lancet::device
