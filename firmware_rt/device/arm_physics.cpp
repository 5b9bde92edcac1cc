#include "device/arm_physics.hpp"

#include <algorithm>
#include <cmath>
#include <string>

namespace lancet::device {

namespace {

// Solves A x = b (n ≤ kMaxJoints, A row-major n×n) by Gaussian elimination with partial pivoting.
// Returns false for a singular A (x untouched).
bool solve(std::array<double, kMaxJoints * kMaxJoints>& a, std::array<double, kMaxJoints>& b, int n,
           std::array<double, kMaxJoints>& x) noexcept {
  const auto at = [&](int r, int c) -> double& { return a[static_cast<std::size_t>(r * n + c)]; };
  for (int c = 0; c < n; ++c) {
    int piv = c;
    for (int r = c + 1; r < n; ++r)
      if (std::abs(at(r, c)) > std::abs(at(piv, c))) piv = r;
    if (!(std::abs(at(piv, c)) > 1e-15)) return false;
    if (piv != c) {
      for (int k = 0; k < n; ++k) std::swap(at(c, k), at(piv, k));
      std::swap(b[static_cast<std::size_t>(c)], b[static_cast<std::size_t>(piv)]);
    }
    for (int r = c + 1; r < n; ++r) {
      const double f = at(r, c) / at(c, c);
      for (int k = c; k < n; ++k) at(r, k) -= f * at(c, k);
      b[static_cast<std::size_t>(r)] -= f * b[static_cast<std::size_t>(c)];
    }
  }
  for (int r = n - 1; r >= 0; --r) {
    double s = b[static_cast<std::size_t>(r)];
    for (int k = r + 1; k < n; ++k) s -= at(r, k) * x[static_cast<std::size_t>(k)];
    x[static_cast<std::size_t>(r)] = s / at(r, r);
  }
  return true;
}

}  // namespace

Result<std::unique_ptr<ArmPhysics>> ArmPhysics::create(const arm::ArmConfig& config) {
  auto kin = arm::make_kinematics(config);
  if (!kin.ok()) return kin.error();
  const int n = kin.value().joint_count();
  if (n < 1 || n > kMaxJoints || static_cast<int>(config.joints.size()) != n || static_cast<int>(config.actuators.size()) != n)
    return Error{ErrorCode::kInvalid, config.source + ": the arm needs 1.." + std::to_string(kMaxJoints) +
                                          " joints, one joint and one actuator entry each (found " + std::to_string(config.joints.size()) +
                                          " joints, " + std::to_string(config.actuators.size()) + " actuators)"};
  std::unique_ptr<ArmPhysics> p(new ArmPhysics(config, kin.value()));
  p->n_ = n;
  if (config.sim) {
    p->params_.mass = config.sim->stylus_mass;
    p->params_.hand_stiffness = config.sim->hand_stiffness;
    p->params_.hand_damping = config.sim->hand_damping;
    p->params_.encoder_noise_counts = config.sim->encoder_noise_counts;
  }
  for (int j = 0; j < n; ++j) {
    const auto& joint = config.joints[static_cast<std::size_t>(j)];
    const auto& act = config.actuators[static_cast<std::size_t>(j)];
    // Joint torque per ampere through the gear (linear): invert the config's current mapping.
    const double amps_per_unit = std::abs(arm::motor_current_for_joint_torque(joint, act, 1.0));
    p->peak_[static_cast<std::size_t>(j)] = amps_per_unit > 0 ? act.peak_current / amps_per_unit : 0.0;
    p->q_[static_cast<std::size_t>(j)] = std::clamp(0.0, joint.min, joint.max);
  }
  // A parallel arm has no natural q = 0: start with the tool at the device-frame origin (where a
  // config puts the workspace centre), or at the model's own centre when the origin is out of reach.
  if (const arm::DeltaArm* delta = p->kin_.delta()) {
    const auto q = delta->inverse(Vec3{});
    p->reset(q ? *q : delta->inverse(delta->centre()).value_or(std::array<double, 3>{}));
  }
  p->target_ = p->tool_position();
  return p;
}

void ArmPhysics::reset(std::span<const double> q) noexcept {
  for (int j = 0; j < n_; ++j) {
    const auto& joint = config_.joints[static_cast<std::size_t>(j)];
    const double v = j < static_cast<int>(q.size()) ? q[static_cast<std::size_t>(j)] : 0.0;
    q_[static_cast<std::size_t>(j)] = std::clamp(std::isfinite(v) ? v : 0.0, joint.min, joint.max);
    qd_[static_cast<std::size_t>(j)] = 0;
  }
}

Vec3 ArmPhysics::tool_position() const noexcept { return kin_.position(std::span<const double>(q_.data(), static_cast<std::size_t>(n_))); }

Vec3 ArmPhysics::tool_velocity() const noexcept {
  const auto J = kin_.jacobian(std::span<const double>(q_.data(), static_cast<std::size_t>(n_)));
  Vec3 v{};
  for (int j = 0; j < n_; ++j) v += J.column[static_cast<std::size_t>(j)] * qd_[static_cast<std::size_t>(j)];
  return v;
}

void ArmPhysics::step(const JointCommand& cmd, double dt) noexcept {
  if (!(dt > 0) || !std::isfinite(dt)) return;
  const std::span<const double> qs(q_.data(), static_cast<std::size_t>(n_));
  const auto J = kin_.jacobian(qs);
  const Vec3 x = kin_.position(qs);
  Vec3 xd{};
  for (int j = 0; j < n_; ++j) xd += J.column[static_cast<std::size_t>(j)] * qd_[static_cast<std::size_t>(j)];
  const Vec3 f_hand = holding_ ? (target_ - x) * params_.hand_stiffness - xd * params_.hand_damping : Vec3{};
  std::array<double, kMaxJoints * kMaxJoints> m{};
  std::array<double, kMaxJoints> rhs{}, acc{};
  for (int i = 0; i < n_; ++i) {
    const auto ui = static_cast<std::size_t>(i);
    const double t = i < cmd.n && std::isfinite(cmd.tau[ui]) ? cmd.tau[ui] : 0.0;
    tau_[ui] = std::clamp(t, -peak_[ui], peak_[ui]);
    rhs[ui] = tau_[ui] + dot(J.column[ui], f_hand) - params_.joint_damping * qd_[ui];
    for (int k = 0; k < n_; ++k)
      m[static_cast<std::size_t>(i * n_ + k)] = params_.mass * dot(J.column[ui], J.column[static_cast<std::size_t>(k)]) + (i == k ? params_.rotor_inertia : 0.0);
  }
  if (!solve(m, rhs, n_, acc)) acc.fill(0.0);
  for (int j = 0; j < n_; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const auto& joint = config_.joints[uj];
    qd_[uj] += acc[uj] * dt;
    q_[uj] += qd_[uj] * dt;
    if (q_[uj] < joint.min) {  // hard stop
      q_[uj] = joint.min;
      qd_[uj] = std::max(0.0, qd_[uj]);
    } else if (q_[uj] > joint.max) {
      q_[uj] = joint.max;
      qd_[uj] = std::min(0.0, qd_[uj]);
    }
  }
  // The force on the tool those torques make: least squares of Jᵀ F = τ, F = (J Jᵀ)⁻¹ J τ.
  std::array<double, kMaxJoints * kMaxJoints> jj{};
  std::array<double, kMaxJoints> jt{}, f{};
  for (int r = 0; r < 3; ++r) {
    const auto comp = [&](const Vec3& v, int c) { return c == 0 ? v.x : c == 1 ? v.y : v.z; };
    double s = 0;
    for (int j = 0; j < n_; ++j) s += comp(J.column[static_cast<std::size_t>(j)], r) * tau_[static_cast<std::size_t>(j)];
    jt[static_cast<std::size_t>(r)] = s;
    for (int c = 0; c < 3; ++c) {
      double e = 0;
      for (int j = 0; j < n_; ++j) e += comp(J.column[static_cast<std::size_t>(j)], r) * comp(J.column[static_cast<std::size_t>(j)], c);
      jj[static_cast<std::size_t>(r * 3 + c)] = e + (r == c ? 1e-12 : 0.0);
    }
  }
  rendered_ = solve(jj, jt, 3, f) ? Vec3{f[0], f[1], f[2]} : Vec3{};
}

std::int64_t ArmPhysics::encoder_counts(int j) noexcept {
  const auto& joint = config_.joints[static_cast<std::size_t>(j)];
  const double per_count = arm::joint_position_from_counts(joint, 1) - arm::joint_position_from_counts(joint, 0);
  const double zero = arm::joint_position_from_counts(joint, 0);
  auto counts = static_cast<std::int64_t>(std::llround((q_[static_cast<std::size_t>(j)] - zero) / per_count));
  if (params_.encoder_noise_counts > 0) {
    noise_state_ ^= noise_state_ << 13;
    noise_state_ ^= noise_state_ >> 7;
    noise_state_ ^= noise_state_ << 17;
    const auto span = static_cast<std::uint64_t>(2 * params_.encoder_noise_counts + 1);
    counts += static_cast<std::int64_t>(noise_state_ % span) - params_.encoder_noise_counts;
  }
  return counts;
}

}  // namespace lancet::device
