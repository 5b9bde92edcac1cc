// ModbusArm (device/modbus_arm.hpp) against real Modbus peers, no hardware:
//   - the in-process ArmServer (armsim/modbus_server.hpp) over TCP on an ephemeral loopback port,
//     and over RTU on an openpty() pair (server on the master, ModbusArm opens the slave's path);
//   - the lancet-armsim binary as a child process;
//   - a foreign server: Debian's python3-pymodbus serving the same map (tests/.../pymodbus_arm.py;
//     skipped when pymodbus is not installed);
//   - fault injection on the server side: dropped, late and corrupted replies, a cut connection,
//     encoder glitches, faults at run time (lancet-armsim --control); and a malloc guard over the
//     steady-state read/write path.
// No test depends on the machine's speed: replies come within a generous response timeout, and a
// test whose subject is a timeout has the server withhold the reply on command (hold_replies) and
// releases it when it chooses; the drive-side watchdog runs on the server's manual clock. Where a
// test waits for another thread or process, it waits for the event (test::eventually), with a
// deadline that only catches hangs.

#include <errno.h>
#include <fcntl.h>
#include <modbus.h>
#include <netinet/in.h>
#include <pty.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "arm/arm_config.hpp"
#include "armsim/modbus_server.hpp"
#include "device/modbus_arm.hpp"
#include "malloc_guard.hpp"
#include "process.hpp"
#include "temp_files.hpp"
#include "wait.hpp"

#ifndef LANCET_SOURCE_DIR
#define LANCET_SOURCE_DIR "."
#endif
#ifndef LANCET_BINARY_DIR
#define LANCET_BINARY_DIR "."
#endif

namespace {

using namespace lancet;
using namespace lancet::device;
using armsim::ArmServer;
using armsim::ArmSnapshot;
using armsim::FaultInjection;
using armsim::HandMode;
using armsim::ServerOptions;
using Clock = std::chrono::steady_clock;

const std::string kTcpConfig = std::string(LANCET_SOURCE_DIR) + "/hw_configs/modbus_tcp_arm.toml";
const std::string kSimConfig = std::string(LANCET_SOURCE_DIR) + "/hw_configs/sim_3dof.toml";
const std::string kArmsim = std::string(LANCET_BINARY_DIR) + "/firmware_rt/lancet-armsim";
const std::string kPymodbusScript = std::string(LANCET_SOURCE_DIR) + "/tests/firmware_rt/device/pymodbus_arm.py";
// A map unlike any shipped one: per-joint registers apart, f32 torque setpoints, swapped bytes,
// low words first, bit 0 = ready, bit 2 = fault, an active-low e-stop (see the file's comment).
const std::string kForeignConfig = std::string(LANCET_SOURCE_DIR) + "/tests/firmware_rt/device/data/foreign_modbus_arm.toml";

// Functional tests use a generous response timeout: the server's thread (or process) answers
// within it on a loaded two-core VM under a sanitizer. The shipped one is for the real loop.
constexpr double kTimeout = 2.0;
// While the server withholds a reply on purpose the client's timeout is shortened to this: the
// reply never comes before the test releases it, so any value gives the same outcome, quickly.
constexpr double kShortTimeout = 0.02;

// The shipped map's status bits and enable values (hw_configs/modbus_tcp_arm.toml).
constexpr std::uint32_t kFaultBit = 1u << 0, kEnabledBit = 1u << 1, kCommLostBit = 1u << 2;
constexpr std::uint32_t kEnableOn = 1, kEnableOff = 0;

arm::ArmConfig load(const std::string& path) {
  auto c = arm::load_arm_config(path);
  EXPECT_TRUE(c.ok()) << (c.ok() ? "" : c.error().message);
  return c.ok() ? c.value() : arm::ArmConfig{};
}

// The shipped config at `port`; the drive-side watchdog off unless a test is about it (a test that
// pauses between writes would otherwise see the drives go torque-free).
arm::ArmConfig tcp_config(int port, double timeout = kTimeout) {
  arm::ArmConfig c = load(kTcpConfig);
  c.modbus->port = port;
  c.modbus->response_timeout = timeout;
  c.modbus->drive_watchdog = 0;
  return c;
}

arm::ArmConfig rtu_config(const std::string& device, double timeout = kTimeout) {
  arm::ArmConfig c = load(kTcpConfig);
  c.modbus->drive_watchdog = 0;
  c.modbus->transport = arm::ModbusTransport::kRtu;
  c.modbus->host.clear();
  c.modbus->device = device;
  c.modbus->baud = 115200;
  c.modbus->parity = arm::Parity::kEven;
  c.modbus->unit_id = 17;
  c.modbus->response_timeout = timeout;
  return c;
}

ServerOptions quiet_options() {
  ServerOptions o;
  o.hand = HandMode::kHold;
  o.physics_rate = 0;     // the test steps the physics: values are deterministic
  o.manual_clock = true;  // and its clock: the drive-side watchdog never trips between two steps
  return o;
}

std::unique_ptr<ArmServer> make_server(const arm::ArmConfig& config, const ServerOptions& o = quiet_options()) {
  auto s = ArmServer::create(config, o);
  EXPECT_TRUE(s.ok()) << (s.ok() ? "" : s.error().message);
  return s.ok() ? std::move(s).value() : nullptr;
}

std::unique_ptr<ModbusArm> make_arm(const arm::ArmConfig& config, FaultPolicy policy = {}) {
  auto a = ModbusArm::create(config, policy);
  EXPECT_TRUE(a.ok()) << (a.ok() ? "" : a.error().message);
  return a.ok() ? std::move(a).value() : nullptr;
}

JointCommand torques(double t0, double t1, double t2) {
  JointCommand c;
  c.n = 3;
  c.tau[0] = t0;
  c.tau[1] = t1;
  c.tau[2] = t2;
  return c;
}

/// Joint torque of one current lsb on joint j (N·m).
double torque_lsb(const arm::ArmConfig& c, int j) {
  const auto uj = static_cast<std::size_t>(j);
  return c.modbus->registers.setpoint.scale / std::abs(arm::motor_current_for_joint_torque(c.joints[uj], c.actuators[uj], 1.0));
}

/// A TCP server on an ephemeral port and a ModbusArm pointed at it (not configured yet).
struct TcpRig {
  explicit TcpRig(const ServerOptions& o = quiet_options(), FaultPolicy policy = {}, double timeout = kTimeout) {
    arm::ArmConfig served = load(kTcpConfig);
    served.modbus->drive_watchdog = 0;
    server = make_server(served, o);
    if (!server) return;
    auto p = server->start_tcp(0);
    EXPECT_TRUE(p.ok()) << (p.ok() ? "" : p.error().message);
    if (!p.ok()) return;
    port = p.value();
    config = tcp_config(port, timeout);
    arm = make_arm(config, policy);
  }
  [[nodiscard]] bool ready() const { return server && arm; }
  bool bring_up() {
    const Result<void> c = arm->configure();
    EXPECT_TRUE(c.ok()) << c.error().message;
    if (!c.ok()) return false;
    const Result<void> a = arm->activate();
    EXPECT_TRUE(a.ok()) << a.error().message;
    return a.ok();
  }
  std::unique_ptr<ArmServer> server;
  std::unique_ptr<ModbusArm> arm;
  arm::ArmConfig config;
  int port = 0;
};

/// A pty pair in raw mode; the test keeps the slave open too so the master never sees a hang-up.
struct Pty {
  Pty() {
    char name[256] = {};
    if (openpty(&master, &slave, name, nullptr, nullptr) != 0) return;
    termios t{};
    tcgetattr(slave, &t);
    cfmakeraw(&t);
    tcsetattr(slave, TCSANOW, &t);
    path = name;
  }
  ~Pty() {
    if (master >= 0) close(master);
    if (slave >= 0) close(slave);
  }
  Pty(const Pty&) = delete;
  Pty& operator=(const Pty&) = delete;
  int master = -1, slave = -1;
  std::string path;
};

/// A port nobody listens on (bound, read, released).
int free_port() {
  const int s = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof a;
  bind(s, reinterpret_cast<sockaddr*>(&a), sizeof a);
  getsockname(s, reinterpret_cast<sockaddr*>(&a), &len);
  close(s);
  return ntohs(a.sin_port);
}

/// The port in a child's "... on 127.0.0.1:<port>" line; nullopt if it exits or never says it.
std::optional<int> wait_for_port(test::Child& child, const std::string& output) {
  const std::string marker = "' on 127.0.0.1:";
  const auto end = Clock::now() + test::kHangTimeout;
  while (Clock::now() < end) {
    const std::string text = test::read_file(output);
    const std::size_t at = text.find(marker);
    const std::size_t eol = at == std::string::npos ? std::string::npos : text.find('\n', at);
    if (eol != std::string::npos && text.find("serving '") < at) return std::stoi(text.substr(at + marker.size(), eol - at - marker.size()));
    if (child.wait_exit(std::chrono::milliseconds(20))) return std::nullopt;
  }
  return std::nullopt;
}

using test::eventually;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

std::string describe(const IoCounters& c) {
  return "reads " + std::to_string(c.reads) + ", writes " + std::to_string(c.writes) + ", ok " + std::to_string(c.ok) + ", timeouts " +
         std::to_string(c.timeouts) + ", crc errors " + std::to_string(c.crc_errors) + ", protocol errors " + std::to_string(c.protocol_errors) +
         ", disconnects " + std::to_string(c.disconnects);
}

// ---------------------------------------------------------------------------------------------
// Codec, error mapping and transaction planning

TEST(ModbusCodec, RegisterCountsAndWordOrder) {
  using arm::FieldType;
  using modbus::Layout;
  EXPECT_EQ(modbus::register_count(FieldType::kU16), 1);
  EXPECT_EQ(modbus::register_count(FieldType::kI16), 1);
  EXPECT_EQ(modbus::register_count(FieldType::kU32), 2);
  EXPECT_EQ(modbus::register_count(FieldType::kI32), 2);
  EXPECT_EQ(modbus::register_count(FieldType::kF32), 2);
  std::uint16_t r[2] = {};
  const Layout i32{FieldType::kI32, true, false}, u32{FieldType::kU32, true, false}, u32_low{FieldType::kU32, false, false};
  modbus::encode_value(i32, -2, r);
  EXPECT_EQ(r[0], 0xFFFF);
  EXPECT_EQ(r[1], 0xFFFE);
  EXPECT_EQ(modbus::decode_value(i32, r), -2);
  modbus::encode_value(u32, 0x12345678, r);
  EXPECT_EQ(r[0], 0x1234);
  EXPECT_EQ(r[1], 0x5678);
  modbus::encode_value(u32_low, 0x12345678, r);
  EXPECT_EQ(r[0], 0x5678);
  EXPECT_EQ(r[1], 0x1234);
  EXPECT_EQ(modbus::decode_value(u32_low, r), 0x12345678);
  EXPECT_EQ(modbus::decode_word(u32_low, r), 0x12345678u);
  r[0] = 0x8000;
  EXPECT_EQ(modbus::decode_value({FieldType::kI16, true, false}, r), -32768);
  EXPECT_EQ(modbus::decode_value({FieldType::kU16, true, false}, r), 32768);
  for (double v : {-2147483648.0, -1.0, 0.0, 1.0, 300000.0, 2147483647.0})
    for (bool hwf : {true, false})
      for (bool swap : {true, false}) {
        const Layout l{FieldType::kI32, hwf, swap};
        modbus::encode_value(l, v, r);
        EXPECT_EQ(modbus::decode_value(l, r), v) << hwf << swap;
      }
}

TEST(ModbusCodec, ByteSwappedRegistersAndFloats) {
  using arm::FieldType;
  std::uint16_t r[2] = {};
  // byte_order = "little": each register's two bytes swapped.
  modbus::encode_word({FieldType::kU16, true, true}, 0x1234, r);
  EXPECT_EQ(r[0], 0x3412);
  modbus::encode_value({FieldType::kU32, false, true}, 0x12345678, r);
  EXPECT_EQ(r[0], 0x7856);  // low half first, bytes swapped
  EXPECT_EQ(r[1], 0x3412);
  // f32: IEEE 754 single, in either word order.
  const float f = 1.5F;  // 0x3FC00000
  modbus::encode_value({FieldType::kF32, true, false}, f, r);
  EXPECT_EQ(r[0], 0x3FC0);
  EXPECT_EQ(r[1], 0x0000);
  modbus::encode_value({FieldType::kF32, false, true}, -0.1, r);
  EXPECT_FLOAT_EQ(static_cast<float>(modbus::decode_value({FieldType::kF32, false, true}, r)), -0.1F);
  EXPECT_EQ(modbus::encode_value({FieldType::kF32, true, false}, 0.1, r), static_cast<double>(0.1F)) << "the value stored is returned";
}

TEST(ModbusCodec, EncodeRoundsAndClampsToTheTypesRange) {
  using arm::FieldType;
  std::uint16_t r[2] = {};
  bool clamped = false;
  const modbus::Layout i16{FieldType::kI16, true, false};
  EXPECT_EQ(modbus::encode_value(i16, 40000, r, &clamped), 32767);
  EXPECT_TRUE(clamped);
  EXPECT_EQ(modbus::decode_value(i16, r), 32767);
  EXPECT_EQ(modbus::encode_value(i16, -40000, r, &clamped), -32768);
  EXPECT_TRUE(clamped);
  EXPECT_EQ(modbus::encode_value({FieldType::kU16, true, false}, -1, r, &clamped), 0);
  EXPECT_TRUE(clamped);
  EXPECT_EQ(modbus::encode_value({FieldType::kI32, true, false}, 1e12, r, &clamped), 2147483647);
  EXPECT_EQ(modbus::encode_value(i16, -5.4, r, &clamped), -5);
  EXPECT_FALSE(clamped);
  EXPECT_EQ(modbus::encode_value(i16, 2.5, r, &clamped), 2) << "nearest, ties to even";
  EXPECT_EQ(modbus::encode_value(i16, std::nan(""), r, &clamped), 0);
  EXPECT_TRUE(clamped);
}

TEST(ModbusCodec, ErrnoMapsToIoStatus) {
  EXPECT_EQ(modbus::io_status_from_errno(0), IoStatus::kOk);
  EXPECT_EQ(modbus::io_status_from_errno(ETIMEDOUT), IoStatus::kTimeout);
  EXPECT_EQ(modbus::io_status_from_errno(EMBBADCRC), IoStatus::kCrcError);
  for (int e : {EMBBADDATA, EMBBADEXC, EMBMDATA, EMBXILFUN, EMBXILADD, EMBXILVAL, EMBXSFAIL, EMBXSBUSY, EMBXGTAR, EMBBADSLAVE, EMBUNKEXC})
    EXPECT_EQ(modbus::io_status_from_errno(e), IoStatus::kProtocolError) << modbus_strerror(e);
  for (int e : {ECONNRESET, EPIPE, ECONNREFUSED, EBADF, ENOTCONN, EIO})
    EXPECT_EQ(modbus::io_status_from_errno(e), IoStatus::kDisconnected) << modbus_strerror(e);
}

TEST(ModbusCodec, PlanMergesContiguousRegistersOfOneTable) {
  using arm::RegisterTable;
  using modbus::RegisterSpan;
  // Encoders 0..5, status 6, buttons 7 of the input table: one read.
  auto b = modbus::plan_blocks({{RegisterTable::kInput, 7, 1}, {RegisterTable::kInput, 0, 6}, {RegisterTable::kInput, 6, 1}}, 125);
  ASSERT_EQ(b.size(), 1u);
  EXPECT_EQ(b[0].address, 0);
  EXPECT_EQ(b[0].count, 8);
  // A gap or another table splits; offsets pack the blocks back to back.
  b = modbus::plan_blocks({{RegisterTable::kHolding, 0, 3}, {RegisterTable::kHolding, 4, 1}, {RegisterTable::kInput, 3, 2}}, 125);
  ASSERT_EQ(b.size(), 3u);
  EXPECT_EQ(b[0].table, RegisterTable::kInput);
  EXPECT_EQ(b[0].offset, 0);
  EXPECT_EQ(b[1].table, RegisterTable::kHolding);
  EXPECT_EQ(b[1].offset, 2);
  EXPECT_EQ(b[2].address, 4);
  EXPECT_EQ(b[2].offset, 5);
  // The per-transaction limit splits too.
  b = modbus::plan_blocks({{RegisterTable::kInput, 0, 100}, {RegisterTable::kInput, 100, 100}}, 125);
  EXPECT_EQ(b.size(), 2u);
}

// ---------------------------------------------------------------------------------------------
// Create and configure

TEST(ModbusArm, CreateNeedsAModbusSection) {
  auto a = ModbusArm::create(load(kSimConfig));
  ASSERT_FALSE(a.ok());
  EXPECT_TRUE(contains(a.error().message, "[bus.modbus]")) << a.error().message;
  EXPECT_TRUE(contains(a.error().message, "sim_3dof.toml")) << a.error().message;
}

TEST(ModbusArm, TheShippedMapIsOneReadAndOneWritePerTick) {
  auto a = make_arm(tcp_config(1502));
  ASSERT_TRUE(a);
  EXPECT_EQ(a->read_transactions(), 1);   // input 0..7: encoders, status, buttons
  EXPECT_EQ(a->write_transactions(), 1);  // holding 0..4: currents, control, heartbeat
  EXPECT_EQ(a->endpoint(), "127.0.0.1:1502");
  EXPECT_EQ(a->joint_count(), 3);
  EXPECT_EQ(a->name(), "modbus arm 'modbus-bench-3dof'");

  // A control register away from the per-tick registers is not written every tick.
  arm::ArmConfig c = tcp_config(1502);
  c.modbus->registers.heartbeat->address = {3};
  c.modbus->registers.enable->address = {10};
  c.modbus->registers.fault_reset->address = {10};
  c.modbus->registers.buttons->address = {20};
  a = make_arm(c);
  ASSERT_TRUE(a);
  EXPECT_EQ(a->write_transactions(), 1);  // holding 0..3
  EXPECT_EQ(a->read_transactions(), 2);   // input 0..6, 20
}

TEST(ModbusArm, ConfigureNamesTheEndpointWhenNobodyListens) {
  const int port = free_port();
  auto a = make_arm(tcp_config(port));
  ASSERT_TRUE(a);
  const Result<void> o = a->configure();
  ASSERT_FALSE(o.ok());
  const std::string& m = o.error().message;
  EXPECT_TRUE(contains(m, "127.0.0.1:" + std::to_string(port))) << m;
  EXPECT_TRUE(contains(m, "cannot connect")) << m;
  EXPECT_TRUE(contains(m, "refused")) << m;
  EXPECT_EQ(a->state(), Lifecycle::kUnconfigured);
}

TEST(ModbusArm, ConfigureNamesTheSerialDeviceThatIsMissing) {
  auto a = make_arm(rtu_config("/dev/lancet-no-such-tty"));
  ASSERT_TRUE(a);
  const Result<void> o = a->configure();
  ASSERT_FALSE(o.ok());
  EXPECT_TRUE(contains(o.error().message, "/dev/lancet-no-such-tty")) << o.error().message;
  EXPECT_TRUE(contains(o.error().message, "cannot open the serial device")) << o.error().message;
}

TEST(ModbusArm, ConfigureFailsWhenTheArmDoesNotAnswerAndCanBeRetried) {
  ServerOptions o = quiet_options();
  o.faults.drop_replies = 1.0;  // no reply, ever: a timeout whatever its length
  TcpRig rig(o, {}, kShortTimeout);
  ASSERT_TRUE(rig.ready());
  const Result<void> c = rig.arm->configure();
  ASSERT_FALSE(c.ok());
  const std::string& m = c.error().message;
  EXPECT_TRUE(contains(m, "127.0.0.1:" + std::to_string(rig.port))) << m;
  EXPECT_TRUE(contains(m, "does not answer")) << m;
  EXPECT_TRUE(contains(m, "input registers 0..7")) << m;
  EXPECT_TRUE(contains(m, "timed out")) << m;
  EXPECT_EQ(rig.arm->state(), Lifecycle::kUnconfigured);
  rig.server->set_faults({});
  rig.arm->set_response_timeout(kTimeout);
  EXPECT_TRUE(rig.arm->configure().ok());
}

// ---------------------------------------------------------------------------------------------
// TCP against the in-process server

TEST(ModbusArmTcp, EncodersReadBackEqualTheSimulatorsCounts) {
  TcpRig rig;
  ASSERT_TRUE(rig.ready());
  ASSERT_TRUE(rig.bring_up());
  const double poses[][3] = {{0, 0, 0}, {0.5, -0.3, 0.2}, {-1.1, 1.2, -1.6}, {1e-4, 2e-4, -3e-4}};
  for (const auto& q : poses) {
    rig.server->set_pose(q);
    const ArmSnapshot truth = rig.server->snapshot();
    JointState s;
    ASSERT_EQ(rig.arm->read(s), IoStatus::kOk);
    ASSERT_EQ(s.n, 3);
    for (int j = 0; j < 3; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      EXPECT_EQ(s.counts[uj], truth.counts[uj]) << "joint " << j;
      EXPECT_DOUBLE_EQ(s.q[uj], arm::joint_position_from_counts(rig.config.joints[uj], truth.counts[uj]));
      const double per_count = std::abs(arm::joint_position_from_counts(rig.config.joints[uj], 1) - arm::joint_position_from_counts(rig.config.joints[uj], 0));
      EXPECT_NEAR(s.q[uj], truth.q[uj], per_count);
    }
  }
  EXPECT_EQ(rig.arm->counters().ok, 4u);
}

TEST(ModbusArmTcp, AWrittenTorqueBecomesTheSimulatorsMotorTorque) {
  TcpRig rig;
  ASSERT_TRUE(rig.ready());
  ASSERT_TRUE(rig.bring_up());
  for (const JointCommand& cmd : {torques(0.5, -0.25, 0.1), torques(-1.3, 0.001, -0.7), torques(0, 0, 0)}) {
    ASSERT_EQ(rig.arm->write(cmd), IoStatus::kOk);
    rig.server->step_physics(1e-3);
    const ArmSnapshot snap = rig.server->snapshot();
    EXPECT_TRUE(snap.enabled);
    for (int j = 0; j < 3; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      EXPECT_NEAR(snap.motor_torque[uj], cmd.tau[uj], torque_lsb(rig.config, j)) << "joint " << j;
      EXPECT_NEAR(snap.current[uj], rig.arm->commanded_current(j), 1e-12);
    }
  }
  // Beyond the peak current: clamped at the driver (and counted), the motor gives its peak.
  ASSERT_EQ(rig.arm->write(torques(50, -50, 0)), IoStatus::kOk);
  rig.server->step_physics(1e-3);
  const ArmSnapshot snap = rig.server->snapshot();
  EXPECT_NEAR(snap.current[0], rig.config.actuators[0].peak_current, 1e-9);
  EXPECT_NEAR(std::abs(snap.current[1]), rig.config.actuators[1].peak_current, 1e-9);
  EXPECT_EQ(rig.arm->current_clamps(), 2u);
  const double peak0 = rig.config.actuators[0].peak_torque() * rig.config.joints[0].gear_ratio;
  EXPECT_NEAR(snap.motor_torque[0], peak0, 1e-9);
  EXPECT_NEAR(snap.motor_torque[1], -peak0, 1e-9);  // joint 1 turns the other way, same motor
  // Non-finite torques send zero current.
  ASSERT_EQ(rig.arm->write(torques(std::nan(""), INFINITY, 0)), IoStatus::kOk);
  rig.server->step_physics(1e-3);
  for (int j = 0; j < 3; ++j) EXPECT_EQ(rig.server->snapshot().motor_torque[static_cast<std::size_t>(j)], 0.0);
}

TEST(ModbusArmTcp, ActivateEnablesTheDrivesAndDeactivateZeroesAndDisablesThem) {
  TcpRig rig;
  ASSERT_TRUE(rig.ready());
  ASSERT_TRUE(rig.arm->configure().ok());
  EXPECT_FALSE(rig.server->snapshot().enabled);
  ASSERT_TRUE(rig.arm->activate().ok());
  ArmSnapshot snap = rig.server->snapshot();
  EXPECT_TRUE(snap.enabled);
  EXPECT_EQ(snap.control, kEnableOn);
  for (int i = 0; i < 5; ++i) ASSERT_EQ(rig.arm->write(torques(0.2, 0.2, 0.2)), IoStatus::kOk);
  snap = rig.server->snapshot();
  EXPECT_EQ(snap.heartbeat, 5u);  // bumped on every write
  EXPECT_EQ(snap.control, kEnableOn);  // held as a level in the same transaction
  EXPECT_NE(snap.current[0], 0.0);
  ASSERT_TRUE(rig.arm->deactivate().ok());
  rig.server->step_physics(1e-3);
  snap = rig.server->snapshot();
  EXPECT_FALSE(snap.enabled);
  EXPECT_EQ(snap.control, 0u);
  for (int j = 0; j < 3; ++j) {
    EXPECT_EQ(snap.current[static_cast<std::size_t>(j)], 0.0);
    EXPECT_EQ(snap.motor_torque[static_cast<std::size_t>(j)], 0.0);
  }
  // Reading still works while inactive (monitoring).
  JointState s;
  EXPECT_EQ(rig.arm->read(s), IoStatus::kOk);
}

TEST(ModbusArmTcp, AHostNameIsResolved) {
  TcpRig rig;
  ASSERT_TRUE(rig.ready());
  arm::ArmConfig c = rig.config;
  c.modbus->host = "localhost";
  auto a = make_arm(c);
  ASSERT_TRUE(a);
  const Result<void> o = a->configure();
  ASSERT_TRUE(o.ok()) << o.error().message;
  JointState s;
  EXPECT_EQ(a->read(s), IoStatus::kOk);
}

TEST(ModbusArmTcp, StatusAndButtonsDecode) {
  TcpRig rig;
  ASSERT_TRUE(rig.ready());
  ASSERT_TRUE(rig.bring_up());
  JointState s;
  ASSERT_EQ(rig.arm->read(s), IoStatus::kOk);
  EXPECT_EQ(s.status, kEnabledBit);
  EXPECT_EQ(s.buttons, 0u);
  // Config buttons: 0 handle_trigger (bit 0), 1 handle_thumb (bit 1), 2 foot_pedal (bit 4).
  rig.server->set_buttons(1u << 4);
  ASSERT_EQ(rig.arm->read(s), IoStatus::kOk);
  EXPECT_EQ(s.buttons, 1u << 2);
  rig.server->set_buttons((1u << 0) | (1u << 1) | (1u << 3));
  ASSERT_EQ(rig.arm->read(s), IoStatus::kOk);
  EXPECT_EQ(s.buttons, 0b011u);  // bit 3 is no configured button
  // An active-low button reads pressed when its bit is 0.
  arm::ArmConfig c = rig.config;
  c.buttons[2].active_low = true;
  auto low = make_arm(c);
  ASSERT_TRUE(low);
  ASSERT_TRUE(low->configure().ok());
  ASSERT_EQ(low->read(s), IoStatus::kOk);
  EXPECT_EQ(s.buttons, 0b111u);
}

TEST(ModbusArmTcp, ADriveFaultTripsAtOnceAndRearmResetsIt) {
  TcpRig rig(quiet_options(), {.max_consecutive_errors = 100});
  ASSERT_TRUE(rig.ready());
  ASSERT_TRUE(rig.bring_up());
  ASSERT_EQ(rig.arm->write(torques(0.3, 0, 0)), IoStatus::kOk);
  rig.server->set_drive_fault(true);
  JointState s;
  EXPECT_EQ(rig.arm->read(s), IoStatus::kFault);
  EXPECT_EQ(rig.arm->fault_cause(), IoStatus::kDeviceFault);
  EXPECT_EQ(rig.arm->counters().device_faults, 1u);
  EXPECT_TRUE((s.status & kFaultBit) != 0);
  // The config's bits, named: the fault itself and what it did to the enable.
  EXPECT_STREQ(rig.arm->fault_detail().c_str(), "status 0x0001: fault (bit 0), not enabled (bit 1 low)");
  EXPECT_EQ(rig.arm->fault_detail().code, 0x0001u);
  EXPECT_EQ(rig.arm->write(torques(0.3, 0, 0)), IoStatus::kFault);
  EXPECT_EQ(rig.server->snapshot().current[0], 0.0);  // the fault path sent zero
  ASSERT_TRUE(rig.arm->rearm().ok());
  const ArmSnapshot snap = rig.server->snapshot();
  EXPECT_FALSE(snap.drive_fault);  // the fault-reset bit cleared it
  EXPECT_TRUE(snap.enabled);
  EXPECT_EQ(snap.control, kEnableOn);
  EXPECT_EQ(rig.arm->read(s), IoStatus::kOk);
  EXPECT_EQ(s.status, kEnabledBit);
}

TEST(ModbusArmTcp, RearmFailsWhileTheDriveKeepsItsFault) {
  TcpRig rig;
  ASSERT_TRUE(rig.ready());
  ASSERT_TRUE(rig.bring_up());
  rig.server->set_drive_fault(true, /*sticky=*/true);
  JointState s;
  ASSERT_EQ(rig.arm->read(s), IoStatus::kFault);
  const Result<void> r = rig.arm->rearm();
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(contains(r.error().message, "still reports a fault")) << r.error().message;
  EXPECT_EQ(rig.arm->state(), Lifecycle::kFault);
  EXPECT_FALSE(rig.server->snapshot().enabled);
  rig.server->set_drive_fault(false);
  const Result<void> again = rig.arm->rearm();
  ASSERT_TRUE(again.ok()) << again.error().message;
  EXPECT_TRUE(rig.server->snapshot().enabled);
}

// The test's clock for the driver's readings (ModbusArm::set_clock).
std::int64_t g_test_clock_ns = 0;
std::int64_t test_clock() noexcept { return g_test_clock_ns; }

TEST(ModbusArmTcp, VelocityIsAFilteredFiniteDifference) {
  TcpRig rig;
  ASSERT_TRUE(rig.ready());
  ASSERT_TRUE(rig.bring_up());
  rig.arm->set_clock(&test_clock);
  g_test_clock_ns = 1'000'000'000;
  JointState s;
  double q[3] = {0, 0, 0};
  rig.server->set_pose(q);
  ASSERT_EQ(rig.arm->read(s), IoStatus::kOk);
  EXPECT_EQ(s.qd[0], 0.0);  // no history yet
  // Joint 0 ramps at 1 rad/s by the driver's clock (a reading every 1 ms, 1 mrad further): the
  // estimate settles there within the encoder's quantisation (one count over 1 ms).
  const double per_count = std::abs(arm::joint_position_from_counts(rig.config.joints[0], 1) - arm::joint_position_from_counts(rig.config.joints[0], 0));
  for (int i = 1; i <= 200; ++i) {
    g_test_clock_ns += 1'000'000;
    q[0] = i * 1e-3;
    rig.server->set_pose(q);
    ASSERT_EQ(rig.arm->read(s), IoStatus::kOk);
    ASSERT_TRUE(std::isfinite(s.qd[0]));
    ASSERT_GT(s.qd[0], 0.0) << "reading " << i;
  }
  EXPECT_NEAR(s.qd[0], 1.0, per_count / 1e-3);
  EXPECT_EQ(s.qd[1], 0.0);
  EXPECT_EQ(s.qd[2], 0.0);
  // A first-order low-pass (100 Hz): 1 ms after the ramp stops the estimate has lost the fraction
  // dt / (dt + 1 / (2π·100 Hz)) of itself, and it decays to nothing.
  const double before = s.qd[0];
  g_test_clock_ns += 1'000'000;
  ASSERT_EQ(rig.arm->read(s), IoStatus::kOk);
  const double alpha = 1e-3 / (1e-3 + 1.0 / (2.0 * 3.141592653589793 * 100.0));
  EXPECT_NEAR(s.qd[0], (1.0 - alpha) * before, 1e-12);
  for (int i = 0; i < 100; ++i) {
    g_test_clock_ns += 1'000'000;
    ASSERT_EQ(rig.arm->read(s), IoStatus::kOk);
  }
  EXPECT_NEAR(s.qd[0], 0.0, 1e-12);
  rig.arm->set_clock(nullptr);
}

TEST(ModbusArmTcp, ThePhysicsThreadFollowsTheCommands) {
  ServerOptions o = quiet_options();
  o.physics_rate = 1000;
  o.hand = HandMode::kFree;
  TcpRig rig(o);
  ASSERT_TRUE(rig.ready());
  ASSERT_TRUE(rig.bring_up());
  JointState s;
  ASSERT_EQ(rig.arm->read(s), IoStatus::kOk);
  const double q0 = s.q[0];
  // Joint 0 (direction +1) pushed positive for a while with no hand: it turns positive.
  ASSERT_TRUE(eventually([&] {
    EXPECT_EQ(rig.arm->write(torques(0.05, 0, 0)), IoStatus::kOk);
    EXPECT_EQ(rig.arm->read(s), IoStatus::kOk);
    return s.q[0] > q0 + 0.01;
  }));
  EXPECT_GT(s.qd[0], 0.0);
  EXPECT_GT(rig.server->snapshot().steps, 10u);
}

TEST(ModbusArmTcp, ReadAndWriteAllocateNothingInSteadyState) {
  TcpRig rig;
  ASSERT_TRUE(rig.ready());
  ASSERT_TRUE(rig.bring_up());
  JointState s;
  for (int i = 0; i < 200; ++i) {  // warm-up
    ASSERT_EQ(rig.arm->read(s), IoStatus::kOk);
    ASSERT_EQ(rig.arm->write(torques(0.01 * i, 0, 0)), IoStatus::kOk);
  }
  lancet::test::MallocGuard guard;
  for (int i = 0; i < 2000; ++i) {
    ASSERT_EQ(rig.arm->read(s), IoStatus::kOk);
    ASSERT_EQ(rig.arm->write(torques(0.001 * (i % 100), -0.1, 0.05)), IoStatus::kOk);
  }
  EXPECT_EQ(guard.count(), 0u) << "ModbusArm read/write (or libmodbus under them) allocated; malloc counted: "
                               << lancet::test::malloc_is_counted();
}

// ---------------------------------------------------------------------------------------------
// RTU over a pty pair

TEST(ModbusArmRtu, EncodersAndTorquesOverAPty) {
  Pty pty;
  ASSERT_GE(pty.master, 0) << "openpty: " << std::strerror(errno);
  const arm::ArmConfig config = rtu_config(pty.path);
  auto server = make_server(config);
  ASSERT_TRUE(server);
  ASSERT_TRUE(server->start_rtu(pty.master).ok());
  auto a = make_arm(config);
  ASSERT_TRUE(a);
  EXPECT_EQ(a->endpoint(), pty.path);
  const Result<void> c = a->configure();
  ASSERT_TRUE(c.ok()) << c.error().message;
  ASSERT_TRUE(a->activate().ok());
  const double q[3] = {0.4, -0.2, 0.9};
  server->set_pose(q);
  JointState s;
  ASSERT_EQ(a->read(s), IoStatus::kOk);
  const ArmSnapshot truth = server->snapshot();
  for (int j = 0; j < 3; ++j) EXPECT_EQ(s.counts[static_cast<std::size_t>(j)], truth.counts[static_cast<std::size_t>(j)]);
  const JointCommand cmd = torques(-0.4, 0.8, 0.15);
  ASSERT_EQ(a->write(cmd), IoStatus::kOk);
  server->step_physics(1e-3);
  const ArmSnapshot after = server->snapshot();
  for (int j = 0; j < 3; ++j)
    EXPECT_NEAR(after.motor_torque[static_cast<std::size_t>(j)], cmd.tau[static_cast<std::size_t>(j)], torque_lsb(config, j));
  EXPECT_EQ(after.heartbeat, 1u);
  for (int i = 0; i < 200; ++i) {
    ASSERT_EQ(a->read(s), IoStatus::kOk);
    ASSERT_EQ(a->write(cmd), IoStatus::kOk);
  }
  lancet::test::MallocGuard guard;
  for (int i = 0; i < 500; ++i) {
    ASSERT_EQ(a->read(s), IoStatus::kOk);
    ASSERT_EQ(a->write(cmd), IoStatus::kOk);
  }
  EXPECT_EQ(guard.count(), 0u) << "RTU read/write allocated";
  ASSERT_TRUE(a->deactivate().ok());
  EXPECT_EQ(server->snapshot().control, 0u);
  a.reset();
  server->stop();
}

TEST(ModbusArmRtu, CorruptRepliesAreCrcErrorsAndNeverAccepted) {
  Pty pty;
  ASSERT_GE(pty.master, 0);
  const arm::ArmConfig config = rtu_config(pty.path);
  auto server = make_server(config);
  ASSERT_TRUE(server);
  ASSERT_TRUE(server->start_rtu(pty.master).ok());
  auto a = make_arm(config, {.max_consecutive_errors = 1'000'000});
  ASSERT_TRUE(a);
  ASSERT_TRUE(a->configure().ok());
  ASSERT_TRUE(a->activate().ok());
  const double q[3] = {0.3, 0.3, -0.3};
  server->set_pose(q);
  const ArmSnapshot truth = server->snapshot();
  FaultInjection f;
  f.corrupt = 0.3;
  server->set_faults(f);
  JointState s;
  int ok = 0;
  for (int i = 0; i < 300; ++i) {
    const IoStatus st = a->read(s);
    if (st == IoStatus::kOk) {
      ++ok;
      for (int j = 0; j < 3; ++j) ASSERT_EQ(s.counts[static_cast<std::size_t>(j)], truth.counts[static_cast<std::size_t>(j)]);
    }
    (void)a->write(torques(0.1, 0.1, 0.1));
  }
  const IoCounters& c = a->counters();
  std::printf("rtu corrupt replies: %s\n", describe(c).c_str());
  EXPECT_TRUE(contains(a->last_error().c_str(), pty.path + ": CRC error in the reply to ")) << a->last_error().c_str();
  EXPECT_GT(ok, 100);
  EXPECT_GT(c.crc_errors, 20u);
  // Over RTU every flipped byte is a CRC error: one per corrupted reply, nothing else (the seeded
  // draws corrupt the same replies on every run; every reply comes within the timeout).
  EXPECT_EQ(c.crc_errors, server->snapshot().stats.corrupted) << describe(c);
  EXPECT_EQ(c.crc_errors + c.ok, c.reads + c.writes) << describe(c);
  EXPECT_EQ(c.timeouts + c.protocol_errors + c.stale_replies, 0u) << describe(c);
  EXPECT_EQ(a->state(), Lifecycle::kActive);
}

// ---------------------------------------------------------------------------------------------
// Fault injection over TCP

TEST(ModbusArmFaults, DroppedRepliesTimeOutThenFaultWithZeroTorque) {
  TcpRig rig(quiet_options(), {.max_consecutive_errors = 3});
  ASSERT_TRUE(rig.ready());
  ASSERT_TRUE(rig.bring_up());
  ASSERT_EQ(rig.arm->write(torques(0.4, 0.4, 0.4)), IoStatus::kOk);
  EXPECT_NE(rig.server->snapshot().current[0], 0.0);
  FaultInjection drop;
  drop.drop_replies = 1.0;  // no reply, ever: a timeout whatever its length
  rig.server->set_faults(drop);
  rig.arm->set_response_timeout(kShortTimeout);
  JointState s;
  EXPECT_EQ(rig.arm->read(s), IoStatus::kTimeout);
  EXPECT_EQ(rig.arm->read(s), IoStatus::kTimeout);
  EXPECT_EQ(rig.arm->read(s), IoStatus::kFault);
  EXPECT_EQ(rig.arm->fault_cause(), IoStatus::kTimeout);
  EXPECT_EQ(rig.arm->counters().timeouts, 3u);
  EXPECT_EQ(rig.arm->last_errno(), ETIMEDOUT);
  // Once the bus answers again, the fault path's best-effort write lands: zero current.
  rig.server->set_faults({});
  rig.arm->set_response_timeout(kTimeout);
  EXPECT_EQ(rig.arm->write(torques(0.4, 0.4, 0.4)), IoStatus::kFault);
  rig.server->step_physics(1e-3);
  const ArmSnapshot snap = rig.server->snapshot();
  for (int j = 0; j < 3; ++j) {
    EXPECT_EQ(snap.current[static_cast<std::size_t>(j)], 0.0);
    EXPECT_EQ(snap.motor_torque[static_cast<std::size_t>(j)], 0.0);
  }
  EXPECT_EQ(rig.arm->read(s), IoStatus::kFault);  // still in fault until rearm
  ASSERT_TRUE(rig.arm->rearm().ok());
  EXPECT_EQ(rig.arm->read(s), IoStatus::kOk);
}

TEST(ModbusArmFaults, WithheldRepliesTimeOutAfterTheResponseTimeoutAndRearmRecovers) {
  TcpRig rig(quiet_options(), {.max_consecutive_errors = 3});
  ASSERT_TRUE(rig.ready());
  ASSERT_TRUE(rig.bring_up());
  rig.arm->set_response_timeout(kShortTimeout);
  rig.server->hold_replies(3);
  JointState s;
  for (int i = 0; i < 3; ++i) {
    const auto t0 = Clock::now();
    const IoStatus st = rig.arm->read(s);
    const double took = seconds_since(t0);
    EXPECT_EQ(st, i < 2 ? IoStatus::kTimeout : IoStatus::kFault);
    // It waited the whole response timeout for the withheld reply, and then gave up. How soon
    // after the timeout it returns is the scheduler's business on a loaded VM: the upper bound
    // only catches a wait for the reply itself (it never comes) or a timeout read in the wrong unit.
    EXPECT_GE(took, kShortTimeout);
    EXPECT_LT(took, 5.0);
  }
  EXPECT_EQ(rig.arm->fault_cause(), IoStatus::kTimeout);
  EXPECT_TRUE(contains(rig.arm->fault_detail().c_str(), "127.0.0.1:" + std::to_string(rig.port) + ": timed out, no reply within 20 ms to read input registers 0..7"))
      << rig.arm->fault_detail().c_str();
  // The late replies still arrive, on the same connection: recognised by their transaction ids,
  // thrown away and counted, never taken for the answer to rearm's requests.
  ASSERT_TRUE(eventually([&] { return rig.server->held_replies() == 3; }));
  rig.server->release_replies();
  rig.arm->set_response_timeout(kTimeout);
  const Result<void> r = rig.arm->rearm();
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(rig.arm->counters().stale_replies, 3u);
  EXPECT_EQ(rig.server->snapshot().stats.connections, 1u) << "no reconnect was needed";
  const double q[3] = {0.3, -0.2, 0.1};
  rig.server->set_pose(q);
  const ArmSnapshot truth = rig.server->snapshot();
  for (int i = 0; i < 20; ++i) {
    ASSERT_EQ(rig.arm->read(s), IoStatus::kOk);
    EXPECT_EQ(s.counts[0], truth.counts[0]);
  }
}

TEST(ModbusArmFaults, DelayedRepliesGoOutLateWhileTheServerGoesOn) {
  // --delay-us: a reply held back for its delay (not the server: it goes on taking requests).
  TcpRig rig;
  ASSERT_TRUE(rig.ready());
  ASSERT_TRUE(rig.bring_up());
  FaultInjection late;
  late.delay_us = 3'600'000'000;  // an hour: it comes when the test says (clear)
  rig.server->set_faults(late);
  rig.arm->set_response_timeout(kShortTimeout);
  JointState s;
  EXPECT_EQ(rig.arm->read(s), IoStatus::kTimeout);
  rig.server->set_faults({});
  rig.arm->set_response_timeout(kTimeout);
  EXPECT_EQ(rig.arm->write(torques(0.1, 0, 0)), IoStatus::kOk) << "answered while the late reply waits";
  EXPECT_EQ(rig.server->snapshot().stats.delayed, 1u);
  ASSERT_TRUE(rig.server->control("clear").ok());  // the waiting reply goes out now
  ASSERT_EQ(rig.arm->read(s), IoStatus::kOk);
  EXPECT_EQ(rig.arm->counters().stale_replies, 1u);
  const auto st = rig.server->snapshot().stats;
  EXPECT_EQ(st.replies, st.requests);
}

TEST(ModbusArmFaults, ADisconnectFaultsAtOnceAndRearmReconnectsWhenTheServerIsBack) {
  TcpRig rig(quiet_options(), {.max_consecutive_errors = 100});
  ASSERT_TRUE(rig.ready());
  ASSERT_TRUE(rig.bring_up());
  JointState s;
  ASSERT_EQ(rig.arm->read(s), IoStatus::kOk);
  // The server stops listening, then closes the connection, before it returns; it refuses
  // connections until the test lets it listen again.
  rig.server->disconnect_clients(ArmServer::kUntilAccepted);
  EXPECT_EQ(rig.arm->read(s), IoStatus::kFault);
  EXPECT_EQ(rig.arm->fault_cause(), IoStatus::kDisconnected);
  EXPECT_EQ(rig.arm->counters().disconnects, 1u);
  EXPECT_TRUE(contains(rig.arm->fault_detail().c_str(), "127.0.0.1:" + std::to_string(rig.port) + ": connection")) << rig.arm->fault_detail().c_str();
  EXPECT_EQ(rig.arm->write(torques(0.1, 0, 0)), IoStatus::kFault);  // best effort, fails fast
  // While the server refuses connections, rearm fails and says where and why.
  const Result<void> refused = rig.arm->rearm();
  ASSERT_FALSE(refused.ok());
  EXPECT_TRUE(contains(refused.error().message, "127.0.0.1:" + std::to_string(rig.port))) << refused.error().message;
  EXPECT_EQ(rig.arm->state(), Lifecycle::kFault);
  EXPECT_FALSE(rig.arm->rearm().ok()) << "still refused";
  // Once it listens again, rearm reconnects and the arm is active.
  rig.server->accept_connections();
  const Result<void> back = rig.arm->rearm();
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(rig.arm->state(), Lifecycle::kActive);
  EXPECT_EQ(rig.arm->read(s), IoStatus::kOk);
  EXPECT_EQ(rig.arm->write(torques(0.1, 0, 0)), IoStatus::kOk);
  EXPECT_GE(rig.server->snapshot().stats.connections, 2u);
}

TEST(ModbusArmFaults, ActivateAfterADisconnectReconnects) {
  TcpRig rig;
  ASSERT_TRUE(rig.ready());
  ASSERT_TRUE(rig.bring_up());
  rig.server->disconnect_clients(0);  // cut, but keep listening
  JointState s;
  EXPECT_EQ(rig.arm->read(s), IoStatus::kFault);
  EXPECT_EQ(rig.arm->fault_cause(), IoStatus::kDisconnected);
  (void)rig.arm->deactivate();  // the link is gone: it may fail, the arm is inactive anyway
  EXPECT_EQ(rig.arm->state(), Lifecycle::kInactive);
  const Result<void> a = rig.arm->activate();
  ASSERT_TRUE(a.ok()) << a.error().message;
  EXPECT_EQ(rig.arm->read(s), IoStatus::kOk);
  EXPECT_TRUE(rig.server->snapshot().enabled);
}

TEST(ModbusArmFaults, CorruptRepliesAreCountedAndNeverAccepted) {
  TcpRig rig(quiet_options(), {.max_consecutive_errors = 1'000'000});
  ASSERT_TRUE(rig.ready());
  ASSERT_TRUE(rig.bring_up());
  const double q[3] = {-0.5, 0.7, 0.25};
  rig.server->set_pose(q);
  const ArmSnapshot truth = rig.server->snapshot();
  FaultInjection f;
  f.corrupt = 0.3;
  rig.server->set_faults(f);
  JointState s;
  int ok = 0;
  for (int i = 0; i < 300; ++i) {
    if (rig.arm->read(s) == IoStatus::kOk) {
      ++ok;
      for (int j = 0; j < 3; ++j) ASSERT_EQ(s.counts[static_cast<std::size_t>(j)], truth.counts[static_cast<std::size_t>(j)]);
      ASSERT_EQ(s.status, kEnabledBit);
    }
    (void)rig.arm->write(torques(0.2, -0.2, 0.1));
  }
  const IoCounters& c = rig.arm->counters();
  std::printf("tcp corrupt replies: %s\n", describe(c).c_str());
  EXPECT_GT(ok, 100);
  // TCP has no CRC: each garbled frame (id, function, byte count) is one protocol error, nothing
  // else (the seeded draws corrupt the same replies on every run; every reply comes in time).
  EXPECT_EQ(c.protocol_errors, rig.server->snapshot().stats.corrupted) << describe(c);
  EXPECT_GT(c.protocol_errors, 20u);
  EXPECT_EQ(c.crc_errors + c.timeouts + c.stale_replies, 0u) << describe(c);
  EXPECT_EQ(c.protocol_errors + c.ok, c.reads + c.writes) << describe(c);
  EXPECT_EQ(rig.arm->state(), Lifecycle::kActive);
  // Writes are applied whether or not their reply came back intact: the registers hold the command.
  rig.server->set_faults({});
  ASSERT_EQ(rig.arm->write(torques(0.2, -0.2, 0.1)), IoStatus::kOk);
  rig.server->step_physics(1e-3);
  EXPECT_NEAR(rig.server->snapshot().motor_torque[0], 0.2, torque_lsb(rig.config, 0));
}

TEST(ModbusArmFaults, EncoderGlitchesShowInQWithoutNaN) {
  TcpRig rig;
  ASSERT_TRUE(rig.ready());
  ASSERT_TRUE(rig.bring_up());
  const double q[3] = {0.1, 0.2, 0.3};
  rig.server->set_pose(q);
  const ArmSnapshot truth = rig.server->snapshot();
  FaultInjection f;
  f.encoder_glitch = 0.5;
  rig.server->set_faults(f);
  JointState s;
  int glitched = 0;
  for (int i = 0; i < 200; ++i) {
    ASSERT_EQ(rig.arm->read(s), IoStatus::kOk);  // the device layer reports what the encoder says
    bool any = false;
    for (int j = 0; j < 3; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      ASSERT_TRUE(std::isfinite(s.q[uj]) && std::isfinite(s.qd[uj]));
      const std::int64_t jump = s.counts[uj] - truth.counts[uj];
      if (jump != 0) {
        EXPECT_EQ(std::abs(jump), rig.config.joints[uj].counts_per_rev);
        EXPECT_NEAR(std::abs(s.q[uj] - q[j]), std::abs(arm::joint_position_from_counts(rig.config.joints[uj], jump) - rig.config.joints[uj].offset), 1e-3);
        any = true;
      }
    }
    glitched += any ? 1 : 0;
  }
  EXPECT_GT(glitched, 20);
  EXPECT_EQ(rig.server->snapshot().stats.glitches, static_cast<std::uint64_t>(glitched));
  rig.server->set_faults({});
  ASSERT_EQ(rig.arm->read(s), IoStatus::kOk);
  EXPECT_EQ(s.counts[0], truth.counts[0]);
}

// ---------------------------------------------------------------------------------------------
// The lancet-armsim binary

class LancetArmsim : public test::TempDirTest {};

TEST_F(LancetArmsim, ServesTheArmAndExitsCleanlyOnSigterm) {
  const std::string out = (dir_ / "armsim.out").string();
  test::Child child({kArmsim, kTcpConfig, "--port", "0", "--hand", "hold"}, out);
  ASSERT_TRUE(child.started()) << kArmsim;
  const auto port = wait_for_port(child, out);
  ASSERT_TRUE(port) << test::read_file(out);
  auto a = make_arm(tcp_config(*port));
  ASSERT_TRUE(a);
  const Result<void> c = a->configure();
  ASSERT_TRUE(c.ok()) << c.error().message;
  ASSERT_TRUE(a->activate().ok());
  JointState s;
  ASSERT_EQ(a->read(s), IoStatus::kOk);
  const double q0 = s.q[0];
  // Held by the hand's spring, joint 0 yields a little to a positive torque.
  ASSERT_TRUE(eventually([&] {
    EXPECT_EQ(a->write(torques(0.3, 0, 0)), IoStatus::kOk);
    EXPECT_EQ(a->read(s), IoStatus::kOk);
    return s.q[0] > q0 + 1e-3;
  })) << "q0 " << s.q[0];
  ASSERT_TRUE(a->deactivate().ok());
  child.signal(SIGTERM);
  const auto status = child.wait_exit(std::chrono::seconds(5));
  ASSERT_TRUE(status);
  EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 0) << test::read_file(out);
  EXPECT_TRUE(contains(test::read_file(out), "lancet-armsim: SIGTERM after")) << test::read_file(out);
}

/// Writes one command into lancet-armsim's --control FIFO and waits for its acknowledgement on
/// the child's output (`armsim: control: <command>`, or `armsim: control: error: ...`).
::testing::AssertionResult send_control(const std::string& fifo, const std::string& out, const std::string& command,
                                        const std::string& ack_prefix = "armsim: control: ") {
  const auto acks = [&] {
    const std::string text = test::read_file(out);
    std::size_t n = 0;
    for (std::size_t at = text.find(ack_prefix); at != std::string::npos; at = text.find(ack_prefix, at + 1)) ++n;
    return n;
  };
  const std::size_t before = acks();
  const int fd = open(fifo.c_str(), O_WRONLY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) return ::testing::AssertionFailure() << "open " << fifo << ": " << std::strerror(errno);
  const std::string line = command + "\n";
  const bool wrote = write(fd, line.data(), line.size()) == static_cast<ssize_t>(line.size());
  close(fd);
  if (!wrote) return ::testing::AssertionFailure() << "write " << fifo << ": " << std::strerror(errno);
  if (!eventually([&] { return acks() > before; }))
    return ::testing::AssertionFailure() << "no '" << ack_prefix << "' for '" << command << "'; output:\n" << test::read_file(out);
  return ::testing::AssertionSuccess();
}

TEST_F(LancetArmsim, ScheduledDisconnectFaultsTheArmAndRefusesUntilCleared) {
  const std::string out = (dir_ / "armsim.out").string(), fifo = (dir_ / "control").string();
  // The cut comes 0.5 s after the first write with the drives on; the refusal lasts until `clear`.
  test::Child child({kArmsim, kTcpConfig, "--port", "0", "--hand", "hold", "--disconnect-after", "0.5", "--reconnect-after", "3600",
                     "--control", fifo},
                    out);
  const auto port = wait_for_port(child, out);
  ASSERT_TRUE(port) << test::read_file(out);
  auto a = make_arm(tcp_config(*port), {.max_consecutive_errors = 100});
  ASSERT_TRUE(a);
  ASSERT_TRUE(a->configure().ok());
  const Result<void> on = a->activate();
  JointState s;
  if (on.ok()) {
    ASSERT_TRUE(eventually([&] {
      (void)a->read(s);
      (void)a->write(torques(0, 0, 0));
      return a->state() == Lifecycle::kFault;
    })) << test::read_file(out);
    EXPECT_EQ(a->fault_cause(), IoStatus::kDisconnected);
    for (int i = 0; i < 3; ++i) EXPECT_FALSE(a->rearm().ok()) << "refused until cleared";
  } else {
    // A machine stalled for the whole 0.5 s inside activate() meets the cut there.
    EXPECT_EQ(a->last_error().status, IoStatus::kDisconnected) << on.error().message;
    EXPECT_FALSE(a->activate().ok()) << "refused until cleared";
  }
  ASSERT_TRUE(send_control(fifo, out, "clear"));
  const Result<void> back = on.ok() ? a->rearm() : a->activate();
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(a->read(s), IoStatus::kOk);
  child.signal(SIGTERM);
  ASSERT_TRUE(child.wait_exit(test::kHangTimeout));
  EXPECT_NE(test::read_file(out).find("1 forced disconnects"), std::string::npos) << test::read_file(out);
}

TEST_F(LancetArmsim, ControlCommandsInjectFaultsAtRunTime) {
  const std::string out = (dir_ / "armsim.out").string(), fifo = (dir_ / "control").string();
  test::Child child({kArmsim, kTcpConfig, "--port", "0", "--hand", "hold", "--control", fifo}, out);
  const auto port = wait_for_port(child, out);
  ASSERT_TRUE(port) << test::read_file(out);
  const arm::ArmConfig config = tcp_config(*port);
  auto a = make_arm(config, {.max_consecutive_errors = 1, .max_glitches = 1});
  ASSERT_TRUE(a);
  // Encoders that move at most 5 rad/s: a jump of a million counts (48 rad on joint 0) is a glitch
  // unless the two readings were almost 5 s apart.
  Plausibility plausible;
  plausible.n = 3;
  for (int j = 0; j < 3; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    plausible.max_speed[uj] = 5.0;
    plausible.resolution[uj] = std::abs(arm::joint_position_from_counts(config.joints[uj], 1) - arm::joint_position_from_counts(config.joints[uj], 0));
  }
  a->set_plausibility(plausible);
  ASSERT_TRUE(a->configure().ok());
  ASSERT_TRUE(a->activate().ok());
  JointState s;
  const auto rearm = [&] {
    const Result<void> r = a->rearm();
    if (!r.ok()) return ::testing::AssertionFailure() << r.error().message;
    if (a->read(s) != IoStatus::kOk) return ::testing::AssertionFailure() << "read after rearm: " << a->last_error().c_str();
    return ::testing::AssertionSuccess();
  };
  ASSERT_EQ(a->read(s), IoStatus::kOk);

  // fault: the drive latches its fault bit, until the fault reset of a rearm.
  ASSERT_TRUE(send_control(fifo, out, "fault"));
  EXPECT_EQ(a->read(s), IoStatus::kFault);
  EXPECT_EQ(a->fault_cause(), IoStatus::kDeviceFault);
  EXPECT_TRUE(rearm());

  // drop: the connection cut, new ones refused for the time given (here until clear).
  ASSERT_TRUE(send_control(fifo, out, "drop 3600"));
  EXPECT_EQ(a->read(s), IoStatus::kFault);
  EXPECT_EQ(a->fault_cause(), IoStatus::kDisconnected);
  EXPECT_FALSE(a->rearm().ok()) << "refused";
  ASSERT_TRUE(send_control(fifo, out, "clear"));
  EXPECT_TRUE(rearm());

  // late: every reply an hour late; the driver times out. clear sends the waiting reply now: it
  // is thrown away as stale.
  ASSERT_TRUE(send_control(fifo, out, "late 3600 3600000000"));
  a->set_response_timeout(kShortTimeout);
  EXPECT_EQ(a->read(s), IoStatus::kFault);
  EXPECT_EQ(a->fault_cause(), IoStatus::kTimeout);
  a->set_response_timeout(kTimeout);
  ASSERT_TRUE(send_control(fifo, out, "clear"));
  EXPECT_TRUE(rearm());
  EXPECT_EQ(a->counters().stale_replies, 1u);

  // garbage: every reply corrupted (over TCP in its framing: a protocol error).
  ASSERT_TRUE(send_control(fifo, out, "garbage 3600"));
  EXPECT_EQ(a->read(s), IoStatus::kFault);
  EXPECT_EQ(a->fault_cause(), IoStatus::kProtocolError);
  ASSERT_TRUE(send_control(fifo, out, "clear"));
  EXPECT_TRUE(rearm());

  // glitch: one big jump on the next reply that carries the encoders.
  ASSERT_TRUE(send_control(fifo, out, "glitch 1000000"));
  EXPECT_EQ(a->read(s), IoStatus::kFault);
  EXPECT_EQ(a->fault_cause(), IoStatus::kImplausible);
  EXPECT_TRUE(rearm());
  EXPECT_EQ(a->counters().faults, 5u);

  // A command it does not know is refused, and says why.
  ASSERT_TRUE(send_control(fifo, out, "explode", "armsim: control: error: "));
  EXPECT_NE(test::read_file(out).find("armsim: control: error: 'explode': expected fault, drop S"), std::string::npos) << test::read_file(out);
  ASSERT_TRUE(a->deactivate().ok());
  child.signal(SIGTERM);
  const auto status = child.wait_exit(test::kHangTimeout);
  ASSERT_TRUE(status);
  EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 0) << test::read_file(out);
  EXPECT_FALSE(std::filesystem::exists(fifo)) << "the FIFO it made is removed";
}

TEST_F(LancetArmsim, ServesRtuOnAnInheritedPty) {
  Pty pty;  // not close-on-exec: the child inherits the master
  ASSERT_GE(pty.master, 0);
  const std::string out = (dir_ / "armsim.out").string();
  test::Child child({kArmsim, kTcpConfig, "--rtu-fd", std::to_string(pty.master), "--hand", "hold"}, out);
  ASSERT_TRUE(eventually([&] { return contains(test::read_file(out), "(rtu, unit 1)"); })) << test::read_file(out);
  arm::ArmConfig config = rtu_config(pty.path);
  config.modbus->unit_id = 1;  // the shipped file's unit
  auto a = make_arm(config);
  ASSERT_TRUE(a);
  const Result<void> c = a->configure();
  ASSERT_TRUE(c.ok()) << c.error().message;
  ASSERT_TRUE(a->activate().ok());
  JointState s;
  for (int i = 0; i < 50; ++i) {
    ASSERT_EQ(a->read(s), IoStatus::kOk);
    ASSERT_EQ(a->write(torques(0, 0, 0)), IoStatus::kOk);
  }
  EXPECT_EQ(s.status, kEnabledBit);
  ASSERT_TRUE(a->deactivate().ok());
  child.signal(SIGTERM);
  const auto status = child.wait_exit(std::chrono::seconds(5));
  ASSERT_TRUE(status);
  EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 0) << test::read_file(out);
}

// A measurement, not a check (run it by name with --gtest_also_run_disabled_tests): the time of one
// Modbus TCP transaction on loopback against the lancet-armsim binary, paced at 1 kHz like the
// servo, each read() and write() timed apart (the shipped map: one transaction each). The numbers
// set the shipped response_timeout_ms (hw_configs/modbus_tcp_arm.toml; docs/PERFORMANCE.md).
TEST_F(LancetArmsim, DISABLED_MeasureLoopbackTransactionLatency) {
  const std::string out = (dir_ / "armsim.out").string();
  test::Child child({kArmsim, kTcpConfig, "--port", "0", "--hand", "script"}, out);
  const auto port = wait_for_port(child, out);
  ASSERT_TRUE(port) << test::read_file(out);
  arm::ArmConfig config = tcp_config(*port, 0.5);  // long enough never to cut a slow one short
  auto a = make_arm(config);
  ASSERT_TRUE(a);
  ASSERT_TRUE(a->configure().ok());
  ASSERT_TRUE(a->activate().ok());
  const char* env = std::getenv("LANCET_LATENCY_TICKS");
  const int ticks = env != nullptr ? std::atoi(env) : 20000;
  std::vector<double> reads, writes;
  reads.reserve(static_cast<std::size_t>(ticks));
  writes.reserve(static_cast<std::size_t>(ticks));
  JointState s;
  auto next = Clock::now();
  for (int i = -500; i < ticks; ++i) {
    next += std::chrono::milliseconds(1);
    std::this_thread::sleep_until(next);
    auto t0 = Clock::now();
    ASSERT_EQ(a->read(s), IoStatus::kOk);
    auto t1 = Clock::now();
    ASSERT_EQ(a->write(torques(0.01 * (i % 7 - 3), 0, 0)), IoStatus::kOk);
    auto t2 = Clock::now();
    if (i >= 0) {
      reads.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
      writes.push_back(std::chrono::duration<double, std::micro>(t2 - t1).count());
    }
    if (Clock::now() - next > std::chrono::milliseconds(50)) next = Clock::now();  // no catch-up burst
  }
  for (auto* v : {&reads, &writes}) {
    std::sort(v->begin(), v->end());
    const auto q = [&](double p) { return (*v)[std::min(v->size() - 1, static_cast<std::size_t>(p * static_cast<double>(v->size())))]; };
    std::printf("[ info     ] %s, %zu transactions at 1 kHz: p50 %.0f us, p99 %.0f us, p99.9 %.0f us, p99.99 %.0f us, max %.0f us\n",
                v == &reads ? "read (input 0..7)" : "write (holding 0..4)", v->size(), q(0.5), q(0.99), q(0.999), q(0.9999), v->back());
  }
  ASSERT_TRUE(a->deactivate().ok());
  child.signal(SIGTERM);
  (void)child.wait_exit(std::chrono::seconds(5));
}

TEST_F(LancetArmsim, RefusesAConfigWithoutARegisterMap) {
  const std::string out = (dir_ / "armsim.out").string();
  test::Child child({kArmsim, kSimConfig, "--port", "0"}, out);
  const auto status = child.wait_exit(std::chrono::seconds(10));
  ASSERT_TRUE(status);
  EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 2);
  EXPECT_TRUE(contains(test::read_file(out), "[bus.modbus]")) << test::read_file(out);
}

// ---------------------------------------------------------------------------------------------
// A foreign server: pymodbus

class PymodbusServer : public test::TempDirTest {};

TEST_F(PymodbusServer, ModbusArmReadsAndWritesTheShippedMapOnAForeignServer) {
  if (std::system("/usr/bin/python3 -c 'import pymodbus' >/dev/null 2>&1") != 0)
    GTEST_SKIP() << "python3-pymodbus is not installed (apt-get install --no-install-recommends python3-pymodbus)";
  const std::string out = (dir_ / "pymodbus.out").string();
  test::Child child({"/usr/bin/python3", kPymodbusScript, "--config", kTcpConfig, "--port", "0", "--counts", "1000,-2000,300000",
                     "--status", "0", "--buttons", "0x13"},
                    out);
  const auto port = wait_for_port(child, out);
  ASSERT_TRUE(port) << test::read_file(out);
  const arm::ArmConfig config = tcp_config(*port);
  auto a = make_arm(config);
  ASSERT_TRUE(a);
  const Result<void> c = a->configure();
  ASSERT_TRUE(c.ok()) << c.error().message;
  ASSERT_TRUE(a->activate().ok());
  JointState s;
  ASSERT_EQ(a->read(s), IoStatus::kOk);
  const std::int64_t expected[3] = {1000, -2000, 300000};
  for (int j = 0; j < 3; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    EXPECT_EQ(s.counts[uj], expected[j]);
    EXPECT_DOUBLE_EQ(s.q[uj], arm::joint_position_from_counts(config.joints[uj], expected[j]));
  }
  EXPECT_EQ(s.buttons, 0b111u);  // raw 0x13: bits 0, 1, 4
  EXPECT_EQ(s.status, kEnabledBit);

  const JointCommand cmd = torques(0.1, -0.2, 0.05);
  ASSERT_EQ(a->write(cmd), IoStatus::kOk);
  // Read the holding registers back with a second, plain libmodbus client.
  modbus_t* peek = modbus_new_tcp("127.0.0.1", *port);
  ASSERT_NE(peek, nullptr);
  modbus_set_response_timeout(peek, 1, 0);
  ASSERT_EQ(modbus_connect(peek), 0) << modbus_strerror(errno);
  std::uint16_t regs[5] = {};
  ASSERT_EQ(modbus_read_registers(peek, 0, 5, regs), 5) << modbus_strerror(errno);
  const double lsb = config.modbus->registers.setpoint.scale;
  for (int j = 0; j < 3; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const double amps = arm::motor_current_for_joint_torque(config.joints[uj], config.actuators[uj], cmd.tau[uj]);
    EXPECT_EQ(static_cast<std::int16_t>(regs[j]), static_cast<std::int16_t>(std::lround(amps / lsb))) << "joint " << j;
  }
  EXPECT_EQ(regs[3], kEnableOn);
  EXPECT_EQ(regs[4], 1u);  // heartbeat: one write so far
  ASSERT_TRUE(a->deactivate().ok());
  ASSERT_EQ(modbus_read_registers(peek, 0, 5, regs), 5);
  EXPECT_EQ(regs[0], 0u);
  EXPECT_EQ(regs[3], 0u);
  modbus_close(peek);
  modbus_free(peek);
  child.signal(SIGTERM);
  (void)child.wait_exit(std::chrono::seconds(5));
}

TEST_F(PymodbusServer, ModbusArmReadsWritesAndNamesTheFaultsOfAForeignMap) {
  if (std::system("/usr/bin/python3 -c 'import pymodbus' >/dev/null 2>&1") != 0)
    GTEST_SKIP() << "python3-pymodbus is not installed (apt-get install --no-install-recommends python3-pymodbus)";
  const std::string out = (dir_ / "pymodbus.out").string();
  // Counts as the encoder reports them: 0.25 · raw + 1000 (the last one a quarter count off whole).
  test::Child child({"/usr/bin/python3", kPymodbusScript, "--config", kForeignConfig, "--port", "0", "--counts", "1500,-2000,300000.25",
                     "--buttons", "0x201"},
                    out);
  const auto port = wait_for_port(child, out);
  ASSERT_TRUE(port) << test::read_file(out);
  arm::ArmConfig config = load(kForeignConfig);
  config.modbus->port = *port;
  config.modbus->response_timeout = kTimeout;
  auto a = make_arm(config, {.max_consecutive_errors = 100});
  ASSERT_TRUE(a);
  EXPECT_EQ(a->read_transactions(), 4);   // input 3..4 (status, buttons), 10..11, 20..21, 30..31
  EXPECT_EQ(a->write_transactions(), 4);  // holding 60..61 (heartbeat), 100..101, 104..105, 108..109
  const Result<void> c = a->configure();
  ASSERT_TRUE(c.ok()) << c.error().message;
  const Result<void> on = a->activate();
  ASSERT_TRUE(on.ok()) << on.error().message;

  // Encoders: scale and bias, low word first, bytes swapped; a fraction of a count moves q.
  JointState s;
  ASSERT_EQ(a->read(s), IoStatus::kOk);
  const double counts[3] = {1500, -2000, 300000.25};
  for (int j = 0; j < 3; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    EXPECT_EQ(s.counts[uj], std::llround(counts[j])) << "joint " << j;
    const auto& jc = config.joints[uj];
    const double per_count = arm::joint_position_from_counts(jc, 1) - arm::joint_position_from_counts(jc, 0);
    EXPECT_NEAR(s.q[uj], arm::joint_position_from_counts(jc, 0) + counts[j] * per_count, 1e-12) << "joint " << j;
  }
  EXPECT_EQ(s.status, 0x0021u) << "ready (bit 0) and the active-low e-stop released (bit 5 high)";
  EXPECT_EQ(s.buttons, 0b11u);  // raw 0x201: bits 0 and 9

  // Setpoints: motor torque in mN·m as f32, high word first, bytes swapped; read back with a plain
  // libmodbus client and decoded here by hand.
  const JointCommand cmd = torques(0.3, -0.45, 0.05);
  ASSERT_EQ(a->write(cmd), IoStatus::kOk);
  modbus_t* peek = modbus_new_tcp("127.0.0.1", *port);
  ASSERT_NE(peek, nullptr);
  modbus_set_slave(peek, 7);
  modbus_set_response_timeout(peek, 1, 0);
  ASSERT_EQ(modbus_connect(peek), 0) << modbus_strerror(errno);
  const auto swap = [](std::uint16_t r) { return static_cast<std::uint16_t>((r >> 8) | (r << 8)); };
  const auto holding = [&](int address, int count) {
    std::vector<std::uint16_t> regs(static_cast<std::size_t>(count));
    EXPECT_EQ(modbus_read_registers(peek, address, count, regs.data()), count) << modbus_strerror(errno);
    return regs;
  };
  for (int j = 0; j < 3; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const auto regs = holding(100 + 4 * j, 2);
    const std::uint32_t bits = (static_cast<std::uint32_t>(swap(regs[0])) << 16) | swap(regs[1]);
    float mnm = 0;
    std::memcpy(&mnm, &bits, sizeof mnm);
    const double amps = arm::motor_current_for_joint_torque(config.joints[uj], config.actuators[uj], cmd.tau[uj]);
    EXPECT_NEAR(mnm, amps * config.actuators[uj].torque_constant * 1e3, 1e-3) << "joint " << j;
    EXPECT_NEAR(a->commanded_current(j), amps, 1e-6);
  }
  auto hb = holding(60, 2);  // u32, low word first, bytes swapped
  EXPECT_EQ((static_cast<std::uint32_t>(swap(hb[1])) << 16) | swap(hb[0]), 1u) << "one write so far";
  EXPECT_EQ(swap(holding(40, 1)[0]), 0x000Fu) << "enable on";
  EXPECT_EQ(swap(holding(70, 1)[0]), 80u) << "the drive watchdog: 800 ms in 10 ms counts, written at activation";

  // The server raises bit 2: a fault, named by its bit in the fault detail.
  child.signal(SIGUSR1);
  IoStatus st = IoStatus::kOk;
  ASSERT_TRUE(eventually([&] {
    st = a->read(s);
    return st != IoStatus::kOk;
  }));
  EXPECT_EQ(st, IoStatus::kFault);
  EXPECT_EQ(a->fault_cause(), IoStatus::kDeviceFault);
  EXPECT_STREQ(a->fault_detail().c_str(), "status 0x0024: fault (bit 2), not ready (bit 0 low)");
  // rearm writes the fault-reset value to the enable register (0x0080), then enable again.
  const Result<void> r = a->rearm();
  ASSERT_TRUE(r.ok()) << r.error().message;
  ASSERT_EQ(a->read(s), IoStatus::kOk);
  EXPECT_EQ(s.status, 0x0021u);
  // The e-stop is active low: pressed, bit 5 reads 0.
  child.signal(SIGUSR2);
  ASSERT_TRUE(eventually([&] { return a->read(s) != IoStatus::kOk; }));
  EXPECT_STREQ(a->fault_detail().c_str(), "status 0x0000: e-stop (bit 5 low), not ready (bit 0 low)");
  child.signal(SIGUSR2);  // released
  ASSERT_TRUE(eventually([&] { return a->rearm().ok(); }));
  ASSERT_TRUE(a->deactivate().ok());
  EXPECT_EQ(swap(holding(40, 1)[0]), 0x0006u) << "enable off";
  for (int j = 0; j < 3; ++j) EXPECT_EQ(holding(100 + 4 * j, 2), (std::vector<std::uint16_t>{0, 0})) << "zero torque";
  modbus_close(peek);
  modbus_free(peek);
  child.signal(SIGTERM);
  (void)child.wait_exit(std::chrono::seconds(5));
}

// ---------------------------------------------------------------------------------------------
// A foreign map against the in-process arm simulator

TEST(ModbusArmForeignMap, TheSimulatorServesItAndTheDriverDrivesItWithoutAllocating) {
  arm::ArmConfig config = load(kForeignConfig);
  auto server = make_server(config);
  ASSERT_TRUE(server);
  auto p = server->start_tcp(0);
  ASSERT_TRUE(p.ok()) << p.error().message;
  config.modbus->port = p.value();
  config.modbus->response_timeout = kTimeout;
  auto a = make_arm(config);
  ASSERT_TRUE(a);
  ASSERT_TRUE(a->configure().ok());
  EXPECT_FALSE(server->snapshot().enabled);
  const Result<void> on = a->activate();
  ASSERT_TRUE(on.ok()) << on.error().message;
  ArmSnapshot snap = server->snapshot();
  EXPECT_TRUE(snap.enabled);
  EXPECT_EQ(snap.control, 0x000Fu);
  EXPECT_DOUBLE_EQ(snap.watchdog_ms, 800.0) << "the simulator takes the watchdog time the driver wrote";
  const double q[3] = {0.2, -0.4, 0.7};
  server->set_pose(q);
  const ArmSnapshot truth = server->snapshot();
  JointState s;
  ASSERT_EQ(a->read(s), IoStatus::kOk);
  for (int j = 0; j < 3; ++j) EXPECT_EQ(s.counts[static_cast<std::size_t>(j)], truth.counts[static_cast<std::size_t>(j)]);
  // Torque setpoints in f32: the motors give the torque asked for, to float precision.
  const JointCommand cmd = torques(0.5, -0.25, 0.1);
  ASSERT_EQ(a->write(cmd), IoStatus::kOk);
  server->step_physics(1e-3);
  snap = server->snapshot();
  for (int j = 0; j < 3; ++j) EXPECT_NEAR(snap.motor_torque[static_cast<std::size_t>(j)], cmd.tau[static_cast<std::size_t>(j)], 1e-5);
  for (int i = 0; i < 100; ++i) {
    ASSERT_EQ(a->read(s), IoStatus::kOk);
    ASSERT_EQ(a->write(cmd), IoStatus::kOk);
  }
  lancet::test::MallocGuard guard;
  for (int i = 0; i < 500; ++i) {
    ASSERT_EQ(a->read(s), IoStatus::kOk);
    ASSERT_EQ(a->write(torques(0.001 * (i % 100), -0.1, 0.05)), IoStatus::kOk);
  }
  EXPECT_EQ(guard.count(), 0u) << "four reads and four writes per tick, f32 and swapped bytes: nothing allocated";
}

TEST(ModbusArmForeignMap, ActivateWaitsForReadyAndNamesWhatIsMissing) {
  arm::ArmConfig config = load(kForeignConfig);
  auto server = make_server(config);
  ASSERT_TRUE(server);
  auto p = server->start_tcp(0);
  ASSERT_TRUE(p.ok());
  config.modbus->port = p.value();
  config.modbus->response_timeout = kTimeout;
  auto a = make_arm(config);
  ASSERT_TRUE(a);
  ASSERT_TRUE(a->configure().ok());
  server->set_estop(true);
  JointState s;
  EXPECT_EQ(a->read(s), IoStatus::kOk) << "while the drives are off, the status is reported, not judged";
  const Result<void> o = a->activate();
  ASSERT_FALSE(o.ok());
  EXPECT_TRUE(contains(o.error().message, "e-stop (bit 5 low)")) << o.error().message;
  EXPECT_EQ(a->state(), Lifecycle::kInactive);
  EXPECT_EQ(server->snapshot().control, 0x0006u) << "switched off again";
  server->set_estop(false);
  const Result<void> again = a->activate();
  ASSERT_TRUE(again.ok()) << again.error().message;
  EXPECT_TRUE(server->snapshot().enabled);
}

// ---------------------------------------------------------------------------------------------
// Late replies: thrown away and counted, never a false fault, never a stale reading
//
// The server withholds replies on command (hold_replies) and sends them when the test says:
// before the next request, or while the client waits for it (release_replies_with_next_request).
// The client's timeout is produced by the withheld reply, not by the machine's speed; a withheld
// reply carries the registers of its request's time, so one taken for a later request's shows as
// an old reading.

enum class Transport { kTcp, kRtu };

std::string transport_name(const ::testing::TestParamInfo<Transport>& info) { return info.param == Transport::kTcp ? "Tcp" : "Rtu"; }
void PrintTo(Transport t, std::ostream* os) { *os << (t == Transport::kTcp ? "TCP" : "RTU"); }

/// The in-process server and a ModbusArm pointed at it, over TCP (an ephemeral loopback port) or
/// RTU (a pty pair), the drive watchdog off; brought up (configured and active).
struct Rig {
  explicit Rig(Transport t, FaultPolicy policy = {}, const ServerOptions& o = quiet_options()) {
    if (t == Transport::kRtu) {
      pty = std::make_unique<Pty>();
      if (pty->master < 0) {
        ADD_FAILURE() << "openpty: " << std::strerror(errno);
        return;
      }
      config = rtu_config(pty->path);
      server = make_server(config, o);
      if (!server) return;
      const Result<void> started = server->start_rtu(pty->master);
      if (!started.ok()) {
        ADD_FAILURE() << started.error().message;
        return;
      }
    } else {
      arm::ArmConfig served = load(kTcpConfig);
      served.modbus->drive_watchdog = 0;
      server = make_server(served, o);
      if (!server) return;
      auto p = server->start_tcp(0);
      if (!p.ok()) {
        ADD_FAILURE() << p.error().message;
        return;
      }
      config = tcp_config(p.value());
    }
    arm = make_arm(config, policy);
    if (!arm) return;
    const Result<void> c = arm->configure();
    if (c.ok()) {
      const Result<void> a = arm->activate();
      up = a.ok();
      if (!up) ADD_FAILURE() << a.error().message;
    } else {
      ADD_FAILURE() << c.error().message;
    }
  }
  ~Rig() {
    arm.reset();
    if (server) server->stop();
  }
  Rig(const Rig&) = delete;
  Rig& operator=(const Rig&) = delete;

  /// One read (or write) whose reply the server withholds: kTimeout from the client, and the reply
  /// held at the server (carrying the registers of this moment) until the test releases it.
  IoStatus withheld(bool is_read) {
    const int before = server->held_replies();
    arm->set_response_timeout(kShortTimeout);
    server->hold_replies(1);
    JointState s;
    const IoStatus st = is_read ? arm->read(s) : arm->write(torques(0.01, 0, 0));
    arm->set_response_timeout(kTimeout);
    // The client gave up; the server may not even have taken the request yet.
    EXPECT_TRUE(eventually([&] { return server->held_replies() == before + 1; })) << "the server never got the request";
    return st;
  }
  /// Moves the arm somewhere new (each call elsewhere) and reads it: the fresh counts, or a failure.
  ::testing::AssertionResult reads_fresh() {
    ++pose;
    const double q[3] = {0.01 * pose, -0.007 * pose, 0.004 * pose};
    server->set_pose(q);
    const ArmSnapshot truth = server->snapshot();
    JointState s;
    const IoStatus st = arm->read(s);
    if (st != IoStatus::kOk) return ::testing::AssertionFailure() << "read: " << to_string(st) << ", " << arm->last_error().c_str();
    for (int j = 0; j < 3; ++j)
      if (s.counts[static_cast<std::size_t>(j)] != truth.counts[static_cast<std::size_t>(j)])
        return ::testing::AssertionFailure() << "joint " << j << " read " << s.counts[static_cast<std::size_t>(j)] << ", the arm is at "
                                             << truth.counts[static_cast<std::size_t>(j)] << ": a late reply was taken for this one";
    return ::testing::AssertionSuccess();
  }
  /// Ticks of read (fresh) and write: none one reply behind.
  void ticks_stay_fresh(int n) {
    for (int i = 0; i < n; ++i) {
      ASSERT_TRUE(reads_fresh()) << "tick " << i;
      ASSERT_EQ(arm->write(torques(0.01, 0, 0)), IoStatus::kOk) << "tick " << i;
    }
  }

  std::unique_ptr<Pty> pty;  // outlives the server that serves on it
  std::unique_ptr<ArmServer> server;
  std::unique_ptr<ModbusArm> arm;
  arm::ArmConfig config;
  bool up = false;
  int pose = 0;
};

class ModbusArmLate : public ::testing::TestWithParam<Transport> {};

TEST_P(ModbusArmLate, AReplyThatComesBeforeTheNextRequestIsDiscarded) {
  Rig rig(GetParam());
  ASSERT_TRUE(rig.up);
  ASSERT_EQ(rig.withheld(true), IoStatus::kTimeout);
  rig.server->release_replies();  // in the client's input before its next request goes out
  EXPECT_TRUE(rig.reads_fresh());
  rig.ticks_stay_fresh(20);
  const IoCounters& c = rig.arm->counters();
  EXPECT_EQ(c.timeouts, 1u) << describe(c);
  EXPECT_EQ(c.stale_replies, 1u) << describe(c);
  EXPECT_EQ(c.protocol_errors + c.crc_errors, 0u) << describe(c);
  EXPECT_EQ(rig.arm->state(), Lifecycle::kActive);
}

TEST_P(ModbusArmLate, AReplyThatComesWhileTheNextRequestWaitsIsDiscarded) {
  Rig rig(GetParam());
  ASSERT_TRUE(rig.up);
  ASSERT_EQ(rig.withheld(true), IoStatus::kTimeout);
  rig.server->release_replies_with_next_request();
  EXPECT_TRUE(rig.reads_fresh());
  // A late read reply while a write waits: told apart by its function code (RTU) or id (TCP).
  ASSERT_EQ(rig.withheld(true), IoStatus::kTimeout);
  rig.server->release_replies_with_next_request();
  ASSERT_EQ(rig.arm->write(torques(0.01, 0, 0)), IoStatus::kOk);
  rig.ticks_stay_fresh(20);
  const IoCounters& c = rig.arm->counters();
  EXPECT_EQ(c.timeouts, 2u) << describe(c);
  EXPECT_EQ(c.stale_replies, 2u) << describe(c);
  EXPECT_EQ(c.protocol_errors + c.crc_errors, 0u) << describe(c);
}

TEST_P(ModbusArmLate, TwoLateRepliesInARowAreBothDiscarded) {
  Rig rig(GetParam());
  ASSERT_TRUE(rig.up);
  // A read and then a write time out; both replies come while the next read waits. Remembering
  // only the last late request, a driver takes the read's reply for the next read's (stale) and
  // stays one reply behind from then on.
  ASSERT_EQ(rig.withheld(true), IoStatus::kTimeout);
  ASSERT_EQ(rig.withheld(false), IoStatus::kTimeout);
  rig.server->release_replies_with_next_request();
  EXPECT_TRUE(rig.reads_fresh());
  rig.ticks_stay_fresh(20);
  // And the same with the replies already in before the read goes out.
  ASSERT_EQ(rig.withheld(true), IoStatus::kTimeout);
  ASSERT_EQ(rig.withheld(false), IoStatus::kTimeout);
  rig.server->release_replies();
  EXPECT_TRUE(rig.reads_fresh());
  rig.ticks_stay_fresh(20);
  const IoCounters& c = rig.arm->counters();
  EXPECT_EQ(c.timeouts, 4u) << describe(c);
  EXPECT_EQ(c.stale_replies, 4u) << describe(c);
  EXPECT_EQ(c.protocol_errors + c.crc_errors, 0u) << describe(c);
  EXPECT_EQ(rig.arm->state(), Lifecycle::kActive) << "two errors in a row stay under the default policy's three";
}

TEST_P(ModbusArmLate, TwoLateReadsInARowAreBothDiscarded) {
  Rig rig(GetParam());
  ASSERT_TRUE(rig.up);
  // Two replies of the same kind (function and length): over RTU only their order tells them apart.
  ASSERT_EQ(rig.withheld(true), IoStatus::kTimeout);
  ASSERT_EQ(rig.withheld(true), IoStatus::kTimeout);
  rig.server->release_replies_with_next_request();
  EXPECT_TRUE(rig.reads_fresh());
  rig.ticks_stay_fresh(20);
  // Two late writes: both replies come while the next write waits.
  ASSERT_EQ(rig.withheld(false), IoStatus::kTimeout);
  ASSERT_EQ(rig.withheld(false), IoStatus::kTimeout);
  rig.server->release_replies_with_next_request();
  ASSERT_EQ(rig.arm->write(torques(0.01, 0, 0)), IoStatus::kOk);
  rig.ticks_stay_fresh(20);
  const IoCounters& c = rig.arm->counters();
  EXPECT_EQ(c.timeouts, 4u) << describe(c);
  EXPECT_EQ(c.stale_replies, 4u) << describe(c);
  EXPECT_EQ(c.protocol_errors + c.crc_errors, 0u) << describe(c);
  EXPECT_EQ(rig.arm->state(), Lifecycle::kActive);
}

TEST_P(ModbusArmLate, ManyLateRepliesInARowAreAllDiscarded) {
  Rig rig(GetParam(), {.max_consecutive_errors = 100});
  ASSERT_TRUE(rig.up);
  for (int i = 0; i < 7; ++i) ASSERT_EQ(rig.withheld(i % 2 == 0), IoStatus::kTimeout) << i;
  rig.server->release_replies_with_next_request();
  EXPECT_TRUE(rig.reads_fresh());
  rig.ticks_stay_fresh(20);
  const IoCounters& c = rig.arm->counters();
  EXPECT_EQ(c.timeouts, 7u) << describe(c);
  EXPECT_EQ(c.stale_replies, 7u) << describe(c);
  EXPECT_EQ(c.protocol_errors + c.crc_errors, 0u) << describe(c);
}

TEST_P(ModbusArmLate, AReplyThatNeverComesLeavesTheNextOnesFresh) {
  Rig rig(GetParam());
  ASSERT_TRUE(rig.up);
  ASSERT_EQ(rig.withheld(true), IoStatus::kTimeout);
  rig.server->discard_held_replies();  // the request is never answered
  ASSERT_EQ(rig.arm->write(torques(0.01, 0, 0)), IoStatus::kOk);
  rig.ticks_stay_fresh(20);
  const IoCounters& c = rig.arm->counters();
  EXPECT_EQ(c.timeouts, 1u) << describe(c);
  EXPECT_EQ(c.stale_replies, 0u) << describe(c);
  EXPECT_EQ(c.protocol_errors + c.crc_errors, 0u) << describe(c);
}

INSTANTIATE_TEST_SUITE_P(Transports, ModbusArmLate, ::testing::Values(Transport::kTcp, Transport::kRtu), transport_name);

TEST(ModbusArmLateTcp, MoreLateRepliesThanItRemembersAreStillKnownByTheirIds) {
  // Past kMaxLateRequests the oldest owed ids are forgotten; replies sent since the last answered
  // request are known as late by their ids all the same.
  Rig rig(Transport::kTcp, {.max_consecutive_errors = 100});
  ASSERT_TRUE(rig.up);
  const int n = static_cast<int>(ModbusArm::kMaxLateRequests) + 4;
  for (int i = 0; i < n; ++i) ASSERT_EQ(rig.withheld(i % 2 == 0), IoStatus::kTimeout) << i;
  rig.server->release_replies();
  EXPECT_TRUE(rig.reads_fresh());
  rig.ticks_stay_fresh(20);
  const IoCounters& c = rig.arm->counters();
  EXPECT_EQ(c.stale_replies, static_cast<std::uint64_t>(n)) << describe(c);
  EXPECT_EQ(c.protocol_errors, 0u) << describe(c);
}

TEST(ModbusArmLateRtu, AnUnansweredReadCostsTheNextLookalikeReadATimeoutNeverAStaleReading) {
  // Over RTU the reply to the next read looks like the reply owed to the unanswered one: the
  // driver takes it for that (the safe guess), so this read times out; the write after it, which
  // looks like neither, settles what is owed, and the ticks after read fresh values.
  Rig rig(Transport::kRtu);
  ASSERT_TRUE(rig.up);
  ASSERT_EQ(rig.withheld(true), IoStatus::kTimeout);
  rig.server->discard_held_replies();
  rig.arm->set_response_timeout(kShortTimeout);  // its reply is taken for the owed one: it ends in a timeout
  JointState s;
  EXPECT_EQ(rig.arm->read(s), IoStatus::kTimeout);
  rig.arm->set_response_timeout(kTimeout);
  ASSERT_EQ(rig.arm->write(torques(0.01, 0, 0)), IoStatus::kOk);
  rig.ticks_stay_fresh(20);
  const IoCounters& c = rig.arm->counters();
  EXPECT_EQ(c.timeouts, 2u) << describe(c);
  EXPECT_EQ(c.stale_replies, 1u) << describe(c);
  EXPECT_EQ(c.protocol_errors + c.crc_errors, 0u) << describe(c);
}

TEST(ModbusArmStale, ActivateLeavesNoLateReplyBehind) {
  TcpRig rig;
  ASSERT_TRUE(rig.ready());
  ASSERT_TRUE(rig.arm->configure().ok());
  // A slow start: the first reads time out (inactive: no fault), their replies come late, and are
  // all in the socket before activate sends anything.
  rig.arm->set_response_timeout(kShortTimeout);
  rig.server->hold_replies(3);
  JointState s;
  for (int i = 0; i < 3; ++i) EXPECT_EQ(rig.arm->read(s), IoStatus::kTimeout);
  ASSERT_TRUE(eventually([&] { return rig.server->held_replies() == 3; }));
  rig.server->release_replies();
  rig.arm->set_response_timeout(kTimeout);
  const Result<void> a = rig.arm->activate();
  ASSERT_TRUE(a.ok()) << a.error().message;
  const double q[3] = {-0.3, 0.5, 0.2};
  rig.server->set_pose(q);
  const ArmSnapshot truth = rig.server->snapshot();
  ASSERT_EQ(rig.arm->read(s), IoStatus::kOk);
  for (int j = 0; j < 3; ++j) EXPECT_EQ(s.counts[static_cast<std::size_t>(j)], truth.counts[static_cast<std::size_t>(j)]) << "a fresh reading, not a late one";
  EXPECT_EQ(rig.arm->counters().stale_replies, 3u);
  EXPECT_EQ(rig.arm->state(), Lifecycle::kActive);
}

// ---------------------------------------------------------------------------------------------
// Errors in words

TEST(ModbusArmFaults, AnExceptionIsNamedWithItsRegisters) {
  TcpRig rig(quiet_options(), {.max_consecutive_errors = 1});
  ASSERT_TRUE(rig.ready());
  // The driver reads a register the simulator does not have.
  arm::ArmConfig c = rig.config;
  c.modbus->registers.buttons->address = {50};
  auto a = make_arm(c, {.max_consecutive_errors = 1});
  ASSERT_TRUE(a);
  const Result<void> o = a->configure();
  ASSERT_FALSE(o.ok());
  EXPECT_TRUE(contains(o.error().message, "exception 0x02 (illegal data address) to read input registers 50..50")) << o.error().message;
  EXPECT_EQ(a->last_errno(), MODBUS_ENOBASE + 2);
  EXPECT_EQ(a->last_error().status, IoStatus::kProtocolError);
  EXPECT_EQ(a->last_error().code, 2u);
  EXPECT_EQ(a->last_error().node, 1) << "the unit id";
}

// ---------------------------------------------------------------------------------------------
// The drive-side watchdog of the simulator, in simulated time: the server's clock moves only
// with step_physics(), so "silent for exactly the watchdog time" is exact.

TEST(ModbusArmWatchdog, TheDrivesGoTorqueFreeWhenTheHeartbeatStopsAndStayFaultedUntilReset) {
  arm::ArmConfig served = load(kTcpConfig);
  served.modbus->drive_watchdog = 0.1;
  auto server = make_server(served);  // quiet_options(): the manual clock, no physics thread
  ASSERT_TRUE(server);
  auto p = server->start_tcp(0);
  ASSERT_TRUE(p.ok());
  arm::ArmConfig config = served;
  config.modbus->port = p.value();
  config.modbus->response_timeout = kTimeout;
  auto a = make_arm(config, {.max_consecutive_errors = 100});
  ASSERT_TRUE(a);
  ASSERT_TRUE(a->configure().ok());
  ASSERT_TRUE(a->activate().ok());
  const auto step_ms = [&](int ms) { server->step_physics(1e-3, ms); };
  // A heartbeat every 100 ms, the watchdog time itself: never a trip (1 s of simulated time).
  JointState s;
  for (int i = 0; i < 10; ++i) {
    ASSERT_EQ(a->read(s), IoStatus::kOk);
    ASSERT_EQ(a->write(torques(0.2, 0, 0)), IoStatus::kOk);
    step_ms(100);
  }
  ArmSnapshot snap = server->snapshot();
  EXPECT_EQ(snap.stats.watchdog_trips, 0u);
  EXPECT_TRUE(snap.enabled);
  EXPECT_NE(snap.motor_torque[0], 0.0);
  // The host stops: after exactly 100 ms of silence the drives still hold; one microsecond more
  // and they are torque-free, in that very step.
  ASSERT_EQ(a->write(torques(0.2, 0, 0)), IoStatus::kOk);
  const std::int64_t last_beat = server->snapshot().clock_ns;
  step_ms(100);
  snap = server->snapshot();
  EXPECT_EQ(snap.clock_ns - last_beat, 100'000'000);
  EXPECT_EQ(snap.stats.watchdog_trips, 0u) << "silent for the watchdog time, not longer";
  EXPECT_NE(snap.motor_torque[0], 0.0);
  server->step_physics(1e-6);
  snap = server->snapshot();
  EXPECT_EQ(snap.stats.watchdog_trips, 1u);
  EXPECT_NEAR(snap.stats.last_trip_silence_ms, 100.001, 1e-9);
  EXPECT_FALSE(snap.enabled);
  EXPECT_TRUE(snap.comm_lost);
  EXPECT_TRUE(snap.drive_fault);
  for (int j = 0; j < 3; ++j) EXPECT_EQ(snap.motor_torque[static_cast<std::size_t>(j)], 0.0) << "joint " << j;
  EXPECT_EQ(snap.status, kFaultBit | kCommLostBit);
  // The driver reports it, in the config's words; the fault stays until a fault reset.
  EXPECT_EQ(a->read(s), IoStatus::kFault);
  EXPECT_EQ(a->fault_cause(), IoStatus::kDeviceFault);
  EXPECT_STREQ(a->fault_detail().c_str(), "status 0x0005: fault (bit 0), communication lost (bit 2), not enabled (bit 1 low)");
  for (int i = 0; i < 50; ++i) {
    (void)a->write(torques(0.2, 0, 0));  // the heartbeat again: still latched
    step_ms(1);
  }
  snap = server->snapshot();
  EXPECT_TRUE(snap.comm_lost);
  EXPECT_EQ(snap.motor_torque[0], 0.0);
  const Result<void> r = a->rearm();
  ASSERT_TRUE(r.ok()) << r.error().message;
  snap = server->snapshot();
  EXPECT_TRUE(snap.enabled);
  EXPECT_FALSE(snap.comm_lost);
  // Deactivated, the drives are off: a silent heartbeat is no reason to trip.
  ASSERT_TRUE(a->deactivate().ok());
  step_ms(1000);
  EXPECT_EQ(server->snapshot().stats.watchdog_trips, 1u);
  a.reset();
  server->stop();
}

TEST(ModbusArmWatchdog, RequestsAreTakenAndTheHeartbeatWatchedWhileAReplyIsLate) {
  // A late reply waits in the server's outbox: the server goes on taking requests (the heartbeat)
  // and watching it meanwhile.
  arm::ArmConfig served = load(kTcpConfig);
  served.modbus->drive_watchdog = 0.1;
  auto server = make_server(served);
  ASSERT_TRUE(server);
  auto p = server->start_tcp(0);
  ASSERT_TRUE(p.ok());
  arm::ArmConfig config = served;
  config.modbus->port = p.value();
  config.modbus->response_timeout = kTimeout;
  auto a = make_arm(config, {.max_consecutive_errors = 100});
  ASSERT_TRUE(a);
  ASSERT_TRUE(a->configure().ok());
  ASSERT_TRUE(a->activate().ok());
  ASSERT_EQ(a->write(torques(0.2, 0, 0)), IoStatus::kOk);
  a->set_response_timeout(kShortTimeout);
  server->hold_replies(1);
  JointState s;
  EXPECT_EQ(a->read(s), IoStatus::kTimeout);
  a->set_response_timeout(kTimeout);
  ASSERT_TRUE(eventually([&] { return server->held_replies() == 1; }));
  for (int i = 0; i < 5; ++i) {
    ASSERT_EQ(a->write(torques(0.2, 0, 0)), IoStatus::kOk) << "answered while the late reply waits";
    server->step_physics(1e-3, 100);
  }
  EXPECT_EQ(server->snapshot().stats.watchdog_trips, 0u);
  server->step_physics(1e-3, 101);  // then silent longer than the watchdog time
  EXPECT_EQ(server->snapshot().stats.watchdog_trips, 1u);
  EXPECT_EQ(server->held_replies(), 1);
  a.reset();
  server->stop();
}

// ---------------------------------------------------------------------------------------------
// Reconnection

TEST_F(LancetArmsim, AKilledArmsimRestartedOnTheSamePortIsReconnectedAndTheArmStaysOffUntilRearm) {
  const std::string out = (dir_ / "armsim.out").string();
  auto child = std::make_unique<test::Child>(std::vector<std::string>{kArmsim, kTcpConfig, "--port", "0", "--hand", "hold"}, out);
  const auto port = wait_for_port(*child, out);
  ASSERT_TRUE(port) << test::read_file(out);
  auto a = make_arm(tcp_config(*port), {.max_consecutive_errors = 100});
  ASSERT_TRUE(a);
  ASSERT_TRUE(a->configure().ok());
  ASSERT_TRUE(a->activate().ok());
  JointState s;
  for (int i = 0; i < 20; ++i) {
    ASSERT_EQ(a->read(s), IoStatus::kOk);
    ASSERT_EQ(a->write(torques(0.1, 0, 0)), IoStatus::kOk);
  }
  // The box dies.
  child->signal(SIGKILL);
  ASSERT_TRUE(child->wait_exit(std::chrono::seconds(5)));
  ASSERT_TRUE(eventually([&] {
    (void)a->read(s);
    return a->state() == Lifecycle::kFault;
  }));
  EXPECT_EQ(a->fault_cause(), IoStatus::kDisconnected);
  EXPECT_TRUE(a->link_lost());
  const Result<void> down = a->reconnect();
  ASSERT_FALSE(down.ok());
  EXPECT_TRUE(contains(down.error().message, "127.0.0.1:" + std::to_string(*port))) << down.error().message;
  EXPECT_TRUE(contains(down.error().message, "reconnect: cannot connect")) << down.error().message;
  EXPECT_EQ(a->state(), Lifecycle::kFault);

  // It comes back on the same port: reconnect() reopens the link and leaves the drives off.
  const std::string out2 = (dir_ / "armsim2.out").string();
  child = std::make_unique<test::Child>(std::vector<std::string>{kArmsim, kTcpConfig, "--port", std::to_string(*port), "--hand", "hold"}, out2);
  const auto port2 = wait_for_port(*child, out2);
  ASSERT_EQ(port2, port) << test::read_file(out2);
  Result<void> back = Result<void>::failure(ErrorCode::kSystem, "not tried");
  ASSERT_TRUE(eventually([&] {
    back = a->reconnect();
    return back.ok();
  })) << back.error().message;
  EXPECT_EQ(a->state(), Lifecycle::kFault) << "a reconnect never re-arms";
  EXPECT_FALSE(a->link_lost());
  EXPECT_EQ(a->counters().reconnects, 1u);
  EXPECT_EQ(a->read(s), IoStatus::kFault);
  EXPECT_EQ(a->write(torques(0.5, 0.5, 0.5)), IoStatus::kFault);  // zero torque goes out instead
  modbus_t* peek = modbus_new_tcp("127.0.0.1", *port);
  ASSERT_NE(peek, nullptr);
  modbus_set_response_timeout(peek, 1, 0);
  ASSERT_EQ(modbus_connect(peek), 0);
  std::uint16_t regs[5] = {};
  ASSERT_EQ(modbus_read_registers(peek, 0, 5, regs), 5);
  EXPECT_EQ(regs[0], 0u);
  EXPECT_EQ(regs[3], kEnableOff) << "the drives stay off until rearm";
  // Only rearm resumes.
  const Result<void> r = a->rearm();
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(a->state(), Lifecycle::kActive);
  ASSERT_EQ(modbus_read_registers(peek, 0, 5, regs), 5);
  EXPECT_EQ(regs[3], kEnableOn);
  EXPECT_EQ(a->read(s), IoStatus::kOk);
  modbus_close(peek);
  modbus_free(peek);
  ASSERT_TRUE(a->deactivate().ok());
  child->signal(SIGTERM);
  (void)child->wait_exit(std::chrono::seconds(5));
}

TEST(ModbusArmRtu, ReconnectReopensTheSerialDevice) {
  Pty pty;
  ASSERT_GE(pty.master, 0);
  const arm::ArmConfig config = rtu_config(pty.path);
  auto server = make_server(config);
  ASSERT_TRUE(server);
  ASSERT_TRUE(server->start_rtu(pty.master).ok());
  auto a = make_arm(config, {.max_consecutive_errors = 1});
  ASSERT_TRUE(a);
  ASSERT_TRUE(a->configure().ok());
  ASSERT_TRUE(a->activate().ok());
  FaultInjection drop;
  drop.drop_replies = 1.0;  // no reply, ever: a timeout whatever its length
  server->set_faults(drop);
  a->set_response_timeout(kShortTimeout);
  JointState s;
  EXPECT_EQ(a->read(s), IoStatus::kFault);
  server->set_faults({});
  a->set_response_timeout(kTimeout);
  const Result<void> o = a->reconnect();
  ASSERT_TRUE(o.ok()) << o.error().message;
  EXPECT_EQ(a->state(), Lifecycle::kFault);
  EXPECT_FALSE(server->snapshot().enabled) << "the drives stay off until rearm";
  ASSERT_TRUE(a->rearm().ok());
  EXPECT_TRUE(server->snapshot().enabled);
  EXPECT_EQ(a->read(s), IoStatus::kOk);
  a.reset();
  server->stop();
}

}  // namespace
