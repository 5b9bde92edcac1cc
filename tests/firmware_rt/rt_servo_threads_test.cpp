// The device handover between the servo thread and the supervisor thread, on two real threads, so
// that ThreadSanitizer (preset tsan, label threads) sees every access of it: the servo ticks the
// simulated arm flat out and faults it now and then, the viz side asks for re-arms, the
// supervisor thread re-arms. Every fault must be re-armed, and the servo must never touch the
// device while the supervisor holds it.

#include <gtest/gtest.h>

#include <atomic>
#include <memory>
#include <thread>

#include "app/rt_servo.hpp"
#include "arm/arm_config.hpp"
#include "device/sim_arm.hpp"
#include "lancet/shared_model/validate.hpp"

namespace lancet::app {
namespace {

TEST(RtServoThreads, ReArmHandshakeBetweenTheServoAndTheSupervisorThreads) {
  auto cfg = arm::load_arm_config(std::string(LANCET_SOURCE_DIR) + "/hw_configs/sim_3dof.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  const arm::ArmConfig config = std::move(cfg).value();
  const arm::Kinematics kin = arm::make_kinematics(config).value();
  auto arm = std::move(device::SimArm::create(config).value());
  arm->set_fixed_dt(1e-3);
  ASSERT_TRUE(arm->configure().ok());
  ASSERT_TRUE(arm->activate().ok());
  RtModel model;
  model.servo.kinematics = kin;
  model.servo.device_origin = 0.5 * (config.safety.workspace_min + config.safety.workspace_max);
  for (std::size_t j = 0; j < config.safety.max_joint_torque.size(); ++j) model.servo.max_joint_torque[j] = config.safety.max_joint_torque[j];
  auto shared = std::make_unique<SharedState>();
  std::int64_t t = 1'000'000'000;
  RtServo servo(model, *shared, t, arm.get());

  constexpr int kFaults = 20;
  std::atomic<bool> done{false};
  std::atomic<int> faults_injected{0};
  std::atomic<std::uint64_t> ticks_while_granted{0};
  std::thread servo_thread([&] {
    rt::Watchdog watchdog;
    rt::LoopLive live;
    std::uint64_t n = 0, seq = 0;
    int quiet_ticks = 0;
    while (faults_injected.load() < kFaults || servo.data().rearms < static_cast<std::uint64_t>(kFaults)) {
      if (n > 2'000'000) break;  // a hang would fail the expectations below, not the test runner
      t += model.servo.period_ns;
      shared->viz_heartbeat.beat(t, 1);
      // The device is the servo's only while the handover is idle: inject then, and only then.
      const bool idle = servo.data().handover.load(std::memory_order_acquire) == static_cast<int>(Handover::kIdle);
      if (idle && ++quiet_ticks > 50 && arm->state() == device::Lifecycle::kActive && faults_injected.load() < kFaults) {
        arm->inject(device::IoStatus::kDeviceFault, 1);
        faults_injected.fetch_add(1);
        quiet_ticks = 0;
      }
      // The viz's W key, pressed while faulted.
      if (idle && arm->state() == device::Lifecycle::kFault && n % 20 == 0) {
        Command c{};
        c.kind = CommandKind::kRearm;
        c.seq = ++seq;
        c.t_ns = t;
        wire::seal(c);
        (void)shared->commands.try_push(c);
      }
      servo.tick(rt::TickContext{t, t, ++n, watchdog, live});
      if (servo.data().handover.load(std::memory_order_acquire) == static_cast<int>(Handover::kGranted)) {
        ticks_while_granted.fetch_add(1);
        // The servo must not have touched the device this tick: it reports kFault without a read.
        EXPECT_EQ(servo.data().last_read, device::IoStatus::kFault);
      }
      ToolSample s;
      while (shared->samples.try_pop(s)) {
      }
      std::this_thread::yield();
    }
    done.store(true);
  });
  std::uint64_t jobs = 0;
  while (!done.load()) {
    if (servo.supervise()) ++jobs;
    std::this_thread::yield();
  }
  servo_thread.join();
  EXPECT_EQ(faults_injected.load(), kFaults);
  EXPECT_EQ(jobs, static_cast<std::uint64_t>(kFaults)) << "every fault re-armed by the supervisor";
  EXPECT_EQ(servo.data().rearms, static_cast<std::uint64_t>(kFaults));
  EXPECT_EQ(arm->counters().faults, static_cast<std::uint64_t>(kFaults));
  EXPECT_EQ(arm->state(), device::Lifecycle::kActive);
  EXPECT_GT(ticks_while_granted.load(), 0u) << "the servo ticked on while the supervisor held the device";
}

}  // namespace
}  // namespace lancet::app
