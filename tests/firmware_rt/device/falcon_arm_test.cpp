// FalconArm against an emulated Novint Falcon: unmodified libusb in this process talks to the
// FTDI chip that umockdev puts in a testbed (data/novint_falcon.umockdev), and every usbdevfs ioctl
// on its node is answered by FalconEmulator (falcon_emulator.hpp): the chip's control requests
// checked, the loader's handshake and echoes, then the firmware answering each command packet
// from a simulated delta mechanism driven by the commanded motor torques.
//
// Covered: the bring-up's control requests (reset, UART mode, 8N1, no flow control, the loader's
// 9600 baud and 16 ms latency, DTR pulse, 140 kbaud, then 1.5 Mbaud and 1 ms); the firmware
// upload, and no upload when the firmware already runs (or when asked to always); each failure
// named: no device, another product id, a missing firmware file, an echo mismatch (the byte), no
// reply after the upload; homing (activate waits for the switches and names the motors left; the
// counts' jump is no glitch); encoders to q and the tool point; torques to motor commands and the
// force felt at the grip through the Jacobian; the grip buttons; a dropped reply, a malformed
// reply, a burst of either (the fault, zero torque at the Falcon), unplug and replug (the firmware
// uploaded again, homing again); allocation per exchange.
//
// No test depends on the machine's speed: the exchange timeout is generous (umockdev's handler
// thread may be held back on a loaded machine), a reply withheld on purpose never comes, and every
// other wait is for an event.

#include "device/falcon_arm.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <thread>
#include <tuple>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <memory>
#include <string>
#include <vector>

#include "arm/arm_config.hpp"
#include "device/ftdi.hpp"
#include "tools/bringup.hpp"
#include "falcon_emulator.hpp"
#include "malloc_guard.hpp"
#include "usb_testbed.hpp"
#include "wait.hpp"

#ifndef LANCET_SOURCE_DIR
#define LANCET_SOURCE_DIR "."
#endif

namespace lancet::device {
namespace {

using test::FalconEmulator;
using test::FalconEmulatorOptions;
using test::FalconSnapshot;

constexpr const char* kFalconFile = LANCET_SOURCE_DIR "/tests/firmware_rt/device/data/novint_falcon.umockdev";
constexpr const char* kFalconSysPath = "/sys/devices/pci0000:00/0000:00:14.0/usb1/1-1";
constexpr double kTimeout = 2.0;  // an exchange the emulator answers (the shipped 2 ms is for the real loop)

std::string source_path(const std::string& rel) { return std::string(LANCET_SOURCE_DIR) + "/" + rel; }

// A made-up firmware image: the loader echoes whatever it is sent, so any bytes do (we ship none).
std::vector<std::uint8_t> fake_firmware(std::size_t n) {
  std::vector<std::uint8_t> f(n);
  std::uint32_t x = 2463534242u;
  for (auto& b : f) {
    x ^= x << 13, x ^= x >> 17, x ^= x << 5;
    b = static_cast<std::uint8_t>(x);
  }
  return f;
}

class FalconArmTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!test::in_umockdev()) GTEST_SKIP() << test::not_in_umockdev_reason();
    dir_ = std::filesystem::temp_directory_path() / ("lancet-falcon-" + std::to_string(getpid()) + "-" +
                                                     ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::create_directories(dir_);
    firmware_ = fake_firmware(1000);  // 17 chunks, the last one short
    std::ofstream(dir_ / "falcon.bin", std::ios::binary).write(reinterpret_cast<const char*>(firmware_.data()),
                                                             static_cast<std::streamsize>(firmware_.size()));
    auto c = arm::load_arm_config(source_path("hw_configs/novint_falcon.toml"));
    ASSERT_TRUE(c.ok()) << c.error().message;
    cfg_ = std::move(c).value();
    cfg_.falcon->firmware = (dir_ / "falcon.bin").string();
    cfg_.falcon->timeout = kTimeout;
    cfg_.falcon->homing_timeout = 10;
  }
  void TearDown() override {
    arm_.reset();  // closes libusb before the testbed goes
    bed_.reset();
    emu_.reset();
    if (!dir_.empty()) std::filesystem::remove_all(dir_);
  }

  /// The options of an emulated Falcon at the centre, with home switches a few mm towards the
  /// user (where home_stroke() takes the grip).
  FalconEmulatorOptions options() {
    FalconEmulatorOptions o;
    o.firmware = firmware_;
    auto k = arm::make_kinematics(cfg_);
    EXPECT_TRUE(k.ok());
    probe_kin_ = k.value();
    // Thigh angles at device-frame points (the model's closed-form inverse).
    const auto at = [&](Vec3 p) {
      const auto q = probe_kin_->delta()->inverse(p);
      EXPECT_TRUE(q.has_value());
      return q.value_or(std::array<double, 3>{});
    };
    o.start_q = at({0, 0, 0});
    const auto stroke = at(kStroke);
    for (int m = 0; m < 3; ++m) o.home_angles[static_cast<std::size_t>(m)] = 0.5 * (o.start_q[static_cast<std::size_t>(m)] + stroke[static_cast<std::size_t>(m)]);
    return o;
  }

  void start(FalconEmulatorOptions o, FaultPolicy policy = {}, bool plug = true) {
    emu_ = std::make_unique<FalconEmulator>(cfg_, std::move(o));
    bed_ = std::make_unique<test::UsbTestbed>(*emu_, kFalconFile, kFalconSysPath);
    if (plug) {
      ASSERT_TRUE(bed_->plug(2));
    }
    make_arm(policy);
  }
  /// A FalconArm for cfg_ (the emulated Falcon stays as it is), with the encoder plausibility check
  /// lancet-rt turns on (app::plausibility_of), so that a jump the Falcon makes on purpose (homing)
  /// is seen to pass it.
  void make_arm(FaultPolicy policy = {}) {
    arm_.reset();
    auto a = FalconArm::create(cfg_, policy);
    ASSERT_TRUE(a.ok()) << a.error().message;
    arm_ = std::move(a).value();
    Plausibility p;
    p.n = 3;
    for (std::size_t j = 0; j < 3; ++j) {
      p.max_speed[j] = cfg_.joints[j].max_speed;
      p.resolution[j] = std::abs(arm::joint_position_from_counts(cfg_.joints[j], 1) - arm::joint_position_from_counts(cfg_.joints[j], 0));
    }
    arm_->set_plausibility(p);
  }
  void configure() {
    const Result<void> r = arm_->configure();
    ASSERT_TRUE(r.ok()) << r.error().message;
  }
  /// Exchanges zero commands while the emulated hand takes the grip to `p` and back: each thigh
  /// passes its home switch on the way.
  void home_stroke() {
    for (const Vec3 target : {kStroke, Vec3{0, 0, 0}}) {
      emu_->with_physics([&](ArmPhysics& p) { p.set_hand_target(target); });
      JointState s{};
      for (int i = 0; i < 400; ++i) (void)arm_->read(s);
    }
  }
  void start_active(FaultPolicy policy = {}) {
    start(options(), policy);
    ASSERT_FALSE(HasFatalFailure());
    configure();
    ASSERT_FALSE(HasFatalFailure());
    home_stroke();
    const Result<void> r = arm_->activate();
    ASSERT_TRUE(r.ok()) << r.error().message;
  }
  static bool has_request(const FalconSnapshot& s, std::uint8_t request, std::uint16_t value, std::uint16_t index = 0) {
    return std::any_of(s.requests.begin(), s.requests.end(),
                       [&](const test::FtdiRequest& r) { return r.request == request && r.value == value && r.index == index; });
  }

  static constexpr Vec3 kStroke{0, -0.03, 0};  // 30 mm towards the user (device frame: y away, z up)

  std::filesystem::path dir_;
  std::vector<std::uint8_t> firmware_;
  arm::ArmConfig cfg_;
  std::optional<arm::Kinematics> probe_kin_;
  std::unique_ptr<FalconEmulator> emu_;
  std::unique_ptr<test::UsbTestbed> bed_;
  std::unique_ptr<FalconArm> arm_;
};

// ---------------------------------------------------------------------------------------------
// Bring-up

TEST_F(FalconArmTest, ConfigureUploadsTheFirmwareWithTheChipSetUpAsTheLoaderWantsIt) {
  start(options());
  ASSERT_FALSE(HasFatalFailure());
  configure();
  ASSERT_FALSE(HasFatalFailure());
  const FalconSnapshot s = emu_->snapshot();
  EXPECT_EQ(s.mode, FalconSnapshot::Mode::kRunning);
  EXPECT_EQ(s.uploads_completed, 1u);
  EXPECT_EQ(s.uploaded, firmware_.size());
  EXPECT_EQ(arm_->stats().uploads, 1u);
  EXPECT_EQ(s.unexpected_requests, 0u);
  // The chip's set-up: reset, UART mode, 8N1 without flow control; the loader's rates and DTR
  // pulse (9600 baud is 0x4138, 140 kbaud is divisor 21.375: 0x0015 with wIndex 1); normal mode.
  EXPECT_TRUE(has_request(s, ftdi::kReset, ftdi::kResetPort));
  EXPECT_TRUE(has_request(s, ftdi::kBitMode, 0));
  EXPECT_TRUE(has_request(s, ftdi::kDataFormat, 8));
  EXPECT_TRUE(has_request(s, ftdi::kFlowControl, 0));
  EXPECT_TRUE(has_request(s, ftdi::kLatencyTimer, 16));
  EXPECT_TRUE(has_request(s, ftdi::kBaudRate, 0x4138));
  EXPECT_TRUE(has_request(s, ftdi::kModemControl, ftdi::kDtrHigh));
  EXPECT_TRUE(has_request(s, ftdi::kBaudRate, 0x0015, 1));
  EXPECT_TRUE(has_request(s, ftdi::kBaudRate, 2));
  EXPECT_TRUE(has_request(s, ftdi::kReset, ftdi::kPurgeRx));
  EXPECT_TRUE(has_request(s, ftdi::kReset, ftdi::kPurgeTx));
  // It ends in normal mode: 1.5 Mbaud, latency 1 ms, and homing mode on with the red LED.
  EXPECT_NEAR(s.baud, 1.5e6, 1);
  EXPECT_EQ(s.latency_ms, 1);
  EXPECT_TRUE(s.eight_n_one);
  EXPECT_TRUE(s.flow_none);
  EXPECT_TRUE(s.homing_mode);
  EXPECT_EQ(s.leds, falcon::kLedRed);
  EXPECT_FALSE(arm_->device_location().empty());
}

TEST_F(FalconArmTest, AFalconWhoseFirmwareRunsIsNotUploadedAgainUnlessAskedTo) {
  FalconEmulatorOptions o = options();
  o.firmware_running = true;
  start(o);
  ASSERT_FALSE(HasFatalFailure());
  configure();
  EXPECT_EQ(arm_->stats().found_running, 1u);
  EXPECT_EQ(arm_->stats().uploads, 0u);
  EXPECT_EQ(emu_->snapshot().uploads_completed, 0u);
  EXPECT_FALSE(has_request(emu_->snapshot(), ftdi::kBaudRate, 0x4138));  // the loader's rate never set
  // upload = "always": the DTR pulse resets it into its loader, and the firmware goes in anyway.
  cfg_.falcon->upload = arm::FirmwareUpload::kAlways;
  make_arm();
  configure();
  EXPECT_EQ(arm_->stats().uploads, 1u);
  EXPECT_EQ(emu_->snapshot().uploads_completed, 1u);
}

TEST_F(FalconArmTest, NoFalconOnTheBusIsSaidSo) {
  start(options(), {}, false);
  ASSERT_FALSE(HasFatalFailure());
  const Result<void> r = arm_->configure();
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("no Novint Falcon (0403:cb48) on the USB bus"), std::string::npos) << r.error().message;
}

TEST_F(FalconArmTest, AnFtdiChipWithAnotherProductIdIsNamed) {
  cfg_.falcon->pid = 0x6001;  // a config for a Falcon with a rewritten EEPROM, on a stock one
  start(options());
  ASSERT_FALSE(HasFatalFailure());
  const Result<void> r = arm_->configure();
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("no Novint Falcon (0403:6001)"), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find("another product id (0403:cb48 at bus 001 address 002)"), std::string::npos) << r.error().message;
}

TEST_F(FalconArmTest, AMissingFirmwareFileIsNamed) {
  cfg_.falcon->firmware = (dir_ / "nowhere.bin").string();
  start(options());
  ASSERT_FALSE(HasFatalFailure());
  const Result<void> r = arm_->configure();
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("bus.falcon.firmware: cannot read " + (dir_ / "nowhere.bin").string()), std::string::npos)
      << r.error().message;
}

TEST_F(FalconArmTest, AWrongEchoStopsTheUploadAtThatByte) {
  FalconEmulatorOptions o = options();
  o.corrupt_echo_at = 500;
  start(o);
  ASSERT_FALSE(HasFatalFailure());
  const Result<void> r = arm_->configure();
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("echo mismatch at byte 500 of 1000"), std::string::npos) << r.error().message;
  EXPECT_EQ(arm_->state(), Lifecycle::kUnconfigured);
  EXPECT_LT(emu_->snapshot().uploaded, firmware_.size());  // it stopped there
}

TEST_F(FalconArmTest, AFirmwareThatNeverAnswersIsNoReplyAfterUpload) {
  FalconEmulatorOptions o = options();
  o.start_after_upload = false;
  start(o);
  ASSERT_FALSE(HasFatalFailure());
  const Result<void> r = arm_->configure();
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("no reply after the firmware upload"), std::string::npos) << r.error().message;
  EXPECT_EQ(emu_->snapshot().uploaded, firmware_.size());
}

// ---------------------------------------------------------------------------------------------
// Homing, encoders, torques, buttons

TEST_F(FalconArmTest, ActivateWaitsForTheHomeSwitchesAndNamesTheMotorsLeft) {
  start(options());
  ASSERT_FALSE(HasFatalFailure());
  configure();
  arm_->set_timeout(kTimeout);
  cfg_.falcon->homing_timeout = 0.2;
  make_arm();  // the same Falcon, a short homing wait
  configure();
  Result<void> r = arm_->activate();
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("not homed within 0 s: motor 1, 2, 3 has not passed its home switch"), std::string::npos)
      << r.error().message;
  home_stroke();
  EXPECT_EQ(arm_->homed(), falcon::kAllHomed);
  r = arm_->activate();
  ASSERT_TRUE(r.ok()) << r.error().message;
  // The counts became absolute mid-stream: not a glitch.
  EXPECT_EQ(arm_->counters().glitches, 0u);
  JointState js{};
  ASSERT_EQ(arm_->read(js), IoStatus::kOk);  // the first command since: green, homing mode off
  const FalconSnapshot s = emu_->snapshot();
  EXPECT_FALSE(s.homing_mode);
  EXPECT_EQ(s.leds, falcon::kLedGreen);
}

TEST_F(FalconArmTest, EncodersGiveTheMechanismsThighAnglesAndToolPoint) {
  start_active();
  ASSERT_FALSE(HasFatalFailure());
  auto kin = arm::make_kinematics(cfg_);
  ASSERT_TRUE(kin.ok());
  for (const Vec3 target : {Vec3{0.02, 0.01, -0.015}, Vec3{-0.025, -0.02, 0.02}}) {
    emu_->with_physics([&](ArmPhysics& p) { p.set_hand_target(target); });
    JointState s{};
    for (int i = 0; i < 500; ++i) {
      ASSERT_EQ(arm_->read(s), IoStatus::kOk) << arm_->last_error().c_str();
      ASSERT_EQ(arm_->write(JointCommand{3, {}}), IoStatus::kOk);
    }
    ASSERT_EQ(arm_->read(s), IoStatus::kOk);
    const double count = 2 * std::numbers::pi / (1280 * cfg_.joints[0].gear_ratio);
    std::array<double, 3> q{};
    Vec3 tool{};
    emu_->with_physics([&](ArmPhysics& p) {
      for (int j = 0; j < 3; ++j) q[static_cast<std::size_t>(j)] = p.q(j);
      tool = p.tool_position();
    });
    for (int j = 0; j < 3; ++j) EXPECT_NEAR(s.q[static_cast<std::size_t>(j)], q[static_cast<std::size_t>(j)], 1.01 * count) << j;
    const Vec3 read_tool = kin.value().position(std::span<const double>(s.q.data(), 3));
    EXPECT_LT(norm(read_tool - tool), 2e-4) << "read " << read_tool.x << " " << read_tool.y << " " << read_tool.z;
    EXPECT_LT(norm(tool - target), 0.01);  // the hand got it there (a spring, no motor torque)
  }
}

TEST_F(FalconArmTest, TorquesBecomeMotorCommandsAndTheGripFeelsTheCommandedForce) {
  start_active();
  ASSERT_FALSE(HasFatalFailure());
  auto kin = arm::make_kinematics(cfg_);
  ASSERT_TRUE(kin.ok());
  JointState s{};
  for (const Vec3 force : {Vec3{1.5, 0, 0}, Vec3{0, -2.0, 1.0}, Vec3{-0.5, 0.7, -3.0}}) {
    ASSERT_EQ(arm_->read(s), IoStatus::kOk);
    const arm::Jacobian j = kin.value().jacobian(std::span<const double>(s.q.data(), 3));
    const arm::JointArray tau = arm::joint_torques(j, force);
    JointCommand cmd{3, {}};
    for (int m = 0; m < 3; ++m) cmd.tau[static_cast<std::size_t>(m)] = tau[static_cast<std::size_t>(m)];
    ASSERT_EQ(arm_->write(cmd), IoStatus::kOk);
    ASSERT_EQ(arm_->read(s), IoStatus::kOk);  // the reply to that command: the emulator has it
    const FalconSnapshot e = emu_->snapshot();
    for (int m = 0; m < 3; ++m) {
      const auto um = static_cast<std::size_t>(m);
      EXPECT_EQ(e.motor[um], static_cast<std::int16_t>(std::lround(cfg_.falcon->motor_command_per_nm * tau[um]))) << m;
    }
    // The force the servo meant, recovered at the pose it read: within the command's 1/10000 N·m steps.
    EXPECT_LT(norm(e.meant - force), 0.02 + 0.005 * norm(force))
        << "meant " << e.meant.x << " " << e.meant.y << " " << e.meant.z;
  }
  // Torques beyond the command's range clamp to it; NaN sends nothing.
  ASSERT_EQ(arm_->write(JointCommand{3, {100.0, -100.0, NAN}}), IoStatus::kOk);
  ASSERT_EQ(arm_->read(s), IoStatus::kOk);
  const FalconSnapshot e = emu_->snapshot();
  EXPECT_EQ(e.motor[0], -32767);
  EXPECT_EQ(e.motor[1], 32767);
  EXPECT_EQ(e.motor[2], 0);
}

TEST_F(FalconArmTest, GripButtonsMapThroughTheConfig) {
  start_active();
  ASSERT_FALSE(HasFatalFailure());
  JointState s{};
  emu_->set_grip(0x4);  // the centre button: [[buttons]] entry "center", bit 2
  ASSERT_EQ(arm_->read(s), IoStatus::kOk);
  ASSERT_EQ(arm_->read(s), IoStatus::kOk);
  std::uint32_t want = 0;
  for (std::size_t i = 0; i < cfg_.buttons.size(); ++i)
    if (cfg_.buttons[i].bit == 2) want |= 1u << i;
  EXPECT_NE(want, 0u);
  EXPECT_EQ(s.buttons, want);
  EXPECT_EQ(s.status & 0x7u, 0x7u);  // homed
}

// ---------------------------------------------------------------------------------------------
// Faults

TEST_F(FalconArmTest, ADroppedReplyIsATimeoutAndTheNextExchangeGoesOn) {
  start_active();
  ASSERT_FALSE(HasFatalFailure());
  arm_->set_timeout(0.05);  // the reply is withheld on purpose: it never comes
  emu_->drop_replies(1);
  JointState s{};
  ASSERT_EQ(arm_->write(JointCommand{3, {}}), IoStatus::kOk);
  EXPECT_EQ(arm_->read(s), IoStatus::kTimeout);
  EXPECT_NE(std::string(arm_->last_error().c_str()).find("no reply to the last command"), std::string::npos);
  arm_->set_timeout(kTimeout);
  ASSERT_EQ(arm_->write(JointCommand{3, {}}), IoStatus::kOk);
  EXPECT_EQ(arm_->read(s), IoStatus::kOk);
  EXPECT_EQ(arm_->state(), Lifecycle::kActive);
}

TEST_F(FalconArmTest, AMalformedReplyIsAProtocolErrorAndTheScanResynchronises) {
  start_active();
  ASSERT_FALSE(HasFatalFailure());
  emu_->corrupt_replies(1);
  JointState s{};
  ASSERT_EQ(arm_->write(JointCommand{3, {}}), IoStatus::kOk);
  EXPECT_EQ(arm_->read(s), IoStatus::kProtocolError);
  EXPECT_NE(std::string(arm_->last_error().c_str()).find("malformed reply"), std::string::npos);
  ASSERT_EQ(arm_->write(JointCommand{3, {}}), IoStatus::kOk);
  EXPECT_EQ(arm_->read(s), IoStatus::kOk);
  EXPECT_EQ(arm_->counters().protocol_errors, 1u);
}

TEST_F(FalconArmTest, ABurstOfBadRepliesFaultsTheArmAndTheFalconGetsZeroTorque) {
  start_active();
  ASSERT_FALSE(HasFatalFailure());
  JointState s{};
  ASSERT_EQ(arm_->read(s), IoStatus::kOk);
  ASSERT_EQ(arm_->write(JointCommand{3, {0.1, 0.1, 0.1}}), IoStatus::kOk);
  ASSERT_EQ(arm_->read(s), IoStatus::kOk);
  ASSERT_NE(emu_->snapshot().motor[0], 0);
  emu_->corrupt_replies(10);
  for (int i = 0; i < 5 && arm_->state() != Lifecycle::kFault; ++i) {
    (void)arm_->write(JointCommand{3, {0.1, 0.1, 0.1}});
    (void)arm_->read(s);
  }
  ASSERT_EQ(arm_->state(), Lifecycle::kFault);
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kProtocolError);
  EXPECT_NE(std::string(arm_->fault_detail().c_str()).find("malformed reply"), std::string::npos);
  EXPECT_EQ(arm_->write(JointCommand{3, {0.1, 0.1, 0.1}}), IoStatus::kFault);
  (void)arm_->read(s);
  const FalconSnapshot e = emu_->snapshot();
  EXPECT_EQ(e.motor, (std::array<std::int16_t, 3>{0, 0, 0}));
  EXPECT_EQ(e.leds, falcon::kLedRed);  // the Falcon shows the fault
  // Re-armed, forces come back.
  emu_->corrupt_replies(0);
  ASSERT_TRUE(arm_->rearm().ok());
  ASSERT_EQ(arm_->read(s), IoStatus::kOk);
  ASSERT_EQ(arm_->write(JointCommand{3, {0.1, 0.1, 0.1}}), IoStatus::kOk);
  ASSERT_EQ(arm_->read(s), IoStatus::kOk);
  EXPECT_NE(emu_->snapshot().motor[0], 0);
  EXPECT_EQ(emu_->snapshot().leds, falcon::kLedGreen);
}

TEST_F(FalconArmTest, UnplugFaultsTheArmAndReconnectUploadsTheFirmwareAgainAtTheNewAddress) {
  start_active();
  ASSERT_FALSE(HasFatalFailure());
  JointState s{};
  bed_->unplug();
  emu_->power_cycle();
  // The write or the read after the unplug finds the Falcon gone (a disconnect faults the arm at
  // once, so the call itself reports the fault; its cause is the disconnect).
  (void)arm_->write(JointCommand{3, {}});
  (void)arm_->read(s);
  ASSERT_EQ(arm_->state(), Lifecycle::kFault);
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kDisconnected);
  EXPECT_TRUE(arm_->link_lost());
  EXPECT_FALSE(arm_->reconnect().ok());  // still unplugged
  ASSERT_TRUE(bed_->plug(3));
  const Result<void> r = arm_->reconnect();
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(arm_->device_location(), "bus 001 address 003");
  EXPECT_EQ(arm_->stats().uploads, 2u);  // a replugged Falcon has lost its firmware
  EXPECT_EQ(arm_->state(), Lifecycle::kFault);  // still no torque until re-armed
  // Homing was lost with the power: rearm needs the switches again.
  home_stroke();
  const Result<void> re = arm_->rearm();
  ASSERT_TRUE(re.ok()) << re.error().message;
  EXPECT_EQ(arm_->state(), Lifecycle::kActive);
}

// libusb allocates one URB descriptor per submitted transfer (the OUT, and the IN it resubmits):
// nothing else per exchange.
TEST_F(FalconArmTest, AnExchangeAllocatesOnlyWhatLibusbDoesPerTransfer) {
  start_active();
  ASSERT_FALSE(HasFatalFailure());
  JointState s{};
  for (int i = 0; i < 20; ++i) {
    ASSERT_EQ(arm_->read(s), IoStatus::kOk);
    ASSERT_EQ(arm_->write(JointCommand{3, {0.01, 0, 0}}), IoStatus::kOk);
  }
  constexpr int kExchanges = 200;
  const auto before = arm_->port()->stats();
  test::MallocGuard guard;
  for (int i = 0; i < kExchanges; ++i) {
    (void)arm_->read(s);
    (void)arm_->write(JointCommand{3, {0.01, 0, 0}});
  }
  const std::uint64_t allocs = guard.count();
  const auto after = arm_->port()->stats();
  const std::uint64_t transfers = (after.writes - before.writes) + (after.in_packets - before.in_packets) + 1;
  EXPECT_LE(allocs, transfers) << allocs << " allocations for " << transfers << " transfers";
  if (!test::malloc_is_counted()) {
    EXPECT_EQ(allocs, 0u) << "operator new on the read/write path";
  }
}

// ---------------------------------------------------------------------------------------------
// lancetctl's bring-up commands on the emulated Falcon (list, probe, calibrate = homing, monitor, jog)

class FalconBringup : public FalconArmTest {
 protected:
  /// The config on disk (the tools read a file), pointing at this test's firmware.
  std::string write_config() {
    std::string text = read_text(source_path("hw_configs/novint_falcon.toml"));
    const auto at = text.find("firmware = \"");
    const auto end = text.find('"', at + 12);
    text.replace(at, end + 1 - at, "firmware = \"" + (dir_ / "falcon.bin").string() + "\"");
    const auto t = text.find("timeout_ms = 2.0");
    text.replace(t, 16, "timeout_ms = 1000");
    const std::string path = (dir_ / "falcon.toml").string();
    std::ofstream(path) << text;
    return path;
  }
  /// Runs a tool with its output in a file; returns (exit code, output).
  template <class F>
  std::pair<int, std::string> run(F&& tool) {
    const std::string out = (dir_ / "out.txt").string();
    std::FILE* f = std::fopen(out.c_str(), "w+");
    const int code = tool(f);
    std::fclose(f);
    return {code, read_text(out)};
  }
  static std::string read_text(const std::string& path) {
    std::ifstream f(path);
    return std::string(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
  }
};

TEST_F(FalconBringup, ListProbeCalibrateMonitorAndJogWorkOnIt) {
  start(options());
  ASSERT_FALSE(HasFatalFailure());
  arm_.reset();  // the tools open the Falcon themselves
  const std::string cfg = write_config();

  auto [code, out] = run([](std::FILE* f) { return tools::run_list(f); });
  EXPECT_EQ(code, 0);
  EXPECT_NE(out.find("0403:cb48  bus 001 address 002"), std::string::npos) << out;
  EXPECT_NE(out.find("Novint Falcon: hw_configs/novint_falcon.toml"), std::string::npos) << out;

  std::tie(code, out) = run([&](std::FILE* f) { return tools::run_probe(cfg, f); });
  EXPECT_EQ(code, 0) << out;
  EXPECT_NE(out.find("falcon arm 'novint-falcon', 3 joints, delta kinematics"), std::string::npos) << out;
  EXPECT_NE(out.find("status 0x8"), std::string::npos) << out;  // homing mode, nothing homed yet
  EXPECT_NE(out.find("not homed (status bits 0..2)"), std::string::npos) << out;
  EXPECT_EQ(emu_->snapshot().uploads_completed, 1u);

  // calibrate homes it: the hand strokes through the switches while it runs.
  std::atomic<bool> done{false};
  std::thread hand([&] {
    for (int i = 0; !done; ++i) {
      emu_->with_physics([&](ArmPhysics& p) { p.set_hand_target((i / 300) % 2 == 0 ? kStroke : Vec3{}); });
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
  });
  std::tie(code, out) = run([&](std::FILE* f) { return tools::run_calibrate(cfg, {}, false, f); });
  done = true;
  hand.join();
  EXPECT_EQ(code, 0) << out;
  EXPECT_NE(out.find("homed: motor 1 yes, motor 2 yes, motor 3 yes"), std::string::npos) << out;
  EXPECT_NE(out.find("Nothing to write"), std::string::npos) << out;
  EXPECT_FALSE(std::filesystem::exists(arm::calibration_path(cfg)));
  EXPECT_EQ(emu_->snapshot().uploads_completed, 1u);  // the firmware stayed: not uploaded again

  emu_->with_physics([&](ArmPhysics& p) { p.set_hand_target({0.01, 0.0, 0.0}); });
  std::tie(code, out) = run([&](std::FILE* f) { return tools::run_monitor(cfg, 0.3, 20, f); });
  EXPECT_EQ(code, 0) << out;
  EXPECT_NE(out.find("tool"), std::string::npos) << out;

  // jog: a tenth of the joint's limit for half a second; the hand lets go so the thigh can move.
  emu_->with_physics([&](ArmPhysics& p) { p.set_hand_holding(false); });
  std::tie(code, out) = run([&](std::FILE* f) { return tools::run_jog(cfg, 0, 0.05, 0.5, true, f); });
  EXPECT_EQ(code, 0) << out;
  EXPECT_NE(out.find("joint 0 leg_1 moved"), std::string::npos) << out;
  EXPECT_EQ(emu_->snapshot().motor, (std::array<std::int16_t, 3>{0, 0, 0}));  // torque off after
}

}  // namespace
}  // namespace lancet::device
