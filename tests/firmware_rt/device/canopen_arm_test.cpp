// CanopenArm against emulated CiA 402 nodes (canopen_nodes.hpp) on a virtual CAN interface. The
// bus tests need SocketCAN and an interface `vcan0` (LANCET_CAN_IFACE overrides it): run them with
// run_can_tests_in_qemu.sh, which boots a kernel with vcan in QEMU; elsewhere they skip. The codec,
// create() and missing-interface tests run anywhere.

#include "device/canopen_arm.hpp"

#include <gtest/gtest.h>
#include <linux/can.h>
#include <net/if.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <numbers>
#include <string>
#include <vector>

#include "armsim/canopen_nodes.hpp"
#include "malloc_guard.hpp"

namespace lancet::device {
namespace {

using canopen::Cia402State;
using armsim::CanopenNodeSet;

std::int64_t now_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

std::string iface_name() {
  const char* e = std::getenv("LANCET_CAN_IFACE");
  return e != nullptr && *e != '\0' ? e : "vcan0";
}

std::string config_path() {
  if (const char* p = std::getenv("LANCET_CANOPEN_CONFIG")) return p;
#ifdef LANCET_SOURCE_DIR
  return std::string(LANCET_SOURCE_DIR) + "/hw_configs/canopen_arm.toml";
#else
  return "hw_configs/canopen_arm.toml";
#endif
}

// hw_configs/canopen_arm.toml on the test interface, with a 50 ms heartbeat so that a lost one
// shows within 100 ms, and a 4 ms SYNC (LANCET_CAN_SYNC_US overrides it): in a QEMU TCG guest one
// SYNC → TPDO round trip takes 0.5–1 ms, too close to the config's 1 ms.
arm::ArmConfig test_config() {
  auto c = arm::load_arm_config(config_path());
  if (!c.ok()) {
    ADD_FAILURE() << c.error().message;
    return {};
  }
  arm::ArmConfig cfg = std::move(c).value();
  cfg.canopen->interface_name = iface_name();
  cfg.canopen->heartbeat_period = 0.05;
  const char* us = std::getenv("LANCET_CAN_SYNC_US");
  cfg.canopen->sync_period = (us != nullptr ? std::atof(us) : 4000.0) * 1e-6;
  return cfg;
}

// Waits short enough for the tests, long enough for a QEMU TCG guest.
CanopenTiming test_timing() {
  CanopenTiming t;
  t.read_budget_fraction = 0.9;
  t.sdo_timeout = 0.2;
  t.boot_timeout = 0.3;
  t.state_timeout = 0.5;
  return t;
}

bool bus_available(const std::string& iface, std::string& why) {
  const int fd = ::socket(PF_CAN, SOCK_RAW, CAN_RAW);
  if (fd < 0) {
    why = std::string("no SocketCAN in this kernel (socket(PF_CAN): ") + std::strerror(errno) +
          "); run these tests through tests/firmware_rt/device/run_can_tests_in_qemu.sh";
    return false;
  }
  ifreq ifr{};
  std::snprintf(ifr.ifr_name, sizeof ifr.ifr_name, "%s", iface.c_str());
  const bool ok = ::ioctl(fd, SIOCGIFINDEX, &ifr) == 0;
  if (!ok) why = "no CAN interface '" + iface + "' (" + std::strerror(errno) + "): ip link add dev " + iface + " type vcan";
  ::close(fd);
  return ok;
}

// Joint torque → ‰ of the rated torque, written out independently of the driver's helper.
double expected_per_mille(const arm::ArmConfig& cfg, int j, double tau) {
  const auto& jc = cfg.joints[static_cast<std::size_t>(j)];
  const auto& a = cfg.actuators[static_cast<std::size_t>(j)];
  const double output = jc.type == arm::JointType::kRevolute ? tau : tau * jc.lead / (2 * std::numbers::pi);
  const double motor_nm = jc.direction * output / jc.gear_ratio;
  const double rated_mnm = std::round(a.torque_constant * a.continuous_current * 1000);
  return std::round(motor_nm * 1000 / rated_mnm * 1000);
}

// ---------------------------------------------------------------------------------------------
// Anywhere

TEST(CanopenCodec, StatuswordStatesAndTheWayToOperationEnabled) {
  EXPECT_EQ(canopen::cia402_state(0x0200), Cia402State::kNotReadyToSwitchOn);
  EXPECT_EQ(canopen::cia402_state(0x0250), Cia402State::kSwitchOnDisabled);
  EXPECT_EQ(canopen::cia402_state(0x0231), Cia402State::kReadyToSwitchOn);
  EXPECT_EQ(canopen::cia402_state(0x0233), Cia402State::kSwitchedOn);
  EXPECT_EQ(canopen::cia402_state(0x0637), Cia402State::kOperationEnabled);
  EXPECT_EQ(canopen::cia402_state(0x0217), Cia402State::kQuickStopActive);
  EXPECT_EQ(canopen::cia402_state(0x021F), Cia402State::kFaultReactionActive);
  EXPECT_EQ(canopen::cia402_state(0x0218), Cia402State::kFault);
  // shutdown → switch on → enable operation; a fault needs a rising edge of bit 7.
  EXPECT_EQ(canopen::controlword_toward_enabled(0x0250, 0), canopen::kCwShutdown);
  EXPECT_EQ(canopen::controlword_toward_enabled(0x0231, 0x06), canopen::kCwSwitchOn);
  EXPECT_EQ(canopen::controlword_toward_enabled(0x0233, 0x07), canopen::kCwEnableOperation);
  EXPECT_EQ(canopen::controlword_toward_enabled(0x0237, 0x0F), canopen::kCwEnableOperation);
  EXPECT_EQ(canopen::controlword_toward_enabled(0x0218, 0x0F), canopen::kCwFaultReset);
  EXPECT_EQ(canopen::controlword_toward_enabled(0x0218, 0x80), 0x0000);
  EXPECT_EQ(canopen::tpdo_cob_id(1, 3), 0x183u);
  EXPECT_EQ(canopen::rpdo_cob_id(1, 3), 0x203u);
  EXPECT_STREQ(canopen::sdo_abort_text(0x06020000), "object does not exist in the object dictionary");
}

TEST(CanopenCodec, TorqueIsPerMilleOfTheRatedTorque) {
  const arm::ArmConfig cfg = test_config();
  ASSERT_EQ(cfg.joint_count(), 4);
  EXPECT_EQ(canopen::rated_torque_mnm(cfg.actuators[0]), 91u);  // 0.0302 N·m/A × 3 A = 90.6 mN·m
  EXPECT_EQ(canopen::rated_torque_mnm(cfg.actuators[3]), 12u);  // 0.0115 × 1 = 11.5 mN·m
  for (int j = 0; j < 4; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const std::uint32_t rated = canopen::rated_torque_mnm(cfg.actuators[uj]);
    for (double tau : {0.3, -0.25, 2.0, 0.01}) {
      const double want = std::clamp(expected_per_mille(cfg, j, tau), -30000.0, 30000.0);
      EXPECT_EQ(canopen::torque_per_mille(cfg.joints[uj], cfg.actuators[uj], rated, 30000, tau), want) << "joint " << j << " tau " << tau;
    }
    EXPECT_EQ(canopen::torque_per_mille(cfg.joints[uj], cfg.actuators[uj], rated, 2000, 1e6), 2000 * (cfg.joints[uj].direction));
    EXPECT_EQ(canopen::torque_per_mille(cfg.joints[uj], cfg.actuators[uj], rated, 2000, std::nan("")), 0);
  }
}

TEST(CanopenArmCreate, NeedsACanopenSectionAndTheDriversObjects) {
  arm::ArmConfig cfg = test_config();
  arm::ArmConfig no_bus = cfg;
  no_bus.canopen.reset();
  auto a = CanopenArm::create(no_bus);
  ASSERT_FALSE(a.ok());
  EXPECT_NE(a.error().message.find("[bus.canopen]"), std::string::npos) << a.error().message;

  arm::ArmConfig no_position = cfg;
  auto& entries = no_position.canopen->tpdos[0].entries;
  entries.erase(std::remove_if(entries.begin(), entries.end(), [](const arm::PdoEntry& e) { return e.index == 0x6064; }), entries.end());
  auto b = CanopenArm::create(no_position);
  ASSERT_FALSE(b.ok());
  EXPECT_NE(b.error().message.find("position_actual (0x6064"), std::string::npos) << b.error().message;

  auto c = CanopenArm::create(cfg);
  ASSERT_TRUE(c.ok()) << c.error().message;
  EXPECT_EQ(c.value()->joint_count(), 4);
  EXPECT_EQ(c.value()->node(0).rated_torque_mnm, 91u);
  EXPECT_EQ(c.value()->node(0).max_torque, 2654);  // peak 241.6 mN·m over 91 mN·m, in ‰
}

TEST(CanopenArmNoBus, AMissingInterfaceGivesAClearError) {
  arm::ArmConfig cfg = test_config();
  cfg.canopen->interface_name = "lancetnocan7";
  auto a = CanopenArm::create(cfg);
  ASSERT_TRUE(a.ok()) << a.error().message;
  const Outcome o = a.value()->configure();
  ASSERT_FALSE(o.ok());
  const std::string& m = o.error->message;
  EXPECT_NE(m.find("'lancetnocan7'"), std::string::npos) << m;
  // Here (no SocketCAN) or in the guest (SocketCAN, but no such interface):
  EXPECT_TRUE(m.find("does not exist") != std::string::npos || m.find("no SocketCAN") != std::string::npos) << m;
  EXPECT_NE(m.find("errno"), std::string::npos) << m;
  EXPECT_EQ(a.value()->state(), Lifecycle::kUnconfigured);
  std::printf("  error: %s\n", m.c_str());
}

// ---------------------------------------------------------------------------------------------
// On a (virtual) CAN bus with emulated nodes

class CanopenArmBus : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string why;
    if (!bus_available(iface_name(), why)) GTEST_SKIP() << why;
    cfg_ = test_config();
    ASSERT_TRUE(cfg_.canopen.has_value());
    period_ns_ = static_cast<std::int64_t>(std::llround(cfg_.canopen->sync_period * 1e9));
  }

  void start_nodes(CanopenNodeSet::Options o = {}) {
    auto r = CanopenNodeSet::start(cfg_, o);
    ASSERT_TRUE(r.ok()) << r.error().message;
    nodes_ = std::move(r).value();
  }

  void make_arm(FaultPolicy p = {}) {
    auto a = CanopenArm::create(cfg_, p, test_timing());
    ASSERT_TRUE(a.ok()) << a.error().message;
    arm_ = std::move(a).value();
  }

  void bring_up(FaultPolicy policy = {}) {
    start_nodes();
    make_arm(policy);
    const Outcome c = arm_->configure();
    ASSERT_TRUE(c.ok()) << c.error->message;
    const Outcome a = arm_->activate();
    ASSERT_TRUE(a.ok()) << a.error->message;
    next_tick_ = now_ns();
  }

  // One servo tick at the sync period: read, then write.
  IoStatus tick(const JointCommand& cmd) {
    pace();
    const IoStatus r = arm_->read(state_);
    last_write_ = arm_->write(cmd);
    return r;
  }
  IoStatus tick() {
    JointCommand zero{};
    zero.n = 4;
    return tick(zero);
  }
  // A tick that should be good. The guest runs on an emulated CPU on a shared host: now and then a
  // round trip overruns the read budget. A timeout that leaves the device active (fewer than three
  // in a row) is counted in late_ and the tick is repeated; TearDown bounds how many there were.
  IoStatus good_tick(const JointCommand& cmd) {
    IoStatus s = IoStatus::kOk;
    for (int attempt = 0; attempt < 3; ++attempt) {
      ++ticks_;
      s = tick(cmd);
      if (s != IoStatus::kTimeout || arm_->state() != Lifecycle::kActive) return s;
      ++late_;
    }
    return s;
  }
  IoStatus good_tick() {
    JointCommand zero{};
    zero.n = 4;
    return good_tick(zero);
  }
  void TearDown() override {
    if (late_ > 0) std::printf("  %d of %d ticks were late (TPDOs after the read budget): repeated\n", late_, ticks_);
    EXPECT_LE(late_, 2 + ticks_ / 20) << "too many late round trips for the guest's load";
  }
  // Waits (up to 1 s) for the emulated nodes to have processed what was sent.
  template <class Pred>
  bool eventually(Pred pred) {
    const std::int64_t end = now_ns() + 1'000'000'000;
    while (!pred()) {
      if (now_ns() > end) return false;
      usleep(1000);
    }
    return true;
  }
  void pace() {
    const std::int64_t now = now_ns();
    if (next_tick_ == 0 || now - next_tick_ > 5 * period_ns_) next_tick_ = now;
    timespec ts{};
    ts.tv_sec = static_cast<time_t>(next_tick_ / 1'000'000'000);
    ts.tv_nsec = static_cast<long>(next_tick_ % 1'000'000'000);
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    }
    next_tick_ += period_ns_;
  }
  // Ticks until the device leaves kActive (at most `max` ticks); returns the ticks taken.
  int ticks_until_fault(const JointCommand& cmd, int max) {
    for (int i = 1; i <= max; ++i) {
      (void)tick(cmd);
      if (arm_->state() == Lifecycle::kFault) return i;
    }
    return -1;
  }
  static JointCommand torques(std::initializer_list<double> t) {
    JointCommand c{};
    for (double v : t) c.tau[static_cast<std::size_t>(c.n++)] = v;
    return c;
  }
  // Every node that can hear the host holds zero torque (`deaf`: a silent node, which hears nothing
  // and gives no torque of its own).
  void expect_all_torque_zero(const char* when, int deaf = 0) {
    for (int id : cfg_.canopen->node_ids) {
      (void)eventually([&] { return nodes_->node(id).torque_actual == 0; });
      const auto v = nodes_->node(id);
      if (id != deaf) {
        EXPECT_EQ(v.target_torque, 0) << when << ": node " << id;
      }
      EXPECT_EQ(v.torque_actual, 0) << when << ": node " << id;
    }
  }

  arm::ArmConfig cfg_;
  std::unique_ptr<CanopenNodeSet> nodes_;  // declared first: outlives the arm
  std::unique_ptr<CanopenArm> arm_;
  JointState state_{};
  IoStatus last_write_ = IoStatus::kOk;
  int ticks_ = 0, late_ = 0;
  std::int64_t period_ns_ = 1'000'000;
  std::int64_t next_tick_ = 0;
};

TEST_F(CanopenArmBus, ConfiguresTheNodesAndEnablesTheDrives) {
  start_nodes();
  make_arm();
  const Outcome c = arm_->configure();
  ASSERT_TRUE(c.ok()) << c.error->message;
  EXPECT_EQ(arm_->state(), Lifecycle::kInactive);
  for (int j = 0; j < 4; ++j) {
    const int id = cfg_.canopen->node_ids[static_cast<std::size_t>(j)];
    const auto v = nodes_->node(id);
    EXPECT_EQ(v.nmt, 0x05) << "node " << id << " operational";
    EXPECT_EQ(v.mode, 10) << "cyclic synchronous torque";
    EXPECT_EQ(v.rated_torque_mnm, canopen::rated_torque_mnm(cfg_.actuators[static_cast<std::size_t>(j)]));
    EXPECT_EQ(v.max_torque, static_cast<std::uint16_t>(arm_->node(j).max_torque));
    EXPECT_EQ(v.heartbeat_ms, 50);
    EXPECT_EQ(canopen::cia402_state(v.statusword), Cia402State::kSwitchOnDisabled);
    // The config's map: TPDO1 statusword + position every SYNC, TPDO2 inputs every 10th, RPDO1.
    EXPECT_EQ(v.tpdo[0].cob_id, canopen::tpdo_cob_id(1, id));
    EXPECT_EQ(v.tpdo[0].type, 1);
    ASSERT_EQ(v.tpdo[0].count, 2);
    EXPECT_EQ(v.tpdo[0].map[0], 0x60410010u);
    EXPECT_EQ(v.tpdo[0].map[1], 0x60640020u);
    EXPECT_EQ(v.tpdo[1].cob_id, canopen::tpdo_cob_id(2, id));
    EXPECT_EQ(v.tpdo[1].type, 10);
    EXPECT_EQ(v.tpdo[1].map[0], 0x60FD0020u);
    EXPECT_NE(v.tpdo[2].cob_id & 0x80000000u, 0u) << "unused TPDO3 left invalid";
    EXPECT_EQ(v.rpdo[0].cob_id, canopen::rpdo_cob_id(1, id));
    ASSERT_EQ(v.rpdo[0].count, 2);
    EXPECT_EQ(v.rpdo[0].map[0], 0x60400010u);
    EXPECT_EQ(v.rpdo[0].map[1], 0x60710010u);
    EXPECT_NE(v.rpdo[1].cob_id & 0x80000000u, 0u);
    EXPECT_EQ(arm_->node(j).vendor_id, CanopenNodeSet::Options{}.vendor_id);
  }
  // Reading while inactive is monitoring: allowed, moves nothing.
  IoStatus r = IoStatus::kTimeout;
  for (int i = 0; i < 3 && r == IoStatus::kTimeout; ++i) r = arm_->read(state_);
  EXPECT_EQ(r, IoStatus::kOk);
  EXPECT_EQ(state_.status & 0xFu, 0u) << "no drive enabled yet";

  const Outcome a = arm_->activate();
  ASSERT_TRUE(a.ok()) << a.error->message;
  EXPECT_EQ(arm_->state(), Lifecycle::kActive);
  for (int id : cfg_.canopen->node_ids) {
    EXPECT_EQ(canopen::cia402_state(nodes_->node(id).statusword), Cia402State::kOperationEnabled) << "node " << id;
  }
  next_tick_ = now_ns();
  EXPECT_EQ(good_tick(), IoStatus::kOk);
  EXPECT_EQ(last_write_, IoStatus::kOk);
  EXPECT_EQ(state_.status & 0xFFFFu, 0xFu) << "all four enabled, none faulted";
}

TEST_F(CanopenArmBus, EncodersDecodeToThePhysicsJointPositions) {
  bring_up();
  const std::array<double, 4> q0 = {0.3, -0.2, 0.05, 1.0};
  nodes_->with_physics([&](ArmPhysics& p) {
    p.set_hand_holding(false);
    p.reset(q0);
  });
  for (int i = 0; i < 5; ++i) ASSERT_EQ(good_tick(), IoStatus::kOk) << "tick " << i;
  for (int j = 0; j < 4; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const std::int64_t counts = nodes_->with_physics([&](ArmPhysics& p) { return p.encoder_counts(j); });
    EXPECT_EQ(state_.counts[uj], counts) << "joint " << j;
    const double lsb = std::abs(arm::joint_position_from_counts(cfg_.joints[uj], 1) - arm::joint_position_from_counts(cfg_.joints[uj], 0));
    EXPECT_NEAR(state_.q[uj], q0[uj], lsb) << "joint " << j;
    EXPECT_NEAR(state_.qd[uj], 0.0, 1e-9) << "joint " << j;
  }
  EXPECT_LT(state_.counts[1], 0) << "negative positions survive the 32-bit field";
}

TEST_F(CanopenArmBus, PositionUnwrapsPastThe32BitField) {
  // 2^40 counts per motor revolution: 2^31 counts of the roll joint is 0.0031 rad.
  cfg_.joints[3].counts_per_rev = std::int64_t{1} << 40;
  bring_up();
  nodes_->with_physics([](ArmPhysics& p) { p.set_hand_holding(false); });
  for (int i = 0; i <= 40; ++i) {
    const std::array<double, 4> q = {0, 0, 0, 0.001 * i};
    nodes_->with_physics([&](ArmPhysics& p) { p.reset(q); });
    ASSERT_EQ(good_tick(), IoStatus::kOk) << "tick " << i;
  }
  const std::int64_t counts = nodes_->with_physics([](ArmPhysics& p) { return p.encoder_counts(3); });
  EXPECT_GT(counts, std::int64_t{1} << 33);
  EXPECT_EQ(state_.counts[3], counts);
  EXPECT_NEAR(state_.q[3], 0.04, 1e-9);
}

TEST_F(CanopenArmBus, ButtonsFollowTheButtonsNodesDigitalInputs) {
  bring_up();
  nodes_->set_digital_inputs(4, 1u << 16);  // jaw_close (config button 0)
  int i = 0;
  for (; i < 30 && state_.buttons != 1u; ++i) ASSERT_EQ(good_tick(), IoStatus::kOk);
  EXPECT_EQ(state_.buttons, 1u) << "TPDO2 comes every 10th SYNC";
  nodes_->set_digital_inputs(4, 1u << 17);  // clutch_pedal (button 1)
  for (i = 0; i < 30 && state_.buttons != 2u; ++i) ASSERT_EQ(good_tick(), IoStatus::kOk);
  EXPECT_EQ(state_.buttons, 2u);
  nodes_->set_digital_inputs(1, 0xFFFF0000u);  // another node's inputs are not the buttons
  for (i = 0; i < 12; ++i) ASSERT_EQ(good_tick(), IoStatus::kOk);
  EXPECT_EQ(state_.buttons, 2u);
}

TEST_F(CanopenArmBus, TorquesArriveAsPerMilleAndMoveTheArm) {
  bring_up();
  const std::array<double, 4> q0 = {0.0, 0.0, 0.1, 0.0};
  nodes_->with_physics([&](ArmPhysics& p) {
    p.set_hand_holding(false);
    p.reset(q0);
  });
  // Small torques: the arm must not reach its hard stops within the test (no gravity, little inertia).
  const JointCommand cmd = torques({0.01, -0.01, 0.2, 0.001});
  ASSERT_EQ(good_tick(cmd), IoStatus::kOk);
  ASSERT_EQ(good_tick(cmd), IoStatus::kOk);  // the drives apply an RPDO at the next SYNC
  for (int j = 0; j < 4; ++j) {
    const int id = cfg_.canopen->node_ids[static_cast<std::size_t>(j)];
    const double want = expected_per_mille(cfg_, j, cmd.tau[static_cast<std::size_t>(j)]);
    EXPECT_EQ(arm_->node(j).target_torque, want) << "joint " << j;
    EXPECT_EQ(nodes_->node(id).target_torque, want) << "node " << id;
    EXPECT_EQ(nodes_->node(id).torque_actual, want) << "node " << id;
  }
  for (int i = 0; i < 20; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk) << "tick " << i;
  for (int j = 0; j < 4; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const double q = nodes_->with_physics([&](ArmPhysics& p) { return p.q(j); });
    EXPECT_LT(q, cfg_.joints[uj].max - 1e-3) << "joint " << j << " off its stops";
    EXPECT_GT(q, cfg_.joints[uj].min + 1e-3) << "joint " << j << " off its stops";
    const double sign = cmd.tau[uj] > 0 ? 1.0 : -1.0;
    EXPECT_GT(sign * (q - q0[uj]), 1e-3) << "joint " << j << " moved with its torque";
    EXPECT_GT(sign * (state_.q[uj] - q0[uj]), 1e-3) << "joint " << j << " as read";
    EXPECT_GT(sign * state_.qd[uj], 0.0) << "joint " << j << " velocity estimate";
  }
}

TEST_F(CanopenArmBus, ANodeThatStopsAnsweringTimesOutToAFaultWithZeroTorque) {
  bring_up();
  const JointCommand cmd = torques({0.2, 0.2, 1.0, 0.01});
  for (int i = 0; i < 5; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk);
  EXPECT_NE(nodes_->node(1).target_torque, 0);
  nodes_->set_silent(2, true);
  EXPECT_EQ(tick(cmd), IoStatus::kTimeout);
  EXPECT_EQ(arm_->last_event().node_id, 2);
  EXPECT_EQ(arm_->last_event().cob_id, 0x182u);
  const int n = ticks_until_fault(cmd, 10);
  ASSERT_GT(n, 0);
  EXPECT_LE(n, 2) << "three timeouts in a row trip the fault";
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kTimeout);
  EXPECT_EQ(last_write_, IoStatus::kFault);
  (void)tick(cmd);  // one more SYNC: the zero torque the fault sent is applied
  expect_all_torque_zero("after the fault", 2);
  std::printf("  %s\n", arm_->describe(arm_->last_event()).c_str());

  // The node comes back; an explicit rearm brings the torque back.
  nodes_->set_silent(2, false);
  const Outcome r = arm_->rearm();
  ASSERT_TRUE(r.ok()) << r.error->message;
  next_tick_ = now_ns();
  for (int i = 0; i < 5; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk) << "tick " << i;
  EXPECT_EQ(nodes_->node(2).target_torque, expected_per_mille(cfg_, 1, 0.2));
}

TEST_F(CanopenArmBus, AMissingHeartbeatIsADisconnect) {
  bring_up();
  const JointCommand cmd = torques({0.2, 0.2, 1.0, 0.01});
  nodes_->set_heartbeat_enabled(3, false);
  const int n = ticks_until_fault(cmd, 2000);
  ASSERT_GT(n, 0);
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kDisconnected);
  EXPECT_EQ(arm_->last_event().what, CanopenEvent::What::kHeartbeatLost);
  EXPECT_EQ(arm_->last_event().node_id, 3);
  (void)tick(cmd);
  expect_all_torque_zero("after the heartbeat loss");
  std::printf("  after %d ticks: %s\n", n, arm_->describe(arm_->last_event()).c_str());
  nodes_->set_heartbeat_enabled(3, true);
  const Outcome r = arm_->rearm();
  ASSERT_TRUE(r.ok()) << r.error->message;
  next_tick_ = now_ns();
  for (int i = 0; i < 100; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk) << "tick " << i;  // > 2 heartbeat periods
}

TEST_F(CanopenArmBus, AnEmcyIsADeviceFaultAndAFaultResetRecovers) {
  bring_up();
  const JointCommand cmd = torques({0.2, 0.2, 1.0, 0.01});
  for (int i = 0; i < 3; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk);
  nodes_->inject_fault(1, 0x2310, 0x03);  // continuous over-current; error register: generic + current
  const int n = ticks_until_fault(cmd, 20);
  EXPECT_GT(n, 0);
  EXPECT_LE(n, 2) << "the EMCY is read at the next SYNC";
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kDeviceFault);
  const CanopenEvent& e = arm_->last_event();
  EXPECT_EQ(e.what, CanopenEvent::What::kEmcy);
  EXPECT_EQ(e.node_id, 1);
  EXPECT_EQ(e.emcy.error_code, 0x2310);
  EXPECT_EQ(e.emcy.error_register, 0x03);
  EXPECT_NE(arm_->describe(e).find("0x2310"), std::string::npos);
  std::printf("  %s\n", arm_->describe(e).c_str());
  (void)tick(cmd);
  expect_all_torque_zero("after the EMCY");
  EXPECT_EQ(canopen::cia402_state(nodes_->node(1).statusword), Cia402State::kFault);

  const Outcome r = arm_->rearm();
  ASSERT_TRUE(r.ok()) << r.error->message;
  EXPECT_EQ(arm_->state(), Lifecycle::kActive);
  EXPECT_EQ(nodes_->node(1).fault_resets, 1u);
  EXPECT_EQ(canopen::cia402_state(nodes_->node(1).statusword), Cia402State::kOperationEnabled);
  next_tick_ = now_ns();
  for (int i = 0; i < 5; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk) << "tick " << i;
  EXPECT_EQ(nodes_->node(1).torque_actual, expected_per_mille(cfg_, 0, 0.2));
}

TEST_F(CanopenArmBus, AShortTpdoIsAProtocolErrorThatDoesNotTripAlone) {
  bring_up();
  nodes_->corrupt_next_tpdos(2, 1);
  IoStatus s = IoStatus::kTimeout;
  for (int i = 0; i < 3 && s == IoStatus::kTimeout; ++i) s = tick();  // a late frame is reported a tick later
  EXPECT_EQ(s, IoStatus::kProtocolError);
  EXPECT_EQ(arm_->last_event().what, CanopenEvent::What::kBadLength);
  EXPECT_EQ(good_tick(), IoStatus::kOk);
  EXPECT_EQ(arm_->state(), Lifecycle::kActive);
  EXPECT_EQ(arm_->counters().protocol_errors, 1u);
}

TEST_F(CanopenArmBus, ARebootedNodeIsConfiguredAgainByRearm) {
  bring_up();
  nodes_->power_cycle(3);
  const int n = ticks_until_fault(torques({0, 0, 0, 0}), 20);
  EXPECT_GT(n, 0);
  EXPECT_LE(n, 2) << "the boot-up message is read at the next SYNC";
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kDisconnected);
  EXPECT_EQ(arm_->last_event().what, CanopenEvent::What::kNotOperational);
  EXPECT_EQ(nodes_->node(3).rated_torque_mnm, 1000u) << "the node's default after power-up";
  const Outcome r = arm_->rearm();
  ASSERT_TRUE(r.ok()) << r.error->message;
  EXPECT_EQ(nodes_->node(3).rated_torque_mnm, canopen::rated_torque_mnm(cfg_.actuators[2]));
  EXPECT_EQ(nodes_->node(3).nmt, 0x05);
  next_tick_ = now_ns();
  for (int i = 0; i < 100; ++i) ASSERT_EQ(good_tick(torques({0, 0, 0.5, 0})), IoStatus::kOk) << "tick " << i;
  EXPECT_EQ(nodes_->node(3).torque_actual, expected_per_mille(cfg_, 2, 0.5));
}

bool set_link_up(const std::string& iface, bool up) {
  const int fd = ::socket(PF_CAN, SOCK_RAW, CAN_RAW);
  if (fd < 0) return false;
  ifreq ifr{};
  std::snprintf(ifr.ifr_name, sizeof ifr.ifr_name, "%s", iface.c_str());
  bool ok = ::ioctl(fd, SIOCGIFFLAGS, &ifr) == 0;
  if (ok) {
    ifr.ifr_flags = static_cast<short>(up ? (ifr.ifr_flags | IFF_UP) : (ifr.ifr_flags & ~IFF_UP));
    ok = ::ioctl(fd, SIOCSIFFLAGS, &ifr) == 0;
  }
  ::close(fd);
  return ok;
}

TEST_F(CanopenArmBus, AnInterfaceGoingDownIsADisconnect) {
  bring_up();
  const JointCommand cmd = torques({0.01, 0.01, 0.1, 0.001});
  for (int i = 0; i < 3; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk);
  if (!set_link_up(iface_name(), false)) GTEST_SKIP() << "cannot take " << iface_name() << " down here (needs CAP_NET_ADMIN)";
  const int n = ticks_until_fault(cmd, 5);
  const bool up_again = set_link_up(iface_name(), true);
  ASSERT_TRUE(up_again);
  ASSERT_GT(n, 0);
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kDisconnected);
  EXPECT_EQ(arm_->last_event().what, CanopenEvent::What::kSocket);
  EXPECT_EQ(arm_->last_event().err_no, ENETDOWN);
  std::printf("  %s\n", arm_->describe(arm_->last_event()).c_str());
  const Outcome r = arm_->rearm();
  ASSERT_TRUE(r.ok()) << r.error->message;
  next_tick_ = now_ns();
  for (int i = 0; i < 5; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk) << "tick " << i;
}

TEST_F(CanopenArmBus, ConfigureNamesANodeThatDoesNotAnswer) {
  start_nodes();
  nodes_->set_silent(3, true);
  make_arm();
  const Outcome c = arm_->configure();
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.error->message.find("node 3 does not answer"), std::string::npos) << c.error->message;
  EXPECT_EQ(arm_->state(), Lifecycle::kUnconfigured);
  std::printf("  error: %s\n", c.error->message.c_str());
}

TEST_F(CanopenArmBus, DeactivateZeroesTorqueDisablesAndLeavesOperational) {
  bring_up();
  const JointCommand cmd = torques({0.2, 0.2, 1.0, 0.01});
  for (int i = 0; i < 3; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk);
  const Outcome d = arm_->deactivate();
  ASSERT_TRUE(d.ok()) << d.error->message;
  for (int id : cfg_.canopen->node_ids) {
    EXPECT_TRUE(eventually([&] { return nodes_->node(id).nmt == 0x7F; })) << "node " << id;
    const auto v = nodes_->node(id);
    EXPECT_EQ(canopen::cia402_state(v.statusword), Cia402State::kReadyToSwitchOn) << "node " << id;
    EXPECT_EQ(v.nmt, 0x7F) << "node " << id << " pre-operational";
    EXPECT_EQ(v.target_torque, 0);
    EXPECT_EQ(v.torque_actual, 0);
  }
  EXPECT_EQ(arm_->read(state_), IoStatus::kNotActive) << "no PDOs while pre-operational";
  const Outcome a = arm_->activate();
  ASSERT_TRUE(a.ok()) << a.error->message;
  next_tick_ = now_ns();
  for (int i = 0; i < 3; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk);
}

TEST_F(CanopenArmBus, ReadAndWriteDoNotAllocate) {
  bring_up();
  const JointCommand cmd = torques({0.01, 0.01, 0.1, 0.001});
  for (int i = 0; i < 50; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk);
  int bad = 0, late = 0;
  {
    lancet::test::MallocGuard guard;
    for (int i = 0; i < 500; ++i) {
      pace();
      const IoStatus r = arm_->read(state_);
      if (r == IoStatus::kTimeout) ++late;
      else if (r != IoStatus::kOk) ++bad;
      if (arm_->write(cmd) != IoStatus::kOk) ++bad;
    }
    EXPECT_EQ(guard.count(), 0u) << "allocations in 500 read+write ticks";
  }
  // Under AddressSanitizer the guard cannot interpose malloc (ASan owns it): only operator new is counted.
  EXPECT_TRUE(lancet::test::malloc_is_counted() || lancet::test::kAddressSanitizer) << "plain malloc not counted in this build";
  EXPECT_EQ(bad, 0);
  EXPECT_LE(late, 25);
  EXPECT_EQ(arm_->state(), Lifecycle::kActive);
  // The fault path too: a silent node, timeouts, kFault, zero torque.
  nodes_->set_silent(4, true);
  {
    lancet::test::MallocGuard guard;
    for (int i = 0; i < 10; ++i) {
      pace();
      (void)arm_->read(state_);
      (void)arm_->write(cmd);
    }
    EXPECT_EQ(guard.count(), 0u) << "allocations on the fault path";
  }
  EXPECT_EQ(arm_->state(), Lifecycle::kFault);
}

TEST_F(CanopenArmBus, BenchTickIo) {
  bring_up(FaultPolicy{1'000'000});  // count late round trips, do not stop at three in a row
  const JointCommand cmd = torques({0.01, 0.01, 0.1, 0.001});
  const char* n_env = std::getenv("LANCET_CAN_BENCH_TICKS");
  const int ticks = n_env != nullptr ? std::max(10, std::atoi(n_env)) : 1000;
  std::vector<double> us;
  us.reserve(static_cast<std::size_t>(ticks));
  int errors = 0;
  for (int i = 0; i < ticks; ++i) {
    pace();
    const std::int64_t t0 = now_ns();
    if (arm_->read(state_) != IoStatus::kOk) ++errors;
    if (arm_->write(cmd) != IoStatus::kOk) ++errors;
    us.push_back(static_cast<double>(now_ns() - t0) * 1e-3);
  }
  std::sort(us.begin(), us.end());
  auto pct = [&](double p) { return us[static_cast<std::size_t>(p * (ticks - 1))]; };
  const char* env = std::getenv("LANCET_CAN_ENV");
  std::printf(
      "{\"bench\": \"canopen_tick_io\", \"interface\": \"%s\", \"nodes\": 4, \"sync_period_us\": %.0f, \"ticks\": %d, "
      "\"p50_us\": %.1f, \"p99_us\": %.1f, \"max_us\": %.1f, \"errors\": %d, \"env\": \"%s\"}\n",
      iface_name().c_str(), cfg_.canopen->sync_period * 1e6, ticks, pct(0.5), pct(0.99), us.back(), errors,
      env != nullptr ? env : "unknown");
  EXPECT_LE(errors, ticks / 50) << "late round trips (timeouts)";
}

}  // namespace
}  // namespace lancet::device
