// The servo driving an arm from hw_configs through the Device interface: encoders → kinematics →
// haptics → Jᵀ F within the joint limits → the device; device errors render zero force, a fault
// holds it until a re-arm command, which a supervisor performs off the servo thread.

#include <gtest/gtest.h>

#include <array>
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
  std::array<std::unique_ptr<device::SimArm>, kHandCount> arms;  // by Hand
  device::SimArm* arm = nullptr;                                  // the right hand's
  RtModel model;
  std::unique_ptr<SharedState> shared = std::make_unique<SharedState>();
  std::unique_ptr<RtServo> servo;
  std::array<std::unique_ptr<TissuePatch>, kHandCount> patch{std::make_unique<TissuePatch>(), std::make_unique<TissuePatch>()};
  std::int64_t t = 1'000'000'000;
  rt::Watchdog watchdog;
  rt::LoopLive live;
  std::uint64_t n = 0;

  /// `hands` simulated arms of hw_configs/sim_3dof.toml, one per hand.
  explicit ArmRig(std::size_t hands = 1) {
    auto c = arm::load_arm_config(std::string(LANCET_SOURCE_DIR) + "/hw_configs/sim_3dof.toml");
    EXPECT_TRUE(c.ok()) << (c.ok() ? "" : c.error().message);
    config = std::move(c).value();
    kin = arm::make_kinematics(config).value();
    model.hands = hands;
    std::array<device::Device*, kHandCount> devices{};
    for (std::size_t h = 0; h < hands; ++h) {
      arms[h] = std::move(device::SimArm::create(config).value());
      arms[h]->set_fixed_dt(1e-3);
      EXPECT_TRUE(arms[h]->configure().ok());
      EXPECT_TRUE(arms[h]->activate().ok());
      servo::ServoModel& m = model.hand[h].servo;
      m.kinematics = *kin;
      m.device_origin = 0.5 * (config.safety.workspace_min + config.safety.workspace_max);
      for (std::size_t j = 0; j < config.safety.max_joint_torque.size(); ++j) m.max_joint_torque[j] = config.safety.max_joint_torque[j];
      devices[h] = arms[h].get();
    }
    arm = arms[0].get();
    servo = std::make_unique<RtServo>(model, *shared, t, devices);
    // A flat tissue at the workspace centre's height (z = 0 in the tissue frame), for each hand.
    const float s = 0.1f;
    for (std::size_t h = 0; h < kHandCount; ++h) {
      patch[h]->n_triangles = 2;
      patch[h]->triangles[0] = {{{-s, -s, 0}, {s, -s, 0}, {s, s, 0}}, 1, 0, 0};
      patch[h]->triangles[1] = {{{-s, -s, 0}, {s, s, 0}, {-s, s, 0}}, 1, 0, 1};
      patch[h]->hand = static_cast<Hand>(h);
    }
  }
  [[nodiscard]] const HandData& hand(Hand h = Hand::kRight) const { return servo->hand(h); }
  /// `h`'s stylus pulled toward p (the viz's target).
  void hold_stylus(Vec3 p, Hand h) {
    StylusTarget tg{};
    tg.seq = n + 1;
    tg.t_ns = t;
    tg.active = 1;
    tg.hand = h;
    tg.target.position = p;
    shared->stylus_target[hand_index(h)].write(tg);
  }
  void tick() {
    t += model.period_ns;
    shared->viz_heartbeat.beat(t, 1);
    if (n % 16 == 0) {
      for (std::size_t h = 0; h < model.hands; ++h) {
        patch[h]->t_ns = t;
        shared->patch[h].publish(*patch[h]);
      }
    }
    servo->tick(rt::TickContext{t, t, ++n, watchdog, live});
    ToolSample s;
    while (shared->samples.try_pop(s)) last[hand_index(s.hand)] = s;
  }
  /// The viz's W key: a sealed re-arm command for hand h.
  void push_rearm(Hand h = Hand::kRight) {
    Command c{};
    c.kind = CommandKind::kRearm;
    c.hand = h;
    c.seq = ++command_seq;
    c.t_ns = t + static_cast<std::int64_t>(command_seq);
    wire::seal(c);
    ASSERT_TRUE(shared->commands.try_push(c));
  }
  std::uint64_t command_seq = 0;
  std::array<ToolSample, kHandCount> last{};  ///< by Hand
};

TEST(RtServoArm, TheArmPressesIntoThePatchAndRendersJacobianTransposeTorques) {
  ArmRig rig;
  for (int i = 0; i < 3000; ++i) rig.tick();
  const HandData& d = rig.hand();
  EXPECT_GT(d.servo.contact_ticks, 300u) << "the scripted hand pushes the stylus into the tissue";
  EXPECT_GT(d.servo.force.z, 0.3);
  EXPECT_EQ(d.last_read, device::IoStatus::kOk);
  // τ = Jᵀ F, within each joint's limit.
  const auto tau = arm::joint_torques(d.servo.jacobian, d.servo.force);
  for (int j = 0; j < 3; ++j) {
    const double lim = rig.model.hand[0].servo.max_joint_torque[static_cast<std::size_t>(j)];
    EXPECT_NEAR(d.out.command.tau[static_cast<std::size_t>(j)], std::clamp(tau[static_cast<std::size_t>(j)], -lim, lim), 1e-12);
  }
  // The sample carries the joints; the tool is the forward kinematics of the encoders.
  EXPECT_EQ(rig.last[0].n_joints, 3u);
  const Vec3 fk = rig.kin->position(std::span<const double>(d.joints.q.data(), 3)) - rig.model.hand[0].servo.device_origin;
  EXPECT_NEAR(norm(rig.last[0].tool.position - fk), 0, 1e-12);
  // The motors' rendered force pushes back out of the tissue, as commanded.
  EXPECT_GT(rig.arm->physics().rendered_force().z, 0.0);
  EXPECT_LE(norm(d.servo.force), rig.model.hand[0].servo.haptic.safety.max_force + 1e-9);
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
  ASSERT_GT(norm(rig.hand().servo.force), 0.3);
  // Two lost replies: zero force on those ticks, no fault (the policy trips at three in a row).
  rig.arm->inject(device::IoStatus::kTimeout, 2);
  rig.tick();
  EXPECT_EQ(rig.hand().servo.force, Vec3{});
  EXPECT_NE(rig.last[0].events & event::kFault, 0u);
  rig.tick();
  rig.tick();
  EXPECT_EQ(rig.arm->state(), device::Lifecycle::kActive);
  EXPECT_GT(norm(rig.hand().servo.force), 0.3) << "back to normal after the glitch";
  // Five in a row: the device faults and the force stays zero even after the bus recovers.
  rig.arm->inject(device::IoStatus::kTimeout, 5);
  for (int i = 0; i < 200; ++i) {
    rig.tick();
    ASSERT_EQ(rig.hand().servo.force, Vec3{}) << "tick " << i;
    ASSERT_EQ(rig.hand().out.command.tau[0], 0.0);
  }
  EXPECT_EQ(rig.arm->state(), device::Lifecycle::kFault);
  EXPECT_EQ(rig.arm->fault_cause(), device::IoStatus::kTimeout);
  for (int i = 0; i < 5; ++i) {
    EXPECT_FALSE(rig.servo->supervise()) << "nobody asked for a re-arm";
    rig.tick();
  }
  EXPECT_EQ(rig.hand().handover.load(), static_cast<int>(Handover::kIdle));
  // The trainee presses W: the servo asks, the supervisor requests the device, the servo grants
  // it at its next tick, the supervisor re-arms and hands it back, forces come back.
  rig.push_rearm();
  rig.tick();
  EXPECT_FALSE(rig.servo->supervise()) << "first the request";
  EXPECT_EQ(rig.hand().handover.load(), static_cast<int>(Handover::kRequested));
  rig.tick();
  EXPECT_EQ(rig.hand().handover.load(), static_cast<int>(Handover::kGranted));
  EXPECT_EQ(rig.hand().servo.force, Vec3{}) << "the servo keeps off the device it granted";
  EXPECT_TRUE(rig.servo->supervise()) << "then the re-arm";
  EXPECT_EQ(rig.arm->state(), device::Lifecycle::kActive);
  rig.tick();
  EXPECT_EQ(rig.hand().handover.load(), static_cast<int>(Handover::kIdle));
  EXPECT_EQ(rig.servo->data().rearms, 1u);
  for (int i = 0; i < 300; ++i) rig.tick();
  EXPECT_GT(norm(rig.hand().servo.force), 0.3);
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
      rig.shared->stylus_target[0].write(tg);
    }
    rig.tick();
    const HandData& d = rig.hand();
    ASSERT_TRUE(is_finite(d.servo.force));
    ASSERT_LE(norm(d.servo.force), rig.model.hand[0].servo.haptic.safety.max_force + 1e-9);
    for (int j = 0; j < 3; ++j) {
      ASSERT_TRUE(std::isfinite(d.out.command.tau[static_cast<std::size_t>(j)]));
      ASSERT_LE(std::abs(d.out.command.tau[static_cast<std::size_t>(j)]), rig.model.hand[0].servo.max_joint_torque[static_cast<std::size_t>(j)] + 1e-12);
    }
  }
}

TEST(RtServoArm, AGlitchingEncoderIsCountedZeroesTheForceAndRepeatedGlitchesFault) {
  ArmRig rig;
  rig.arm->set_plausibility(plausibility_of(rig.config));
  for (int i = 0; i < 3000; ++i) rig.tick();
  ASSERT_GT(norm(rig.hand().servo.force), 0.3);
  // One reading a motor revolution off on joint 0: impossible in a millisecond.
  rig.arm->inject_encoder_offset(0, rig.config.joints[0].counts_per_rev, 1);
  rig.tick();
  EXPECT_EQ(rig.hand().last_read, device::IoStatus::kImplausible);
  EXPECT_EQ(rig.hand().servo.force, Vec3{});
  EXPECT_EQ(rig.arm->counters().glitches, 1u);
  for (int i = 0; i < 50; ++i) rig.tick();
  EXPECT_EQ(rig.arm->state(), device::Lifecycle::kActive) << "one glitch is not a fault";
  EXPECT_GT(norm(rig.hand().servo.force), 0.3);
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
  EXPECT_EQ(st.hand[0].bus.glitches, 4u);
  EXPECT_NE(std::string(st.hand[0].fault_text).find("joint 1 encoder jumped"), std::string::npos) << st.hand[0].fault_text;
}

TEST(RtSupervisor, AnnouncesAFaultWithItsCauseAndTheReArmAndNoticesAStall) {
  ArmRig rig;
  for (int i = 0; i < 200; ++i) rig.tick();
  SupervisorParams p;
  p.shm_name = "/lancet-test";
  p.arm_name[0] = "bench arm";
  p.stall_timeout_ns = 500'000'000;
  RtSupervisor sup(*rig.servo, p, rig.t);
  std::vector<std::string> lines = sup.poll(rig.t);
  EXPECT_TRUE(lines.empty());
  rig.arm->inject(device::IoStatus::kDeviceFault, 1);
  rig.tick();
  lines = sup.poll(rig.t);
  ASSERT_EQ(lines.size(), 1u);
  EXPECT_EQ(lines[0].rfind("right arm: FAULT on bench arm: fault (device fault)", 0), 0u) << lines[0];
  EXPECT_NE(lines[0].find("lancetctl rearm --rt /lancet-test --hand right"), std::string::npos) << lines[0];
  // The re-arm, through the supervisor's own polling.
  rig.push_rearm();
  std::string all;
  for (int i = 0; i < 6; ++i) {
    rig.tick();
    for (const auto& l : sup.poll(rig.t)) all += l + "\n";
  }
  EXPECT_EQ(rig.arm->state(), device::Lifecycle::kActive);
  EXPECT_NE(all.find("right arm: bench arm re-armed: active"), std::string::npos) << all;
  EXPECT_FALSE(sup.stalled());
  // No tick for longer than the stall timeout.
  EXPECT_TRUE(sup.poll(rig.t + 400'000'000).empty());
  lines = sup.poll(rig.t + 600'000'000);
  ASSERT_EQ(lines.size(), 1u);
  EXPECT_NE(lines[0].find("SERVO STALLED"), std::string::npos);
  EXPECT_TRUE(sup.stalled());
}

TEST(RtSupervisor, DescribesAFaultByTheBackendsWordsAndByNumbersOnlyWithoutThem) {
  HandStatus st{};
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

// ---- Two arms in one loop: a fault is the faulted arm's hand's alone; a re-arm is for the hand
// it names.

TEST(RtServoTwoArms, AFaultOnTheLeftArmZeroesTheLeftHandOnlyAndAReArmForItReArmsOnlyIt) {
  ArmRig rig(2);
  const auto press = [&rig] {
    rig.hold_stylus({0.0, 0.0, -0.004}, Hand::kLeft);  // the right hand follows its script
    rig.tick();
  };
  for (int i = 0; i < 3000; ++i) press();
  device::SimArm& right = *rig.arms[0];
  device::SimArm& left = *rig.arms[1];
  ASSERT_GT(norm(rig.hand(Hand::kRight).servo.force), 0.3);
  ASSERT_GT(norm(rig.hand(Hand::kLeft).servo.force), 0.3);
  EXPECT_EQ(rig.last[0].hand, Hand::kRight);
  EXPECT_EQ(rig.last[1].hand, Hand::kLeft);
  // The left arm's bus goes quiet: it faults, its hand's force is zero, the right hand feels on.
  left.inject(device::IoStatus::kTimeout, 5);
  for (int i = 0; i < 200; ++i) {
    press();
    ASSERT_EQ(rig.hand(Hand::kLeft).servo.force, Vec3{}) << "tick " << i;
    ASSERT_EQ(rig.hand(Hand::kLeft).out.command.tau[0], 0.0);
    ASSERT_GT(norm(rig.hand(Hand::kRight).servo.force), 0.3) << "tick " << i;
  }
  EXPECT_EQ(left.state(), device::Lifecycle::kFault);
  EXPECT_EQ(right.state(), device::Lifecycle::kActive);
  EXPECT_FALSE(rig.watchdog.tripped()) << "an arm's fault is not the loop's";
  RtStatus st{};
  ASSERT_EQ(rig.servo->read_status(st), ReadStatus::kOk);
  EXPECT_EQ(wire::check(st), nullptr);
  EXPECT_EQ(st.hand[1].device_state, device::Lifecycle::kFault);
  EXPECT_EQ(st.hand[1].device_fault_cause, device::IoStatus::kTimeout);
  EXPECT_GT(st.hand[1].device_errors, 0u);
  EXPECT_EQ(st.hand[0].device_state, device::Lifecycle::kActive);
  EXPECT_EQ(st.hand[0].device_errors, 0u);

  // The supervisor names the hand.
  SupervisorParams p;
  p.shm_name = "/lancet-test";
  p.arm_name = {"bench arm R", "bench arm L"};
  RtSupervisor sup(*rig.servo, p, rig.t);
  std::vector<std::string> lines = sup.poll(rig.t);
  ASSERT_EQ(lines.size(), 1u);
  EXPECT_EQ(lines[0].rfind("left arm: FAULT on bench arm L: fault (timeout)", 0), 0u) << lines[0];

  // Now the right arm faults too; a re-arm for the left hand re-arms the left arm only.
  right.inject(device::IoStatus::kDeviceFault, 1);
  press();
  ASSERT_EQ(right.state(), device::Lifecycle::kFault);
  std::string all;
  for (const auto& l : sup.poll(rig.t)) all += l + "\n";
  EXPECT_NE(all.find("right arm: FAULT on bench arm R: fault (device fault)"), std::string::npos) << all;
  rig.push_rearm(Hand::kLeft);
  all.clear();
  for (int i = 0; i < 10; ++i) {
    press();
    for (const auto& l : sup.poll(rig.t)) all += l + "\n";
  }
  EXPECT_EQ(left.state(), device::Lifecycle::kActive);
  EXPECT_EQ(right.state(), device::Lifecycle::kFault) << "the right arm was not asked for";
  EXPECT_NE(all.find("left arm: bench arm L re-armed: active"), std::string::npos) << all;
  EXPECT_EQ(all.find("right arm: bench arm R re-armed"), std::string::npos) << all;
  for (int i = 0; i < 300; ++i) press();
  EXPECT_GT(norm(rig.hand(Hand::kLeft).servo.force), 0.3) << "the left hand feels again";
  EXPECT_EQ(rig.hand(Hand::kRight).servo.force, Vec3{}) << "the right arm stays faulted until re-armed";
  EXPECT_EQ(rig.servo->data().rearms, 1u);
}

TEST(RtServoTwoArms, TickWithTwoArmsAllocatesNothingAndStaysBounded) {
  ArmRig rig(2);
  for (int i = 0; i < 100; ++i) rig.tick();
  lancet::test::MallocGuard guard;
  for (int i = 0; i < 5000; ++i) {
    rig.hold_stylus({0.02 * std::sin(i * 1e-3), 0.0, -0.004}, Hand::kLeft);
    rig.tick();
    for (std::size_t h = 0; h < kHandCount; ++h) {
      const HandData& d = rig.hand(static_cast<Hand>(h));
      ASSERT_TRUE(is_finite(d.servo.force));
      ASSERT_LE(norm(d.servo.force), rig.model.hand[h].servo.haptic.safety.max_force + 1e-9);
    }
  }
  EXPECT_EQ(guard.count(), 0u);
  EXPECT_GT(rig.hand(Hand::kLeft).servo.contact_ticks, 0u);
}

}  // namespace
}  // namespace lancet::app
