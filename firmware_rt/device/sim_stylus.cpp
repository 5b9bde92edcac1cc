#include "sim_stylus.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace lancet::device {

void step_sim_stylus(const SimStylusParams& p, SimStylusState& s, Vec3 target, Vec3 device_force, double dt) noexcept {
  const Vec3 hand = p.hand_stiffness * (target - s.position) - p.hand_damping * s.velocity;
  const Vec3 accel = (1.0 / p.mass) * (hand + device_force);
  s.velocity += dt * accel;
  const double speed = norm(s.velocity);
  if (speed > p.max_speed) s.velocity = (p.max_speed / speed) * s.velocity;
  s.position += dt * s.velocity;
}

SimStylus::SimStylus(SimStylusParams params, double dt, Vec3 start)
    : Device("sim-stylus"), params_(params), dt_(dt), state_{start, {}}, target_(start) {}

IoStatus SimStylus::on_read(JointState& out) noexcept {
  out.n = 3;
  out.q[0] = state_.position.x, out.q[1] = state_.position.y, out.q[2] = state_.position.z;
  out.qd[0] = state_.velocity.x, out.qd[1] = state_.velocity.y, out.qd[2] = state_.velocity.z;
  return IoStatus::kOk;
}

IoStatus SimStylus::on_write(const JointCommand& cmd) noexcept {
  const Vec3 f = cmd.n >= 3 ? Vec3{cmd.tau[0], cmd.tau[1], cmd.tau[2]} : Vec3{};
  step_sim_stylus(params_, state_, target_, f, dt_);
  return IoStatus::kOk;
}

Vec3 scripted_target(double t, double depth) noexcept {
  constexpr double kStart = 0.015;  // m above the plane
  constexpr double kDescent = 1.0;  // s
  if (t < kDescent) {
    const double a = 0.5 - 0.5 * std::cos(std::numbers::pi * t / kDescent);  // 0 → 1, smooth
    return {0.0, 0.0, kStart + a * (-depth - kStart)};
  }
  const double u = t - kDescent;
  const double x = 0.03 * std::sin(2.0 * std::numbers::pi * u / 4.0);
  const double y = 0.01 * std::sin(2.0 * std::numbers::pi * u / 9.0);
  return {x, y, -depth};
}

Vec3 scripted_target(Hand hand, double t, double depth) noexcept {
  return hand == Hand::kLeft ? kLeftParked : scripted_target(t, depth);
}

}  // namespace lancet::device
