#pragma once
// The `sim` backend: ArmPhysics in the same process, behind the Device lifecycle. write() advances
// the physics by the time since the previous write (or a fixed step for tests); read() returns
// the quantised encoders. Faults can be injected (tests, demos of the fault path).

#include <memory>

#include "arm/arm_config.hpp"
#include "device/arm_physics.hpp"
#include "device/device.hpp"

namespace lancet::device {

class SimArm final : public Device {
 public:
  [[nodiscard]] static Result<std::unique_ptr<SimArm>> create(const arm::ArmConfig& config, FaultPolicy policy = {});

  [[nodiscard]] ArmPhysics& physics() noexcept { return *physics_; }
  [[nodiscard]] const ArmPhysics& physics() const noexcept { return *physics_; }
  /// Integrate every write by exactly dt seconds (0: by the time since the previous write).
  void set_fixed_dt(double dt) noexcept { fixed_dt_ = dt; }
  /// The next `count` reads return `status` instead of data (a lost reply, a corrupt one, …).
  void inject(IoStatus status, int count) noexcept {
    inject_status_ = status;
    inject_count_ = count;
  }
  /// The next `reads` reads report joint j's encoder `counts` off (an encoder glitch).
  void inject_encoder_offset(int j, std::int64_t counts, int reads) noexcept {
    glitch_joint_ = j;
    glitch_counts_ = counts;
    glitch_reads_ = reads;
  }
  [[nodiscard]] int joint_count() const noexcept override { return physics_->joint_count(); }
  void steer_hand(Vec3 target) noexcept override { physics_->set_hand_target(target); }

 protected:
  Result<void> on_configure() override { return Result<void>::success(); }
  Result<void> on_activate() override;
  Result<void> on_deactivate() override;
  Result<void> on_rearm() override;
  IoStatus on_read(JointState& out) noexcept override;
  IoStatus on_write(const JointCommand& cmd) noexcept override;

 private:
  SimArm(std::unique_ptr<ArmPhysics> physics, FaultPolicy policy);

  std::unique_ptr<ArmPhysics> physics_;
  double fixed_dt_ = 0;
  std::int64_t last_write_ns_ = 0;
  IoStatus inject_status_ = IoStatus::kOk;
  int inject_count_ = 0;
  int glitch_joint_ = 0;
  std::int64_t glitch_counts_ = 0;
  int glitch_reads_ = 0;
};

}  // namespace lancet::device
