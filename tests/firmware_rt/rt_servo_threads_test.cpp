// The device handover between the servo thread and the supervisor thread, on two real threads, so
// that ThreadSanitizer (preset tsan, label threads) sees every access of it: the servo ticks the
// simulated arm flat out and faults it now and then, the viz side asks for re-arms, the
// supervisor thread re-arms. Every fault must be re-armed, and the servo must never touch the
// device while the supervisor holds it.
//
// The supervisor's re-arm is held open (GatedArm below) until the servo has ticked kTicksHeld
// times with the device granted away, so the servo ticking on without the device is seen every
// time, whatever the two threads' speeds.

#include <gtest/gtest.h>

#include <atomic>
#include <functional>
#include <memory>
#include <thread>

#include "app/rt_servo.hpp"
#include "arm/arm_config.hpp"
#include "device/sim_arm.hpp"
#include "lancet/shared_model/validate.hpp"
#include "wait.hpp"

namespace lancet::app {
namespace {

// The simulated arm behind a device whose re-arm (the supervisor's side, not real-time) waits,
// before it re-arms the arm, until `progress()` has grown by `hold` since the re-arm began (or
// `abandon()` says the other side gave up), and which counts any read or write that arrives
// meanwhile (the servo must keep off a device it has granted away).
class GatedArm final : public device::Device {
 public:
  GatedArm(device::SimArm& arm, std::function<std::uint64_t()> progress, std::uint64_t hold, std::function<bool()> abandon)
      : Device("gated " + arm.name()), arm_(arm), progress_(std::move(progress)), hold_(hold), abandon_(std::move(abandon)) {}
  [[nodiscard]] int joint_count() const noexcept override { return arm_.joint_count(); }
  void steer_hand(Vec3 target) noexcept override { arm_.steer_hand(target); }
  [[nodiscard]] std::uint64_t rearms_held() const noexcept { return held_.load(); }
  [[nodiscard]] std::uint64_t touched_while_rearming() const noexcept { return touched_.load(); }
  [[nodiscard]] std::uint64_t releases_missed() const noexcept { return releases_missed_.load(); }

 protected:
  Result<void> on_configure() override { return arm_.configure(); }
  Result<void> on_activate() override { return arm_.activate(); }
  Result<void> on_deactivate() override { return arm_.deactivate(); }
  Result<void> on_rearm() override {
    rearming_.store(true);
    const std::uint64_t from = progress_();
    if (test::eventually([&] { return progress_() >= from + hold_ || abandon_(); })) {
      if (progress_() >= from + hold_) held_.fetch_add(1);
    } else {
      releases_missed_.fetch_add(1);
    }
    rearming_.store(false);
    return arm_.rearm();
  }
  // The arm's own fault is this device's fault (its kFault means "already faulted" to a caller).
  device::IoStatus on_read(device::JointState& out) noexcept override {
    if (rearming_.load()) touched_.fetch_add(1);
    return own(arm_.read(out));
  }
  device::IoStatus on_write(const device::JointCommand& cmd) noexcept override {
    if (rearming_.load()) touched_.fetch_add(1);
    return own(arm_.write(cmd));
  }
  static device::IoStatus own(device::IoStatus s) noexcept {
    return s == device::IoStatus::kFault ? device::IoStatus::kDeviceFault : s;
  }

 private:
  device::SimArm& arm_;
  std::function<std::uint64_t()> progress_;
  std::uint64_t hold_;
  std::function<bool()> abandon_;
  std::atomic<bool> rearming_{false};
  std::atomic<std::uint64_t> held_{0}, touched_{0}, releases_missed_{0};
};

TEST(RtServoThreads, ReArmHandshakeBetweenTheServoAndTheSupervisorThreads) {
  auto cfg = arm::load_arm_config(std::string(LANCET_SOURCE_DIR) + "/hw_configs/sim_3dof.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  const arm::ArmConfig config = std::move(cfg).value();
  const arm::Kinematics kin = arm::make_kinematics(config).value();
  auto arm = std::move(device::SimArm::create(config).value());
  arm->set_fixed_dt(1e-3);
  // Each re-arm holds the device until the servo has ticked kTicksHeld times while it was granted
  // away (or the servo thread has given up: a hang, reported below).
  constexpr std::uint64_t kTicksHeld = 5;
  std::atomic<bool> done{false};
  std::atomic<std::uint64_t> ticks_while_granted{0};
  GatedArm gated(
      *arm, [&] { return ticks_while_granted.load(); }, kTicksHeld, [&] { return done.load(); });
  ASSERT_TRUE(gated.configure().ok());
  ASSERT_TRUE(gated.activate().ok());
  // The gated arm is the right hand's; the left hand's built-in stylus ticks beside it.
  RtModel model;
  model.hands = 2;
  servo::ServoModel& right = model.hand[0].servo;
  right.kinematics = kin;
  right.device_origin = 0.5 * (config.safety.workspace_min + config.safety.workspace_max);
  for (std::size_t j = 0; j < config.safety.max_joint_torque.size(); ++j) right.max_joint_torque[j] = config.safety.max_joint_torque[j];
  auto shared = std::make_unique<SharedState>();
  std::int64_t t = 1'000'000'000;
  RtServo servo(model, *shared, t, &gated);

  constexpr int kFaults = 20;
  std::atomic<int> faults_injected{0};
  std::thread servo_thread([&] {
    rt::Watchdog watchdog;
    rt::LoopLive live;
    std::uint64_t n = 0, seq = 0;
    int quiet_ticks = 0;
    while (faults_injected.load() < kFaults || servo.data().rearms < static_cast<std::uint64_t>(kFaults)) {
      if (n > 2'000'000) break;  // a hang would fail the expectations below, not the test runner
      t += model.period_ns;
      shared->viz_heartbeat.beat(t, 1);
      // The device is the servo's only while the handover is idle: inject then, and only then.
      const bool idle = servo.hand(Hand::kRight).handover.load(std::memory_order_acquire) == static_cast<int>(Handover::kIdle);
      if (idle && ++quiet_ticks > 50 && gated.state() == device::Lifecycle::kActive && faults_injected.load() < kFaults) {
        arm->inject(device::IoStatus::kDeviceFault, 1);
        faults_injected.fetch_add(1);
        quiet_ticks = 0;
      }
      // The viz's W key, pressed while faulted.
      if (idle && gated.state() == device::Lifecycle::kFault && n % 20 == 0) {
        Command c{};
        c.kind = CommandKind::kRearm;
        c.seq = ++seq;
        c.t_ns = t;
        wire::seal(c);
        (void)shared->commands.try_push(c);
      }
      servo.tick(rt::TickContext{t, t, ++n, watchdog, live});
      ToolSample s{}, popped{};
      bool sampled = false;
      std::uint64_t left_samples = 0;
      while (shared->samples.try_pop(popped)) {
        if (popped.hand == Hand::kRight) {
          s = popped;
          sampled = true;
        } else {
          ++left_samples;
        }
      }
      EXPECT_EQ(left_samples, 1u) << "the left hand ticks on, whatever the right arm does";
      if (servo.hand(Hand::kRight).handover.load(std::memory_order_acquire) == static_cast<int>(Handover::kGranted)) {
        ticks_while_granted.fetch_add(1);
        // The servo must not have touched the device this tick: it reports kFault without a read
        // or a write, says so in its sample, and commands no force.
        EXPECT_EQ(servo.hand(Hand::kRight).last_read, device::IoStatus::kFault);
        EXPECT_EQ(servo.hand(Hand::kRight).last_write, device::IoStatus::kFault);
        EXPECT_TRUE(sampled) << "the servo ticks on while the device is held";
        EXPECT_NE(s.inputs & input::kDeviceHeld, 0u);
        EXPECT_EQ(s.force, Vec3{});
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
  EXPECT_EQ(gated.state(), device::Lifecycle::kActive);
  EXPECT_EQ(gated.releases_missed(), 0u) << "a re-arm waited in vain for the servo to tick on while it held the device";
  EXPECT_EQ(gated.touched_while_rearming(), 0u) << "the servo read or wrote the device during the supervisor's re-arm";
  EXPECT_EQ(gated.rearms_held(), static_cast<std::uint64_t>(kFaults)) << "every re-arm held the device while the servo ticked";
  EXPECT_GE(ticks_while_granted.load(), kFaults * kTicksHeld) << "the servo ticked on while the supervisor held the device";
}

}  // namespace
}  // namespace lancet::app
