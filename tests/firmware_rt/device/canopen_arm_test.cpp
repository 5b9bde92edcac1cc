// CanopenArm against emulated CiA 402 nodes (canopen_nodes.hpp) on a virtual CAN interface. The
// bus tests need SocketCAN and an interface `vcan0` (LANCET_CAN_IFACE overrides it): run them with
// run_can_tests_in_qemu.sh, which boots a kernel with vcan in QEMU; elsewhere they skip. The tests
// of the programs (lancet-rt and the drive-side watchdog, lancetctl probe / monitor,
// lancet-armsim) find them in LANCET_TOOLS_DIR, which the runner sets in the guest. The codec,
// config, create() and missing-interface tests run anywhere.

#include "device/canopen_arm.hpp"

#include <gtest/gtest.h>
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <sys/mman.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <climits>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <functional>
#include <numbers>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "armsim/canopen_nodes.hpp"
#include "lancet/shared_model/shared_state.hpp"
#include "lancet/shared_model/validate.hpp"
#include "malloc_guard.hpp"
#include "process.hpp"
#include "wait.hpp"

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

// The guest is an emulated CPU on a shared host: under load the whole guest stalls now and then
// (hundreds of ms have been seen; no bound can be promised), and every thread in it with it. So
// each timeout on the bus that a test is not about is far longer than such a stall:
//
// The drive-side watchdog. The master's heartbeat goes out every kDriveWatchdogMs / 4, so a false
// trip needs the guest to stall for 3/4 of it. The watchdog tests wait for it to fire (2 s each).
constexpr int kDriveWatchdogMs = 2000;
constexpr int kMasterNodeId = 127;
// The nodes' heartbeat, and how many periods the master waits before one is overdue: 2 s, so a
// false kHeartbeatLost needs a stall of 1.75 s. Short periods keep activate() quick (it waits for
// each node's first heartbeat); the heartbeat tests are about which node is overdue and why.
constexpr int kNodeHeartbeatMs = 250;
constexpr double kHeartbeatTimeoutFactor = 8;
// lancet-rt and lancetctl wait the driver's default 2 heartbeat periods: their config says 1 s.
constexpr int kProgramHeartbeatMs = 1000;

std::chrono::milliseconds master_heartbeat_period() { return std::chrono::milliseconds(kDriveWatchdogMs / 4); }

// hw_configs/canopen_arm.toml on the test interface, with the heartbeats and the drive-side
// watchdog above and a 4 ms SYNC (LANCET_CAN_SYNC_US overrides it): in a QEMU TCG guest one SYNC →
// TPDO round trip takes 0.2–1 ms, too close to the config's 1 ms.
arm::ArmConfig test_config() {
  auto c = arm::load_arm_config(config_path());
  if (!c.ok()) {
    ADD_FAILURE() << c.error().message;
    return {};
  }
  arm::ArmConfig cfg = std::move(c).value();
  cfg.canopen->interface_name = iface_name();
  cfg.canopen->heartbeat_period = kNodeHeartbeatMs * 1e-3;
  const char* wd = std::getenv("LANCET_CAN_DRIVE_WATCHDOG_MS");  // the bench without it: 0
  cfg.canopen->drive_watchdog = (wd != nullptr ? std::atof(wd) : kDriveWatchdogMs) * 1e-3;
  cfg.canopen->master_node_id = kMasterNodeId;
  const char* us = std::getenv("LANCET_CAN_SYNC_US");
  cfg.canopen->sync_period = (us != nullptr ? std::atof(us) : 4000.0) * 1e-6;
  return cfg;
}

// Waits far longer than a stall of the guest: a test that hits one on purpose (a node that does
// not answer) pays it once. The read budget stays what the tests exercise: 0.9 of the period.
CanopenTiming test_timing() {
  CanopenTiming t;
  t.read_budget_fraction = 0.9;
  t.sdo_timeout = 2.0;
  t.boot_timeout = 3.0;
  t.state_timeout = 3.0;
  t.heartbeat_timeout_factor = kHeartbeatTimeoutFactor;
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
  const Result<void> o = a.value()->configure();
  ASSERT_FALSE(o.ok());
  const std::string& m = o.error().message;
  EXPECT_NE(m.find("'lancetnocan7'"), std::string::npos) << m;
  // Here (no SocketCAN) or in the guest (SocketCAN, but no such interface):
  EXPECT_TRUE(m.find("does not exist") != std::string::npos || m.find("no SocketCAN") != std::string::npos) << m;
  EXPECT_NE(m.find("errno"), std::string::npos) << m;
  EXPECT_EQ(a.value()->state(), Lifecycle::kUnconfigured);
  std::printf("  error: %s\n", m.c_str());
}

TEST(CanopenCodec, EmcyCodesSayWhatTheyMean) {
  EXPECT_STREQ(canopen::emcy_meaning(0x2310).text, "continuous over-current (output side)");
  EXPECT_TRUE(canopen::emcy_meaning(0x2310).specific);
  EXPECT_STREQ(canopen::emcy_meaning(0x3210).text, "DC link over-voltage");
  EXPECT_STREQ(canopen::emcy_meaning(0x4310).text, "drive over-temperature");
  EXPECT_STREQ(canopen::emcy_meaning(0x8130).text, "heartbeat / life guard error");
  EXPECT_STREQ(canopen::emcy_meaning(0x8611).text, "following error");
  EXPECT_STREQ(canopen::emcy_meaning(0x5441).text, "contactor 1 (manufacturer-specific)");
  // Unknown codes fall back to their class: the high byte, else the high nibble.
  EXPECT_STREQ(canopen::emcy_meaning(0x2399).text, "current, device output side");
  EXPECT_FALSE(canopen::emcy_meaning(0x2399).specific);
  EXPECT_STREQ(canopen::emcy_meaning(0x8F01).text, "monitoring");
  EXPECT_STREQ(canopen::emcy_meaning(0xFF42).text, "device-specific");

  char buf[112];
  canopen::Emcy e{};
  e.node_id = 1;
  e.error_code = 0x2310;
  e.error_register = 0x03;
  EXPECT_STREQ(canopen::format_emcy(buf, sizeof buf, e), "node 1: EMCY 0x2310 continuous over-current (output side), error register 0x03");
  e.error_code = 0x2399;
  EXPECT_STREQ(canopen::format_emcy(buf, sizeof buf, e), "node 1: EMCY 0x2399 (0x23xx current, device output side), error register 0x03");
  e.error_code = 0x8F01;
  EXPECT_STREQ(canopen::format_emcy(buf, sizeof buf, e), "node 1: EMCY 0x8F01 (0x8xxx monitoring), error register 0x03");
  char tiny[12];
  EXPECT_STREQ(canopen::format_emcy(tiny, sizeof tiny, e), "node 1: EMC") << "truncated, terminated";
}

TEST(CanopenCodec, InterpolationPeriodIsExactOrNothing) {
  auto ip = [](std::int64_t us) { return canopen::interpolation_period(us); };
  ASSERT_TRUE(ip(1000));
  EXPECT_EQ(ip(1000)->value, 1);
  EXPECT_EQ(ip(1000)->index, -3);
  EXPECT_EQ(ip(4000)->value, 4);
  EXPECT_EQ(ip(4000)->index, -3);
  EXPECT_EQ(ip(2500)->value, 25);
  EXPECT_EQ(ip(2500)->index, -4);
  EXPECT_EQ(ip(250)->value, 25);
  EXPECT_EQ(ip(250)->index, -5);
  EXPECT_EQ(ip(255)->value, 255);
  EXPECT_EQ(ip(255)->index, -6);
  EXPECT_EQ(ip(100000)->value, 1);
  EXPECT_EQ(ip(100000)->index, -1);
  EXPECT_FALSE(ip(333)) << "333 µs needs a value > 255";
  EXPECT_FALSE(ip(0));
  EXPECT_STREQ(canopen::mode_name(10), "cyclic synchronous torque");
  EXPECT_STREQ(canopen::mode_name(0), "no mode");
}

// The shipped file with [bus.canopen] keys replaced (added when absent, removed when the value is "").
std::string canopen_toml(const std::vector<std::pair<std::string, std::string>>& keys) {
  std::ifstream in(config_path());
  std::stringstream ss;
  ss << in.rdbuf();
  std::string out, line, section;
  std::istringstream lines(ss.str());
  while (std::getline(lines, line)) {
    if (!line.empty() && line[0] == '[') section = line.substr(0, line.find(']') + 1);
    bool replaced = false;
    if (section == "[bus.canopen]") {
      for (std::size_t k = 0; k < keys.size(); ++k) {
        const std::string& key = keys[k].first;
        if (line.rfind(key + " ", 0) == 0 || line.rfind(key + "=", 0) == 0) {
          if (!keys[k].second.empty()) out += key + " = " + keys[k].second + "\n";  // empty: the key goes
          replaced = true;
        }
      }
    }
    if (!replaced) out += line + "\n";
    if (line == "[bus.canopen]") {
      for (std::size_t k = 0; k < keys.size(); ++k) {
        // Added right below the header; a key the file has is replaced where it stands instead.
        if (!keys[k].second.empty() && ss.str().find("\n" + keys[k].first + " ") == std::string::npos) {
          out += keys[k].first + " = " + keys[k].second + "\n";
        }
      }
    }
  }
  return out;
}

std::string write_text(const std::string& path, const std::string& text) {
  std::ofstream(path) << text;
  return path;
}

TEST(CanopenConfig, MasterNodeIdAndDriveWatchdogHaveDefaultsAndLimits) {
  auto ok = arm::load_arm_config_text(canopen_toml({{"master_node_id", ""}, {"drive_watchdog_ms", ""}}), "arm.toml");
  ASSERT_TRUE(ok.ok()) << ok.error().message;
  EXPECT_EQ(ok.value().canopen->master_node_id, 127);
  EXPECT_DOUBLE_EQ(ok.value().canopen->drive_watchdog, 0.1);

  auto set = arm::load_arm_config_text(canopen_toml({{"master_node_id", "100"}, {"drive_watchdog_ms", "250"}}), "arm.toml");
  ASSERT_TRUE(set.ok()) << set.error().message;
  EXPECT_EQ(set.value().canopen->master_node_id, 100);
  EXPECT_DOUBLE_EQ(set.value().canopen->drive_watchdog, 0.25);
  auto off = arm::load_arm_config_text(canopen_toml({{"drive_watchdog_ms", "0"}}), "arm.toml");
  ASSERT_TRUE(off.ok()) << off.error().message;
  EXPECT_EQ(off.value().canopen->drive_watchdog, 0.0);

  // Each error names the file, line and column, the field, and what was expected.
  auto expect_error = [](const std::string& text, const std::string& field, const std::string& words) {
    auto r = arm::load_arm_config_text(text, "arm.toml");
    ASSERT_FALSE(r.ok()) << field;
    const std::string& m = r.error().message;
    EXPECT_TRUE(std::regex_search(m, std::regex("arm\\.toml:[0-9]+:[0-9]+: " + std::regex_replace(field, std::regex("\\."), "\\.") + ": ")))
        << m;
    EXPECT_NE(m.find(words), std::string::npos) << m;
    std::printf("  %s", m.c_str());
  };
  expect_error(canopen_toml({{"master_node_id", "3"}}), "bus.canopen.master_node_id", "no drive uses");
  expect_error(canopen_toml({{"node_ids", "[1, 2, 3, 127]"}, {"buttons_node", "1"}, {"master_node_id", ""}}),
               "bus.canopen.master_node_id", "(the default)");
  expect_error(canopen_toml({{"master_node_id", "128"}}), "bus.canopen.master_node_id", "1..127");
  expect_error(canopen_toml({{"drive_watchdog_ms", "3"}}), "bus.canopen.drive_watchdog_ms", "at least 10 ms");
  expect_error(canopen_toml({{"sync_period_us", "5000"}, {"drive_watchdog_ms", "15"}}), "bus.canopen.drive_watchdog_ms", "at least 20 ms");
  expect_error(canopen_toml({{"drive_watchdog_ms", "12.5"}}), "bus.canopen.drive_watchdog_ms", "integer");
  expect_error(canopen_toml({{"sync_period_us", "333"}}), "bus.canopen.sync_period_us", "0x60C2");
  expect_error(canopen_toml({{"sync_period_us", "1000.5"}}), "bus.canopen.sync_period_us", "whole number of microseconds");
  // Profile torque writes no 0x60C2: any whole number of µs will do.
  auto tq = arm::load_arm_config_text(canopen_toml({{"mode", "\"tq\""}, {"sync_period_us", "333"}}), "arm.toml");
  EXPECT_TRUE(tq.ok()) << tq.error().message;
}

TEST(CanopenArmCreate, RefusesAPeriodOrAMasterIdTheBusCannotUse) {
  arm::ArmConfig cfg = test_config();
  arm::ArmConfig odd = cfg;
  odd.canopen->sync_period = 333e-6;
  auto a = CanopenArm::create(odd);
  ASSERT_FALSE(a.ok());
  EXPECT_NE(a.error().message.find("0x60C2"), std::string::npos) << a.error().message;
  arm::ArmConfig clash = cfg;
  clash.canopen->master_node_id = clash.canopen->node_ids[1];
  auto b = CanopenArm::create(clash);
  ASSERT_FALSE(b.ok());
  EXPECT_NE(b.error().message.find("master_node_id"), std::string::npos) << b.error().message;
}

// ---------------------------------------------------------------------------------------------
// On a (virtual) CAN bus with emulated nodes

class CanopenArmBus : public ::testing::Test {
 protected:
  // Timeouts in a row never trip the arm in these tests (a stalled guest makes runs of late round
  // trips), except where they are the subject: that test passes its own policy. What trips at once
  // (a lost link, a heartbeat overdue, a reboot, an EMCY) still does.
  static FaultPolicy tolerant() { return FaultPolicy{1'000'000}; }

  void SetUp() override {
    std::string why;
    if (!bus_available(iface_name(), why)) GTEST_SKIP() << why;
    cfg_ = test_config();
    ASSERT_TRUE(cfg_.canopen.has_value());
    period_ns_ = static_cast<std::int64_t>(std::llround(cfg_.canopen->sync_period * 1e9));
    budget_ns_ = static_cast<std::int64_t>(std::llround(cfg_.canopen->sync_period * test_timing().read_budget_fraction * 1e9));
  }

  void start_nodes(CanopenNodeSet::Options o = {}) {
    auto r = CanopenNodeSet::start(cfg_, o);
    ASSERT_TRUE(r.ok()) << r.error().message;
    nodes_ = std::move(r).value();
  }

  void make_arm(FaultPolicy p = tolerant()) {
    auto a = CanopenArm::create(cfg_, p, test_timing());
    ASSERT_TRUE(a.ok()) << a.error().message;
    arm_ = std::move(a).value();
  }

  void bring_up(FaultPolicy policy = tolerant()) {
    start_nodes();
    make_arm(policy);
    const Result<void> c = arm_->configure();
    ASSERT_TRUE(c.ok()) << c.error().message;
    const Result<void> a = arm_->activate();
    ASSERT_TRUE(a.ok()) << a.error().message;
    next_tick_ = now_ns();
  }

  // One servo tick at the sync period: read, then write. A read that times out must be the
  // nodes' doing, never the driver's (see timeout_is_justified).
  IoStatus tick(const JointCommand& cmd) {
    pace();
    const std::int64_t t0 = now_ns();
    last_read_t0_ = t0;
    const IoStatus r = arm_->read(state_);
    if (r == IoStatus::kTimeout) {
      char why[200];
      if (!timeout_is_justified(t0, why, sizeof why)) ADD_FAILURE() << why;
    }
    last_write_ = arm_->write(cmd);
    return r;
  }
  IoStatus tick() {
    JointCommand zero{};
    zero.n = 4;
    return tick(zero);
  }
  // Whether the read that began at t0 (CLOCK_MONOTONIC) and reported kTimeout had a reason to: the
  // TPDO it names was not on the bus while it waited. The node records which SYNC each TPDO answered
  // and when its write() returned, by which time vcan has delivered the frame to every socket (in
  // the writer's softirq; only when the kernel has handed softirqs to ksoftirqd, after a stall
  // inside one, a little later: half the read budget is left for that). The read's deadline is at
  // least t0 + the budget, and the driver drains the socket once more after it. So a TPDO of this
  // SYNC sent within half the budget of t0 must have been taken: reported missing, the driver lost
  // it. A stall of the guest only makes TPDOs later (then they are not judged), never earlier.
  // Fills `why` when not justified; allocates nothing (the no-allocation test calls it).
  bool timeout_is_justified(std::int64_t t0, char* why, std::size_t n) const {
    const CanopenEvent& e = arm_->last_event();
    if (e.what != CanopenEvent::What::kMissingTpdo) {
      std::snprintf(why, n, "a read timed out without naming a missing TPDO (event %d)", static_cast<int>(e.what));
      return false;
    }
    const CanopenNodeSet::NodeView v = nodes_->node(e.node_id);
    for (const CanopenNodeSet::PdoView& p : v.tpdo) {
      if ((p.cob_id & 0x7FFu) != e.cob_id || (p.cob_id & 0x80000000u) != 0) continue;
      const std::uint64_t syncs = arm_->syncs();
      // The driver's rule for a TPDO sent every nth SYNC: missing after 2n + 1 SYNCs without one.
      const std::uint64_t slack = p.type <= 1 ? 0 : 2u * p.type + 1;
      const bool recent = p.sent_ns != 0 && p.answered_sync <= syncs && syncs - p.answered_sync <= slack;
      const bool in_time = p.type <= 1 ? p.sent_ns - t0 <= budget_ns_ / 2 : p.sent_ns <= t0;
      if (recent && in_time) {
        std::snprintf(why, n,
                      "node %d: TPDO 0x%03X answering SYNC %llu went out %.3f ms after the read began (budget %.3f ms), "
                      "yet the read reported it missing",
                      e.node_id, e.cob_id, static_cast<unsigned long long>(p.answered_sync), static_cast<double>(p.sent_ns - t0) * 1e-6,
                      static_cast<double>(budget_ns_) * 1e-6);
        return false;
      }
      return true;
    }
    std::snprintf(why, n, "the timeout names 0x%03X, which is no valid TPDO of node %d", e.cob_id, e.node_id);
    return false;
  }
  // A tick that should be good. The guest runs on an emulated CPU on a shared host: now and then a
  // round trip overruns the read budget (each such timeout checked by tick()). The tick is then
  // repeated, until one is good or the device left kActive (which it does not for timeouts under
  // the tolerant policy) or a hang.
  IoStatus good_tick(const JointCommand& cmd) {
    const std::int64_t give_up = now_ns() + std::chrono::nanoseconds(test::kHangTimeout).count();
    for (;;) {
      ++ticks_;
      const IoStatus s = tick(cmd);
      if (s != IoStatus::kOk && s != IoStatus::kTimeout) std::printf("  a tick that should be good: %s\n", bus_story().c_str());
      if (s != IoStatus::kTimeout || arm_->state() != Lifecycle::kActive || now_ns() > give_up) return s;
      ++late_;
    }
  }
  IoStatus good_tick() {
    JointCommand zero{};
    zero.n = 4;
    return good_tick(zero);
  }
  // What the driver last reported, and what each drive's watchdog saw (for failure messages).
  std::string bus_story() const {
    std::string out = std::string(to_string(arm_->state() == Lifecycle::kFault ? arm_->fault_cause() : arm_->last_event().status)) + ": " +
                      (arm_->state() == Lifecycle::kFault ? arm_->fault_detail().c_str() : arm_->last_error().c_str());
    char line[160];
    for (int id : cfg_.canopen->node_ids) {
      const auto v = nodes_->node(id);
      std::snprintf(line, sizeof line, "; node %d: statusword 0x%04X, %llu master heartbeats, longest gap %.0f ms, %llu lost (last after %.0f ms)",
                    id, v.statusword, static_cast<unsigned long long>(v.master_heartbeats), v.max_gap_ms,
                    static_cast<unsigned long long>(v.heartbeat_losses), v.last_loss_ms);
      out += line;
    }
    return out;
  }
  void TearDown() override {
    // What timeout_is_justified() relies on: the nodes number the SYNCs as the driver does (one
    // driver, the only SYNC producer, configured after the nodes started). Not after each tick: a
    // read may end on the last SYNC's late TPDOs before the nodes have heard this one.
    if (arm_ != nullptr && nodes_ != nullptr && arm_->syncs() > 0) {
      EXPECT_TRUE(eventually([&] { return nodes_->syncs_heard() == arm_->syncs(); }))
          << "the nodes heard " << nodes_->syncs_heard() << " SYNCs, the driver sent " << arm_->syncs();
    }
    // How many were late says how loaded the host was, not whether the driver works: printed.
    if (late_ > 0) std::printf("  %d of %d ticks were late (TPDOs after the read budget, each the node's doing): repeated\n", late_, ticks_);
  }
  // Waits for the emulated nodes to have processed what was sent (a deadline that catches hangs).
  template <class Pred>
  static bool eventually(Pred pred) {
    return test::eventually(pred);
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
  // Ticks until the device leaves kActive (at most `max` ticks, or until a hang); returns the
  // ticks taken, -1 when it did not.
  int ticks_until_fault(const JointCommand& cmd, int max = INT_MAX) {
    const std::int64_t give_up = now_ns() + std::chrono::nanoseconds(test::kHangTimeout).count();
    for (int i = 1; i <= max && now_ns() < give_up; ++i) {
      (void)tick(cmd);
      if (arm_->state() == Lifecycle::kFault) return i;
    }
    return -1;
  }
  // Lets more than one of the master's heartbeat periods pass: a master still producing would owe
  // a heartbeat by then, which its next read() sends (it sends one whenever one is due).
  static void sleep_past_a_master_heartbeat_period() { std::this_thread::sleep_for(master_heartbeat_period() * 5 / 4); }
  static JointCommand torques(std::initializer_list<double> t) {
    JointCommand c{};
    for (double v : t) c.tau[static_cast<std::size_t>(c.n++)] = v;
    return c;
  }
  // Every node that can hear the host holds zero torque (`deaf`: a silent node, which hears nothing
  // and gives no torque of its own).
  void expect_all_torque_zero(const char* when, int deaf = 0) {
    for (int id : cfg_.canopen->node_ids) {
      // A drive in fault gives no torque at once; the zero target the host sent counts at its SYNC.
      (void)eventually([&] {
        const auto v = nodes_->node(id);
        return v.torque_actual == 0 && (id == deaf || v.target_torque == 0);
      });
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
  std::int64_t budget_ns_ = 900'000;
  std::int64_t next_tick_ = 0;
  std::int64_t last_read_t0_ = 0;  ///< when the last tick's read() began
};

TEST_F(CanopenArmBus, ConfigureAndReadOnlyObserve) {
  start_nodes();
  const std::array<double, 4> q0 = {0.2, -0.1, 0.05, 0.5};
  nodes_->with_physics([&](ArmPhysics& p) {
    p.set_hand_holding(false);
    p.reset(q0);
  });
  make_arm();
  const Result<void> c = arm_->configure();
  ASSERT_TRUE(c.ok()) << c.error().message;
  EXPECT_EQ(arm_->state(), Lifecycle::kInactive);
  EXPECT_FALSE(arm_->pdos_running());
  for (int j = 0; j < 4; ++j) EXPECT_EQ(arm_->node(j).vendor_id, CanopenNodeSet::Options{}.vendor_id);
  // Reading while inactive is monitoring, by SDO uploads: no SYNC, no PDO, no NMT command.
  for (int i = 0; i < 3; ++i) ASSERT_EQ(arm_->read(state_), IoStatus::kOk) << arm_->last_error().c_str();
  EXPECT_EQ(state_.status & 0xFu, 0u) << "no drive enabled";
  for (int j = 0; j < 4; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    EXPECT_EQ(state_.counts[uj], nodes_->with_physics([&](ArmPhysics& p) { return p.encoder_counts(j); })) << "joint " << j;
  }
  EXPECT_EQ(arm_->syncs(), 0u);
  EXPECT_EQ(arm_->master_heartbeats(), 0u) << "no heartbeat of the master before activate";
  arm_.reset();  // destroying an observer sends nothing either
  for (int id : cfg_.canopen->node_ids) {
    const auto v = nodes_->node(id);
    EXPECT_EQ(v.nmt, 0x7F) << "node " << id << " still pre-operational, as it booted";
    EXPECT_EQ(v.sdo_downloads, 0u) << "node " << id << ": nothing written";
    EXPECT_EQ(v.nmt_commands, 0u) << "node " << id;
    EXPECT_EQ(v.rpdos, 0u) << "node " << id;
    EXPECT_EQ(v.controlword, 0u) << "node " << id;
    EXPECT_EQ(canopen::cia402_state(v.statusword), Cia402State::kSwitchOnDisabled) << "node " << id;
    EXPECT_EQ(v.heartbeat_ms, 0) << "node " << id << ": its default, untouched";
  }
}

TEST_F(CanopenArmBus, ActivateConfiguresTheNodesAndEnablesTheDrives) {
  start_nodes();
  make_arm();
  ASSERT_TRUE(arm_->configure().ok());
  const Result<void> a = arm_->activate();
  ASSERT_TRUE(a.ok()) << a.error().message;
  EXPECT_EQ(arm_->state(), Lifecycle::kActive);
  EXPECT_TRUE(arm_->pdos_running());
  const auto period_us = static_cast<std::uint32_t>(std::llround(cfg_.canopen->sync_period * 1e6));
  const auto ip = canopen::interpolation_period(period_us);
  ASSERT_TRUE(ip);
  for (int j = 0; j < 4; ++j) {
    const int id = cfg_.canopen->node_ids[static_cast<std::size_t>(j)];
    const auto v = nodes_->node(id);
    EXPECT_EQ(v.nmt, 0x05) << "node " << id << " operational";
    EXPECT_EQ(v.mode, 10) << "cyclic synchronous torque, as 0x6061 shows";
    EXPECT_EQ(arm_->node(j).mode_display, 10);
    EXPECT_EQ(v.rated_torque_mnm, canopen::rated_torque_mnm(cfg_.actuators[static_cast<std::size_t>(j)]));
    EXPECT_EQ(v.max_torque, static_cast<std::uint16_t>(arm_->node(j).max_torque));
    EXPECT_EQ(v.heartbeat_ms, kNodeHeartbeatMs);
    // The drive-side watchdog and the cycle.
    EXPECT_EQ(v.consumer, static_cast<std::uint32_t>(kMasterNodeId) << 16 | kDriveWatchdogMs) << "0x1016:1";
    EXPECT_EQ(v.abort_option, canopen::kAbortConnectionDisableVoltage) << "0x6007";
    EXPECT_EQ(v.cycle_period_us, period_us) << "0x1006";
    EXPECT_EQ(v.ip_value, ip->value) << "0x60C2:1";
    EXPECT_EQ(v.ip_index, ip->index) << "0x60C2:2";
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
    EXPECT_EQ(canopen::cia402_state(v.statusword), Cia402State::kOperationEnabled) << "node " << id;
  }
  EXPECT_GT(arm_->master_heartbeats(), 0u);
  next_tick_ = now_ns();
  EXPECT_EQ(good_tick(), IoStatus::kOk);
  EXPECT_EQ(last_write_, IoStatus::kOk);
  EXPECT_EQ(state_.status & 0xFFFFu, 0xFu) << "all four enabled, none faulted";
  // The master's heartbeat keeps coming with the ticks (one every drive watchdog / 4): tick until
  // node 1 has heard two more.
  const std::uint64_t before = nodes_->node(1).master_heartbeats;
  const std::int64_t give_up = now_ns() + std::chrono::nanoseconds(test::kHangTimeout).count();
  while (nodes_->node(1).master_heartbeats < before + 2) {
    ASSERT_LT(now_ns(), give_up) << "node 1 heard " << nodes_->node(1).master_heartbeats - before << " heartbeats of the master in "
                                 << test::kHangTimeout.count() << " s of ticks";
    ASSERT_EQ(good_tick(), IoStatus::kOk);
  }
  // Every drive hears it, and none has missed it for the watchdog time.
  for (int j = 0; j < 4; ++j) {
    const int id = cfg_.canopen->node_ids[static_cast<std::size_t>(j)];
    EXPECT_GT(nodes_->node(id).master_heartbeats, 0u) << "node " << id << " hears the master's heartbeat";
    EXPECT_EQ(nodes_->node(id).heartbeat_losses, 0u) << "node " << id;
  }
}

TEST_F(CanopenArmBus, AModeTheDriveRefusesFailsActivationNamingBoth) {
  start_nodes();
  nodes_->set_refused_mode(2, canopen::kModeCyclicSyncTorque);
  make_arm();
  ASSERT_TRUE(arm_->configure().ok());
  const Result<void> a = arm_->activate();
  ASSERT_FALSE(a.ok());
  const std::string& m = a.error().message;
  EXPECT_NE(m.find("node 2: modes of operation display (0x6061) reads 0 (no mode)"), std::string::npos) << m;
  EXPECT_NE(m.find("(0x6060) = 10 (cyclic synchronous torque)"), std::string::npos) << m;
  std::printf("  error: %s\n", m.c_str());
  EXPECT_EQ(arm_->state(), Lifecycle::kInactive);
  EXPECT_FALSE(arm_->pdos_running());
  // Back to observing: no drive enabled, no drive watching a master that is gone.
  for (int id : cfg_.canopen->node_ids) {
    const auto v = nodes_->node(id);
    EXPECT_NE(canopen::cia402_state(v.statusword), Cia402State::kOperationEnabled) << "node " << id;
    EXPECT_EQ(v.consumer & 0xFFFFu, 0u) << "node " << id << ": 0x1016:1 off again";
  }
  const std::uint64_t sent = arm_->master_heartbeats();
  EXPECT_EQ(arm_->read(state_), IoStatus::kOk) << arm_->last_error().c_str();
  sleep_past_a_master_heartbeat_period();
  EXPECT_EQ(arm_->read(state_), IoStatus::kOk);
  EXPECT_EQ(arm_->master_heartbeats(), sent) << "the master's heartbeat stopped";
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
  for (i = 0; i < 25; ++i) ASSERT_EQ(good_tick(), IoStatus::kOk);  // node 1's TPDO2 came (and was read) at least once
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
  // The velocity estimate is a finite difference of encoder counts: between two SYNCs that came
  // close together (a late tick repeated at once) a slow joint may not move a count. It must never
  // point against the torque, and must follow it over the last ticks.
  std::array<bool, 4> moved{};
  for (int i = 0; i < 20; ++i) {
    ASSERT_EQ(good_tick(cmd), IoStatus::kOk) << "tick " << i;
    for (std::size_t j = 0; j < 4 && i >= 10; ++j) {
      const double sign = cmd.tau[j] > 0 ? 1.0 : -1.0;
      EXPECT_GE(sign * state_.qd[j], 0.0) << "joint " << j << " velocity estimate, tick " << i;
      moved[j] = moved[j] || sign * state_.qd[j] > 0;
    }
  }
  for (int j = 0; j < 4; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const double q = nodes_->with_physics([&](ArmPhysics& p) { return p.q(j); });
    EXPECT_LT(q, cfg_.joints[uj].max - 1e-3) << "joint " << j << " off its stops";
    EXPECT_GT(q, cfg_.joints[uj].min + 1e-3) << "joint " << j << " off its stops";
    const double sign = cmd.tau[uj] > 0 ? 1.0 : -1.0;
    EXPECT_GT(sign * (q - q0[uj]), 1e-3) << "joint " << j << " moved with its torque";
    EXPECT_GT(sign * (state_.q[uj] - q0[uj]), 1e-3) << "joint " << j << " as read";
    EXPECT_TRUE(moved[uj]) << "joint " << j << " velocity estimate";
  }
}

// The subject is the fault policy's run of timeouts: this test has its own (eight in a row; a
// run of eight late round trips before the node goes silent would take a guest too slow for any
// of these tests). The silent node is node 1, the first the driver checks: every tick from then on
// names it, whatever other node a stalled guest makes late as well.
TEST_F(CanopenArmBus, ANodeThatStopsAnsweringTimesOutToAFaultWithZeroTorque) {
  constexpr int kRun = 8;
  bring_up(FaultPolicy{kRun});
  const JointCommand cmd = torques({0.2, 0.2, 1.0, 0.01});
  for (int i = 0; i < 5; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk);
  EXPECT_NE(nodes_->node(1).target_torque, 0);
  EXPECT_EQ(arm_->counters().consecutive_errors, 0u) << "a good read ends a run of errors";
  nodes_->set_silent(1, true);
  EXPECT_EQ(tick(cmd), IoStatus::kTimeout);
  EXPECT_EQ(arm_->last_event().node_id, 1);
  EXPECT_EQ(arm_->last_event().cob_id, 0x181u);
  EXPECT_EQ(arm_->state(), Lifecycle::kActive) << "one timeout does not trip";
  const int n = ticks_until_fault(cmd, 2 * kRun);
  ASSERT_GT(n, 0);
  EXPECT_EQ(n, kRun - 1) << kRun << " timeouts in a row trip the fault, not fewer, not more";
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kTimeout);
  EXPECT_EQ(arm_->fault_detail().node, 1);
  EXPECT_NE(std::string(arm_->fault_detail().c_str()).find("node 1: TPDO1 (0x181) missing"), std::string::npos)
      << arm_->fault_detail().c_str();
  EXPECT_EQ(last_write_, IoStatus::kFault);
  (void)tick(cmd);  // one more SYNC: the zero torque the fault sent is applied
  expect_all_torque_zero("after the fault", 1);
  std::printf("  %s\n", arm_->describe(arm_->last_event()).c_str());

  // The node comes back; an explicit rearm brings the torque back.
  nodes_->set_silent(1, false);
  const Result<void> r = arm_->rearm();
  ASSERT_TRUE(r.ok()) << r.error().message;
  next_tick_ = now_ns();
  for (int i = 0; i < 5; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk) << "tick " << i;
  EXPECT_EQ(nodes_->node(1).target_torque, expected_per_mille(cfg_, 0, 0.2));
}

TEST_F(CanopenArmBus, AMissingHeartbeatIsADisconnect) {
  bring_up();
  const JointCommand cmd = torques({0.2, 0.2, 1.0, 0.01});
  nodes_->set_heartbeat_enabled(3, false);
  const int n = ticks_until_fault(cmd);
  ASSERT_GT(n, 0);
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kDisconnected);
  EXPECT_EQ(arm_->last_event().what, CanopenEvent::What::kHeartbeatLost);
  EXPECT_EQ(arm_->last_event().node_id, 3);
  EXPECT_EQ(arm_->fault_detail().node, 3);
  EXPECT_NE(std::string(arm_->fault_detail().c_str()).find("node 3: heartbeat 0x703 overdue: none for "), std::string::npos)
      << arm_->fault_detail().c_str();
  std::printf("  %s\n", arm_->fault_detail().c_str());
  (void)tick(cmd);
  expect_all_torque_zero("after the heartbeat loss");
  std::printf("  after %d ticks: %s\n", n, arm_->describe(arm_->last_event()).c_str());
  nodes_->set_heartbeat_enabled(3, true);
  const Result<void> r = arm_->rearm();
  ASSERT_TRUE(r.ok()) << r.error().message;
  // Good ticks for longer than a heartbeat takes to be overdue: node 3's heartbeats are heard again.
  const std::int64_t rearmed = now_ns();
  const auto overdue_ns = static_cast<std::int64_t>(kNodeHeartbeatMs * kHeartbeatTimeoutFactor * 1e6);
  next_tick_ = now_ns();
  for (int i = 0; now_ns() - rearmed < overdue_ns + 2LL * kNodeHeartbeatMs * 1'000'000; ++i) {
    ASSERT_EQ(good_tick(cmd), IoStatus::kOk) << "tick " << i << ": " << arm_->last_error().c_str();
  }
}

TEST_F(CanopenArmBus, AnEmcyIsADeviceFaultAndAFaultResetRecovers) {
  bring_up();
  const JointCommand cmd = torques({0.2, 0.2, 1.0, 0.01});
  for (int i = 0; i < 3; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk);
  // inject_fault() itself sends the EMCY: it waits in the driver's socket, ahead of any TPDO of
  // the next SYNC, so the next read finds it, however late that read's TPDOs are.
  nodes_->inject_fault(1, 0x2310, 0x03);  // continuous over-current; error register: generic + current
  const int n = ticks_until_fault(cmd, 20);
  EXPECT_EQ(n, 1) << "the EMCY is read at the next SYNC";
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kDeviceFault);
  const CanopenEvent& e = arm_->last_event();
  EXPECT_EQ(e.what, CanopenEvent::What::kEmcy);
  EXPECT_EQ(e.node_id, 1);
  EXPECT_EQ(e.emcy.error_code, 0x2310);
  EXPECT_EQ(e.emcy.error_register, 0x03);
  EXPECT_NE(arm_->describe(e).find("0x2310"), std::string::npos);
  std::printf("  %s\n", arm_->describe(e).c_str());
  // What the operator sees (lancet-rt, lancetctl): the node, the code, its meaning.
  const FaultDetail& d = arm_->fault_detail();
  EXPECT_EQ(d.status, IoStatus::kDeviceFault);
  EXPECT_EQ(d.node, 1);
  EXPECT_EQ(d.code, 0x2310u);
  EXPECT_STREQ(d.c_str(), "node 1: EMCY 0x2310 continuous over-current (output side), error register 0x03");
  (void)tick(cmd);
  expect_all_torque_zero("after the EMCY");
  EXPECT_EQ(canopen::cia402_state(nodes_->node(1).statusword), Cia402State::kFault);

  const Result<void> r = arm_->rearm();
  ASSERT_TRUE(r.ok()) << r.error().message;
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
  // A late frame is reported a tick later; a stalled guest may make more than one tick late first.
  IoStatus s = IoStatus::kTimeout;
  const std::int64_t give_up = now_ns() + std::chrono::nanoseconds(test::kHangTimeout).count();
  while (s == IoStatus::kTimeout && now_ns() < give_up) s = tick();
  EXPECT_EQ(s, IoStatus::kProtocolError);
  EXPECT_EQ(arm_->last_event().what, CanopenEvent::What::kBadLength);
  EXPECT_STREQ(arm_->last_error().c_str(), "node 2: frame 0x182 has 5 bytes, its mapping 6");
  EXPECT_EQ(good_tick(), IoStatus::kOk);
  EXPECT_EQ(arm_->state(), Lifecycle::kActive);
  EXPECT_EQ(arm_->counters().protocol_errors, 1u);
}

TEST_F(CanopenArmBus, ARebootedNodeIsConfiguredAgainByRearm) {
  bring_up();
  // power_cycle() itself sends the boot-up message: the next read finds it (as the EMCY test says).
  nodes_->power_cycle(3);
  const int n = ticks_until_fault(torques({0, 0, 0, 0}), 20);
  EXPECT_EQ(n, 1) << "the boot-up message is read at the next SYNC";
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kDisconnected);
  EXPECT_EQ(arm_->last_event().what, CanopenEvent::What::kNotOperational);
  EXPECT_STREQ(arm_->fault_detail().c_str(), "node 3: boot-up message (0x703): the node rebooted");
  EXPECT_EQ(nodes_->node(3).rated_torque_mnm, 1000u) << "the node's default after power-up";
  const Result<void> r = arm_->rearm();
  ASSERT_TRUE(r.ok()) << r.error().message;
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
  EXPECT_TRUE(arm_->link_lost());
  EXPECT_NE(std::string(arm_->fault_detail().c_str()).find("socket: Network is down (errno 100)"), std::string::npos)
      << arm_->fault_detail().c_str();
  std::printf("  %s\n", arm_->describe(arm_->last_event()).c_str());
  const Result<void> r = arm_->rearm();
  ASSERT_TRUE(r.ok()) << r.error().message;
  next_tick_ = now_ns();
  for (int i = 0; i < 5; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk) << "tick " << i;
}

TEST_F(CanopenArmBus, ConfigureNamesANodeThatDoesNotAnswer) {
  start_nodes();
  nodes_->set_silent(3, true);
  make_arm();
  const Result<void> c = arm_->configure();
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.error().message.find("node 3 does not answer"), std::string::npos) << c.error().message;
  EXPECT_EQ(arm_->state(), Lifecycle::kUnconfigured);
  std::printf("  error: %s\n", c.error().message.c_str());
}

TEST_F(CanopenArmBus, DeactivateZeroesTorqueDisablesAndLeavesOperational) {
  bring_up();
  const JointCommand cmd = torques({0.2, 0.2, 1.0, 0.01});
  for (int i = 0; i < 3; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk);
  const Result<void> d = arm_->deactivate();
  ASSERT_TRUE(d.ok()) << d.error().message;
  for (int id : cfg_.canopen->node_ids) {
    EXPECT_TRUE(eventually([&] { return nodes_->node(id).nmt == 0x7F; })) << "node " << id;
    const auto v = nodes_->node(id);
    EXPECT_EQ(canopen::cia402_state(v.statusword), Cia402State::kReadyToSwitchOn) << "node " << id;
    EXPECT_EQ(v.nmt, 0x7F) << "node " << id << " pre-operational";
    EXPECT_EQ(v.target_torque, 0);
    EXPECT_EQ(v.torque_actual, 0);
  }
  for (int id : cfg_.canopen->node_ids) EXPECT_EQ(nodes_->node(id).consumer & 0xFFFFu, 0u) << "node " << id << ": watchdog off";
  // Inactive again: read() observes by SDO; no SYNC, and the master's heartbeat has stopped.
  const std::uint64_t syncs = arm_->syncs(), sent = arm_->master_heartbeats();
  EXPECT_EQ(arm_->read(state_), IoStatus::kOk) << arm_->last_error().c_str();
  EXPECT_EQ(state_.status & 0xFu, 0u);
  sleep_past_a_master_heartbeat_period();
  EXPECT_EQ(arm_->read(state_), IoStatus::kOk);
  EXPECT_EQ(arm_->syncs(), syncs);
  EXPECT_EQ(arm_->master_heartbeats(), sent);
  for (int id : cfg_.canopen->node_ids) EXPECT_EQ(nodes_->node(id).heartbeat_losses, 0u) << "node " << id;
  const Result<void> a = arm_->activate();
  ASSERT_TRUE(a.ok()) << a.error().message;
  next_tick_ = now_ns();
  for (int i = 0; i < 3; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk);
}

TEST_F(CanopenArmBus, AFaultBitWithoutEmcyNamesTheNodeAndItsStatusword) {
  bring_up();
  for (int i = 0; i < 3; ++i) ASSERT_EQ(good_tick(), IoStatus::kOk);
  nodes_->inject_fault(3, 0x4310, 0x09, /*with_emcy=*/false);
  const int n = ticks_until_fault(torques({0, 0, 0, 0}), 10);
  ASSERT_GT(n, 0);
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kDeviceFault);
  const FaultDetail& d = arm_->fault_detail();
  EXPECT_EQ(d.node, 3);
  EXPECT_EQ(d.code, 0x0218u);
  EXPECT_STREQ(d.c_str(), "node 3: statusword 0x0218 has the fault bit ('fault')");
}

TEST_F(CanopenArmBus, ATpdoLateWithinTheReadBudgetIsOnTime) {
  start_nodes();
  // A quarter period after the SYNC (the budget here is 0.9 of it): the reads still get it. Every
  // tick that timed out is checked: its TPDO went out past half the budget (the guest stalled), or
  // the test fails (tick()); how many did is the host's load, printed.
  for (int id : cfg_.canopen->node_ids) nodes_->set_tpdo_delay_us(id, period_ns_ / 4000);
  make_arm();
  ASSERT_TRUE(arm_->configure().ok());
  const Result<void> a = arm_->activate();
  ASSERT_TRUE(a.ok()) << a.error().message;
  next_tick_ = now_ns();
  for (int i = 0; i < 60; ++i) ASSERT_EQ(good_tick(), IoStatus::kOk) << arm_->last_error().c_str();
  // The delay took effect: a good tick's TPDOs went out at least the delay after its read began.
  // (After a late tick, a TPDO of the last SYNC may come after the next SYNC went out; CANopen
  // cannot tell it from this SYNC's, and the read takes it. So: a tick whose TPDOs all answered
  // its own SYNC.)
  auto answered_this_sync = [&] {
    for (int id : cfg_.canopen->node_ids)
      if (nodes_->node(id).tpdo[0].answered_sync != arm_->syncs()) return false;
    return true;
  };
  const std::int64_t give_up = now_ns() + std::chrono::nanoseconds(test::kHangTimeout).count();
  do {
    ASSERT_LT(now_ns(), give_up);
    ASSERT_EQ(good_tick(), IoStatus::kOk) << arm_->last_error().c_str();
  } while (!answered_this_sync());
  for (int id : cfg_.canopen->node_ids) {
    const CanopenNodeSet::PdoView p = nodes_->node(id).tpdo[0];
    EXPECT_GE(p.sent_ns - last_read_t0_, period_ns_ / 4) << "node " << id << ": its TPDO1 was held back";
  }
}

// The host stops: no read, no write, so no SYNC and no heartbeat of the master. Each drive's
// watchdog must take its torque off on its own once the consumer time has passed; back on the bus,
// the master finds the cause (EMCY 0x8130), and a rearm enables the drives again.
//
// The event and its cause are asserted. Time: the drive never trips early, measured on the drive's
// own clock (from the last heartbeat it heard to its trip: a stalled guest only makes that
// longer); how late it trips after that is the scheduling of a loaded emulated guest (printed; a
// hang deadline catches a drive that never does).
TEST_F(CanopenArmBus, WhenTheMasterFallsSilentTheDrivesTakeTheirTorqueOff) {
  bring_up();
  nodes_->with_physics([](ArmPhysics& p) { p.set_hand_holding(true); });
  const JointCommand cmd = torques({0.05, 0.05, 0.5, 0.005});
  // Ticks until every drive watches the master's heartbeat: a drive arms its watchdog at the first
  // heartbeat after 0x1016:1 was written (up to a heartbeat period, drive_watchdog / 4, after activate).
  auto all_watching = [&] {
    for (int id : cfg_.canopen->node_ids)
      if (!nodes_->node(id).watching) return false;
    return true;
  };
  const std::int64_t give_up = now_ns() + std::chrono::nanoseconds(test::kHangTimeout).count();
  for (int i = 0; i < 10 || !all_watching(); ++i) {
    ASSERT_LT(now_ns(), give_up) << "the drives never armed their watchdog";
    ASSERT_EQ(good_tick(cmd), IoStatus::kOk);
  }
  for (int id : cfg_.canopen->node_ids) {
    ASSERT_NE(nodes_->node(id).torque_actual, 0) << "node " << id;
    ASSERT_EQ(nodes_->node(id).heartbeat_losses, 0u) << "node " << id;
  }
  const std::int64_t t0 = now_ns();
  const bool all = test::eventually([&] {
    for (int id : cfg_.canopen->node_ids)
      if (nodes_->node(id).heartbeat_losses == 0) return false;
    return true;
  });
  const double after_ms = static_cast<double>(now_ns() - t0) * 1e-6;
  for (int id : cfg_.canopen->node_ids) {
    const auto v = nodes_->node(id);
    ASSERT_EQ(v.heartbeat_losses, 1u) << "node " << id << (all ? "" : " never noticed");
    EXPECT_GE(v.last_loss_ms, kDriveWatchdogMs) << "node " << id << ": tripped before its consumer time";
    EXPECT_EQ(v.torque_actual, 0) << "node " << id;
    EXPECT_EQ(canopen::cia402_state(v.statusword), Cia402State::kSwitchOnDisabled) << "node " << id << ": 0x6007 = 2";
    EXPECT_EQ(v.last_emcy, canopen::kEmcyHeartbeat) << "node " << id;
    std::printf("  node %d: torque off %.0f ms after its last heartbeat of the master (watchdog %d ms)\n", id, v.last_loss_ms,
                kDriveWatchdogMs);
  }
  std::printf("  all four torque-free %.0f ms after the host stopped\n", after_ms);
  // The host comes back: the EMCYs wait in its socket, and the first read reports them.
  next_tick_ = now_ns();
  EXPECT_EQ(ticks_until_fault(cmd, 5), 1);
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kDeviceFault);
  EXPECT_EQ(arm_->fault_detail().code, canopen::kEmcyHeartbeat);
  EXPECT_NE(std::string(arm_->fault_detail().c_str()).find("EMCY 0x8130 heartbeat / life guard error"), std::string::npos)
      << arm_->fault_detail().c_str();
  std::printf("  then: %s\n", arm_->fault_detail().c_str());
  const Result<void> r = arm_->rearm();
  ASSERT_TRUE(r.ok()) << r.error().message;
  next_tick_ = now_ns();
  for (int i = 0; i < 5; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk) << "tick " << i;
  EXPECT_NE(nodes_->node(1).torque_actual, 0);
}

TEST_F(CanopenArmBus, ReconnectAfterTheInterfaceCameBackLeavesTheDrivesDisabled) {
  bring_up();
  const JointCommand cmd = torques({0.01, 0.01, 0.1, 0.001});
  for (int i = 0; i < 3; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk);
  if (!set_link_up(iface_name(), false)) GTEST_SKIP() << "cannot take " << iface_name() << " down here (needs CAP_NET_ADMIN)";
  const int n = ticks_until_fault(cmd, 5);
  EXPECT_GT(n, 0);
  EXPECT_TRUE(arm_->link_lost());
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kDisconnected);
  // While it is down, reconnect() says so and changes nothing.
  const Result<void> down = arm_->reconnect();
  EXPECT_FALSE(down.ok());
  if (!down.ok()) {
    EXPECT_NE(down.error().message.find("is down"), std::string::npos) << down.error().message;
    std::printf("  while down: %s\n", down.error().message.c_str());
  }
  EXPECT_TRUE(arm_->link_lost());
  EXPECT_EQ(arm_->state(), Lifecycle::kFault);
  ASSERT_TRUE(set_link_up(iface_name(), true));
  // The servo would keep ticking meanwhile: a faulted read reports the lost link.
  EXPECT_EQ(arm_->read(state_), IoStatus::kFault);

  const Result<void> up = arm_->reconnect();
  ASSERT_TRUE(up.ok()) << up.error().message;
  EXPECT_FALSE(arm_->link_lost());
  EXPECT_EQ(arm_->state(), Lifecycle::kFault) << "only rearm() resumes torque";
  EXPECT_EQ(arm_->counters().reconnects, 1u);
  EXPECT_TRUE(arm_->pdos_running());
  // The nodes are set up again (watchdog included) with every drive disabled, and the faulted
  // ticks that follow keep them so.
  next_tick_ = now_ns();
  for (int i = 0; i < 20; ++i) {
    (void)tick(cmd);
    EXPECT_EQ(last_write_, IoStatus::kFault);
  }
  for (int id : cfg_.canopen->node_ids) {
    const auto v = nodes_->node(id);
    EXPECT_EQ(v.nmt, 0x05) << "node " << id;
    EXPECT_NE(canopen::cia402_state(v.statusword), Cia402State::kOperationEnabled) << "node " << id;
    EXPECT_EQ(v.torque_actual, 0) << "node " << id;
    EXPECT_EQ(v.target_torque, 0) << "node " << id;
    EXPECT_EQ(v.consumer, static_cast<std::uint32_t>(kMasterNodeId) << 16 | kDriveWatchdogMs) << "node " << id;
  }
  EXPECT_EQ(state_.status & 0xFu, 0u) << "read in fault: no drive enabled";
  const Result<void> r = arm_->rearm();
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(arm_->state(), Lifecycle::kActive);
  next_tick_ = now_ns();
  for (int i = 0; i < 5; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk) << "tick " << i;
  for (int id : cfg_.canopen->node_ids) {
    EXPECT_EQ(canopen::cia402_state(nodes_->node(id).statusword), Cia402State::kOperationEnabled) << "node " << id;
  }
  EXPECT_EQ(nodes_->node(3).torque_actual, expected_per_mille(cfg_, 2, 0.1));
}

// Two arms on one bus in one process: the right arm (nodes 1..4) sends the SYNC, the left arm
// (nodes 11..14, sync_producer = false) sends none and takes its nodes' TPDOs answering the right
// arm's SYNC. Its set-up runs on the right arm's SYNCs (a thread keeps them going meanwhile, as
// lancet-rt does: CanopenArm::keep_sync); then tick by tick both read, and the left arm counts each SYNC it saw. With the
// right arm silent, the left arm's read names the missing SYNC.
TEST_F(CanopenArmBus, AnArmWithoutSyncReadsItsNodesAfterTheOtherArmsSync) {
  bring_up();
  arm::ArmConfig left_cfg = cfg_;
  left_cfg.canopen->node_ids = {11, 12, 13, 14};
  left_cfg.canopen->buttons_node = 14;
  left_cfg.canopen->master_node_id = kMasterNodeId - 1;
  left_cfg.canopen->sync_producer = false;
  auto left_nodes = CanopenNodeSet::start(left_cfg, {});
  ASSERT_TRUE(left_nodes.ok()) << left_nodes.error().message;
  auto made = CanopenArm::create(left_cfg, tolerant(), test_timing());
  ASSERT_TRUE(made.ok()) << made.error().message;
  std::unique_ptr<CanopenArm> left = std::move(made).value();
  ASSERT_TRUE(left->configure().ok());
  {
    std::atomic<bool> done{false};
    std::thread right_sync([&] {
      while (!done.load()) {
        arm_->keep_sync();
        std::this_thread::sleep_for(std::chrono::nanoseconds(period_ns_));
      }
    });
    const Result<void> a = left->activate();
    done.store(true);
    right_sync.join();
    ASSERT_TRUE(a.ok()) << a.error().message;
  }
  EXPECT_EQ(left->state(), Lifecycle::kActive);
  for (int id : left_cfg.canopen->node_ids)
    EXPECT_EQ(canopen::cia402_state(left_nodes.value()->node(id).statusword), Cia402State::kOperationEnabled) << "node " << id;

  // Tick by tick: the right arm's SYNC, then both reads. A good left read follows a SYNC it saw.
  JointCommand zero{};
  zero.n = 4;
  JointState left_state{};
  int good = 0;
  for (int t = 0; t < 50; ++t) {
    pace();
    const std::uint64_t seen_before = left->syncs();
    (void)arm_->read(state_);
    const IoStatus r = left->read(left_state);
    (void)arm_->write(zero);
    (void)left->write(zero);
    if (r != IoStatus::kOk) continue;  // a stalled guest: judged by the counts below
    ++good;
    EXPECT_GT(left->syncs(), seen_before) << "a good read without a SYNC seen";
    EXPECT_EQ(left_state.n, 4);
  }
  EXPECT_GT(good, 0) << left->last_error().c_str();
  EXPECT_EQ(left->state(), Lifecycle::kActive) << left->fault_detail().c_str();
  EXPECT_EQ(arm_->state(), Lifecycle::kActive) << arm_->fault_detail().c_str();
  // The right arm's nodes never answered a SYNC of the left arm's: there was none to answer.
  EXPECT_LE(left->syncs(), arm_->syncs());

  // No SYNC at all (the right arm not read): the left arm's TPDOs cannot come, and it says why.
  JointState js{};
  EXPECT_EQ(left->read(js), IoStatus::kTimeout);
  EXPECT_NE(std::string(left->last_error().c_str()).find("no SYNC from the bus's producer"), std::string::npos) << left->last_error().c_str();
  // Left first, on the right arm's SYNCs, then the right arm.
  {
    std::atomic<bool> done{false};
    std::thread right_sync([&] {
      while (!done.load()) {
        arm_->keep_sync();
        std::this_thread::sleep_for(std::chrono::nanoseconds(period_ns_));
      }
    });
    const Result<void> d = left->deactivate();
    done.store(true);
    right_sync.join();
    EXPECT_TRUE(d.ok()) << d.error().message;
  }
  left.reset();
}

// ---------------------------------------------------------------------------------------------
// The programs in the guest: lancet-rt, lancet-armsim, lancetctl

class CanopenPrograms : public CanopenArmBus {
 protected:
  void SetUp() override {
    CanopenArmBus::SetUp();
    if (IsSkipped()) return;
    const char* dir = std::getenv("LANCET_TOOLS_DIR");
    if (dir == nullptr || *dir == '\0') GTEST_SKIP() << "LANCET_TOOLS_DIR is not set (run_can_tests_in_qemu.sh --with ... sets it)";
    tools_ = dir;
    for (const char* t : {"lancet-rt", "lancet-armsim", "lancetctl"}) {
      ASSERT_EQ(::access((tools_ + "/" + t).c_str(), X_OK), 0) << tools_ << "/" << t << " is missing";
    }
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    base_ = std::string("/tmp/lancet_can_") + info->name();
  }
  // The test config as a file: this interface and period, the drive watchdog of the tests, and a
  // node heartbeat the programs (which wait the driver's default 2 periods) do not miss in a stall.
  std::string config_file(std::vector<std::pair<std::string, std::string>> extra = {}) {
    std::vector<std::pair<std::string, std::string>> keys = {
        {"interface", "\"" + iface_name() + "\""},
        {"sync_period_us", std::to_string(std::llround(cfg_.canopen->sync_period * 1e6))},
        {"heartbeat_ms", std::to_string(kProgramHeartbeatMs)},
        {"master_node_id", std::to_string(kMasterNodeId)},
        {"drive_watchdog_ms", std::to_string(kDriveWatchdogMs)},
    };
    for (auto& e : extra) keys.push_back(std::move(e));
    return write_text(base_ + ".toml", canopen_toml(keys));
  }
  // Waits for an event of a program (a deadline that catches hangs).
  static bool wait_for(const std::function<bool()>& pred) { return test::eventually(pred, test::kHangTimeout, std::chrono::milliseconds(2)); }
  bool all_enabled() const {
    for (int id : cfg_.canopen->node_ids)
      if (canopen::cia402_state(nodes_->node(id).statusword) != Cia402State::kOperationEnabled) return false;
    return true;
  }
  // lancet-rt on the test config, with its own segment and log.
  std::unique_ptr<test::Child> start_lancet_rt(const std::string& config, const std::string& tag) {
    shm_ = "/lancet_can_" + tag;
    ::shm_unlink(shm_.c_str());
    const std::string period = std::to_string(std::llround(cfg_.canopen->sync_period * 1e6));
    rt_log_ = base_ + "_rt.log";
    return std::make_unique<test::Child>(std::vector<std::string>{tools_ + "/lancet-rt", "--config", config, "--shm", shm_, "--no-rt",
                                                                   "--period-us", period, "-q"},
                                         rt_log_);
  }
  // lancet-rt until `steady(rt)` (it enabled the drives and they watch its heartbeat). Up to three
  // starts: lancet-rt runs the driver's default waits (an SDO reply within 100 ms; a config cannot
  // change them), which a stall of the loaded guest can outlast, and then it exits; or its start-up
  // (or a stall) outlasts the drives' watchdog, and the drives (rightly) take the torque off. Its
  // log says which. Before the next start, the killed one's watch must be over (`unwatched`).
  std::unique_ptr<test::Child> start_steady_lancet_rt(const std::string& config, const std::string& tag,
                                                      const std::function<bool(test::Child&)>& steady,
                                                      const std::function<bool()>& unwatched) {
    constexpr int kStarts = 3;
    for (int attempt = 1;; ++attempt) {
      auto rt = start_lancet_rt(config, tag + std::to_string(attempt));
      if (!rt->started()) {
        ADD_FAILURE() << "cannot start " << tools_ << "/lancet-rt";
        return rt;
      }
      if (steady(*rt)) return rt;
      std::printf("  lancet-rt start %d did not settle:\n%s", attempt, test::read_file(rt_log_).c_str());
      if (attempt == kStarts) {
        ADD_FAILURE() << "lancet-rt did not enable the drives and keep them enabled, " << kStarts << " times";
        return rt;
      }
      rt->signal(SIGKILL);
      (void)rt->wait_exit(std::chrono::seconds(5));
      ::shm_unlink(shm_.c_str());
      if (!wait_for(unwatched)) {
        ADD_FAILURE() << "the drives still watch the killed lancet-rt's heartbeat";
        return rt;
      }
    }
  }
  // Until `pred`, or false once lancet-rt has exited (then it never will be).
  static bool wait_while_running(test::Child& rt, const std::function<bool()>& pred) {
    return wait_for([&] { return pred() || rt.wait_exit(std::chrono::milliseconds(0)).has_value(); }) && pred();
  }
  void TearDown() override {
    if (!shm_.empty()) ::shm_unlink(shm_.c_str());
    CanopenArmBus::TearDown();
  }
  std::string tools_, base_, shm_, rt_log_;
};

// SIGSTOP: lancet-rt is alive but stalled (nothing it could do itself). The emulated drives (the
// code lancet-armsim runs) must go torque-free once the watchdog time has passed. Asserted: the
// event, its cause (EMCY 0x8130, 0x6007 = 2) and that no drive tripped early (on its own clock);
// how soon after the watchdog time they did is the guest's scheduling (printed; a hang deadline).
TEST_F(CanopenPrograms, LancetRtStalledByASignalLeavesTheDrivesTorqueFree) {
  start_nodes();
  const std::string config = config_file();
  auto losses = [&] {
    std::uint64_t n = 0;
    for (int id : cfg_.canopen->node_ids) n += nodes_->node(id).heartbeat_losses;
    return n;
  };
  // Steady: every drive enabled and watching lancet-rt's heartbeats as they come (two more each),
  // with no loss since this lancet-rt started.
  auto steady = [&](test::Child& rt) {
    const std::uint64_t before = losses();
    std::vector<std::uint64_t> heard;
    for (int id : cfg_.canopen->node_ids) heard.push_back(nodes_->node(id).master_heartbeats);
    const bool up = wait_while_running(rt, [&] {
      if (!all_enabled()) return false;
      for (std::size_t k = 0; k < heard.size(); ++k) {
        const auto v = nodes_->node(cfg_.canopen->node_ids[k]);
        if (!v.watching || v.master_heartbeats < heard[k] + 2) return false;
      }
      return true;
    });
    return up && all_enabled() && losses() == before;
  };
  auto unwatched = [&] {
    for (int id : cfg_.canopen->node_ids)
      if (nodes_->node(id).watching) return false;
    return true;
  };
  auto rt = start_steady_lancet_rt(config, "stop", steady, unwatched);
  ASSERT_FALSE(HasFailure());
  std::printf("  longest wait between two of lancet-rt's heartbeats so far: %.0f ms\n", nodes_->node(1).max_gap_ms);
  std::vector<std::uint64_t> before;
  for (int id : cfg_.canopen->node_ids) before.push_back(nodes_->node(id).heartbeat_losses);
  rt->signal(SIGSTOP);
  const std::int64_t t0 = now_ns();
  const bool lost = wait_for([&] {
    for (std::size_t k = 0; k < before.size(); ++k)
      if (nodes_->node(cfg_.canopen->node_ids[k]).heartbeat_losses == before[k]) return false;
    return true;
  });
  const double elapsed_ms = static_cast<double>(now_ns() - t0) * 1e-6;
  rt->signal(SIGKILL);
  (void)rt->wait_exit(std::chrono::seconds(5));
  ASSERT_TRUE(lost) << "the drives did not notice within " << test::kHangTimeout.count() << " s";
  for (int id : cfg_.canopen->node_ids) {
    const auto v = nodes_->node(id);
    EXPECT_GE(v.last_loss_ms, kDriveWatchdogMs) << "node " << id << ": tripped before its consumer time";
    EXPECT_EQ(v.torque_actual, 0) << "node " << id;
    EXPECT_EQ(canopen::cia402_state(v.statusword), Cia402State::kSwitchOnDisabled) << "node " << id;
    EXPECT_EQ(v.last_emcy, canopen::kEmcyHeartbeat) << "node " << id;
  }
  std::printf("  lancet-rt stopped: all drives torque-free after %.0f ms (node 1: %.0f ms after the last heartbeat; watchdog %d ms)\n",
              elapsed_ms, nodes_->node(1).last_loss_ms, kDriveWatchdogMs);
}

// kill -9 of lancet-rt, the nodes served by the lancet-armsim program: its stderr says when each
// drive started watching lancet-rt's heartbeat and when each went torque-free.
TEST_F(CanopenPrograms, LancetRtKilledLeavesLancetArmsimsDrivesTorqueFree) {
  const std::string config = config_file();
  const std::string sim_log = base_ + "_armsim.log";
  test::Child sim({tools_ + "/lancet-armsim", config, "--can", iface_name(), "--hand", "hold"}, sim_log);
  ASSERT_TRUE(sim.started());
  ASSERT_TRUE(wait_for([&] { return test::read_file(sim_log).find("serving") != std::string::npos; })) << test::read_file(sim_log);
  // What each drive said, in order: it started watching the master's heartbeat, or lost it.
  struct Said {
    std::size_t at = 0;  // offset in the log
    int node = 0;
    bool lost = false;
    int ms = 0, consumer_ms = 0;  // lost after, consumer time
    bool torque_off = false;      // "torque off, disable voltage (0x6007 = 2)"
  };
  const std::regex said_re(
      "node ([0-9]+): (?:watching the master heartbeat \\(0x77F, consumer time ([0-9]+) ms\\)|"
      "master heartbeat \\(0x77F\\) lost after ([0-9]+) ms \\(consumer time ([0-9]+) ms\\): ([^\n]*))");
  auto said = [&] {
    const std::string log = test::read_file(sim_log);
    std::vector<Said> out;
    for (auto it = std::sregex_iterator(log.begin(), log.end(), said_re); it != std::sregex_iterator(); ++it) {
      const std::smatch& m = *it;
      Said e;
      e.at = static_cast<std::size_t>(m.position(0));
      e.node = std::stoi(m[1].str());
      e.lost = m[3].matched;
      e.consumer_ms = std::stoi(e.lost ? m[4].str() : m[2].str());
      if (e.lost) e.ms = std::stoi(m[3].str());
      e.torque_off = e.lost && m[5].str() == "torque off, disable voltage (0x6007 = 2), EMCY 0x8130";
      out.push_back(e);
    }
    return out;
  };
  // Steady: lancet-rt is active, and each drive has started watching its heartbeat since lancet-rt
  // started (`from`) and lost none since. (A loss of an earlier start's watch can only come before
  // that: the new lancet-rt's NMT reset communication and 0x1016:1 end the old watch before its
  // heartbeat starts the new one, and the drives say things in order.)
  std::size_t from = 0;
  auto watching_since = [&](std::size_t start) {
    std::vector<bool> watching(cfg_.canopen->node_ids.size() + 1, false), lost(watching.size(), false);
    for (const Said& e : said()) {
      if (e.at < start || e.node < 1 || e.node >= static_cast<int>(watching.size())) continue;
      if (!e.lost) watching[static_cast<std::size_t>(e.node)] = true;
      else if (watching[static_cast<std::size_t>(e.node)]) lost[static_cast<std::size_t>(e.node)] = true;
    }
    int n = 0;
    for (std::size_t k = 1; k < watching.size(); ++k) n += watching[k] && !lost[k] ? 1 : 0;
    return n;
  };
  auto steady = [&](test::Child& rt) {
    from = test::read_file(sim_log).size();
    const int nodes = static_cast<int>(cfg_.canopen->node_ids.size());
    return wait_while_running(rt, [&] {
      return test::read_file(rt_log_).find("is active") != std::string::npos && watching_since(from) == nodes;
    });
  };
  // Between starts nothing to wait for: steady() ignores what the drives said before the new start.
  auto unwatched = [] { return true; };
  auto rt = start_steady_lancet_rt(config, "kill", steady, unwatched);
  ASSERT_FALSE(HasFailure()) << test::read_file(sim_log);
  ASSERT_EQ(watching_since(from), static_cast<int>(cfg_.canopen->node_ids.size())) << "a drive lost the heartbeat before the kill";
  const std::size_t killed_at = test::read_file(sim_log).size();
  rt->signal(SIGKILL);
  const std::int64_t t0 = now_ns();
  auto lost_since_kill = [&] {
    std::vector<Said> out;
    for (const Said& e : said())
      if (e.lost && e.at >= killed_at) out.push_back(e);
    return out;
  };
  const bool all = wait_for([&] { return lost_since_kill().size() >= cfg_.canopen->node_ids.size(); });
  const double elapsed_ms = static_cast<double>(now_ns() - t0) * 1e-6;
  (void)rt->wait_exit(std::chrono::seconds(5));
  sim.signal(SIGTERM);
  (void)sim.wait_exit(std::chrono::seconds(5));
  std::printf("%s", test::read_file(sim_log).c_str());
  ASSERT_TRUE(all) << "lancet-armsim did not report four drives torque-free";
  const auto lost = lost_since_kill();
  EXPECT_EQ(lost.size(), cfg_.canopen->node_ids.size()) << "one loss per drive";
  std::vector<int> nodes;
  for (const Said& e : lost) {
    nodes.push_back(e.node);
    EXPECT_TRUE(e.torque_off) << "node " << e.node << ": an enabled drive takes its torque off (0x6007 = 2)";
    EXPECT_EQ(e.consumer_ms, kDriveWatchdogMs) << "node " << e.node;
    EXPECT_GE(e.ms, kDriveWatchdogMs) << "node " << e.node << ": tripped before its consumer time";
  }
  std::sort(nodes.begin(), nodes.end());
  EXPECT_EQ(nodes, cfg_.canopen->node_ids) << "each drive once";
  std::printf("  lancet-rt killed: lancet-armsim's four drives torque-free within %.0f ms (watchdog %d ms)\n", elapsed_ms, kDriveWatchdogMs);
}

// Two arms on one bus (hw_configs/README.md, "Two arms"): lancet-armsim serves each node set (the
// right arm's nodes 1..4, the left's 11..14) on the same interface, and one lancet-rt drives both
// hands (`--hands 2 --config right.toml --left-config left.toml`). The left arm has
// sync_producer = false: the right arm's SYNC, one per tick, drives both node sets. Checked: both
// arms reach active and their bus counters advance with no fault; the bus carries one SYNC per
// tick (a second producer would double it); lancet-armsim killed under the left arm faults the
// left hand only, while the right arm stays active and its bus keeps working; with a new
// lancet-armsim there, `lancetctl rearm --hand left` brings the left arm back (its set-up on the
// right arm's SYNCs from the servo's ticks) and both run again.
// Three processes share the guest's one CPU: a stall of the guest can make three reads in a row
// late (lancet-rt's fault policy, a timeout fault), as in the one-arm tests' starts. Such a run is
// started again (up to three times, each said); any other fault, or a fault of the wrong hand
// for another reason, fails at once.
TEST_F(CanopenPrograms, TwoArmsOnOneBusShareTheRightArmsSyncAndFaultAlone) {
  const std::string right = config_file();
  const std::string left = write_text(base_ + "_left.toml", canopen_toml({
      {"interface", "\"" + iface_name() + "\""},
      {"sync_period_us", std::to_string(std::llround(cfg_.canopen->sync_period * 1e6))},
      {"heartbeat_ms", std::to_string(kProgramHeartbeatMs)},
      {"drive_watchdog_ms", std::to_string(kDriveWatchdogMs)},
      {"node_ids", "[11, 12, 13, 14]"},
      {"buttons_node", "14"},
      {"master_node_id", std::to_string(kMasterNodeId - 1)},
      {"sync_producer", "false"},
  }));
  // Every SYNC on the bus, counted from the test's own socket (it sees every frame of vcan).
  const int sync_fd = ::socket(PF_CAN, SOCK_RAW, CAN_RAW);
  ASSERT_GE(sync_fd, 0) << std::strerror(errno);
  const can_filter only_sync{0x080, CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG};
  ASSERT_EQ(::setsockopt(sync_fd, SOL_CAN_RAW, CAN_RAW_FILTER, &only_sync, sizeof only_sync), 0);
  timeval tv{0, 100'000};
  (void)::setsockopt(sync_fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  ifreq ifr{};
  std::snprintf(ifr.ifr_name, sizeof ifr.ifr_name, "%s", iface_name().c_str());
  ASSERT_EQ(::ioctl(sync_fd, SIOCGIFINDEX, &ifr), 0);
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = ifr.ifr_ifindex;
  ASSERT_EQ(::bind(sync_fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr), 0);
  std::atomic<std::uint64_t> syncs_seen{0};
  std::atomic<bool> stop_counting{false};
  std::thread counter([&] {
    while (!stop_counting.load()) {
      can_frame f{};
      if (::read(sync_fd, &f, sizeof f) == static_cast<ssize_t>(sizeof f)) syncs_seen.fetch_add(1);
    }
  });
  struct Cleanup {
    std::function<void()> f;
    ~Cleanup() { f(); }
  } cleanup{[&] {
    stop_counting.store(true);
    counter.join();
    ::close(sync_fd);
  }};

  constexpr auto kActive = DeviceLifecycle::kActive, kFault = DeviceLifecycle::kFault;
  const std::array<std::string, 2> files{right, left};
  const std::uint64_t more = 200;
  enum class Run { kPassed, kStalled, kFailed };
  // One run: both armsims, lancet-rt, the checks. kStalled: a timeout fault the run is not about,
  // or a set-up that timed out.
  auto run = [&](int attempt) -> Run {
    std::array<std::string, 2> sim_log{base_ + "_armsim_right.log", base_ + "_armsim_left.log"};
    std::array<std::unique_ptr<test::Child>, 2> sims;
    for (std::size_t h = 0; h < 2; ++h) {
      ::unlink(sim_log[h].c_str());
      sims[h] = std::make_unique<test::Child>(
          std::vector<std::string>{tools_ + "/lancet-armsim", files[h], "--can", iface_name(), "--hand", "hold"}, sim_log[h]);
      if (!sims[h]->started() || !wait_for([&] { return test::read_file(sim_log[h]).find("serving") != std::string::npos; })) {
        ADD_FAILURE() << "lancet-armsim did not start: " << test::read_file(sim_log[h]);
        return Run::kFailed;
      }
    }
    shm_ = "/lancet_can_two_arms" + std::to_string(attempt);
    ::shm_unlink(shm_.c_str());
    rt_log_ = base_ + "_rt" + std::to_string(attempt) + ".log";
    test::Child rt({tools_ + "/lancet-rt", "--hands", "2", "--config", right, "--left-config", left, "--shm", shm_, "--no-rt",
                    "--period-us", std::to_string(std::llround(cfg_.canopen->sync_period * 1e6)), "-q"},
                   rt_log_);
    if (!rt.started()) {
      ADD_FAILURE() << "cannot start lancet-rt";
      return Run::kFailed;
    }
    const auto rt_said = [&] { return test::read_file(rt_log_); };
    // lancet-rt's status (checked), until pred holds or a hand faults; false when it never held.
    RtStatus st{};
    const auto status_until = [&](const std::function<bool(const RtStatus&)>& pred, std::array<bool, 2> may_fault) {
      return wait_while_running(rt, [&] {
        auto ch = SharedChannel::open(shm_);
        if (!ch || ch.value().state().rt_status.try_read(st) != ReadStatus::kOk || wire::check(st) != nullptr) return false;
        for (std::size_t h = 0; h < 2; ++h)
          if (!may_fault[h] && st.hand[h].device_state == kFault) return true;  // stop waiting: judged below
        return pred(st);
      }) && pred(st);
    };
    // A fault of a hand that should not have one: a stall (a timeout) runs again, anything else fails.
    const auto judge = [&](const char* when, std::array<bool, 2> may_fault) {
      for (std::size_t h = 0; h < 2; ++h) {
        if (may_fault[h] || st.hand[h].device_state != kFault) continue;
        if (st.hand[h].device_fault_cause == IoStatus::kTimeout) {
          std::printf("  run %d, %s: a timeout fault of hand %zu (a stalled guest): %s\n%s", attempt, when, h, st.hand[h].fault_text,
                      rt_said().c_str());
          return Run::kStalled;
        }
        ADD_FAILURE() << when << ": hand " << h << " faulted: " << st.hand[h].fault_text << "\n" << rt_said();
        return Run::kFailed;
      }
      // lancet-rt gave up on an arm's set-up because its drives' heartbeats or TPDOs did not come
      // within the boot timeout: a guest stalled that long is a stall too (three of them fail).
      if (const std::string said = rt_said(); said.find("after NMT start and SYNC:") != std::string::npos) {
        std::printf("  run %d, %s: a set-up timeout (a stalled guest)\n%s", attempt, when, said.c_str());
        return Run::kStalled;
      }
      ADD_FAILURE() << when << ": lancet-rt ended or hung\n" << rt_said() << test::read_file(sim_log[0]) << test::read_file(sim_log[1]);
      return Run::kFailed;
    };
    const auto stop_all = [&] {
      rt.signal(SIGTERM);
      const auto code = rt.wait_exit(test::kHangTimeout);
      for (auto& sim : sims) {
        sim->signal(SIGTERM);
        (void)sim->wait_exit(std::chrono::seconds(5));
      }
      ::shm_unlink(shm_.c_str());
      return code;
    };

    if (!status_until([&](const RtStatus& s) { return s.hands == 2 && s.hand[0].device_state == kActive && s.hand[1].device_state == kActive; },
                      {false, false})) {
      const Run r = judge("start", {false, false});
      (void)stop_all();
      return r;
    }
    EXPECT_NE(rt_said().find("right hand: arm 'canopen-lap-4dof' (canopen arm"), std::string::npos) << rt_said();
    EXPECT_NE(rt_said().find("left hand: arm 'canopen-lap-4dof' (canopen arm"), std::string::npos) << rt_said();

    // Both buses read and written tick after tick, no fault; one SYNC per tick on the bus.
    const RtStatus started = st;
    const std::uint64_t syncs_at_start = syncs_seen.load();
    if (!status_until([&](const RtStatus& s) {
          for (std::size_t h = 0; h < 2; ++h)
            if (s.hand[h].bus.reads < started.hand[h].bus.reads + more || s.hand[h].bus.writes < started.hand[h].bus.writes + more) return false;
          return true;
        }, {false, false})) {
      const Run r = judge("both arms running", {false, false});
      (void)stop_all();
      return r;
    }
    const std::uint64_t syncs = syncs_seen.load() - syncs_at_start;
    const std::uint64_t right_reads = st.hand[0].bus.reads - started.hand[0].bus.reads;
    for (std::size_t h = 0; h < 2; ++h) {
      EXPECT_EQ(st.hand[h].device_state, kActive) << h << ": " << st.hand[h].fault_text;
      EXPECT_EQ(st.hand[h].bus.faults, 0u) << h << ": " << st.hand[h].fault_text;
    }
    // The counter's thread and the status are read at slightly different moments: a few SYNCs either way.
    EXPECT_LE(syncs, right_reads + 10) << "more SYNCs than the right arm's reads: a second producer?";
    EXPECT_GE(syncs + 10, right_reads) << "fewer SYNCs than the right arm's reads";
    std::printf("  %llu SYNCs on the bus during %llu ticks of the right arm and %llu of the left\n", static_cast<unsigned long long>(syncs),
                static_cast<unsigned long long>(right_reads),
                static_cast<unsigned long long>(st.hand[1].bus.reads - started.hand[1].bus.reads));

    // The left arm's drives vanish (its lancet-armsim killed): the left hand alone faults.
    const std::size_t log_from = rt_said().size();
    sims[1]->signal(SIGKILL);
    (void)sims[1]->wait_exit(std::chrono::seconds(5));
    if (!status_until([&](const RtStatus& s) { return s.hand[1].device_state == kFault; }, {false, true})) {
      const Run r = judge("left armsim killed", {false, true});
      (void)stop_all();
      return r;
    }
    const RtStatus at_fault = st;
    if (!status_until([&](const RtStatus& s) {
          return s.hand[0].bus.reads >= at_fault.hand[0].bus.reads + more && s.hand[0].bus.writes >= at_fault.hand[0].bus.writes + more;
        }, {false, true})) {
      const Run r = judge("right arm after the left's fault", {false, true});
      (void)stop_all();
      return r;
    }
    EXPECT_EQ(st.hand[0].device_state, kActive) << st.hand[0].fault_text;
    EXPECT_EQ(st.hand[0].bus.faults, at_fault.hand[0].bus.faults) << st.hand[0].fault_text;
    EXPECT_EQ(st.hand[1].device_state, kFault);
    EXPECT_TRUE(wait_for([&] { return rt_said().find("left arm: FAULT on canopen arm", log_from) != std::string::npos; })) << rt_said();
    EXPECT_EQ(rt_said().find("right arm: FAULT", log_from), std::string::npos) << rt_said();

    // The left arm's drives back (a new lancet-armsim): once lancet-rt has the link (it reconnects
    // on its own after a lost heartbeat), lancetctl re-arms the left hand, whose set-up runs on the
    // right arm's SYNCs from the servo's ticks; then both arms run again.
    sims[1] = std::make_unique<test::Child>(
        std::vector<std::string>{tools_ + "/lancet-armsim", files[1], "--can", iface_name(), "--hand", "hold"}, sim_log[1] + ".2");
    EXPECT_TRUE(wait_for([&] { return test::read_file(sim_log[1] + ".2").find("serving") != std::string::npos; }));
    if (!status_until([&](const RtStatus& s) { return s.hand[1].link_lost == 0; }, {false, true})) {
      const Run r = judge("left armsim back", {false, true});
      (void)stop_all();
      return r;
    }
    const std::string ctl_log = base_ + "_rearm" + std::to_string(attempt) + ".log";
    test::Child ctl({tools_ + "/lancetctl", "rearm", "--rt", shm_, "--hand", "left", "--yes", "--timeout", "30"}, ctl_log);
    const auto ctl_code = ctl.wait_exit(2 * test::kHangTimeout);
    EXPECT_TRUE(ctl_code.has_value() && WIFEXITED(*ctl_code) && WEXITSTATUS(*ctl_code) == 0) << test::read_file(ctl_log) << rt_said();
    const RtStatus rearmed = st;
    if (!status_until([&](const RtStatus& s) {
          for (std::size_t h = 0; h < 2; ++h)
            if (s.hand[h].device_state != kActive || s.hand[h].bus.reads < rearmed.hand[h].bus.reads + more) return false;
          return true;
        }, {false, false})) {
      const Run r = judge("left arm re-armed", {false, false});
      (void)stop_all();
      return r;
    }
    EXPECT_TRUE(wait_for([&] {
      return rt_said().find("left arm: canopen arm 'canopen-lap-4dof' on " + iface_name() + " re-armed: active", log_from) != std::string::npos;
    })) << rt_said();
    const auto code = stop_all();
    EXPECT_TRUE(code.has_value() && WIFEXITED(*code) && WEXITSTATUS(*code) == 0) << rt_said();
    return Run::kPassed;
  };
  constexpr int kRuns = 3;
  for (int attempt = 1; attempt <= kRuns; ++attempt) {
    const Run r = run(attempt);
    if (r != Run::kStalled) return;
  }
  ADD_FAILURE() << "a timeout fault (a stalled guest) in each of " << kRuns << " runs";
}

// lancetctl probe and monitor only observe: against drives whose TPDOs come a whole period after
// the SYNC they answer, and not one drive changes state.
TEST_F(CanopenPrograms, ProbeAndMonitorMoveNoDriveAndDoNotWaitForLateTpdos) {
  CanopenNodeSet::Options o;
  o.tpdo_delay_us = period_ns_ / 1000;
  start_nodes(o);
  const std::string config = config_file();
  const std::string out = base_ + "_probe.log";
  test::Child probe({tools_ + "/lancetctl", "probe", config}, out);
  const auto st = probe.wait_exit(test::kHangTimeout);
  const std::string text = test::read_file(out);
  std::printf("%s", text.c_str());
  ASSERT_TRUE(st.has_value()) << "probe hangs";
  EXPECT_TRUE(WIFEXITED(*st) && WEXITSTATUS(*st) == 0) << text;
  EXPECT_NE(text.find("joint 3 roll"), std::string::npos) << text;
  EXPECT_NE(text.find("status 0x0\n"), std::string::npos) << "no drive enabled or faulted: " << text;

  const std::string mon = base_ + "_monitor.log";
  test::Child monitor({tools_ + "/lancetctl", "monitor", config, "--duration", "1", "--rate", "20"}, mon);
  const auto ms = monitor.wait_exit(test::kHangTimeout);
  const std::string mtext = test::read_file(mon);
  ASSERT_TRUE(ms.has_value()) << "monitor hangs";
  EXPECT_TRUE(WIFEXITED(*ms) && WEXITSTATUS(*ms) == 0) << mtext;
  // Each line a good reading (how many fit in the second is the guest's speed), none a failed read.
  const std::regex sample_re("^ *[0-9]+\\.[0-9]+ s  q ");
  std::istringstream mlines(mtext);
  int samples = 0;
  for (std::string line; std::getline(mlines, line);) samples += std::regex_search(line, sample_re) ? 1 : 0;
  EXPECT_GE(samples, 1) << mtext;
  EXPECT_EQ(mtext.find("read:"), std::string::npos) << mtext;

  for (int id : cfg_.canopen->node_ids) {
    const auto v = nodes_->node(id);
    EXPECT_EQ(v.nmt, 0x7F) << "node " << id << ": NMT as it booted";
    EXPECT_EQ(canopen::cia402_state(v.statusword), Cia402State::kSwitchOnDisabled) << "node " << id;
    EXPECT_EQ(v.controlword, 0u) << "node " << id;
    EXPECT_EQ(v.sdo_downloads, 0u) << "node " << id << ": nothing written";
    EXPECT_EQ(v.nmt_commands, 0u) << "node " << id;
    EXPECT_EQ(v.rpdos, 0u) << "node " << id;
    EXPECT_GT(v.sdo_requests, 0u) << "node " << id << " was read";
  }
}

TEST_F(CanopenArmBus, ReadAndWriteDoNotAllocate) {
  bring_up();
  const JointCommand cmd = torques({0.01, 0.01, 0.1, 0.001});
  for (int i = 0; i < 50; ++i) ASSERT_EQ(good_tick(cmd), IoStatus::kOk);
  // 500 ticks paced at the SYNC period span several of the master's heartbeat periods and of the
  // nodes': sending the one and decoding the other happen under the guard too.
  int bad = 0, late = 0, unjustified = 0;
  char why[200] = "";
  const std::uint64_t master_before = arm_->master_heartbeats(), node_before = arm_->node(0).heartbeats;
  {
    lancet::test::MallocGuard guard;
    for (int i = 0; i < 500; ++i) {
      pace();
      const std::int64_t t0 = now_ns();
      const IoStatus r = arm_->read(state_);
      if (r == IoStatus::kTimeout) {
        ++late;
        if (!timeout_is_justified(t0, why, sizeof why)) ++unjustified;
      } else if (r != IoStatus::kOk) {
        ++bad;
      }
      if (arm_->write(cmd) != IoStatus::kOk) ++bad;
    }
    EXPECT_EQ(guard.count(), 0u) << "allocations in 500 read+write ticks";
  }
  // Under AddressSanitizer the guard cannot interpose malloc (ASan owns it): only operator new is counted.
  EXPECT_TRUE(lancet::test::malloc_is_counted() || lancet::test::kAddressSanitizer) << "plain malloc not counted in this build";
  EXPECT_EQ(bad, 0);
  EXPECT_EQ(unjustified, 0) << why;
  EXPECT_GT(arm_->master_heartbeats(), master_before) << "the master's heartbeat went out under the guard";
  EXPECT_GT(arm_->node(0).heartbeats, node_before) << "node 1's heartbeat was decoded under the guard";
  ASSERT_EQ(arm_->state(), Lifecycle::kActive) << bus_story();
  if (late > 0) std::printf("  %d of 500 guarded ticks were late (each the node's doing)\n", late);
  // The fault paths too: a silent node (timeouts, each reported and described; node 1, the first
  // the driver checks, so that each names it), then a node that rebooted (a disconnect: kFault and
  // zero torque at once, then the faulted reads and writes).
  nodes_->set_silent(1, true);
  int timeouts = 0;
  {
    lancet::test::MallocGuard guard;
    for (int i = 0; i < 10; ++i) {
      pace();
      if (arm_->read(state_) == IoStatus::kTimeout) ++timeouts;
      (void)arm_->write(cmd);
    }
    EXPECT_EQ(guard.count(), 0u) << "allocations on the timeout path";
  }
  EXPECT_EQ(timeouts, 10);
  EXPECT_EQ(arm_->last_event().node_id, 1);
  nodes_->set_silent(1, false);
  nodes_->power_cycle(1);
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
  EXPECT_EQ(arm_->fault_cause(), IoStatus::kDisconnected);
  expect_all_torque_zero("after the fault");
}

// A benchmark, not a test: it runs only when LANCET_CAN_BENCH_TICKS is set (the runner passes
// LANCET_CAN_* into the guest), e.g.
//   LANCET_CAN_BENCH_TICKS=1000 tests/firmware_rt/device/run_can_tests_in_qemu.sh
//       build/tests/firmware_rt/canopen_arm_test build/can-qemu --gtest_filter=CanopenArmBus.BenchTickIo
// and prints one JSON line: the per-tick read + write time inside the guest (docs/PERFORMANCE.md).
// The figures are the emulator's and the host's; what it asserts is only the accounting.
TEST_F(CanopenArmBus, BenchTickIo) {
  const char* n_env = std::getenv("LANCET_CAN_BENCH_TICKS");
  if (n_env == nullptr || *n_env == '\0') GTEST_SKIP() << "a benchmark: LANCET_CAN_BENCH_TICKS=N runs it (N ticks)";
  bring_up();  // tolerant: late round trips are counted, never a fault
  const JointCommand cmd = torques({0.01, 0.01, 0.1, 0.001});
  const int ticks = std::max(10, std::atoi(n_env));
  std::vector<double> us;
  us.reserve(static_cast<std::size_t>(ticks));
  int late = 0, bad = 0, unjustified = 0;
  char why[200] = "";
  for (int i = 0; i < ticks; ++i) {
    pace();
    const std::int64_t t0 = now_ns();
    const IoStatus r = arm_->read(state_);
    if (r == IoStatus::kTimeout) {
      ++late;
      if (!timeout_is_justified(t0, why, sizeof why)) ++unjustified;
    } else if (r != IoStatus::kOk) {
      ++bad;
    }
    if (arm_->write(cmd) != IoStatus::kOk) ++bad;
    us.push_back(static_cast<double>(now_ns() - t0) * 1e-3);
  }
  std::sort(us.begin(), us.end());
  auto pct = [&](double p) { return us[static_cast<std::size_t>(p * (ticks - 1))]; };
  const char* env = std::getenv("LANCET_CAN_ENV");
  std::printf(
      "{\"bench\": \"canopen_tick_io\", \"interface\": \"%s\", \"nodes\": 4, \"sync_period_us\": %.0f, \"ticks\": %d, "
      "\"p50_us\": %.1f, \"p99_us\": %.1f, \"max_us\": %.1f, \"late\": %d, \"env\": \"%s\"}\n",
      iface_name().c_str(), cfg_.canopen->sync_period * 1e6, ticks, pct(0.5), pct(0.99), us.back(), late,
      env != nullptr ? env : "unknown");
  EXPECT_EQ(bad, 0) << "every read is good or late";
  EXPECT_EQ(unjustified, 0) << why;
  EXPECT_EQ(arm_->state(), Lifecycle::kActive);
}

}  // namespace
}  // namespace lancet::device
