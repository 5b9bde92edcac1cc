// UsbArm against an emulated USB arm: unmodified libusb in this process talks to a device that
// umockdev puts in a testbed (sysfs + /dev from data/usb_arm.umockdev: a root hub and a HID-class
// arm 1209:0001 with interrupt endpoints 0x81 IN and 0x01 OUT), and every usbdevfs ioctl on the
// arm's node is answered by ArmEmulator (usb_arm_emulator.hpp, on tests/support's
// UsbdevfsDevice), which runs an ArmPhysics driven by the currents of the OUT reports and answers
// IN reports from its encoders. Bench below plugs and unplugs it (tests/support's UsbTestbed).
//
// Running: the umockdev preload library must be in LD_PRELOAD. main() checks and, when it is not,
// re-executes this binary under `umockdev-wrapper` (Debian package umockdev), adding
// verify_asan_link_order=0 to ASAN_OPTIONS in AddressSanitizer builds; so a plain `ctest` works.
// Without umockdev-wrapper on PATH the tests that need the testbed are skipped, saying why.
//
// Covered: enumeration by VID:PID and the errors for a wrong VID:PID or endpoint; encoder counts
// to joint positions (both byte orders, narrow wrapping counters); torques to currents within one
// lsb, clamped, moving the simulated arm; buttons; a withheld reply → kTimeout;
// unplug → kDisconnected → kFault, rearm after the arm comes back at a new address; short and
// wrong-id reports → kProtocolError with nothing decoded; the status fault bit → kDeviceFault;
// deactivate; and what allocates per transfer in steady state.
//
// No test depends on the machine's speed: transfers run with a generous timeout (the emulator
// answers on umockdev's handler thread, which a loaded machine may hold back for a while); a test
// whose subject is a timeout withholds the reply and shortens the timeout while it does; the
// emulated firmware's keep-alive watchdog runs on a clock the test advances.

#include "device/usb_arm.hpp"

#include <libusb.h>

#include <gtest/gtest.h>

#include <array>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "arm/arm_config.hpp"
#include "device/arm_physics.hpp"
#include "malloc_guard.hpp"
#include "usb_arm_emulator.hpp"
#include "usb_testbed.hpp"
#include "wait.hpp"

#ifndef LANCET_SOURCE_DIR
#define LANCET_SOURCE_DIR "."
#endif

namespace lancet::device {
namespace {

using arm::ByteOrder;
using arm::FieldType;

// ---------------------------------------------------------------------------------------------
// Environment

std::string source_path(const std::string& rel) { return std::string(LANCET_SOURCE_DIR) + "/" + rel; }

arm::ArmConfig shipped_usb_config() {
  auto c = arm::load_arm_config(source_path("hw_configs/usb_arm.toml"));
  if (!c.ok()) {
    ADD_FAILURE() << c.error().message;
    return {};
  }
  return std::move(c).value();
}

// A transfer timeout no reply from the emulator misses (the shipped 2 ms is for the real loop).
constexpr double kTimeout = 2.0;
// While the emulator withholds the reply on purpose: the reply never comes, so any value gives the
// same outcome, quickly.
constexpr double kShortTimeout = 0.02;

// The shipped layout with a generous timeout and the emulated firmware's keep-alive watchdog off:
// most tests pause between reports (reading only, or not at all), which a firmware would rightly
// take for a stalled host. The watchdog's own test turns it on.
arm::ArmConfig usb_config() {
  arm::ArmConfig c = shipped_usb_config();
  if (c.usb) {
    c.usb->drive_watchdog = 0;
    c.usb->timeout = kTimeout;
  }
  return c;
}

// The same layout, big-endian, 16-bit counters, no report ids, a 16-bit button word.
arm::ArmConfig big_endian_narrow_config() {
  arm::ArmConfig c = usb_config();
  auto& u = *c.usb;
  u.byte_order = ByteOrder::kBig;
  u.in_report_id.reset();
  u.out_report_id.reset();
  u.encoder_counts = {0, FieldType::kI16, ByteOrder::kBig, 1, 0};
  u.buttons = arm::ReportField{6, FieldType::kU16, ByteOrder::kBig, 1, 0};
  u.status = arm::ReportField{8, FieldType::kU8, ByteOrder::kBig, 1, 0};
  u.setpoint = {0, FieldType::kI16, ByteOrder::kBig, 1e-3, 0};
  u.enable = arm::ReportField{6, FieldType::kU8, ByteOrder::kBig, 1, 0};
  u.fault_reset = u.enable;
  return c;
}

// A layout unlike the shipped one: encoders big-endian in half counts from an offset, f32 motor
// torque setpoints in mN·m little-endian, a big-endian 16-bit status with bit 3 = ready, bit 7 =
// fault and an active-low e-stop at bit 0, a control byte 0x0F / 0x06, a fault-reset byte of its
// own (0x80), a 16-bit heartbeat.
arm::ArmConfig foreign_config() {
  arm::ArmConfig c = usb_config();
  auto& u = *c.usb;
  u.encoder_counts = {1, FieldType::kI32, ByteOrder::kBig, 0.5, 100.0};
  u.buttons = arm::ReportField{13, FieldType::kU8, ByteOrder::kLittle, 1, 0};
  u.status = arm::ReportField{14, FieldType::kU16, ByteOrder::kBig, 1, 0};
  u.status_bits = {};
  u.status_bits.ready = {3, false};
  u.status_bits.fault = {7, false};
  u.status_bits.estop = {0, true};
  u.setpoint = {1, FieldType::kF32, ByteOrder::kLittle, 0.001, 0};
  u.setpoint_kind = arm::SetpointKind::kTorque;
  u.enable = arm::ReportField{13, FieldType::kU8, ByteOrder::kLittle, 1, 0};
  u.enable_on = 0x0F;
  u.enable_off = 0x06;
  u.fault_reset = arm::ReportField{14, FieldType::kU8, ByteOrder::kLittle, 1, 0};
  u.fault_reset_value = 0x80;
  u.heartbeat = arm::ReportField{15, FieldType::kU16, ByteOrder::kBig, 1, 0};
  return c;
}

// ---------------------------------------------------------------------------------------------
// The testbed: sysfs and /dev from data/usb_arm.umockdev, the emulator on the arm's node

constexpr const char* kArmSysPath = "/sys/devices/pci0000:00/0000:00:14.0/usb1/1-1";

// The arm and its testbed, enumerated at bus 1 address 2 (with the root hub).
class Bench {
 public:
  explicit Bench(const arm::ArmConfig& cfg)
      : emu_(cfg), tb_(emu_, source_path("tests/firmware_rt/device/data/usb_arm.umockdev"), kArmSysPath) {
    plug(2);
  }

  ArmEmulator& emu() { return emu_; }
  /// Enumerates the arm at bus 1, address `address`.
  void plug(int address) { (void)tb_.plug(address); }  // a refusal is already a test failure
  /// Pulls the cable: the emulator fails what is in flight, the testbed forgets the device.
  void unplug() { tb_.unplug(); }
  void remove_from_testbed() { tb_.remove_from_testbed(); }

 private:
  ArmEmulator emu_;             // outlives tb_, which routes the node's ioctls to it
  lancet::test::UsbTestbed tb_;
};

class UsbArmTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!lancet::test::in_umockdev()) GTEST_SKIP() << lancet::test::not_in_umockdev_reason();
  }

  void start(const arm::ArmConfig& cfg, FaultPolicy policy = {}) {
    cfg_ = cfg;
    bench_ = std::make_unique<Bench>(cfg_);
    auto a = UsbArm::create(cfg_, policy);
    ASSERT_TRUE(a.ok()) << a.error().message;
    arm_ = std::move(a).value();
  }
  void start_active(const arm::ArmConfig& cfg, FaultPolicy policy = {}) {
    start(cfg, policy);
    ASSERT_FALSE(HasFatalFailure());
    Result<void> o = arm_->configure();
    ASSERT_TRUE(o.ok()) << o.error().message;
    o = arm_->activate();
    ASSERT_TRUE(o.ok()) << o.error().message;
  }
  void TearDown() override {
    arm_.reset();  // closes libusb before the testbed goes
    bench_.reset();
  }

  // Puts the simulated arm at q (rad) and returns the count each joint's encoder then shows.
  std::array<std::int64_t, kMaxJoints> place(const std::vector<double>& q) {
    std::array<std::int64_t, kMaxJoints> c{};
    bench_->emu().with_physics([&](ArmPhysics& p) {
      p.reset(q);
      for (int j = 0; j < p.joint_count(); ++j) c[static_cast<std::size_t>(j)] = p.encoder_counts(j);
    });
    return c;
  }
  double physics_q(int j) {
    double v = 0;
    bench_->emu().with_physics([&](ArmPhysics& p) { v = p.q(j); });
    return v;
  }
  /// After withheld replies: reads until one succeeds. A cancelled transfer libusb has not handed
  /// back within UsbArm's margin stays in flight, and calls report kTimeout at once until it is
  /// back (how soon is up to umockdev's handler thread); the machinery must come back by itself.
  ::testing::AssertionResult reads_again() {
    JointState js{};
    if (lancet::test::eventually([&] { return arm_->read(js) == IoStatus::kOk; })) return ::testing::AssertionSuccess();
    return ::testing::AssertionFailure() << "no good read after the withheld ones: " << arm_->last_error().c_str();
  }
  double count_angle(int j) const {
    const auto& joint = cfg_.joints[static_cast<std::size_t>(j)];
    return std::abs(arm::joint_position_from_counts(joint, 1) - arm::joint_position_from_counts(joint, 0));
  }

  arm::ArmConfig cfg_;
  std::unique_ptr<Bench> bench_;
  std::unique_ptr<UsbArm> arm_;
};

// ---------------------------------------------------------------------------------------------
// Lifecycle and enumeration

TEST(UsbArmCreate, NeedsAUsbBusSectionAndAConsistentLayout) {
  auto sim = arm::load_arm_config(source_path("hw_configs/sim_3dof.toml"));
  ASSERT_TRUE(sim.ok()) << sim.error().message;
  auto a = UsbArm::create(sim.value());
  ASSERT_FALSE(a.ok());
  EXPECT_EQ(a.error().code, ErrorCode::kInvalid);
  EXPECT_NE(a.error().message.find("[bus.usb]"), std::string::npos) << a.error().message;

  arm::ArmConfig c = usb_config();
  c.usb->encoder_counts.offset = 60;  // 3 × i32 from byte 60 overruns the 64-byte report
  a = UsbArm::create(c);
  ASSERT_FALSE(a.ok());
  EXPECT_NE(a.error().message.find("encoder_counts"), std::string::npos) << a.error().message;
}

TEST_F(UsbArmTest, FindsTheArmByVidPidTakesItFromUsbhidAndEnables) {
  start(usb_config());
  ASSERT_FALSE(HasFatalFailure());
  Result<void> o = arm_->configure();
  ASSERT_TRUE(o.ok()) << o.error().message;
  EXPECT_EQ(arm_->device_location(), "bus 001 address 002");
  EmulatorSnapshot s = bench_->emu().snapshot();
  EXPECT_EQ(s.driver_detaches, 1) << "the HID interface was bound to usbhid: it must be detached";
  EXPECT_TRUE(s.claimed);
  EXPECT_GE(s.in_reports, 1u) << "configure() checks that the arm answers";
  EXPECT_EQ(s.out_reports, 0u) << "nothing is sent before activate()";
  const auto counts = place({0.25, 0.5, -0.25});
  JointState js{};
  ASSERT_EQ(arm_->read(js), IoStatus::kOk) << "read() works while inactive";
  EXPECT_EQ(js.counts[1], counts[1]);
  EXPECT_EQ(bench_->emu().snapshot().out_reports, 0u);

  o = arm_->activate();
  ASSERT_TRUE(o.ok()) << o.error().message;
  EXPECT_EQ(arm_->state(), Lifecycle::kActive);
  s = bench_->emu().snapshot();
  EXPECT_EQ(s.out_reports, 1u);
  EXPECT_EQ(s.bad_out_reports, 0u);
  EXPECT_TRUE(s.enabled) << "activate() sets the enable bit";
  for (int j = 0; j < 3; ++j) EXPECT_EQ(s.current_counts[static_cast<std::size_t>(j)], 0) << "joint " << j;
}

TEST_F(UsbArmTest, AWrongVidPidSaysWhatWasSeen) {
  arm::ArmConfig c = usb_config();
  c.usb->pid = 0x0002;
  start(c);
  ASSERT_FALSE(HasFatalFailure());
  Result<void> o = arm_->configure();
  ASSERT_FALSE(o.ok());
  EXPECT_EQ(o.error().code, ErrorCode::kNotFound);
  const std::string& m = o.error().message;
  EXPECT_NE(m.find("no USB device 1209:0002"), std::string::npos) << m;
  EXPECT_NE(m.find("1209:0001 at bus 001 address 002"), std::string::npos) << m;
  EXPECT_NE(m.find("1d6b:0002 at bus 001 address 001"), std::string::npos) << m;
  EXPECT_EQ(arm_->state(), Lifecycle::kUnconfigured);
}

TEST_F(UsbArmTest, AMissingEndpointListsTheOnesThere) {
  arm::ArmConfig c = usb_config();
  c.usb->endpoint_in = 0x82;
  start(c);
  ASSERT_FALSE(HasFatalFailure());
  Result<void> o = arm_->configure();
  ASSERT_FALSE(o.ok());
  EXPECT_EQ(o.error().code, ErrorCode::kMismatch);
  EXPECT_NE(o.error().message.find("0x82"), std::string::npos) << o.error().message;
  EXPECT_NE(o.error().message.find("0x81 interrupt IN, 0x01 interrupt OUT"), std::string::npos) << o.error().message;
}

// ---------------------------------------------------------------------------------------------
// Data

TEST_F(UsbArmTest, EncoderCountsDecodeToThePhysicsJointPositions) {
  start_active(usb_config());
  ASSERT_FALSE(HasFatalFailure());
  const std::vector<std::vector<double>> poses{{0.3, -0.1, 0.5}, {-0.8, 1.1, -0.4}, {0.0, 0.0, 0.0}};
  for (const auto& pose : poses) {
    const auto counts = place(pose);
    JointState js{};
    ASSERT_EQ(arm_->read(js), IoStatus::kOk);
    ASSERT_EQ(js.n, 3);
    for (int j = 0; j < 3; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      EXPECT_EQ(js.counts[uj], counts[uj]) << "joint " << j;
      EXPECT_NEAR(js.q[uj], pose[uj], count_angle(j)) << "joint " << j;
    }
    EXPECT_EQ(js.status, 0u);
    EXPECT_GT(js.t_ns, 0);
  }
  // Button bits map to the config's button order (stylus_dark = bit 0, stylus_light = bit 1).
  bench_->emu().set_buttons(0b10);
  JointState js{};
  ASSERT_EQ(arm_->read(js), IoStatus::kOk);
  EXPECT_EQ(js.buttons, 0b10u);
  EXPECT_EQ(arm_->counters().ok, 4u);
}

TEST_F(UsbArmTest, ABigEndianSixteenBitLayoutWithoutReportIdsDecodes) {
  start_active(big_endian_narrow_config());
  ASSERT_FALSE(HasFatalFailure());
  const auto counts = place({-0.5, 0.9, 0.7});
  bench_->emu().set_buttons(0x0001);
  JointState js{};
  ASSERT_EQ(arm_->read(js), IoStatus::kOk);
  for (int j = 0; j < 3; ++j) EXPECT_EQ(js.counts[static_cast<std::size_t>(j)], counts[static_cast<std::size_t>(j)]) << "joint " << j;
  EXPECT_NEAR(js.q[1], 0.9, count_angle(1));
  EXPECT_EQ(js.buttons, 0b01u);

  JointCommand cmd{};
  cmd.n = 3;
  cmd.tau = {0.02, -0.01, 0.0};
  ASSERT_EQ(arm_->write(cmd), IoStatus::kOk);
  const EmulatorSnapshot s = bench_->emu().snapshot();
  EXPECT_EQ(s.bad_out_reports, 0u);
  const double expect0 = arm::motor_current_for_joint_torque(cfg_.joints[0], cfg_.actuators[0], 0.02);
  EXPECT_NEAR(static_cast<double>(s.current_counts[0]) * 1e-3, expect0, 0.5e-3 + 1e-12);
}

TEST_F(UsbArmTest, NarrowCountersThatWrapAreUnwrapped) {
  // 2^20 counts per motor revolution through a 10:1 gear in an i16 field: the counter wraps
  // about every 0.02 rad of joint travel; q must still follow the arm.
  arm::ArmConfig c = big_endian_narrow_config();
  for (auto& j : c.joints) j.counts_per_rev = std::int64_t{1} << 20;
  start_active(c);
  ASSERT_FALSE(HasFatalFailure());
  for (int k = 0; k <= 400; ++k) {
    const double q0 = 0.9 * std::sin(k * 0.01);  // small steps (< half a wrap per read)
    place({q0, 0.0, -k * 0.001});
    JointState js{};
    ASSERT_EQ(arm_->read(js), IoStatus::kOk) << "step " << k;
    ASSERT_NEAR(js.q[0], q0, 2 * count_angle(0)) << "step " << k;
    ASSERT_NEAR(js.q[2], -k * 0.001, 2 * count_angle(2)) << "step " << k;
  }
}

TEST_F(UsbArmTest, TorquesArriveAsCurrentsWithinOneLsbAndMoveTheArm) {
  start_active(usb_config());
  ASSERT_FALSE(HasFatalFailure());
  bench_->emu().with_physics([](ArmPhysics& p) { p.set_hand_holding(false); });
  const double lsb = cfg_.usb->setpoint.scale;
  JointCommand cmd{};
  cmd.n = 3;
  cmd.tau = {0.05, -0.031, 0.0123};
  ASSERT_EQ(arm_->write(cmd), IoStatus::kOk);
  EmulatorSnapshot s = bench_->emu().snapshot();
  for (int j = 0; j < 3; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const double amps = arm::motor_current_for_joint_torque(cfg_.joints[uj], cfg_.actuators[uj], cmd.tau[uj]);
    EXPECT_LE(std::abs(static_cast<double>(s.current_counts[uj]) * lsb - amps), 0.5 * lsb + 1e-12) << "joint " << j;
  }
  EXPECT_TRUE(s.enabled);

  // Yaw torque alone, 200 ticks of 1 ms on the device: the yaw joint turns, and read() sees it.
  cmd.tau = {0.05, 0.0, 0.0};
  const double q0 = physics_q(0);
  JointState js{};
  bool moving_positive = false;
  for (int i = 0; i < 200; ++i) {
    ASSERT_EQ(arm_->read(js), IoStatus::kOk);
    ASSERT_EQ(arm_->write(cmd), IoStatus::kOk);
    moving_positive = moving_positive || js.qd[0] > 0;
  }
  ASSERT_EQ(arm_->read(js), IoStatus::kOk);
  const double q1 = physics_q(0);
  EXPECT_GT(q1 - q0, 0.05) << "0.05 N·m for 0.2 s on the free yaw joint";
  EXPECT_NEAR(js.q[0], q1, count_angle(0));
  EXPECT_TRUE(moving_positive) << "q̇ follows the motion";
  EXPECT_TRUE(std::isfinite(js.qd[0]));
}

TEST_F(UsbArmTest, CurrentsClampToThePeakAndToTheFieldRange) {
  start_active(usb_config());
  ASSERT_FALSE(HasFatalFailure());
  JointCommand cmd{};
  cmd.n = 3;
  cmd.tau = {1e6, -1e6, std::nan("")};
  ASSERT_EQ(arm_->write(cmd), IoStatus::kOk);
  EmulatorSnapshot s = bench_->emu().snapshot();
  const double lsb = cfg_.usb->setpoint.scale;
  const auto peak = static_cast<std::int64_t>(std::llround(cfg_.actuators[0].peak_current / lsb));
  // shoulder has direction −1: a negative torque is a positive current
  EXPECT_EQ(s.current_counts[0], peak);
  EXPECT_EQ(s.current_counts[1], peak);
  EXPECT_EQ(s.current_counts[2], 0) << "a NaN torque sends zero current";

  arm_.reset();
  bench_.reset();
  arm::ArmConfig c = usb_config();
  c.usb->setpoint = {1, FieldType::kI8, ByteOrder::kLittle, 0.01, 0};  // 10 mA per count: 2.5 A does not fit in i8
  c.usb->enable = arm::ReportField{4, FieldType::kU8, ByteOrder::kLittle, 1, 0};
  c.usb->fault_reset = c.usb->enable;
  start_active(c);
  ASSERT_FALSE(HasFatalFailure());
  cmd.tau = {1e6, 1e6, 0.0};
  ASSERT_EQ(arm_->write(cmd), IoStatus::kOk);
  s = bench_->emu().snapshot();
  EXPECT_EQ(s.current_counts[0], 127);
  EXPECT_EQ(s.current_counts[1], -128);
}

// ---------------------------------------------------------------------------------------------
// Errors

TEST_F(UsbArmTest, AWithheldReplyIsATimeoutAfterTheTransferTimeout) {
  start_active(usb_config(), FaultPolicy{1'000'000});
  ASSERT_FALSE(HasFatalFailure());
  bench_->emu().withhold_in(true);
  arm_->set_timeout(kShortTimeout);
  const double timeout = arm_->timeout();
  const UsbArm::TransferStats before = arm_->transfer_stats();
  for (int i = 0; i < 5; ++i) {
    JointState js{};
    js.q[0] = 42;
    const std::uint64_t submitted = arm_->transfer_stats().submitted;
    const auto t0 = std::chrono::steady_clock::now();
    ASSERT_EQ(arm_->read(js), IoStatus::kTimeout) << "attempt " << i;
    const double took = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    EXPECT_EQ(js.q[0], 42) << "nothing is decoded from a timeout";
    // A read that sent a transfer waited for the reply at least the timeout. (One that finds the
    // last cancelled transfer not back yet reports kTimeout at once; how soon libusb hands it back
    // is umockdev's handler thread's business.) The upper bound only catches a wait for the
    // withheld reply itself or a timeout taken in the wrong unit.
    if (arm_->transfer_stats().submitted > submitted) {
      EXPECT_GE(took, timeout) << "attempt " << i;
    }
    EXPECT_LT(took, 5.0) << "attempt " << i;
  }
  EXPECT_EQ(arm_->counters().timeouts, 5u);
  const std::uint64_t sent = arm_->transfer_stats().submitted - before.submitted;
  EXPECT_GE(sent, 1u);
  EXPECT_EQ(bench_->emu().snapshot().discards, sent) << "each timed-out transfer was cancelled";

  // The transfer machinery is not wedged: the next reply is read.
  bench_->emu().withhold_in(false);
  arm_->set_timeout(kTimeout);
  ASSERT_TRUE(reads_again());
  const auto counts = place({0.2, 0.2, 0.2});
  JointState js{};
  ASSERT_EQ(arm_->read(js), IoStatus::kOk);
  EXPECT_EQ(js.counts[0], counts[0]);
  EXPECT_EQ(arm_->counters().consecutive_errors, 0u);
  const UsbArm::TransferStats after = arm_->transfer_stats();
  EXPECT_EQ(after.submitted, after.completed) << "every transfer came back";
}

TEST_F(UsbArmTest, ConsecutiveTimeoutsTripTheFault) {
  start_active(usb_config());  // default policy: 3 in a row
  ASSERT_FALSE(HasFatalFailure());
  bench_->emu().withhold_in(true);
  arm_->set_timeout(kShortTimeout);
  JointState js{};
  EXPECT_EQ(arm_->read(js), IoStatus::kTimeout);
  EXPECT_EQ(arm_->read(js), IoStatus::kTimeout);
  EXPECT_EQ(arm_->read(js), IoStatus::kFault);
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kTimeout);
  bench_->emu().withhold_in(false);
  arm_->set_timeout(kTimeout);
  // Once the last cancelled transfer is back (at once, normally), rearm succeeds.
  Result<void> o = Result<void>::failure(ErrorCode::kSystem, "not tried");
  ASSERT_TRUE(lancet::test::eventually([&] {
    o = arm_->rearm();
    return o.ok();
  })) << o.error().message;
  EXPECT_EQ(arm_->read(js), IoStatus::kOk);
}

TEST_F(UsbArmTest, UnplugTripsTheFaultAndRearmFindsTheArmAtItsNewAddress) {
  start_active(usb_config());
  ASSERT_FALSE(HasFatalFailure());
  JointCommand cmd{};
  cmd.n = 3;
  cmd.tau = {0.01, 0.0, 0.0};
  JointState js{};
  for (int i = 0; i < 20; ++i) {
    ASSERT_EQ(arm_->read(js), IoStatus::kOk);
    ASSERT_EQ(arm_->write(cmd), IoStatus::kOk);
  }

  bench_->unplug();
  EXPECT_EQ(arm_->read(js), IoStatus::kFault);
  EXPECT_EQ(arm_->state(), Lifecycle::kFault);
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kDisconnected);
  EXPECT_EQ(arm_->counters().disconnects, 1u);
  EXPECT_EQ(arm_->counters().faults, 1u);
  EXPECT_EQ(arm_->write(cmd), IoStatus::kFault);

  // Still gone: rearm says so and the fault stays.
  Result<void> o = arm_->rearm();
  ASSERT_FALSE(o.ok());
  EXPECT_NE(o.error().message.find("no USB device 1209:0001"), std::string::npos) << o.error().message;
  EXPECT_EQ(arm_->state(), Lifecycle::kFault);

  // Back, enumerated at address 3.
  bench_->plug(3);
  o = arm_->rearm();
  ASSERT_TRUE(o.ok()) << o.error().message;
  EXPECT_EQ(arm_->state(), Lifecycle::kActive);
  EXPECT_EQ(arm_->device_location(), "bus 001 address 003");
  EXPECT_TRUE(bench_->emu().snapshot().enabled);
  EXPECT_EQ(bench_->emu().snapshot().driver_detaches, 2) << "usbhid bound the re-enumerated arm";
  const auto counts = place({0.1, 0.4, -0.2});
  ASSERT_EQ(arm_->read(js), IoStatus::kOk);
  EXPECT_EQ(js.counts[1], counts[1]);
  EXPECT_EQ(arm_->write(cmd), IoStatus::kOk);
}

TEST_F(UsbArmTest, AnArmThatVanishesWithATransferInFlightIsDisconnected) {
  start_active(usb_config());
  ASSERT_FALSE(HasFatalFailure());
  bench_->emu().vanish_on_next_in();
  JointState js{};
  js.q[0] = 42;
  EXPECT_EQ(arm_->read(js), IoStatus::kFault);
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kDisconnected);
  EXPECT_EQ(js.q[0], 42);
  bench_->remove_from_testbed();
  JointCommand zero{};
  zero.n = 3;
  EXPECT_EQ(arm_->write(zero), IoStatus::kFault);
  bench_->plug(4);
  Result<void> o = arm_->rearm();
  ASSERT_TRUE(o.ok()) << o.error().message;
  EXPECT_EQ(arm_->device_location(), "bus 001 address 004");
  EXPECT_EQ(arm_->read(js), IoStatus::kOk);
}

TEST_F(UsbArmTest, ShortAndWrongIdReportsAreProtocolErrorsAndDecodeNothing) {
  start_active(usb_config());
  ASSERT_FALSE(HasFatalFailure());
  JointState good{};
  ASSERT_EQ(arm_->read(good), IoStatus::kOk);
  place({0.7, 0.7, 0.7});  // what a bad report would carry

  for (Corruption c : {Corruption::kShort, Corruption::kWrongId}) {
    bench_->emu().corrupt_next_in(c);
    JointState js = good;
    EXPECT_EQ(arm_->read(js), IoStatus::kProtocolError);
    EXPECT_EQ(js.counts, good.counts) << "no value of a bad report is used";
    EXPECT_EQ(js.q, good.q);
    EXPECT_EQ(js.t_ns, good.t_ns);
  }
  EXPECT_EQ(arm_->counters().protocol_errors, 2u);
  EXPECT_EQ(arm_->state(), Lifecycle::kActive) << "two in a row stay under the policy's 3";
  JointState js{};
  ASSERT_EQ(arm_->read(js), IoStatus::kOk);
  EXPECT_NEAR(js.q[0], 0.7, count_angle(0));
  EXPECT_EQ(arm_->counters().consecutive_errors, 0u);
}

TEST_F(UsbArmTest, TheStatusFaultBitIsADeviceFault) {
  start_active(usb_config());
  ASSERT_FALSE(HasFatalFailure());
  bench_->emu().set_status(0x05);  // bit 0: fault (bit 2: something the driver passes through)
  JointState js{};
  EXPECT_EQ(arm_->read(js), IoStatus::kFault);
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kDeviceFault);
  EXPECT_EQ(arm_->counters().device_faults, 1u);
  EXPECT_EQ(js.status, 0x05u) << "the status word is delivered with the fault";

  bench_->emu().set_status(0x04);
  Result<void> o = arm_->rearm();
  ASSERT_TRUE(o.ok()) << o.error().message;
  EXPECT_EQ(arm_->read(js), IoStatus::kOk);
  EXPECT_EQ(js.status, 0x04u);
}

TEST_F(UsbArmTest, DeactivateZeroesTheCurrentsAndDisablesAndReadingGoesOn) {
  start_active(usb_config());
  ASSERT_FALSE(HasFatalFailure());
  JointCommand cmd{};
  cmd.n = 3;
  cmd.tau = {0.05, 0.05, 0.05};
  ASSERT_EQ(arm_->write(cmd), IoStatus::kOk);
  EXPECT_NE(bench_->emu().snapshot().current_counts[0], 0);
  Result<void> o = arm_->deactivate();
  ASSERT_TRUE(o.ok()) << o.error().message;
  EmulatorSnapshot s = bench_->emu().snapshot();
  EXPECT_FALSE(s.enabled);
  for (int j = 0; j < 3; ++j) EXPECT_EQ(s.current_counts[static_cast<std::size_t>(j)], 0);
  EXPECT_TRUE(s.claimed) << "kept for read() while inactive";
  EXPECT_EQ(arm_->write(cmd), IoStatus::kNotActive);
  const auto counts = place({0.3, 0.2, 0.1});
  JointState js{};
  ASSERT_EQ(arm_->read(js), IoStatus::kOk) << "reading never moves the arm: allowed while inactive";
  EXPECT_EQ(js.counts[0], counts[0]);

  o = arm_->activate();
  ASSERT_TRUE(o.ok()) << o.error().message;
  EXPECT_TRUE(bench_->emu().snapshot().claimed);
  EXPECT_TRUE(bench_->emu().snapshot().enabled);
  EXPECT_EQ(arm_->read(js), IoStatus::kOk);
}

// ---------------------------------------------------------------------------------------------
// A foreign layout, the keep-alive watchdog, reconnection, errors in words

TEST_F(UsbArmTest, AForeignLayoutWithFloatsScalesAndItsOwnBitsAndValues) {
  start(foreign_config());
  ASSERT_FALSE(HasFatalFailure());
  bench_->emu().set_status(0x0009);  // ready (bit 3), the active-low e-stop released (bit 0 high)
  Result<void> o = arm_->configure();
  ASSERT_TRUE(o.ok()) << o.error().message;
  o = arm_->activate();
  ASSERT_TRUE(o.ok()) << o.error().message;
  EmulatorSnapshot s = bench_->emu().snapshot();
  EXPECT_TRUE(s.enabled);
  EXPECT_EQ(s.enable_raw, 0x0Fu);
  EXPECT_EQ(s.resets, 0u) << "no fault at activation: no reset";

  // Encoders in half counts from 100, big-endian.
  const auto counts = place({0.4, -0.3, 0.2});
  JointState js{};
  ASSERT_EQ(arm_->read(js), IoStatus::kOk);
  for (int j = 0; j < 3; ++j) EXPECT_EQ(js.counts[static_cast<std::size_t>(j)], counts[static_cast<std::size_t>(j)]) << "joint " << j;
  EXPECT_EQ(js.status, 0x0009u);

  // Setpoints: motor torque as f32 mN·m; the heartbeat counts one per report.
  JointCommand cmd{};
  cmd.n = 3;
  cmd.tau = {0.02, -0.015, 0.01};
  const std::uint32_t hb0 = bench_->emu().snapshot().heartbeat;
  ASSERT_EQ(arm_->write(cmd), IoStatus::kOk);
  ASSERT_EQ(arm_->write(cmd), IoStatus::kOk);
  s = bench_->emu().snapshot();
  EXPECT_EQ(s.heartbeat, hb0 + 2);
  for (int j = 0; j < 3; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const double amps = arm::motor_current_for_joint_torque(cfg_.joints[uj], cfg_.actuators[uj], cmd.tau[uj]);
    EXPECT_NEAR(s.setpoint[uj], amps * cfg_.actuators[uj].torque_constant, 1e-7) << "joint " << j;
  }

  // Bit 7 is this device's fault, named in the fault detail.
  bench_->emu().set_status(0x0089);
  EXPECT_EQ(arm_->read(js), IoStatus::kFault);
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kDeviceFault);
  EXPECT_STREQ(arm_->fault_detail().c_str(), "status 0x0089: fault (bit 7)");
  // Cleared at the device: rearm sends one report with the fault-reset byte, then enables.
  bench_->emu().set_status(0x0009);
  o = arm_->rearm();
  ASSERT_TRUE(o.ok()) << o.error().message;
  s = bench_->emu().snapshot();
  EXPECT_EQ(s.resets, 1u);
  EXPECT_TRUE(s.enabled);
  ASSERT_EQ(arm_->read(js), IoStatus::kOk);
  // The e-stop is active low: pressed, bit 0 reads 0.
  bench_->emu().set_status(0x0008);
  EXPECT_EQ(arm_->read(js), IoStatus::kFault);
  EXPECT_STREQ(arm_->fault_detail().c_str(), "status 0x0008: e-stop (bit 0 low)");
}

TEST_F(UsbArmTest, WhenTheKeepAliveStopsTheEmulatedArmGoesTorqueFreeUntilAFaultReset) {
  arm::ArmConfig c = shipped_usb_config();  // the shipped layout: heartbeat byte, 50 ms watchdog
  ASSERT_TRUE(c.usb);
  ASSERT_NEAR(c.usb->drive_watchdog, 0.05, 1e-12);
  c.usb->timeout = kTimeout;
  start_active(c, FaultPolicy{100});
  ASSERT_FALSE(HasFatalFailure());
  ArmEmulator& emu = bench_->emu();
  JointCommand cmd{};
  cmd.n = 3;
  cmd.tau = {0.02, 0.0, 0.0};
  JointState js{};
  // A report every 50 ms of the firmware's clock, the watchdog time itself: never a trip (0.5 s).
  for (int i = 0; i < 10; ++i) {
    ASSERT_EQ(arm_->read(js), IoStatus::kOk);
    ASSERT_EQ(arm_->write(cmd), IoStatus::kOk);
    emu.advance_clock(50'000'000);
  }
  EmulatorSnapshot s = emu.snapshot();
  EXPECT_EQ(s.trips, 0u);
  EXPECT_TRUE(s.enabled);
  // The host stops (a hung servo, a killed process): still on after exactly the watchdog time,
  // torque-free the moment it is longer.
  ASSERT_EQ(arm_->write(cmd), IoStatus::kOk);
  emu.advance_clock(50'000'000);
  s = emu.snapshot();
  EXPECT_EQ(s.trips, 0u) << "silent for the watchdog time, not longer";
  EXPECT_TRUE(s.enabled);
  emu.advance_clock(1'000);
  s = emu.snapshot();
  EXPECT_EQ(s.trips, 1u);
  EXPECT_TRUE(s.tripped);
  EXPECT_FALSE(s.enabled);
  // The driver reports it in the config's words; the fault is latched.
  EXPECT_EQ(arm_->read(js), IoStatus::kFault);
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kDeviceFault);
  EXPECT_STREQ(arm_->fault_detail().c_str(), "status 0x0003: fault (bit 0), communication lost (bit 1)");
  for (int i = 0; i < 20; ++i) {
    (void)arm_->write(cmd);  // the keep-alive again: still off
    emu.advance_clock(1'000'000);
  }
  EXPECT_TRUE(emu.snapshot().tripped);
  Result<void> o = arm_->rearm();
  ASSERT_TRUE(o.ok()) << o.error().message;
  s = emu.snapshot();
  EXPECT_FALSE(s.tripped);
  EXPECT_TRUE(s.enabled);
  EXPECT_EQ(s.resets, 1u);
  ASSERT_EQ(arm_->read(js), IoStatus::kOk);
}

TEST_F(UsbArmTest, ReconnectFindsTheReplugedArmAtItsNewAddressAndKeepsItOff) {
  start_active(usb_config());
  ASSERT_FALSE(HasFatalFailure());
  JointState js{};
  ASSERT_EQ(arm_->read(js), IoStatus::kOk);
  bench_->unplug();
  EXPECT_EQ(arm_->read(js), IoStatus::kFault);
  EXPECT_TRUE(arm_->link_lost());
  EXPECT_NE(std::string(arm_->fault_detail().c_str()).find("the device is"), std::string::npos) << "[" << arm_->fault_detail().c_str() << "]";
  Result<void> o = arm_->reconnect();
  ASSERT_FALSE(o.ok());
  EXPECT_NE(o.error().message.find("no USB device 1209:0001"), std::string::npos) << o.error().message;
  EXPECT_EQ(arm_->state(), Lifecycle::kFault);

  bench_->plug(5);
  o = arm_->reconnect();
  ASSERT_TRUE(o.ok()) << o.error().message;
  EXPECT_EQ(arm_->state(), Lifecycle::kFault) << "a reconnect never re-arms";
  EXPECT_FALSE(arm_->link_lost());
  EXPECT_EQ(arm_->counters().reconnects, 1u);
  EXPECT_EQ(arm_->device_location(), "bus 001 address 005");
  EmulatorSnapshot s = bench_->emu().snapshot();
  EXPECT_FALSE(s.enabled) << "the reconnected arm is sent enable off";
  EXPECT_EQ(s.enable_raw, cfg_.usb->enable_off);
  JointCommand cmd{};
  cmd.n = 3;
  cmd.tau = {0.05, 0.05, 0.05};
  EXPECT_EQ(arm_->write(cmd), IoStatus::kFault);
  for (int j = 0; j < 3; ++j) EXPECT_EQ(bench_->emu().snapshot().current_counts[static_cast<std::size_t>(j)], 0);
  o = arm_->rearm();
  ASSERT_TRUE(o.ok()) << o.error().message;
  EXPECT_TRUE(bench_->emu().snapshot().enabled);
  EXPECT_EQ(arm_->read(js), IoStatus::kOk);
}

TEST_F(UsbArmTest, EveryErrorIsDescribedWithTheDeviceAndTheEndpoint) {
  start_active(usb_config(), FaultPolicy{1'000'000});
  ASSERT_FALSE(HasFatalFailure());
  JointState js{};
  const auto text = [&] { return std::string(arm_->last_error().c_str()); };
  bench_->emu().withhold_in(true);
  arm_->set_timeout(kShortTimeout);
  EXPECT_EQ(arm_->read(js), IoStatus::kTimeout);
  EXPECT_NE(text().find("bus 001 address 002, IN 0x81: no reply"), std::string::npos) << text();
  bench_->emu().withhold_in(false);
  arm_->set_timeout(kTimeout);
  ASSERT_TRUE(reads_again());
  bench_->emu().corrupt_next_in(Corruption::kShort);
  EXPECT_EQ(arm_->read(js), IoStatus::kProtocolError);
  EXPECT_EQ(text(), "bus 001 address 002, IN 0x81: short report: 32 of 64 bytes");
  bench_->emu().corrupt_next_in(Corruption::kWrongId);
  EXPECT_EQ(arm_->read(js), IoStatus::kProtocolError);
  EXPECT_EQ(text(), "bus 001 address 002, IN 0x81: report id 2, expected 1");
  bench_->unplug();
  JointCommand cmd{};
  cmd.n = 3;
  EXPECT_EQ(arm_->write(cmd), IoStatus::kFault);
  EXPECT_NE(std::string(arm_->fault_detail().c_str()).find("bus 001 address 002, OUT 0x01: the device is"), std::string::npos)
      << "[" << arm_->fault_detail().c_str() << "]";
}

// ---------------------------------------------------------------------------------------------
// Allocation in steady state

// Allocations by this thread for `transfers` interrupt transfers done with plain libusb on the
// emulated arm (no UsbArm): the floor that libusb and the umockdev preload set per transfer.
// With libusb 1.0.26 it is exactly 1: gdb puts every one of them at calloc(1, 56), one
// struct usbfs_urb, called from libusb_submit_transfer (linux_usbfs.c, submit_bulk_transfer) and
// freed when the URB is reaped; the umockdev preload allocates nothing in the calling thread.
double libusb_allocations_per_transfer(const arm::UsbBusConfig& u, int transfers) {
  libusb_context* ctx = nullptr;
  if (libusb_init(&ctx) != 0) return -1;
  libusb_device_handle* h = libusb_open_device_with_vid_pid(ctx, u.vid, u.pid);
  double result = -1;
  if (h != nullptr) {
    if (libusb_kernel_driver_active(h, u.interface_number) == 1) (void)libusb_detach_kernel_driver(h, u.interface_number);
    if (libusb_claim_interface(h, u.interface_number) == 0) {
      std::vector<unsigned char> buf(u.in_size);
      libusb_transfer* t = libusb_alloc_transfer(0);
      int done = 0;
      libusb_fill_interrupt_transfer(
          t, h, u.endpoint_in, buf.data(), static_cast<int>(buf.size()), [](libusb_transfer* x) { *static_cast<int*>(x->user_data) = 1; },
          &done, static_cast<unsigned int>(kTimeout * 1e3));  // generous: the floor, not a race
      const auto one = [&] {
        done = 0;
        if (libusb_submit_transfer(t) != 0) return false;
        while (done == 0) (void)libusb_handle_events_completed(ctx, &done);
        return t->status == LIBUSB_TRANSFER_COMPLETED;
      };
      for (int i = 0; i < 20; ++i) (void)one();  // warm up
      bool ok = true;
      lancet::test::MallocGuard guard;
      for (int i = 0; i < transfers && ok; ++i) ok = one();
      const auto n = guard.count();
      if (ok) result = static_cast<double>(n) / transfers;
      libusb_free_transfer(t);
      (void)libusb_release_interface(h, u.interface_number);
    }
    libusb_close(h);
  }
  libusb_exit(ctx);
  return result;
}

TEST_F(UsbArmTest, SteadyStateReadWriteAllocatesOnlyWhatLibusbDoesPerTransfer) {
  start(usb_config());
  ASSERT_FALSE(HasFatalFailure());
  const double floor = libusb_allocations_per_transfer(*cfg_.usb, 200);
  ASSERT_GE(floor, 0) << "plain libusb could not run transfers on the emulated arm";

  Result<void> o = arm_->configure();
  ASSERT_TRUE(o.ok()) << o.error().message;
  o = arm_->activate();
  ASSERT_TRUE(o.ok()) << o.error().message;
  JointState js{};
  JointCommand cmd{};
  cmd.n = 3;
  cmd.tau = {0.01, -0.01, 0.005};
  for (int i = 0; i < 50; ++i) {  // warm up
    ASSERT_EQ(arm_->read(js), IoStatus::kOk);
    ASSERT_EQ(arm_->write(cmd), IoStatus::kOk);
  }
  constexpr int kCycles = 500;
  std::size_t count = 0;
  {
    lancet::test::MallocGuard guard;
    for (int i = 0; i < kCycles; ++i) {
      if (arm_->read(js) != IoStatus::kOk || arm_->write(cmd) != IoStatus::kOk) break;
    }
    count = guard.count();
  }
  EXPECT_EQ(arm_->counters().ok, 50u * 2 + 2 * kCycles);
  const double per_transfer = static_cast<double>(count) / (2.0 * kCycles);
  RecordProperty("allocations_per_transfer_usb_arm", std::to_string(per_transfer));
  RecordProperty("allocations_per_transfer_plain_libusb", std::to_string(floor));
  std::printf("[ info     ] allocations per transfer: UsbArm %.3f, plain libusb %.3f (malloc %s)\n", per_transfer, floor,
              lancet::test::malloc_is_counted() ? "counted" : "not counted: sanitizer build, operator new only");
  // UsbArm adds nothing of its own to what every libusb transfer costs.
  EXPECT_EQ(per_transfer, floor);
  if (!lancet::test::malloc_is_counted()) {
    EXPECT_EQ(count, 0u) << "operator new on the read/write path";
  }
}

}  // namespace
}  // namespace lancet::device

// ---------------------------------------------------------------------------------------------
// Entry point: make sure the umockdev preload library is loaded, re-executing under the wrapper.
