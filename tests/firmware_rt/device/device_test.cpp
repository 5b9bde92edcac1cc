// The Device lifecycle and fault policy (device/device.hpp), driven through the in-process SimArm,
// and the SimArm's own physics: the hand spring, rendered force, motor limits.

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <memory>
#include <numbers>
#include <span>
#include <string>

#include "arm/arm_config.hpp"
#include "arm/kinematics.hpp"
#include "device/device.hpp"
#include "device/sim_arm.hpp"

#ifndef LANCET_SOURCE_DIR
#define LANCET_SOURCE_DIR "."
#endif

namespace {

using namespace lancet;
using namespace lancet::device;

arm::ArmConfig sim_config() {
  auto c = arm::load_arm_config(std::string(LANCET_SOURCE_DIR) + "/hw_configs/sim_3dof.toml");
  EXPECT_TRUE(c.ok()) << (c.ok() ? "" : c.error().message);
  return c.value();
}

std::unique_ptr<SimArm> make_arm(FaultPolicy policy = {}) {
  auto a = SimArm::create(sim_config(), policy);
  EXPECT_TRUE(a.ok()) << (a.ok() ? "" : a.error().message);
  a.value()->set_fixed_dt(1e-3);
  return std::move(a).value();
}

std::unique_ptr<SimArm> active_arm(FaultPolicy policy = {}) {
  auto a = make_arm(policy);
  EXPECT_TRUE(a->configure().ok());
  EXPECT_TRUE(a->activate().ok());
  return a;
}

JointCommand torques(double t0, double t1, double t2) {
  JointCommand c;
  c.n = 3;
  c.tau[0] = t0;
  c.tau[1] = t1;
  c.tau[2] = t2;
  return c;
}

// ---------------------------------------------------------------------------------------------
// Lifecycle

TEST(DeviceLifecycle, StepsOutOfOrderAreRefusedWithTheStateNamed) {
  auto a = make_arm();
  JointState s;
  EXPECT_EQ(a->state(), Lifecycle::kUnconfigured);
  EXPECT_EQ(a->read(s), IoStatus::kNotActive);
  EXPECT_EQ(a->write(torques(0, 0, 0)), IoStatus::kNotActive);
  const Result<void> early = a->activate();
  ASSERT_FALSE(early.ok());
  EXPECT_NE(early.error().message.find("cannot activate from state unconfigured"), std::string::npos) << early.error().message;
  EXPECT_FALSE(a->deactivate().ok());
  EXPECT_FALSE(a->rearm().ok());

  ASSERT_TRUE(a->configure().ok());
  EXPECT_EQ(a->state(), Lifecycle::kInactive);
  EXPECT_FALSE(a->configure().ok());  // twice
  EXPECT_EQ(a->read(s), IoStatus::kOk);  // reading never moves the arm: allowed while inactive
  EXPECT_EQ(a->write(torques(0, 0, 0)), IoStatus::kNotActive);
  EXPECT_FALSE(a->deactivate().ok());
  EXPECT_FALSE(a->rearm().ok());

  ASSERT_TRUE(a->activate().ok());
  EXPECT_EQ(a->state(), Lifecycle::kActive);
  EXPECT_FALSE(a->activate().ok());  // twice
  const Result<void> not_faulted = a->rearm();
  ASSERT_FALSE(not_faulted.ok());
  EXPECT_NE(not_faulted.error().message.find("cannot rearm from state active"), std::string::npos);
  EXPECT_EQ(a->read(s), IoStatus::kOk);
  EXPECT_EQ(s.n, 3);
  EXPECT_GT(s.t_ns, 0);
  EXPECT_EQ(a->write(torques(0, 0, 0)), IoStatus::kOk);

  ASSERT_TRUE(a->deactivate().ok());
  EXPECT_EQ(a->state(), Lifecycle::kInactive);
  EXPECT_EQ(a->write(torques(0, 0, 0)), IoStatus::kNotActive);
  EXPECT_EQ(a->read(s), IoStatus::kOk);
  ASSERT_TRUE(a->activate().ok());  // and back again
  EXPECT_EQ(a->read(s), IoStatus::kOk);
  const IoCounters& c = a->counters();
  EXPECT_EQ(c.reads, 4u);  // reads and writes refused by the state machine are not counted
  EXPECT_EQ(c.writes, 1u);
  EXPECT_EQ(c.ok, 5u);
}

TEST(DeviceLifecycle, ErrorsWhileInactiveAreCountedButNeverTrip) {
  auto a = make_arm({.max_consecutive_errors = 2});
  ASSERT_TRUE(a->configure().ok());
  JointState s;
  a->inject(IoStatus::kDisconnected, 3);
  for (int i = 0; i < 3; ++i) EXPECT_EQ(a->read(s), IoStatus::kDisconnected);
  EXPECT_EQ(a->state(), Lifecycle::kInactive);
  EXPECT_EQ(a->counters().disconnects, 1u) << "one loss, read three times";
  EXPECT_EQ(a->counters().faults, 0u);
  EXPECT_EQ(a->read(s), IoStatus::kOk);
  ASSERT_TRUE(a->activate().ok());
  EXPECT_EQ(a->counters().consecutive_errors, 0u);
}

TEST(DeviceLifecycle, ReadGivesTheEncoderPositionsOfThePhysics) {
  auto a = active_arm();
  const double q[3] = {0.3, -0.2, 0.4};
  a->physics().reset(q);
  JointState s;
  ASSERT_EQ(a->read(s), IoStatus::kOk);
  const auto& cfg = a->physics().config();
  for (int j = 0; j < 3; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const double per_count = std::abs(arm::joint_position_from_counts(cfg.joints[uj], 1) - arm::joint_position_from_counts(cfg.joints[uj], 0));
    EXPECT_NEAR(s.q[uj], q[j], per_count) << "joint " << j;
    EXPECT_EQ(s.counts[uj], a->physics().encoder_counts(j));
  }
}

// ---------------------------------------------------------------------------------------------
// Fault policy

TEST(DeviceFaultPolicy, InjectedErrorsAreCountedByKind) {
  auto a = active_arm({.max_consecutive_errors = 3});
  JointState s;
  a->inject(IoStatus::kTimeout, 2);
  EXPECT_EQ(a->read(s), IoStatus::kTimeout);
  EXPECT_EQ(a->read(s), IoStatus::kTimeout);
  EXPECT_EQ(a->counters().consecutive_errors, 2u);
  EXPECT_EQ(a->read(s), IoStatus::kOk);  // an ok resets the run
  EXPECT_EQ(a->counters().consecutive_errors, 0u);
  a->inject(IoStatus::kCrcError, 1);
  EXPECT_EQ(a->read(s), IoStatus::kCrcError);
  a->inject(IoStatus::kProtocolError, 1);
  EXPECT_EQ(a->read(s), IoStatus::kProtocolError);
  EXPECT_EQ(a->read(s), IoStatus::kOk);
  const IoCounters& c = a->counters();
  EXPECT_EQ(c.timeouts, 2u);
  EXPECT_EQ(c.crc_errors, 1u);
  EXPECT_EQ(c.protocol_errors, 1u);
  EXPECT_EQ(c.disconnects, 0u);
  EXPECT_EQ(c.faults, 0u);
  EXPECT_EQ(c.reads, 6u);
  EXPECT_EQ(c.ok, 2u);
  EXPECT_EQ(a->state(), Lifecycle::kActive);
  EXPECT_EQ(a->fault_cause(), IoStatus::kOk);
}

TEST(DeviceFaultPolicy, ConsecutiveErrorsTripTheFaultAtTheLimit) {
  auto a = active_arm({.max_consecutive_errors = 3});
  JointState s;
  a->inject(IoStatus::kTimeout, 3);
  EXPECT_EQ(a->read(s), IoStatus::kTimeout);
  EXPECT_EQ(a->read(s), IoStatus::kTimeout);
  EXPECT_EQ(a->state(), Lifecycle::kActive);
  EXPECT_EQ(a->read(s), IoStatus::kFault);  // the third in a row trips
  EXPECT_EQ(a->state(), Lifecycle::kFault);
  EXPECT_EQ(a->fault_cause(), IoStatus::kTimeout);
  EXPECT_EQ(a->counters().faults, 1u);
  EXPECT_EQ(a->counters().timeouts, 3u);
}

TEST(DeviceFaultPolicy, ErrorsBrokenByAnOkNeverTrip) {
  auto a = active_arm({.max_consecutive_errors = 3});
  JointState s;
  for (int round = 0; round < 10; ++round) {
    a->inject(IoStatus::kCrcError, 2);
    EXPECT_EQ(a->read(s), IoStatus::kCrcError);
    EXPECT_EQ(a->read(s), IoStatus::kCrcError);
    EXPECT_EQ(a->read(s), IoStatus::kOk);
  }
  EXPECT_EQ(a->state(), Lifecycle::kActive);
  EXPECT_EQ(a->counters().crc_errors, 20u);
  EXPECT_EQ(a->counters().faults, 0u);
}

TEST(DeviceFaultPolicy, GoodWritesDoNotHideFailingReads) {
  // Many buses do not confirm writes: only a good read shows the device answers.
  auto a = active_arm({.max_consecutive_errors = 3});
  JointState s;
  a->inject(IoStatus::kTimeout, 3);
  for (int i = 0; i < 2; ++i) {
    EXPECT_EQ(a->read(s), IoStatus::kTimeout);
    EXPECT_EQ(a->write(torques(0, 0, 0)), IoStatus::kOk);
  }
  EXPECT_EQ(a->read(s), IoStatus::kFault);
  EXPECT_EQ(a->fault_cause(), IoStatus::kTimeout);
}

TEST(DeviceFaultPolicy, OneErrorTripsWithALimitOfOne) {
  auto a = active_arm({.max_consecutive_errors = 1});
  JointState s;
  a->inject(IoStatus::kProtocolError, 1);
  EXPECT_EQ(a->read(s), IoStatus::kFault);
  EXPECT_EQ(a->fault_cause(), IoStatus::kProtocolError);
}

TEST(DeviceFaultPolicy, ADisconnectOrADeviceFaultTripsAtOnce) {
  for (IoStatus cause : {IoStatus::kDisconnected, IoStatus::kDeviceFault}) {
    auto a = active_arm({.max_consecutive_errors = 100});
    JointState s;
    a->inject(cause, 1);
    EXPECT_EQ(a->read(s), IoStatus::kFault) << to_string(cause);
    EXPECT_EQ(a->state(), Lifecycle::kFault);
    EXPECT_EQ(a->fault_cause(), cause);
    EXPECT_EQ(a->counters().faults, 1u);
  }
}

TEST(DeviceFaultPolicy, ALatchedDriveFaultIsCountedOncePerOnset) {
  auto a = active_arm({.max_consecutive_errors = 100});
  JointState s;
  a->inject(IoStatus::kDeviceFault, 50);  // the drive's fault bit, read 50 times in a row
  for (int i = 0; i < 50; ++i) (void)a->read(s);
  EXPECT_EQ(a->counters().device_faults, 1u);
  EXPECT_EQ(a->counters().faults, 1u);
  ASSERT_EQ(a->read(s), IoStatus::kFault);  // the bit cleared; the arm stays faulted until re-armed
  ASSERT_TRUE(a->rearm().ok());
  a->inject(IoStatus::kDeviceFault, 3);  // a second onset
  for (int i = 0; i < 3; ++i) (void)a->read(s);
  EXPECT_EQ(a->counters().device_faults, 2u);
}

TEST(DeviceFaultPolicy, InFaultWriteReturnsFaultAndSendsZeroTorque) {
  auto a = active_arm();
  JointState s;
  ASSERT_EQ(a->write(torques(0.2, -0.2, 0.1)), IoStatus::kOk);
  EXPECT_DOUBLE_EQ(a->physics().motor_torque(0), 0.2);
  a->inject(IoStatus::kDisconnected, 1);
  ASSERT_EQ(a->read(s), IoStatus::kFault);
  const std::uint64_t writes_before = a->counters().writes;
  for (int i = 0; i < 5; ++i) {
    EXPECT_EQ(a->write(torques(0.2, -0.2, 0.1)), IoStatus::kFault);
    for (int j = 0; j < 3; ++j) EXPECT_EQ(a->physics().motor_torque(j), 0.0) << "joint " << j;
  }
  EXPECT_EQ(a->counters().writes, writes_before + 5);
  // A fault never clears by itself: good reads still say kFault.
  for (int i = 0; i < 5; ++i) EXPECT_EQ(a->read(s), IoStatus::kFault);
  EXPECT_EQ(a->state(), Lifecycle::kFault);
}

TEST(DeviceFaultPolicy, RearmIsNeededToRecover) {
  auto a = active_arm({.max_consecutive_errors = 2});
  JointState s;
  a->inject(IoStatus::kTimeout, 2);
  (void)a->read(s);
  ASSERT_EQ(a->read(s), IoStatus::kFault);
  EXPECT_EQ(a->write(torques(0.1, 0, 0)), IoStatus::kFault);
  ASSERT_TRUE(a->rearm().ok());
  EXPECT_EQ(a->state(), Lifecycle::kActive);
  EXPECT_EQ(a->fault_cause(), IoStatus::kOk);
  EXPECT_EQ(a->counters().consecutive_errors, 0u);
  EXPECT_EQ(a->read(s), IoStatus::kOk);
  EXPECT_EQ(a->write(torques(0.1, 0, 0)), IoStatus::kOk);
  EXPECT_DOUBLE_EQ(a->physics().motor_torque(0), 0.1);
  // It can trip and recover again; the fault counter keeps the history.
  a->inject(IoStatus::kDisconnected, 1);
  ASSERT_EQ(a->read(s), IoStatus::kFault);
  ASSERT_TRUE(a->rearm().ok());
  EXPECT_EQ(a->counters().faults, 2u);
  // Deactivating from kFault is allowed too (zero torque, drives off).
  a->inject(IoStatus::kDisconnected, 1);
  ASSERT_EQ(a->read(s), IoStatus::kFault);
  EXPECT_TRUE(a->deactivate().ok());
  EXPECT_EQ(a->state(), Lifecycle::kInactive);
}

TEST(DeviceFaultPolicy, IoTimesAreMeasured) {
  auto a = active_arm();
  JointState s;
  for (int i = 0; i < 10; ++i) ASSERT_EQ(a->read(s), IoStatus::kOk);
  EXPECT_GT(a->counters().max_io_ns, 0);
  EXPECT_GE(a->counters().max_io_ns, a->counters().last_io_ns);
}

// ---------------------------------------------------------------------------------------------
// SimArm physics

TEST(SimArm, TheHandSpringPullsTheToolToTheTarget) {
  auto a = active_arm();
  ArmPhysics& p = a->physics();
  const Vec3 start = p.tool_position();
  const Vec3 target = start + Vec3{0.02, -0.015, 0.01};
  p.set_hand_target(target);
  const JointCommand zero = torques(0, 0, 0);
  JointState s;
  double first_distance = 0;
  for (int i = 0; i < 3000; ++i) {
    ASSERT_EQ(a->read(s), IoStatus::kOk);
    ASSERT_EQ(a->write(zero), IoStatus::kOk);
    if (i == 0) first_distance = norm(p.tool_position() - target);
  }
  EXPECT_GT(first_distance, 0.02);
  EXPECT_LT(norm(p.tool_position() - target), 1e-3);
  EXPECT_LT(norm(p.tool_velocity()), 1e-3);  // and settles there
  // The encoders followed.
  const Vec3 from_encoders = p.kinematics().position(std::span<const double>(s.q.data(), 3));
  EXPECT_LT(norm(from_encoders - p.tool_position()), 1e-3);
}

TEST(SimArm, LettingGoLeavesTheToolWhereTheMotorsPutIt) {
  auto a = active_arm();
  ArmPhysics& p = a->physics();
  p.set_hand_holding(false);
  p.set_hand_target(p.tool_position() + Vec3{0.05, 0, 0});
  const Vec3 start = p.tool_position();
  for (int i = 0; i < 500; ++i) ASSERT_EQ(a->write(torques(0, 0, 0)), IoStatus::kOk);
  EXPECT_LT(norm(p.tool_position() - start), 1e-9);  // no hand, no torque: nothing moves
}

TEST(SimArm, TorquesRenderTheExpectedToolForce) {
  auto a = active_arm();
  ArmPhysics& p = a->physics();
  const double q[3] = {0.2, 0.3, 0.1};
  p.reset(q);
  for (const Vec3 force : {Vec3{1.0, 0, 0}, Vec3{0, -2.0, 0}, Vec3{0.5, 0.5, -1.5}}) {
    const auto J = p.kinematics().jacobian(std::span<const double>(q, 3));
    const arm::JointArray tau = arm::joint_torques(J, force);
    for (int j = 0; j < 3; ++j) ASSERT_LT(std::abs(tau[static_cast<std::size_t>(j)]), p.peak_torque(j)) << "the test wants unclamped torques";
    p.reset(q);  // render at exactly q
    ASSERT_EQ(a->write(torques(tau[0], tau[1], tau[2])), IoStatus::kOk);
    const Vec3 f = p.rendered_force();
    EXPECT_NEAR(f.x, force.x, 1e-6);
    EXPECT_NEAR(f.y, force.y, 1e-6);
    EXPECT_NEAR(f.z, force.z, 1e-6);
  }
}

// The Falcon's delta kinematics as the simulated mechanism (what an emulator of it runs).
TEST(SimArm, ADeltaArmStartsAtTheOriginFollowsTheHandAndRendersForces) {
  arm::ArmConfig c = sim_config();
  c.kinematics.model = arm::KinematicModel::kDelta;
  c.kinematics.delta = arm::DeltaGeometry::novint_falcon();
  c.kinematics.base_offset = {0, 0, -0.111};  // the reachable cube's centre at the origin
  for (auto& j : c.joints) j.min = -85 * std::numbers::pi / 180, j.max = 110 * std::numbers::pi / 180;
  auto made = SimArm::create(c, {});
  ASSERT_TRUE(made.ok()) << made.error().message;
  auto a = std::move(made).value();
  a->set_fixed_dt(1e-3);
  ASSERT_TRUE(a->configure().ok());
  ASSERT_TRUE(a->activate().ok());
  ArmPhysics& p = a->physics();
  EXPECT_LT(norm(p.tool_position()), 1e-9) << "starts at the origin";
  // The hand pulls the tool 3 cm away and it settles there.
  const Vec3 target{0.03, -0.02, 0.025};
  p.set_hand_target(target);
  JointState s;
  for (int i = 0; i < 3000; ++i) {
    ASSERT_EQ(a->read(s), IoStatus::kOk);
    ASSERT_EQ(a->write(torques(0, 0, 0)), IoStatus::kOk);
  }
  EXPECT_LT(norm(p.tool_position() - target), 1e-3);
  EXPECT_LT(norm(p.tool_velocity()), 1e-3);
  const Vec3 from_encoders = p.kinematics().position(std::span<const double>(s.q.data(), 3));
  EXPECT_LT(norm(from_encoders - p.tool_position()), 1e-3);
  // Torques Jᵀ F render F at the tool.
  const double q[3] = {p.q(0), p.q(1), p.q(2)};
  const Vec3 force{0.5, -0.4, 1.0};
  const arm::JointArray tau = arm::joint_torques(p.kinematics().jacobian(std::span<const double>(q, 3)), force);
  for (int j = 0; j < 3; ++j) ASSERT_LT(std::abs(tau[static_cast<std::size_t>(j)]), p.peak_torque(j));
  p.reset(q);
  ASSERT_EQ(a->write(torques(tau[0], tau[1], tau[2])), IoStatus::kOk);
  EXPECT_NEAR(p.rendered_force().x, force.x, 1e-6);
  EXPECT_NEAR(p.rendered_force().y, force.y, 1e-6);
  EXPECT_NEAR(p.rendered_force().z, force.z, 1e-6);
}

TEST(SimArm, MotorTorqueIsClampedAtPeak) {
  auto a = active_arm();
  ArmPhysics& p = a->physics();
  const auto& cfg = p.config();
  for (int j = 0; j < 3; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    // Peak joint torque = Kt × peak current × gear ratio.
    EXPECT_NEAR(p.peak_torque(j), cfg.actuators[uj].torque_constant * cfg.actuators[uj].peak_current * cfg.joints[uj].gear_ratio, 1e-12);
  }
  ASSERT_EQ(a->write(torques(100, -100, 100)), IoStatus::kOk);
  EXPECT_DOUBLE_EQ(p.motor_torque(0), p.peak_torque(0));
  EXPECT_DOUBLE_EQ(p.motor_torque(1), -p.peak_torque(1));
  EXPECT_DOUBLE_EQ(p.motor_torque(2), p.peak_torque(2));
  const double nan = std::numeric_limits<double>::quiet_NaN();
  ASSERT_EQ(a->write(torques(nan, std::numeric_limits<double>::infinity(), 0.05)), IoStatus::kOk);
  EXPECT_EQ(p.motor_torque(0), 0.0);  // non-finite commands become zero, not NaN
  EXPECT_EQ(p.motor_torque(1), 0.0);
  EXPECT_DOUBLE_EQ(p.motor_torque(2), 0.05);
}

TEST(SimArm, DeactivateLeavesZeroTorque) {
  auto a = active_arm();
  ASSERT_EQ(a->write(torques(0.3, 0.3, 0.3)), IoStatus::kOk);
  ASSERT_TRUE(a->deactivate().ok());
  for (int j = 0; j < 3; ++j) EXPECT_EQ(a->physics().motor_torque(j), 0.0);
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Encoder plausibility, fault details, reconnect

Plausibility sim_plausibility(const arm::ArmConfig& c) {
  Plausibility p;
  p.n = 3;
  for (int j = 0; j < 3; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    p.max_speed[uj] = c.joints[uj].max_speed;
    p.resolution[uj] = std::abs(arm::joint_position_from_counts(c.joints[uj], 1) - arm::joint_position_from_counts(c.joints[uj], 0));
  }
  return p;
}

TEST(DevicePlausibility, AJumpBeyondTheJointsSpeedIsAGlitchNotData) {
  const arm::ArmConfig cfg = sim_config();
  EXPECT_NEAR(cfg.joints[0].max_speed, 1800 * M_PI / 180, 1e-9) << "the default max_speed_deg_s";
  auto a = active_arm();
  a->set_plausibility(sim_plausibility(cfg));
  JointState s;
  ASSERT_EQ(a->read(s), IoStatus::kOk);
  const double q0 = s.q[0];
  a->inject_encoder_offset(0, cfg.joints[0].counts_per_rev, 1);  // a motor revolution in one read
  JointState g = s;
  EXPECT_EQ(a->read(g), IoStatus::kImplausible);
  EXPECT_EQ(a->counters().glitches, 1u);
  EXPECT_EQ(a->last_error().status, IoStatus::kImplausible);
  EXPECT_EQ(a->last_error().node, 0);
  EXPECT_NE(std::string(a->last_error().c_str()).find("joint 0 encoder jumped"), std::string::npos) << a->last_error().c_str();
  // The next good reading is judged against the last plausible one, not the glitch.
  ASSERT_EQ(a->read(s), IoStatus::kOk);
  EXPECT_NEAR(s.q[0], q0, 1e-3);
  EXPECT_EQ(a->state(), Lifecycle::kActive);
  // Small real motion (a few counts) is never a glitch.
  a->inject_encoder_offset(1, 2, 1);
  EXPECT_EQ(a->read(s), IoStatus::kOk);
}

TEST(DevicePlausibility, RepeatedGlitchesFaultTheArmButGoodReadsDrainTheBucket) {
  const arm::ArmConfig cfg = sim_config();
  FaultPolicy policy;
  policy.max_glitches = 3;
  policy.glitch_leak_reads = 100;
  auto a = active_arm(policy);
  a->set_plausibility(sim_plausibility(cfg));
  JointState s;
  ASSERT_EQ(a->read(s), IoStatus::kOk);
  // Two glitches, each followed by 100 good reads: drained, no fault.
  for (int round = 0; round < 5; ++round) {
    a->inject_encoder_offset(2, 10 * cfg.joints[2].counts_per_rev, 1);
    EXPECT_EQ(a->read(s), IoStatus::kImplausible);
    for (int i = 0; i < 100; ++i) ASSERT_EQ(a->read(s), IoStatus::kOk);
  }
  EXPECT_EQ(a->state(), Lifecycle::kActive);
  // Three close together: a fault, with the glitch as its cause.
  a->inject_encoder_offset(2, 10 * cfg.joints[2].counts_per_rev, 3);
  (void)a->read(s);
  (void)a->read(s);
  EXPECT_EQ(a->read(s), IoStatus::kFault);
  EXPECT_EQ(a->state(), Lifecycle::kFault);
  EXPECT_EQ(a->fault_cause(), IoStatus::kImplausible);
  EXPECT_EQ(a->fault_detail().node, 2);
  EXPECT_EQ(a->counters().glitches, 8u);
  // A re-arm clears it; the reference starts afresh (the arm may have moved while faulted).
  ASSERT_TRUE(a->rearm().ok());
  EXPECT_EQ(a->fault_detail().status, IoStatus::kOk);
  EXPECT_EQ(a->read(s), IoStatus::kOk);
}

TEST(DeviceFaultDetail, AnErrorWithoutWordsIsNamedByItsStatus) {
  auto a = active_arm();
  a->inject(IoStatus::kDisconnected, 1);
  JointState s;
  EXPECT_EQ(a->read(s), IoStatus::kFault);
  EXPECT_EQ(a->fault_detail().status, IoStatus::kDisconnected);
  EXPECT_STREQ(a->fault_detail().c_str(), "disconnected");
  EXPECT_TRUE(a->link_lost());
  // The sim backend cannot reconnect: an honest error, and the arm stays faulted.
  const Result<void> r = a->reconnect();
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kUnsupported);
  EXPECT_NE(r.error().message.find("reconnect is not supported"), std::string::npos) << r.error().message;
  EXPECT_EQ(a->state(), Lifecycle::kFault);
  ASSERT_TRUE(a->rearm().ok());
  EXPECT_FALSE(a->link_lost());
  const Result<void> not_faulted = a->reconnect();
  EXPECT_FALSE(not_faulted.ok()) << "reconnect is for a faulted device only";
}
