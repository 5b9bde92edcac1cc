// The servo driving an arm from hw_configs through the Device interface: encoders → kinematics →
// haptics → Jᵀ F within the joint limits → the device; device errors render zero force, a fault
// holds it until a re-arm command, which a supervisor performs off the servo thread.

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <memory>

#include "app/rt_servo.hpp"
#include "arm/arm_config.hpp"
#include "app/device_factory.hpp"
#include "app/supervisor.hpp"
#include "device/sim_arm.hpp"
#include "lancet/shared_model/validate.hpp"
#include "malloc_guard.hpp"

namespace lancet::app {
namespace {

struct ArmRig {
  arm::ArmConfig config;
  std::optional<arm::Kinematics> kin;
  std::unique_ptr<device::SimArm> arm;
  RtModel model;
  std::unique_ptr<SharedState> shared = std::make_unique<SharedState>();
  std::unique_ptr<RtServo> servo;
  std::unique_ptr<TissuePatch> patch = std::make_unique<TissuePatch>();
  std::int64_t t = 1'000'000'000;
  rt::Watchdog watchdog;
  rt::LoopLive live;
  std::uint64_t n = 0;

  ArmRig() {
    auto c = arm::load_arm_config(std::string(LANCET_SOURCE_DIR) + "/hw_configs/sim_3dof.toml");
    EXPECT_TRUE(c.ok()) << (c.ok() ? "" : c.error().message);
    config = std::move(c).value();
    kin = arm::make_kinematics(config).value();
    arm = std::move(device::SimArm::create(config).value());
    arm->set_fixed_dt(1e-3);
    EXPECT_TRUE(arm->configure().ok());
    EXPECT_TRUE(arm->activate().ok());
    model.servo.kinematics = *kin;
    model.servo.device_origin = 0.5 * (config.safety.workspace_min + config.safety.workspace_max);
    for (std::size_t j = 0; j < config.safety.max_joint_torque.size(); ++j) model.servo.max_joint_torque[j] = config.safety.max_joint_torque[j];
    servo = std::make_unique<RtServo>(model, *shared, t, arm.get());
    // A flat tissue at the workspace centre's height (z = 0 in the tissue frame).
    const float s = 0.1f;
    patch->n_triangles = 2;
    patch->triangles[0] = {{{-s, -s, 0}, {s, -s, 0}, {s, s, 0}}, 1, 0, 0};
    patch->triangles[1] = {{{-s, -s, 0}, {s, s, 0}, {-s, s, 0}}, 1, 0, 1};
  }
  void tick() {
    t += model.servo.period_ns;
    shared->viz_heartbeat.beat(t, 1);
    if (n % 16 == 0) {
      patch->t_ns = t;
      shared->patch.publish(*patch);
    }
    servo->tick(rt::TickContext{t, t, ++n, watchdog, live});
    ToolSample s;
    while (shared->samples.try_pop(s)) last = s;
  }
  /// The viz's W key: a sealed re-arm command.
  void push_rearm() {
    Command c{};
    c.kind = CommandKind::kRearm;
    c.seq = ++command_seq;
    c.t_ns = t + static_cast<std::int64_t>(command_seq);
    wire::seal(c);
    ASSERT_TRUE(shared->commands.try_push(c));
  }
  std::uint64_t command_seq = 0;
  ToolSample last{};
};

TEST(RtServoArm, TheArmPressesIntoThePatchAndRendersJacobianTransposeTorques) {
  ArmRig rig;
  for (int i = 0; i < 3000; ++i) rig.tick();
  const RtData& d = rig.servo->data();
  EXPECT_GT(d.servo.contact_ticks, 300u) << "the scripted hand pushes the stylus into the tissue";
  EXPECT_GT(d.servo.force.z, 0.3);
  EXPECT_EQ(d.last_read, device::IoStatus::kOk);
  // τ = Jᵀ F, within each joint's limit.
  const auto tau = arm::joint_torques(d.servo.jacobian, d.servo.force);
  for (int j = 0; j < 3; ++j) {
    const double lim = rig.model.servo.max_joint_torque[static_cast<std::size_t>(j)];
    EXPECT_NEAR(d.out.command.tau[static_cast<std::size_t>(j)], std::clamp(tau[static_cast<std::size_t>(j)], -lim, lim), 1e-12);
  }
  // The sample carries the joints; the tool is the forward kinematics of the encoders.
  EXPECT_EQ(rig.last.n_joints, 3u);
  const Vec3 fk = rig.kin->position(std::span<const double>(d.joints.q.data(), 3)) - rig.model.servo.device_origin;
  EXPECT_NEAR(norm(rig.last.tool.position - fk), 0, 1e-12);
  // The motors' rendered force pushes back out of the tissue, as commanded.
  EXPECT_GT(rig.arm->physics().rendered_force().z, 0.0);
  EXPECT_LE(norm(d.servo.force), rig.model.servo.haptic.safety.max_force + 1e-9);
}

TEST(RtServoArm, TickWithTheArmAllocatesNothing) {
  ArmRig rig;
  for (int i = 0; i < 100; ++i) rig.tick();
  lancet::test::MallocGuard guard;
  for (int i = 0; i < 5000; ++i) rig.tick();
  EXPECT_EQ(guard.count(), 0u);
}

TEST(RtServoArm, DeviceErrorsZeroTheForceAndAFaultWaitsForARearm) {
  ArmRig rig;
  for (int i = 0; i < 3000; ++i) rig.tick();
  ASSERT_GT(norm(rig.servo->data().servo.force), 0.3);
  // Two lost replies: zero force on those ticks, no fault (the policy trips at three in a row).
  rig.arm->inject(device::IoStatus::kTimeout, 2);
  rig.tick();
  EXPECT_EQ(rig.servo->data().servo.force, Vec3{});
  EXPECT_NE(rig.last.events & event::kFault, 0u);
  rig.tick();
  rig.tick();
  EXPECT_EQ(rig.arm->state(), device::Lifecycle::kActive);
  EXPECT_GT(norm(rig.servo->data().servo.force), 0.3) << "back to normal after the glitch";
  // Five in a row: the device faults and the force stays zero even after the bus recovers.
  rig.arm->inject(device::IoStatus::kTimeout, 5);
  for (int i = 0; i < 200; ++i) {
    rig.tick();
    ASSERT_EQ(rig.servo->data().servo.force, Vec3{}) << "tick " << i;
    ASSERT_EQ(rig.servo->data().out.command.tau[0], 0.0);
  }
  EXPECT_EQ(rig.arm->state(), device::Lifecycle::kFault);
  EXPECT_EQ(rig.arm->fault_cause(), device::IoStatus::kTimeout);
  for (int i = 0; i < 5; ++i) {
    EXPECT_FALSE(rig.servo->supervise()) << "nobody asked for a re-arm";
    rig.tick();
  }
  EXPECT_EQ(rig.servo->data().handover.load(), static_cast<int>(Handover::kIdle));
  // The trainee presses W: the servo asks, the supervisor requests the device, the servo grants
  // it at its next tick, the supervisor re-arms and hands it back, forces come back.
  rig.push_rearm();
  rig.tick();
  EXPECT_FALSE(rig.servo->supervise()) << "first the request";
  EXPECT_EQ(rig.servo->data().handover.load(), static_cast<int>(Handover::kRequested));
  rig.tick();
  EXPECT_EQ(rig.servo->data().handover.load(), static_cast<int>(Handover::kGranted));
  EXPECT_EQ(rig.servo->data().servo.force, Vec3{}) << "the servo keeps off the device it granted";
  EXPECT_TRUE(rig.servo->supervise()) << "then the re-arm";
  EXPECT_EQ(rig.arm->state(), device::Lifecycle::kActive);
  rig.tick();
  EXPECT_EQ(rig.servo->data().handover.load(), static_cast<int>(Handover::kIdle));
  EXPECT_EQ(rig.servo->data().rearms, 1u);
  for (int i = 0; i < 300; ++i) rig.tick();
  EXPECT_GT(norm(rig.servo->data().servo.force), 0.3);
  EXPECT_EQ(rig.arm->counters().faults, 1u);
}

TEST(RtServoArm, ForcesAndTorquesStayFiniteAndBoundedForWildTargets) {
  ArmRig rig;
  std::uint64_t seq = 0;
  for (int i = 0; i < 4000; ++i) {
    if (i % 50 == 0) {
      StylusTarget tg{};
      tg.seq = ++seq;
      tg.t_ns = rig.t;
      tg.active = 1;
      const double a = i * 0.37;
      tg.target.position = {0.08 * std::sin(a), 0.08 * std::cos(1.3 * a), -0.05 + 0.1 * std::sin(0.7 * a)};
      rig.shared->stylus_target.write(tg);
    }
    rig.tick();
    const RtData& d = rig.servo->data();
    ASSERT_TRUE(is_finite(d.servo.force));
    ASSERT_LE(norm(d.servo.force), rig.model.servo.haptic.safety.max_force + 1e-9);
    for (int j = 0; j < 3; ++j) {
      ASSERT_TRUE(std::isfinite(d.out.command.tau[static_cast<std::size_t>(j)]));
      ASSERT_LE(std::abs(d.out.command.tau[static_cast<std::size_t>(j)]), rig.model.servo.max_joint_torque[static_cast<std::size_t>(j)] + 1e-12);
    }
  }
}

TEST(RtServoArm, AGlitchingEncoderIsCountedZeroesTheForceAndRepeatedGlitchesFault) {
  ArmRig rig;
  rig.arm->set_plausibility(plausibility_of(rig.config));
  for (int i = 0; i < 3000; ++i) rig.tick();
  ASSERT_GT(norm(rig.servo->data().servo.force), 0.3);
  // One reading a motor revolution off on joint 0: impossible in a millisecond.
  rig.arm->inject_encoder_offset(0, rig.config.joints[0].counts_per_rev, 1);
  rig.tick();
  EXPECT_EQ(rig.servo->data().last_read, device::IoStatus::kImplausible);
  EXPECT_EQ(rig.servo->data().servo.force, Vec3{});
  EXPECT_EQ(rig.arm->counters().glitches, 1u);
  for (int i = 0; i < 50; ++i) rig.tick();
  EXPECT_EQ(rig.arm->state(), device::Lifecycle::kActive) << "one glitch is not a fault";
  EXPECT_GT(norm(rig.servo->data().servo.force), 0.3);
  // Glitch after glitch: a fault, with the joint named. The fault path allocates nothing either.
  rig.arm->inject_encoder_offset(1, 4 * rig.config.joints[1].counts_per_rev, 3);
  {
    lancet::test::MallocGuard guard;
    for (int i = 0; i < 5; ++i) rig.tick();
    EXPECT_EQ(guard.count(), 0u);
  }
  EXPECT_EQ(rig.arm->state(), device::Lifecycle::kFault);
  EXPECT_EQ(rig.arm->fault_cause(), device::IoStatus::kImplausible);
  EXPECT_EQ(rig.arm->fault_detail().node, 1);
  RtStatus st{};
  ASSERT_EQ(rig.servo->read_status(st), ReadStatus::kOk);
  EXPECT_EQ(st.bus.glitches, 4u);
  EXPECT_NE(std::string(st.fault_text).find("joint 1 encoder jumped"), std::string::npos) << st.fault_text;
}

TEST(RtSupervisor, AnnouncesAFaultWithItsCauseAndTheReArmAndNoticesAStall) {
  ArmRig rig;
  for (int i = 0; i < 200; ++i) rig.tick();
  SupervisorParams p;
  p.shm_name = "/lancet-test";
  p.arm_name = "bench arm";
  p.stall_timeout_ns = 500'000'000;
  RtSupervisor sup(*rig.servo, p, rig.t);
  std::vector<std::string> lines = sup.poll(rig.t);
  EXPECT_TRUE(lines.empty());
  rig.arm->inject(device::IoStatus::kDeviceFault, 1);
  rig.tick();
  lines = sup.poll(rig.t);
  ASSERT_EQ(lines.size(), 1u);
  EXPECT_NE(lines[0].find("FAULT on bench arm: fault (device fault)"), std::string::npos) << lines[0];
  EXPECT_NE(lines[0].find("lancetctl rearm --rt /lancet-test"), std::string::npos) << lines[0];
  // The re-arm, through the supervisor's own polling.
  rig.push_rearm();
  std::string all;
  for (int i = 0; i < 6; ++i) {
    rig.tick();
    for (const auto& l : sup.poll(rig.t)) all += l + "\n";
  }
  EXPECT_EQ(rig.arm->state(), device::Lifecycle::kActive);
  EXPECT_NE(all.find("bench arm re-armed: active"), std::string::npos) << all;
  EXPECT_FALSE(sup.stalled());
  // No tick for longer than the stall timeout.
  EXPECT_TRUE(sup.poll(rig.t + 400'000'000).empty());
  lines = sup.poll(rig.t + 600'000'000);
  ASSERT_EQ(lines.size(), 1u);
  EXPECT_NE(lines[0].find("SERVO STALLED"), std::string::npos);
  EXPECT_TRUE(sup.stalled());
}

TEST(RtSupervisor, DescribesAFaultByTheBackendsWordsAndByNumbersOnlyWithoutThem) {
  RtStatus st{};
  st.has_arm = 1;
  st.device_state = device::Lifecycle::kFault;
  st.device_fault_cause = device::IoStatus::kDeviceFault;
  st.fault_node = 1;
  st.fault_code = 0x2310;
  std::strcpy(st.fault_text, "node 1: EMCY 0x2310 continuous over-current");
  EXPECT_EQ(describe_arm(st), "fault (device fault): node 1: EMCY 0x2310 continuous over-current");
  st.fault_text[0] = '\0';
  EXPECT_EQ(describe_arm(st), "fault (device fault) [node 1] [code 0x2310]");
  st.link_lost = 1;
  EXPECT_EQ(describe_arm(st), "fault (device fault) [node 1] [code 0x2310]; bus link lost (reconnecting)");
  st.has_arm = 0;
  EXPECT_EQ(describe_arm(st), "built-in simulated stylus");
}

}  // namespace
}  // namespace lancet::app
