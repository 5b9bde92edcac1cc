#include "device/sim_arm.hpp"

#include "lancet/shared_model/units.hpp"

#include <algorithm>

#include <time.h>

namespace lancet::device {

SimArm::SimArm(std::unique_ptr<ArmPhysics> physics, FaultPolicy policy)
    : Device("sim arm '" + physics->config().name + "'", policy), physics_(std::move(physics)) {}

Result<std::unique_ptr<SimArm>> SimArm::create(const arm::ArmConfig& config, FaultPolicy policy) {
  auto p = ArmPhysics::create(config);
  if (!p.ok()) return p.error();
  return std::unique_ptr<SimArm>(new SimArm(std::move(p).value(), policy));
}

Result<void> SimArm::on_activate() {
  last_write_ns_ = 0;
  return Result<void>::success();
}

Result<void> SimArm::on_deactivate() {
  JointCommand zero{};
  zero.n = joint_count();
  physics_->step(zero, fixed_dt_ > 0 ? fixed_dt_ : 1e-3);
  return Result<void>::success();
}

Result<void> SimArm::on_rearm() {
  inject_count_ = 0;
  last_write_ns_ = 0;
  return Result<void>::success();
}

IoStatus SimArm::on_read(JointState& out) noexcept {
  if (inject_count_ > 0) {
    --inject_count_;
    return inject_status_;
  }
  const auto& cfg = physics_->config();
  out.n = joint_count();
  for (int j = 0; j < out.n; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    out.counts[uj] = physics_->encoder_counts(j);
    if (glitch_reads_ > 0 && j == glitch_joint_) out.counts[uj] += glitch_counts_;
    out.q[uj] = arm::joint_position_from_counts(cfg.joints[uj], out.counts[uj]);
    out.qd[uj] = physics_->qd(j);
  }
  if (glitch_reads_ > 0) --glitch_reads_;
  out.buttons = 0;
  out.status = 0;
  return IoStatus::kOk;
}

IoStatus SimArm::on_write(const JointCommand& cmd) noexcept {
  double dt = fixed_dt_;
  if (!(dt > 0)) {
    const std::int64_t now = monotonic_ns();
    dt = last_write_ns_ == 0 ? 1e-3 : std::clamp(static_cast<double>(now - last_write_ns_) * 1e-9, 0.0, 5e-3);
    last_write_ns_ = now;
  }
  physics_->step(cmd, dt);
  return IoStatus::kOk;
}

}  // namespace lancet::device
