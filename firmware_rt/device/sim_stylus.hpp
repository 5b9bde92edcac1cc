#pragma once
// The built-in simulated stylus: a point mass (the stylus and the hand holding it) that a hand
// spring pulls toward a target while the device force pushes back, integrated semi-implicitly.
// It is a Device like the bus backends: read() gives its position and velocity as three Cartesian
// joints (q = x, y, z in m; qd in m/s; the servo's model pairs it with arm::Kinematics::cartesian()),
// write() applies the commanded force (tau = f_x, f_y, f_z in N) for one period. Where the hand
// pulls comes through steer_hand(). Real-time safe after construction.

#include "device/device.hpp"
#include "lancet/shared_model/geometry.hpp"
#include "lancet/shared_model/messages.hpp"

namespace lancet::device {

struct SimStylusParams {
  double mass = 0.15;            ///< kg, stylus plus hand
  double hand_stiffness = 1500;  ///< N/m, hand spring toward the target
  double hand_damping = 21;      ///< N·s/m
  double max_speed = 2.0;        ///< m/s, clamp (a hand does not move faster)
};

struct SimStylusState {
  Vec3 position;  ///< m
  Vec3 velocity;  ///< m/s
};

/// One semi-implicit Euler step of dt seconds under the hand spring toward `target` and the device
/// force (N, on the hand).
void step_sim_stylus(const SimStylusParams& p, SimStylusState& s, Vec3 target, Vec3 device_force, double dt) noexcept;

/// The built-in script: descend to `depth` below z = 0 in 1 s, then a slow figure-of-eight.
Vec3 scripted_target(double t, double depth) noexcept;

/// Where the left hand's built-in script parks its stylus: above the tissue, out of contact, to
/// one side of the right hand's figure-of-eight (tissue frame, m).
inline constexpr Vec3 kLeftParked{0.0, 0.040, 0.020};

/// Each hand's built-in script: the right hand presses and draws scripted_target(t, depth); the
/// left hand holds kLeftParked. Real-time safe.
Vec3 scripted_target(Hand hand, double t, double depth) noexcept;

class SimStylus final : public Device {
 public:
  /// Starts at `start` (m), at rest; each write() advances the stylus by dt seconds.
  SimStylus(SimStylusParams params, double dt, Vec3 start);

  [[nodiscard]] int joint_count() const noexcept override { return 3; }
  void steer_hand(Vec3 target) noexcept override { target_ = target; }
  [[nodiscard]] const SimStylusState& state() const noexcept { return state_; }

 protected:
  Result<void> on_configure() override { return Result<void>::success(); }
  Result<void> on_activate() override { return Result<void>::success(); }
  Result<void> on_deactivate() override { return Result<void>::success(); }
  Result<void> on_rearm() override { return Result<void>::success(); }
  IoStatus on_read(JointState& out) noexcept override;
  IoStatus on_write(const JointCommand& cmd) noexcept override;

 private:
  SimStylusParams params_;
  double dt_;
  SimStylusState state_;
  Vec3 target_;
};

}  // namespace lancet::device
