// The CiA 402 state machine from both ends (the driver's commands, the drive's transitions),
// modes, the interpolation period and the torque units.

#include "device/canopen/cia402.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "device/canopen/torque_units.hpp"

namespace lancet::device::canopen {
namespace {

using S = Cia402State;
constexpr S kStates[] = {S::kNotReadyToSwitchOn, S::kSwitchOnDisabled, S::kReadyToSwitchOn, S::kSwitchedOn,
                         S::kOperationEnabled,   S::kQuickStopActive,  S::kFaultReactionActive, S::kFault};

TEST(CanopenCia402, StatuswordsOfTheSpec) {
  EXPECT_EQ(cia402_state(0x0237), S::kOperationEnabled);
  EXPECT_EQ(cia402_state(0x0250), S::kSwitchOnDisabled);
  EXPECT_EQ(cia402_state(0x0218), S::kFault);
  EXPECT_EQ(cia402_state(0x0021), S::kReadyToSwitchOn);
  EXPECT_EQ(cia402_state(0x0027 | kSwWarning), S::kOperationEnabled) << "the warning bit is no state";
  EXPECT_STREQ(to_string(S::kOperationEnabled), "operation enabled");
}

TEST(CanopenCia402, StatuswordOfEveryStateDecodesBack) {
  for (const S s : kStates) {
    EXPECT_EQ(cia402_state(statusword_of(s)), s) << to_string(s);
    EXPECT_EQ(cia402_state(static_cast<std::uint16_t>(kSwRemote | statusword_of(s))), s) << to_string(s) << " (remote)";
  }
  EXPECT_EQ(statusword_of(S::kOperationEnabled) | kSwRemote, 0x0237);
}

TEST(CanopenCia402, DriveTransitions) {
  EXPECT_EQ(drive_transition(S::kSwitchOnDisabled, kCwShutdown, 0), S::kReadyToSwitchOn);   // 2
  EXPECT_EQ(drive_transition(S::kReadyToSwitchOn, kCwSwitchOn, 0), S::kSwitchedOn);         // 3
  EXPECT_EQ(drive_transition(S::kSwitchedOn, kCwEnableOperation, 0), S::kOperationEnabled); // 4
  EXPECT_EQ(drive_transition(S::kReadyToSwitchOn, kCwEnableOperation, 0), S::kOperationEnabled) << "3 and 4 at once";
  EXPECT_EQ(drive_transition(S::kOperationEnabled, 0x0002, 0), S::kQuickStopActive);      // 11
  EXPECT_EQ(drive_transition(S::kQuickStopActive, kCwDisableVoltage, 0), S::kSwitchOnDisabled);  // 12
  EXPECT_EQ(drive_transition(S::kOperationEnabled, kCwShutdown, 0), S::kReadyToSwitchOn);   // 8
  EXPECT_EQ(drive_transition(S::kOperationEnabled, kCwSwitchOn, 0), S::kSwitchedOn);        // 5
  EXPECT_EQ(drive_transition(S::kOperationEnabled, kCwDisableVoltage, 0), S::kSwitchOnDisabled);  // 9
  EXPECT_EQ(drive_transition(S::kFault, kCwFaultReset, 0), S::kSwitchOnDisabled) << "rising edge of bit 7";
  EXPECT_EQ(drive_transition(S::kFault, kCwFaultReset, kCwFaultReset), S::kFault) << "bit 7 held: no edge";
  EXPECT_EQ(drive_transition(S::kFault, kCwEnableOperation, 0), S::kFault);
  EXPECT_EQ(drive_transition(S::kNotReadyToSwitchOn, kCwShutdown, 0), S::kNotReadyToSwitchOn);
}

TEST(CanopenCia402, TheDriversCommandsBringEveryDriveToOperationEnabled) {
  for (const S start : {S::kSwitchOnDisabled, S::kReadyToSwitchOn, S::kSwitchedOn, S::kOperationEnabled, S::kQuickStopActive, S::kFault}) {
    S s = start;
    std::uint16_t cw = kCwEnableOperation | kCwFaultReset;  // the worst previous one: bit 7 still set
    for (int step = 0; step < 6 && s != S::kOperationEnabled; ++step) {
      const std::uint16_t next = controlword_toward_enabled(statusword_of(s), cw);
      s = drive_transition(s, next, cw);
      cw = next;
    }
    EXPECT_EQ(s, S::kOperationEnabled) << "from " << to_string(start);
  }
}

TEST(CanopenCia402, ModesAndInterpolationPeriod) {
  EXPECT_STREQ(mode_name(kModeCyclicSyncTorque), "cyclic synchronous torque");
  EXPECT_STREQ(mode_name(-3), "another mode");
  EXPECT_EQ(supported_mode_bit(kModeProfileTorque) | supported_mode_bit(kModeCyclicSyncTorque), (1u << 3) | (1u << 9));
  const auto ms = interpolation_period(1000);
  ASSERT_TRUE(ms);
  EXPECT_EQ(ms->value, 1);
  EXPECT_EQ(ms->index, -3);
  EXPECT_FALSE(interpolation_period(0));
  EXPECT_FALSE(interpolation_period(333));
}

TEST(CanopenTorqueUnits, PerMilleAndBackAgree) {
  arm::ActuatorConfig act{};
  act.torque_constant = 0.0302;
  act.continuous_current = 3.0;
  act.peak_current = 9.0;
  arm::JointConfig joint{};
  joint.gear_ratio = 10.0;
  joint.direction = -1;
  const std::uint32_t rated = rated_torque_mnm(act);
  EXPECT_EQ(rated, 91u);  // 90.6 mN·m
  for (const double tau : {-0.5, -0.01, 0.0, 0.25, 0.9}) {
    const std::int16_t pm = torque_per_mille(joint, act, rated, 30000, tau);
    // One ‰ of the rated torque is the resolution: 0.091 mN·m at the motor, × gear at the joint.
    EXPECT_NEAR(joint_torque_from_per_mille(joint, act, rated, pm), tau, 0.5e-3 * rated * 1e-3 * joint.gear_ratio) << tau;
  }
  EXPECT_EQ(torque_per_mille(joint, act, rated, 100, 1e3), -100) << "clamped to the limit, direction −1";
  EXPECT_EQ(torque_per_mille(joint, act, rated, 100, std::nan("")), 0);
}

}  // namespace
}  // namespace lancet::device::canopen
