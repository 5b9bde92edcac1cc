// Arm configs: the shipped files load clean and in SI units; a broken file reports every error at
// once with its line and field path; each kind of check on its own; the report format and the
// `lancetctl validate` exit codes; and mutated files never crash the loader.

#include "arm/arm_config.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <numbers>
#include <random>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "arm/kinematics.hpp"
#include "temp_files.hpp"
#include "tools/validate_cmd.hpp"

#ifndef LANCET_SOURCE_DIR
#define LANCET_SOURCE_DIR "."
#endif

namespace lancet::arm {
namespace {

constexpr double kDeg = std::numbers::pi / 180;

std::string config_dir() { return std::string(LANCET_SOURCE_DIR) + "/hw_configs/"; }

const std::vector<std::string>& shipped() {
  static const std::vector<std::string> files{"sim_3dof.toml", "modbus_tcp_arm.toml", "canopen_arm.toml", "usb_arm.toml"};
  return files;
}

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::string shipped_text(const std::string& name) {
  const std::string t = read_text(config_dir() + name);
  EXPECT_FALSE(t.empty()) << name;
  return t;
}

// The sim arm with the Novint Falcon's delta kinematics in place of its PHANToM model: the
// README's [kinematics] example for the Falcon (so the documented values load).
std::string falcon_kinematics() {
  const std::string readme = read_text(config_dir() + "README.md");
  const auto begin = readme.find("[kinematics]\nmodel = \"delta\"");
  const auto end = readme.find("```", begin);
  EXPECT_TRUE(begin != std::string::npos && end != std::string::npos) << "the README's Falcon example";
  return begin == std::string::npos || end == std::string::npos ? std::string() : readme.substr(begin, end - begin) + "\n";
}

std::string delta_text() {
  std::string t = shipped_text("sim_3dof.toml");
  const auto from = t.find("[kinematics]"), to = t.find("[[joints]]");
  EXPECT_TRUE(from != std::string::npos && to != std::string::npos);
  t.replace(from, to - from, falcon_kinematics());
  return t;
}

// Replaces the first occurrence of `from` (which must exist).
std::string replaced(std::string text, const std::string& from, const std::string& to) {
  const auto at = text.find(from);
  EXPECT_NE(at, std::string::npos) << "test setup: no \"" << from << "\" in the text";
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

// 1-based line of the first occurrence of `needle`.
int line_of(const std::string& text, const std::string& needle) {
  const auto at = text.find(needle);
  EXPECT_NE(at, std::string::npos) << needle;
  return 1 + static_cast<int>(std::count(text.begin(), text.begin() + static_cast<std::ptrdiff_t>(at), '\n'));
}

ConfigReport check(const std::string& text) { return validate_arm_config_text(text, "t.toml"); }

std::string dump(const ConfigReport& r) { return format_report(r); }

// The report holds exactly one error, for this field on this line.
void expect_one(const ConfigReport& r, int line, const std::string& field, const std::string& in_message = {}) {
  ASSERT_EQ(r.errors.size(), 1u) << dump(r);
  EXPECT_EQ(r.errors[0].line, line) << dump(r);
  EXPECT_EQ(r.errors[0].field, field) << dump(r);
  EXPECT_EQ(r.errors[0].file, "t.toml");
  EXPECT_GE(r.errors[0].column, 1);
  if (!in_message.empty()) {
    EXPECT_NE(r.errors[0].message.find(in_message), std::string::npos) << dump(r);
  }
}

// --- shipped configs ------------------------------------------------------------------------

TEST(ArmConfig, ShippedConfigsValidateClean) {
  for (const std::string& f : shipped()) {
    const ConfigReport r = validate_arm_config_file(config_dir() + f);
    EXPECT_TRUE(r.readable) << f;
    EXPECT_TRUE(r.ok()) << f << ":\n" << dump(r);
    auto c = load_arm_config(config_dir() + f);
    ASSERT_TRUE(c.ok()) << c.error().message;
    EXPECT_EQ(static_cast<int>(c.value().joints.size()), c.value().joint_count()) << f;
    EXPECT_EQ(static_cast<int>(c.value().actuators.size()), c.value().joint_count()) << f;
    EXPECT_EQ(c.value().source, config_dir() + f);
  }
}

TEST(ArmConfig, SimConfigLoadsInSiUnits) {
  auto r = load_arm_config(config_dir() + "sim_3dof.toml");
  ASSERT_TRUE(r.ok()) << r.error().message;
  const ArmConfig& c = r.value();
  EXPECT_EQ(c.name, "sim-3dof");
  EXPECT_EQ(c.backend, Backend::kSim);
  ASSERT_TRUE(c.sim.has_value());
  EXPECT_FALSE(c.usb || c.modbus || c.canopen);
  EXPECT_EQ(c.kinematics.model, KinematicModel::kPhantom);
  EXPECT_NEAR(c.kinematics.l1, 0.20955, 1e-12);
  EXPECT_NEAR(c.kinematics.base_offset.z, 0.20955, 1e-12);
  ASSERT_EQ(c.joints.size(), 3u);
  EXPECT_EQ(c.joints[0].name, "base_yaw");
  EXPECT_EQ(c.joints[0].counts_per_rev, 4000);
  EXPECT_DOUBLE_EQ(c.joints[0].gear_ratio, 11.6);
  EXPECT_EQ(c.joints[2].direction, -1);
  EXPECT_NEAR(c.joints[1].min, -25 * kDeg, 1e-12);
  EXPECT_NEAR(c.joints[1].max, 75 * kDeg, 1e-12);
  EXPECT_NEAR(c.actuators[0].peak_torque(), 0.0235 * 3.0, 1e-12);
  EXPECT_NEAR(c.actuators[0].continuous_torque(), 0.0235 * 1.2, 1e-12);
  EXPECT_DOUBLE_EQ(c.safety.max_force, 8.0);
  EXPECT_NEAR(c.safety.watchdog_period, 0.002, 1e-12);
  EXPECT_NEAR(c.safety.workspace_min.y, -0.19, 1e-12);
  ASSERT_EQ(c.safety.max_joint_torque.size(), 3u);
  ASSERT_EQ(c.buttons.size(), 2u);
  EXPECT_EQ(c.buttons[1].action, ButtonAction::kClutch);
  EXPECT_EQ(c.buttons[1].bit, 1);
}

TEST(ArmConfig, DeltaConfigLoadsInSiUnits) {
  auto r = load_arm_config_text(delta_text(), "delta.toml");
  ASSERT_TRUE(r.ok()) << r.error().message;
  const ArmConfig& c = r.value();
  EXPECT_EQ(c.kinematics.model, KinematicModel::kDelta);
  EXPECT_EQ(c.joint_count(), 3);
  const DeltaGeometry& g = c.kinematics.delta;
  EXPECT_DOUBLE_EQ(g.a, 0.060);
  EXPECT_DOUBLE_EQ(g.b, 0.1025);
  EXPECT_DOUBLE_EQ(g.c, 0.01443);
  EXPECT_DOUBLE_EQ(g.d, 0.01125);
  EXPECT_DOUBLE_EQ(g.e, 0.01125);
  EXPECT_DOUBLE_EQ(g.f, -0.025);
  EXPECT_DOUBLE_EQ(g.r, 0.040);
  EXPECT_DOUBLE_EQ(g.s, -0.02309);
  EXPECT_DOUBLE_EQ(g.leg_angles[0], 105 * kDeg);
  EXPECT_DOUBLE_EQ(g.leg_angles[2], -135 * kDeg);
  EXPECT_DOUBLE_EQ(c.kinematics.base_offset.z, -0.111);
  for (const JointConfig& j : c.joints) EXPECT_EQ(j.type, JointType::kRevolute);
  auto k = make_kinematics(c);
  ASSERT_TRUE(k.ok()) << k.error().message;
  ASSERT_NE(k.value().delta(), nullptr);
  EXPECT_EQ(k.value().joint_count(), 3);
}

TEST(ArmConfig, BusSectionsLoad) {
  auto usb = load_arm_config(config_dir() + "usb_arm.toml");
  ASSERT_TRUE(usb.ok()) << usb.error().message;
  ASSERT_TRUE(usb.value().usb.has_value());
  const UsbBusConfig& u = *usb.value().usb;
  EXPECT_EQ(u.vid, 0x1209);
  EXPECT_EQ(u.endpoint_in, 0x81);
  EXPECT_EQ(u.in_size, 64u);
  ASSERT_TRUE(u.in_report_id.has_value());
  EXPECT_EQ(*u.in_report_id, 1);
  EXPECT_EQ(u.encoder_counts.type, FieldType::kI32);
  EXPECT_NEAR(u.setpoint.scale, 0.001, 1e-15);
  EXPECT_EQ(u.setpoint_kind, SetpointKind::kCurrent);
  ASSERT_TRUE(u.heartbeat.has_value());
  EXPECT_EQ(u.heartbeat->offset, 8u);
  EXPECT_NEAR(u.drive_watchdog, 0.05, 1e-15);
  EXPECT_EQ(u.status_bits.fault.bit, 0);
  EXPECT_EQ(u.status_bits.comm_lost.bit, 1);
  EXPECT_FALSE(u.status_bits.ready.mapped());
  ASSERT_TRUE(u.enable && u.fault_reset);
  EXPECT_EQ(u.enable->offset, u.fault_reset->offset);
  EXPECT_EQ(u.fault_reset_value, 2u);
  ASSERT_TRUE(u.buttons.has_value());
  EXPECT_EQ(u.buttons->offset, 13u);

  auto mb = load_arm_config(config_dir() + "modbus_tcp_arm.toml");
  ASSERT_TRUE(mb.ok()) << mb.error().message;
  ASSERT_TRUE(mb.value().modbus.has_value());
  const ModbusBusConfig& m = *mb.value().modbus;
  EXPECT_EQ(m.transport, ModbusTransport::kTcp);
  EXPECT_EQ(m.host, "127.0.0.1");
  EXPECT_EQ(m.port, 1502);
  EXPECT_EQ(m.unit_id, 1);
  EXPECT_GT(m.response_timeout, 0.0);  // set from a measurement; see the file's comment
  EXPECT_NEAR(m.drive_watchdog, 0.1, 1e-15);
  EXPECT_EQ(m.registers.setpoint.table, RegisterTable::kHolding);
  EXPECT_EQ(m.registers.setpoint.address, (std::vector<std::uint16_t>{0, 1, 2}));
  EXPECT_NEAR(m.registers.setpoint.scale, 0.001, 1e-15);
  EXPECT_EQ(m.registers.encoder_counts.address, (std::vector<std::uint16_t>{0, 2, 4}));
  ASSERT_TRUE(m.registers.heartbeat.has_value());
  EXPECT_EQ(m.registers.heartbeat->address, std::vector<std::uint16_t>{4});
  EXPECT_EQ(m.registers.status_bits.enabled.bit, 1);
  EXPECT_EQ(m.registers.enable_on, 1u);
  EXPECT_EQ(m.registers.fault_reset_value, 2u);
  EXPECT_EQ(mb.value().kinematics.links.size(), 3u);
  EXPECT_NEAR(mb.value().kinematics.links[0].alpha, std::numbers::pi / 2, 1e-15);
  EXPECT_NEAR(mb.value().kinematics.links[0].d, 0.12, 1e-15);

  auto co = load_arm_config(config_dir() + "canopen_arm.toml");
  ASSERT_TRUE(co.ok()) << co.error().message;
  ASSERT_TRUE(co.value().canopen.has_value());
  const CanopenBusConfig& c = *co.value().canopen;
  EXPECT_EQ(c.interface_name, "can0");
  EXPECT_EQ(c.node_ids, (std::vector<int>{1, 2, 3, 4}));
  EXPECT_EQ(c.mode, Cia402Mode::kCyclicSyncTorque);
  ASSERT_EQ(c.tpdos.size(), 2u);
  EXPECT_EQ(c.tpdos[1].sync_divider, 10);
  ASSERT_EQ(c.rpdos.size(), 1u);
  ASSERT_EQ(c.rpdos[0].entries.size(), 2u);
  EXPECT_EQ(c.rpdos[0].entries[1].index, 0x6071);
  EXPECT_TRUE(c.sync_producer) << "the default: this master sends the SYNC";
  EXPECT_EQ(co.value().joints[2].type, JointType::kPrismatic);
  EXPECT_NEAR(co.value().joints[2].lead, 0.0377, 1e-15);
  EXPECT_NEAR(co.value().joints[2].max, 0.2, 1e-15);
}

TEST(ArmConfig, ReadmeExampleValidates) {
  const std::string readme = read_text(config_dir() + "README.md");
  const auto begin = readme.find("```toml\n");
  ASSERT_NE(begin, std::string::npos);
  const auto end = readme.find("```", begin + 8);
  ASSERT_NE(end, std::string::npos);
  const ConfigReport r = check(readme.substr(begin + 8, end - begin - 8));
  EXPECT_TRUE(r.ok()) << dump(r);
}

// --- everything at once -----------------------------------------------------------------------

const char* const kBroken = R"(schema_version = 2
name = ""
backend = "modbus"
colour = "red"

[kinematics]
model = "phantom"
l1_mm = -5
l2_mm = "long"
links = []

[[joints]]
name = "a"
counts_per_rev = 0
gear_ratio = 0
direction = 2
min_deg = 10
max_deg = 10
gear_ration = 3

[[joints]]
name = "a"
counts_per_rev = 100
gear_ratio = 1.5
direction = -1
min_mm = 0
max_deg = 1

[[actuators]]
torque_constant_nm_per_a = 0.1
peak_current_a = 1
continuous_current_a = 2

[bus.modbus]
transport = "tcp"
host = "h"
baud = 9600
unit_id = 300
[bus.modbus.registers]
encoder_counts = { table = "input", address = 0, type = "i32" }
status = { table = "input", address = 4, type = "u16", bits = { fault = 0 } }
current_command = { table = "input", address = 0, type = "i16", lsb_ma = 1 }

[bus.canopen]
interface = "can0"

[safety]
max_force_n = 0
max_joint_torque_nm = [1, 2]
max_slew_n_per_s = -1
workspace_min_mm = [0, 0, 0]
workspace_max_mm = [1, 0, -1]
watchdog_period_ms = 0

[[buttons]]
name = "x"
bit = 40
)";

TEST(ArmConfig, BrokenConfigReportsEveryErrorWithLineAndField) {
  const ConfigReport r = check(kBroken);
  const std::vector<std::pair<int, std::string>> expected{
      {1, "schema_version"},
      {2, "name"},
      {4, "colour"},                                   // unknown key
      {8, "kinematics.l1_mm"},                         // out of range
      {9, "kinematics.l2_mm"},                         // wrong type
      {10, "kinematics.links"},                        // not for this model
      {12, "joints"},                                  // 2 joints, the model has 3
      {14, "joints[0].counts_per_rev"},
      {15, "joints[0].gear_ratio"},
      {16, "joints[0].direction"},
      {18, "joints[0].max_deg"},                       // min >= max
      {19, "joints[0].gear_ration"},                   // typo
      {21, "joints[1].min_deg"},                       // missing: reported at the table header
      {22, "joints[1].name"},                          // duplicate
      {26, "joints[1].min_mm"},                        // prismatic key on a revolute joint
      {29, "actuators"},                               // 1 actuator, the model has 3
      {31, "actuators[0].peak_current_a"},             // peak < continuous
      {37, "bus.modbus.baud"},                         // RTU key with TCP transport
      {38, "bus.modbus.unit_id"},
      {41, "bus.modbus.registers.status.address"},     // overlaps encoder_counts
      {42, "bus.modbus.registers.current_command.table"},
      {42, "bus.modbus.registers.current_command.lsb_ma"},  // replaced by scale
      {44, "bus.canopen"},                             // not the backend's section
      {48, "safety.max_force_n"},
      {49, "safety.max_joint_torque_nm"},
      {50, "safety.max_slew_n_per_s"},
      {52, "safety.workspace_max_mm[1]"},
      {52, "safety.workspace_max_mm[2]"},
      {53, "safety.watchdog_period_ms"},
      {55, "buttons"},                                 // no button word in the Modbus map
      {57, "buttons[0].bit"},
  };
  std::vector<std::pair<int, std::string>> got;
  for (const ConfigError& e : r.errors) got.emplace_back(e.line, e.field);
  EXPECT_EQ(got, expected) << dump(r);
  EXPECT_FALSE(r.ok());
  EXPECT_TRUE(r.readable);
  // Spot checks on columns and on the expected/found parts.
  ASSERT_EQ(r.errors.size(), expected.size());
  EXPECT_EQ(r.errors[0].column, 18);
  EXPECT_EQ(r.errors[0].expected, "the integer 1");
  EXPECT_EQ(r.errors[0].found, "integer 2");
  EXPECT_EQ(r.errors[11].column, 1);
  EXPECT_NE(r.errors[11].message.find("did you mean \"gear_ratio\"?"), std::string::npos);
  EXPECT_EQ(r.errors[18].expected, "an integer in 1..247");
  EXPECT_EQ(r.errors[18].found, "integer 300");
  // The loader refuses it, with the whole report as the message.
  auto loaded = load_arm_config_text(kBroken, "t.toml");
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(loaded.error().code, ErrorCode::kInvalid);
  EXPECT_EQ(loaded.error().message, format_report(r));
}

// --- one kind of error at a time --------------------------------------------------------------

class OneError : public ::testing::Test {
 protected:
  std::string sim_ = shipped_text("sim_3dof.toml");
  std::string modbus_ = shipped_text("modbus_tcp_arm.toml");
  std::string canopen_ = shipped_text("canopen_arm.toml");
  std::string usb_ = shipped_text("usb_arm.toml");
};

TEST_F(OneError, SyntaxErrorReportsLineAndColumn) {
  const std::string t = replaced(sim_, "gear_ratio = 13.2", "gear_ratio = 13.2.5");
  const ConfigReport r = check(t);
  ASSERT_EQ(r.errors.size(), 1u) << dump(r);
  EXPECT_EQ(r.errors[0].line, line_of(t, "13.2.5"));
  EXPECT_GT(r.errors[0].column, 1);
  EXPECT_EQ(r.errors[0].field, "");
  EXPECT_NE(r.errors[0].message.find("syntax"), std::string::npos);
  // Inputs that trip toml++ 3.3's internal asserts (upstream PR #301) are plain syntax errors here.
  for (const std::string& bad : {std::string("schema_version = 1\n[\n"), std::string("schema_version = 1\n[[ # c\n"),
                                 std::string("schema_version = 1\n[[[1]]]\n"), std::string("schema_version = 1\na = [}]\n")}) {
    const ConfigReport rb = check(bad);
    ASSERT_EQ(rb.errors.size(), 1u) << bad;
    EXPECT_EQ(rb.errors[0].line, 2) << bad;
    EXPECT_NE(rb.errors[0].message.find("syntax"), std::string::npos) << bad;
  }
  // Duplicate keys are a TOML error too.
  const std::string d = replaced(sim_, "direction = -1\n", "direction = -1\ndirection = 1\n");
  const ConfigReport rd = check(d);
  ASSERT_EQ(rd.errors.size(), 1u) << dump(rd);
  EXPECT_EQ(rd.errors[0].line, line_of(d, "direction = -1") + 1);
}

TEST_F(OneError, UnknownKeyEverywhere) {
  std::string t = replaced(sim_, "gear_ratio = 13.2", "gear_raito = 13.2");
  ConfigReport r = check(t);
  // The typo also leaves gear_ratio missing: both are reported.
  ASSERT_EQ(r.errors.size(), 2u) << dump(r);
  EXPECT_EQ(r.errors[1].field, "joints[1].gear_raito");
  EXPECT_EQ(r.errors[1].line, line_of(t, "gear_raito"));
  EXPECT_NE(r.errors[1].message.find("did you mean \"gear_ratio\"?"), std::string::npos) << dump(r);
  EXPECT_EQ(r.errors[0].field, "joints[1].gear_ratio");

  t = replaced(sim_, "[bus.sim]\n", "[bus.sim]\nmass_kg = 1\n");
  expect_one(check(t), line_of(t, "mass_kg"), "bus.sim.mass_kg", "unknown key");
  t = replaced(modbus_, "type = \"u16\" }", "type = \"u16\", scale = 2 }");
  expect_one(check(t), line_of(t, "scale = 2"), "bus.modbus.registers.buttons.scale", "unknown key");
  t = replaced(canopen_, "{ index = 0x6071, subindex = 0, bits = 16 }", "{ index = 0x6071, subindex = 0, bits = 16, sub = 1 }");
  expect_one(check(t), line_of(t, "sub = 1"), "bus.canopen.rpdo[0].entries[1].sub", "unknown key");
  t = replaced(sim_, "[safety]\n", "[safety]\nmax_velocity = 1\n");
  expect_one(check(t), line_of(t, "max_velocity"), "safety.max_velocity");
  t = replaced(sim_, "[kinematics]\n", "[kinematic]\nmodel = \"dh\"\n[kinematics]\n");
  expect_one(check(t), line_of(t, "[kinematic]"), "kinematic", "did you mean \"kinematics\"?");
  // Two neighbouring letters swapped count as one edit.
  t = replaced(sim_, "name = \"sim-3dof\"\n", "name = \"sim-3dof\"\nnmae = \"x\"\n");
  expect_one(check(t), line_of(t, "nmae"), "nmae", "unknown key \"nmae\" (did you mean \"name\"?)");
}

TEST_F(OneError, MissingRequiredKey) {
  std::string t = replaced(sim_, "counts_per_rev = 4000     # 1000-line encoder, quadrature\n", "");
  expect_one(check(t), line_of(t, "[[joints]]"), "joints[0].counts_per_rev", "missing");
  t = replaced(modbus_, "unit_id = 1\n", "");
  expect_one(check(t), line_of(t, "[bus.modbus]"), "bus.modbus.unit_id", "missing");
  t = replaced(sim_, "max_force_n = 8.0\n", "");
  expect_one(check(t), line_of(t, "[safety]"), "safety.max_force_n");
  t = replaced(sim_, "name = \"sim-3dof\"\n", "");
  expect_one(check(t), 1, "name");
}

TEST_F(OneError, WrongTypes) {
  std::string t = replaced(sim_, "counts_per_rev = 4000     #", "counts_per_rev = 4000.0   #");
  expect_one(check(t), line_of(t, "4000.0"), "joints[0].counts_per_rev", "found float 4000");
  t = replaced(sim_, "gear_ratio = 11.6", "gear_ratio = \"11.6\"");
  expect_one(check(t), line_of(t, "\"11.6\""), "joints[0].gear_ratio", "found string \"11.6\"");
  t = replaced(sim_, "backend = \"sim\"", "backend = 1");
  // The backend is unknown now: only that is reported (the bus is not judged against it).
  expect_one(check(t), line_of(t, "backend = 1"), "backend", "one of \"sim\", \"usb\", \"modbus\", \"canopen\", \"falcon\"");
  t = replaced(sim_, "backend = \"sim\"", "backend = \"modbsu\"");
  expect_one(check(t), line_of(t, "modbsu"), "backend",
             "expected one of \"sim\", \"usb\", \"modbus\", \"canopen\", \"falcon\", found string \"modbsu\" (did you mean \"modbus\"?)");
  t = replaced(sim_, "workspace_min_mm = [-100.0, -190.0, -135.0]", "workspace_min_mm = [-100.0, -190.0]");
  expect_one(check(t), line_of(t, "workspace_min_mm"), "safety.workspace_min_mm", "array of 2");
  t = replaced(sim_, "workspace_min_mm = [-100.0, -190.0, -135.0]", "workspace_min_mm = [-100.0, true, -135.0]");
  expect_one(check(t), line_of(t, "workspace_min_mm"), "safety.workspace_min_mm[1]", "boolean true");
  t = replaced(sim_, "action = \"clutch\"", "action = \"clutch\"\nactive_low = 1");
  expect_one(check(t), line_of(t, "active_low"), "buttons[1].active_low", "true or false");
  t = replaced(sim_, "[bus.sim]", "[bus.sim.extra]\n[bus.simx]");
  const ConfigReport r = check(t);
  ASSERT_GE(r.errors.size(), 1u) << dump(r);
}

TEST_F(OneError, NonFiniteNumbersAreRejected) {
  std::string t = replaced(sim_, "max_force_n = 8.0", "max_force_n = inf");
  expect_one(check(t), line_of(t, "= inf"), "safety.max_force_n");
  t = replaced(sim_, "offset_deg = 0.0", "offset_deg = nan");
  expect_one(check(t), line_of(t, "= nan"), "joints[0].offset_deg", "finite");
}

TEST_F(OneError, JointRanges) {
  std::string t = replaced(sim_, "counts_per_rev = 4000     #", "counts_per_rev = -4000    #");
  expect_one(check(t), line_of(t, "-4000"), "joints[0].counts_per_rev");
  t = replaced(sim_, "gear_ratio = 13.2", "gear_ratio = 0.0");
  expect_one(check(t), line_of(t, "gear_ratio = 0.0"), "joints[1].gear_ratio", "(0, ");
  t = replaced(sim_, "direction = -1", "direction = 0");
  expect_one(check(t), line_of(t, "direction = 0"), "joints[2].direction", "one of -1, 1");
  t = replaced(sim_, "min_deg = -25.0", "min_deg = 75.0");
  expect_one(check(t), line_of(t, "max_deg = 75.0"), "joints[1].max_deg", "> min_deg (75)");
  t = replaced(sim_, "min_deg = -25.0", "min_deg = 80.0");
  expect_one(check(t), line_of(t, "max_deg = 75.0"), "joints[1].max_deg");
}

TEST_F(OneError, JointUnitFamilyFollowsTheModel) {
  // A revolute joint takes _deg keys; a prismatic one _mm keys and lead_mm.
  std::string t = replaced(sim_, "offset_deg = 0.0\nmin_deg = -60.0", "offset_mm = 0.0\nmin_deg = -60.0");
  expect_one(check(t), line_of(t, "offset_mm = 0.0"), "joints[0].offset_mm", "only for prismatic joints");
  t = replaced(canopen_, "lead_mm = 37.7            # drum circumference: shaft travel per drum revolution\n", "");
  expect_one(check(t), line_of(t, "name = \"insertion\"") - 1, "joints[2].lead_mm", "missing");
  t = replaced(canopen_, "min_mm = 0.0\n", "min_deg = 0.0\n");
  ConfigReport r = check(t);
  ASSERT_EQ(r.errors.size(), 2u) << dump(r);  // min_deg is not for it, min_mm is missing
  EXPECT_EQ(r.errors[0].field, "joints[2].min_mm");
  EXPECT_EQ(r.errors[1].field, "joints[2].min_deg");
}

TEST_F(OneError, ActuatorPeakBelowContinuous) {
  const std::string t = replaced(sim_, "peak_current_a = 3.0", "peak_current_a = 1.0");
  expect_one(check(t), line_of(t, "peak_current_a = 1.0"), "actuators[0].peak_current_a", ">= continuous_current_a (1.2)");
}

TEST_F(OneError, JointCountMismatches) {
  // A fourth DH link: joints, actuators, torque limits and Modbus per-joint fields disagree.
  std::string t = replaced(modbus_, "[[joints]]\nname = \"base_yaw\"",
                           "[[kinematics.links]]\na_mm = 10\nalpha_deg = 0\nd_mm = 0\ntheta_offset_deg = 0\n\n"
                           "[[joints]]\nname = \"base_yaw\"");
  ConfigReport r = check(t);
  std::vector<std::string> fields;
  for (const auto& e : r.errors) fields.push_back(e.field);
  // encoder_counts now takes 8 input registers (0..7) and runs into status and buttons;
  // current_command takes 4 holding registers (0..3) and runs into control.
  EXPECT_EQ(fields, (std::vector<std::string>{"joints", "actuators", "bus.modbus.registers.status.address",
                                              "bus.modbus.registers.buttons.address",
                                              "bus.modbus.registers.enable.address", "safety.max_joint_torque_nm"}))
      << dump(r);
  EXPECT_EQ(r.errors[0].line, line_of(t, "[[joints]]"));
  EXPECT_EQ(r.errors[0].expected, "4 [[joints]] entries (one per joint of the kinematic model)");
  EXPECT_EQ(r.errors[0].found, "3");
  // CAN node ids: one per joint.
  t = replaced(canopen_, "node_ids = [1, 2, 3, 4]", "node_ids = [1, 2, 4]");
  expect_one(check(t), line_of(t, "node_ids"), "bus.canopen.node_ids", "4 node ids");
  // More than kMaxJoints links.
  std::string links;
  for (int i = 0; i < 9; ++i) links += "[[kinematics.links]]\na_mm = 1\nalpha_deg = 0\nd_mm = 0\ntheta_offset_deg = 0\n";
  t = replaced(modbus_, "[[joints]]\nname = \"base_yaw\"", links + "[[joints]]\nname = \"base_yaw\"");
  r = check(t);
  ASSERT_GE(r.errors.size(), 1u);
  EXPECT_EQ(r.errors[0].field, "kinematics.links") << dump(r);
}

TEST_F(OneError, ModbusChecks) {
  std::string t = replaced(modbus_, "unit_id = 1", "unit_id = 0");
  expect_one(check(t), line_of(t, "unit_id = 0"), "bus.modbus.unit_id", "1..247");
  t = replaced(modbus_, "unit_id = 1", "unit_id = 248");
  expect_one(check(t), line_of(t, "unit_id = 248"), "bus.modbus.unit_id");
  t = replaced(modbus_, "port = 1502", "port = 70000");
  expect_one(check(t), line_of(t, "port = 70000"), "bus.modbus.port");
  // Duplicate register address in the same table; the same address in the other table is fine.
  t = replaced(modbus_, "heartbeat = { table = \"holding\", address = 4,", "heartbeat = { table = \"holding\", address = 3,");
  expect_one(check(t), line_of(t, "heartbeat = "), "bus.modbus.registers.heartbeat.address",
             "not used by bus.modbus.registers.enable.address");
  t = replaced(modbus_, "status = { table = \"input\", address = 6,", "status = { table = \"holding\", address = 6,");
  EXPECT_TRUE(check(t).ok()) << dump(check(t));
  // A 32-bit value at the top of the register space overruns it.
  t = replaced(modbus_, "status = { table = \"input\", address = 6, type = \"u16\",",
               "status = { table = \"input\", address = 65535, type = \"u32\",");
  expect_one(check(t), line_of(t, "65535"), "bus.modbus.registers.status.address", "0..65535");
  // Commands must go to holding registers.
  t = replaced(modbus_, "current_command = { table = \"holding\"", "current_command = { table = \"input\"");
  expect_one(check(t), line_of(t, "current_command = "), "bus.modbus.registers.current_command.table");
  // RTU keys with TCP, and an RTU section with its own checks.
  t = replaced(modbus_, "port = 1502\n", "port = 1502\nparity = \"even\"\n");
  expect_one(check(t), line_of(t, "parity"), "bus.modbus.parity", "transport = \"rtu\"");
  t = replaced(modbus_, "transport = \"tcp\"\nhost = \"127.0.0.1\"\nport = 1502\n",
               "transport = \"rtu\"\ndevice = \"/dev/ttyUSB0\"\nbaud = 115200\nparity = \"mark\"\n");
  expect_one(check(t), line_of(t, "\"mark\""), "bus.modbus.parity", "\"none\", \"even\", \"odd\"");
}

TEST_F(OneError, CanopenChecks) {
  std::string t = replaced(canopen_, "node_ids = [1, 2, 3, 4]", "node_ids = [1, 2, 128, 4]");
  expect_one(check(t), line_of(t, "node_ids"), "bus.canopen.node_ids[2]", "1..127");
  t = replaced(canopen_, "node_ids = [1, 2, 3, 4]", "node_ids = [1, 2, 0, 4]");
  expect_one(check(t), line_of(t, "node_ids"), "bus.canopen.node_ids[2]");
  t = replaced(canopen_, "node_ids = [1, 2, 3, 4]", "node_ids = [1, 2, 2, 4]");
  expect_one(check(t), line_of(t, "node_ids"), "bus.canopen.node_ids[2]", "not used by another joint");
  t = replaced(canopen_, "bitrate = 1000000", "bitrate = 1000001");
  expect_one(check(t), line_of(t, "bitrate"), "bus.canopen.bitrate");
  t = replaced(canopen_, "buttons_node = 4 ", "buttons_node = 9 ");
  expect_one(check(t), line_of(t, "buttons_node"), "bus.canopen.buttons_node", "one of node_ids");
  t = replaced(canopen_, "interface = \"can0\"", "interface = \"a-very-long-can-interface\"");
  expect_one(check(t), line_of(t, "interface ="), "bus.canopen.interface");
  // sync_producer is a boolean: a 0 / 1 or a string is not.
  t = replaced(canopen_, "bitrate = 1000000\n", "bitrate = 1000000\nsync_producer = 0\n");
  expect_one(check(t), line_of(t, "sync_producer"), "bus.canopen.sync_producer", "expected true or false, found integer 0");
  t = replaced(canopen_, "bitrate = 1000000\n", "bitrate = 1000000\nsync_producer = \"no\"\n");
  expect_one(check(t), line_of(t, "sync_producer"), "bus.canopen.sync_producer", "expected true or false, found string \"no\"");
  t = replaced(canopen_, "bitrate = 1000000\n", "bitrate = 1000000\nsync_produce = false\n");
  expect_one(check(t), line_of(t, "sync_produce ="), "bus.canopen.sync_produce", "did you mean \"sync_producer\"");
  t = replaced(canopen_, "bitrate = 1000000\n", "bitrate = 1000000\nsync_producer = false\n");
  auto consumer = load_arm_config_text(t, "t.toml");
  ASSERT_TRUE(consumer.ok()) << consumer.error().message;
  EXPECT_FALSE(consumer.value().canopen->sync_producer);
  // The target torque not mapped: the RPDO cannot drive the arm.
  t = replaced(canopen_, "  { index = 0x6071, subindex = 0, bits = 16 },\n", "");
  expect_one(check(t), line_of(t, "[[bus.canopen.rpdo]]"), "bus.canopen.rpdo", "target_torque (0x6071:00, 16 bits)");
  // Position mapped with the wrong width.
  t = replaced(canopen_, "{ index = 0x6064, subindex = 0, bits = 32 }", "{ index = 0x6064, subindex = 0, bits = 16 }");
  expect_one(check(t), line_of(t, "[[bus.canopen.tpdo]]"), "bus.canopen.tpdo", "mapped with 16 bits");
  // More than 64 bits in one PDO.
  t = replaced(canopen_, "  { index = 0x6064, subindex = 0, bits = 32 },\n",
               "  { index = 0x6064, subindex = 0, bits = 32 },\n  { index = 0x606C, subindex = 0, bits = 32 },\n");
  expect_one(check(t), line_of(t, "entries = [\n  { index = 0x6041"), "bus.canopen.tpdo[0].entries", "64 bits");
  // Two TPDOs with the same number; bits other than 8/16/32.
  t = replaced(canopen_, "number = 2\n", "number = 1\n");
  expect_one(check(t), line_of(t, "number = 1\nsync_divider"), "bus.canopen.tpdo[1].number", "not used by");
  t = replaced(canopen_, "{ index = 0x60FD, subindex = 0, bits = 32 }", "{ index = 0x60FD, subindex = 0, bits = 24 }");
  expect_one(check(t), line_of(t, "bits = 24"), "bus.canopen.tpdo[1].entries[0].bits", "one of 8, 16, 32");
}

TEST_F(OneError, UsbChecks) {
  std::string t = replaced(usb_, "vid = 0x1209", "vid = 0x12090");
  expect_one(check(t), line_of(t, "vid ="), "bus.usb.vid", "0x0000..0xFFFF");
  EXPECT_NE(check(t).errors[0].found.find("0x12090"), std::string::npos);
  t = replaced(usb_, "pid = 0x0001", "pid = -1");
  expect_one(check(t), line_of(t, "pid ="), "bus.usb.pid");
  t = replaced(usb_, "endpoint_in = 0x81", "endpoint_in = 0x01");
  expect_one(check(t), line_of(t, "endpoint_in"), "bus.usb.endpoint_in", "0x0081..0x008F");
  // A field that runs past the report, and one that overlaps another.
  t = replaced(usb_, "size = 64\nreport_id = 1", "size = 14\nreport_id = 1");
  expect_one(check(t), line_of(t, "status = "), "bus.usb.in_report.status.offset", "fits in size = 14");
  t = replaced(usb_, "buttons = { offset = 13,", "buttons = { offset = 12,");
  expect_one(check(t), line_of(t, "buttons = "), "bus.usb.in_report.buttons.offset",
             "not used by bus.usb.in_report.encoder_counts.offset (1..12)");
  // Byte 0 is the report ID.
  t = replaced(usb_, "current_command = { offset = 1,", "current_command = { offset = 0,");
  expect_one(check(t), line_of(t, "current_command = "), "bus.usb.out_report.current_command.offset",
             "report_id");
  // Commands are signed.
  t = replaced(usb_, "type = \"i16\", scale", "type = \"u16\", scale");
  expect_one(check(t), line_of(t, "current_command = "), "bus.usb.out_report.current_command.type");
}

TEST(ArmConfig, AForeignModbusMapLoads) {
  // The map the device tests cross-check against a pymodbus server (its comment says how it is foreign).
  auto r = load_arm_config(std::string(LANCET_SOURCE_DIR) + "/tests/firmware_rt/device/data/foreign_modbus_arm.toml");
  ASSERT_TRUE(r.ok()) << r.error().message;
  const ModbusBusConfig& b = *r.value().modbus;
  const ModbusRegisterMap& m = b.registers;
  EXPECT_EQ(m.encoder_counts.address, (std::vector<std::uint16_t>{10, 20, 30}));
  EXPECT_EQ(m.encoder_counts.type, FieldType::kI32);
  EXPECT_FALSE(m.encoder_counts.high_word_first);
  EXPECT_EQ(m.encoder_counts.byte_order, ByteOrder::kLittle);
  EXPECT_DOUBLE_EQ(m.encoder_counts.scale, 0.25);
  EXPECT_DOUBLE_EQ(m.encoder_counts.bias, 1000.0);
  EXPECT_EQ(m.setpoint_kind, SetpointKind::kTorque);
  EXPECT_EQ(m.setpoint.type, FieldType::kF32);
  EXPECT_TRUE(m.setpoint.high_word_first) << "its own word_order over the map's";
  EXPECT_EQ(m.setpoint.address, (std::vector<std::uint16_t>{100, 104, 108}));
  EXPECT_EQ(m.status_bits.ready.bit, 0);
  EXPECT_EQ(m.status_bits.fault.bit, 2);
  EXPECT_FALSE(m.status_bits.fault.active_low);
  EXPECT_EQ(m.status_bits.estop.bit, 5);
  EXPECT_TRUE(m.status_bits.estop.active_low);
  EXPECT_FALSE(m.status_bits.enabled.mapped());
  EXPECT_EQ(m.enable_on, 0x000Fu);
  EXPECT_EQ(m.enable_off, 0x0006u);
  EXPECT_EQ(m.fault_reset_value, 0x0080u);
  ASSERT_TRUE(m.watchdog_timeout.has_value());
  EXPECT_DOUBLE_EQ(m.watchdog_timeout->scale, 10.0);
  EXPECT_NEAR(b.drive_watchdog, 0.8, 1e-15);
  // The status bits read as the config says.
  EXPECT_TRUE(m.status_bits.estop.active(0x0000));
  EXPECT_FALSE(m.status_bits.estop.active(0x0020));
  EXPECT_TRUE(m.status_bits.fault.active(0x0004));
}

TEST_F(OneError, ModbusRegisterMapChecks) {
  // Per-joint addresses: one per joint, each value's registers apart from the others'.
  std::string t = replaced(modbus_, "encoder_counts = { table = \"input\", address = 0,", "encoder_counts = { table = \"input\", address = [0, 20],");
  expect_one(check(t), line_of(t, "encoder_counts = "), "bus.modbus.registers.encoder_counts.address", "an array of 3 addresses");
  t = replaced(modbus_, "encoder_counts = { table = \"input\", address = 0,", "encoder_counts = { table = \"input\", address = [20, 21, 30],");
  expect_one(check(t), line_of(t, "encoder_counts = "), "bus.modbus.registers.encoder_counts.address[1]",
             "not used by bus.modbus.registers.encoder_counts.address[0] (20..21)");
  t = replaced(modbus_, "encoder_counts = { table = \"input\", address = 0,", "encoder_counts = { table = \"input\", address = [20, 40, 30],");
  EXPECT_TRUE(check(t).ok()) << dump(check(t));
  t = replaced(modbus_, "buttons = { table = \"input\", address = 7,", "buttons = { table = \"input\", address = [7],");
  expect_one(check(t), line_of(t, "buttons = "), "bus.modbus.registers.buttons.address", "0..65535");
  // Setpoints: exactly one of current_command and torque_command.
  t = replaced(modbus_, "current_command = {", "torque_command = {");
  EXPECT_TRUE(check(t).ok()) << dump(check(t));
  t = replaced(modbus_, "current_command = { table = \"holding\", address = 0, type = \"i16\", scale = 0.001 }",
               "current_command = { table = \"holding\", address = 0, type = \"i16\", scale = 0.001 }\n"
               "torque_command = { table = \"holding\", address = 10, type = \"f32\" }");
  expect_one(check(t), line_of(t, "torque_command"), "bus.modbus.registers.torque_command", "only one of current_command and torque_command");
  t = replaced(modbus_, "current_command = { table = \"holding\", address = 0, type = \"i16\", scale = 0.001 }   # A per count; 3 joints: 0..2\n", "");
  expect_one(check(t), line_of(t, "[bus.modbus.registers]"), "bus.modbus.registers.current_command", "torque_command");
  t = replaced(modbus_, "type = \"i16\", scale = 0.001", "type = \"i16\", scale = 0");
  expect_one(check(t), line_of(t, "scale = 0 "), "bus.modbus.registers.current_command.scale", "> 0");
  t = replaced(modbus_, "type = \"i16\", scale = 0.001", "type = \"u16\", scale = 0.001");
  expect_one(check(t), line_of(t, "\"u16\", scale"), "bus.modbus.registers.current_command.type", "\"i16\", \"i32\", \"f32\"");
  // Encoders may be floats, with a bias; status words may not.
  t = replaced(modbus_, "address = 0, type = \"i32\" }", "address = 0, type = \"f32\", scale = 4, bias = -12.5 }");
  EXPECT_TRUE(check(t).ok()) << dump(check(t));
  t = replaced(modbus_, "address = 6, type = \"u16\",", "address = 6, type = \"f32\",");
  expect_one(check(t), line_of(t, "\"f32\""), "bus.modbus.registers.status.type", "\"u16\", \"u32\"");
  // Word and byte order, per map and per entry.
  t = replaced(modbus_, "byte_order = \"big\"", "byte_order = \"middle\"");
  expect_one(check(t), line_of(t, "\"middle\""), "bus.modbus.registers.byte_order", "\"little\", \"big\"");
  t = replaced(modbus_, "address = 0, type = \"i32\" }", "address = 0, type = \"i32\", word_order = \"low_first\", byte_order = \"little\" }");
  EXPECT_TRUE(check(t).ok()) << dump(check(t));
}

TEST_F(OneError, ModbusStatusBitsChecks) {
  std::string t = replaced(modbus_, "bits = { fault = 0, enabled = 1, comm_lost = 2 }", "bits = { faults = 0, enabled = 1 }");
  expect_one(check(t), line_of(t, "faults"), "bus.modbus.registers.status.bits.faults", "did you mean \"fault\"?");
  t = replaced(modbus_, "bits = { fault = 0, enabled = 1, comm_lost = 2 }", "bits = { fault = 16 }");
  expect_one(check(t), line_of(t, "fault = 16"), "bus.modbus.registers.status.bits.fault", "0..15");
  t = replaced(modbus_, "bits = { fault = 0, enabled = 1, comm_lost = 2 }", "bits = { fault = 2, ready = 2 }");
  expect_one(check(t), line_of(t, "ready = 2"), "bus.modbus.registers.status.bits.ready", "not used by bus.modbus.registers.status.bits.fault");
  t = replaced(modbus_, "bits = { fault = 0, enabled = 1, comm_lost = 2 }", "bits = { ready = { bit = 0, active_low = true }, estop = { bit = 3 } }");
  EXPECT_TRUE(check(t).ok()) << dump(check(t));
  t = replaced(modbus_, "bits = { fault = 0, enabled = 1, comm_lost = 2 }", "bits = { estop = { bit = 3, active_low = 1 } }");
  expect_one(check(t), line_of(t, "active_low = 1"), "bus.modbus.registers.status.bits.estop.active_low", "true or false");
  t = replaced(modbus_, "bits = { fault = 0, enabled = 1, comm_lost = 2 }", "bits = { estop = \"five\" }");
  expect_one(check(t), line_of(t, "\"five\""), "bus.modbus.registers.status.bits.estop", "{ bit = N, active_low = true }");
  // A status word without its bits' meaning is an error: a fixed meaning is how faults were missed.
  t = replaced(modbus_, ", bits = { fault = 0, enabled = 1, comm_lost = 2 }", "");
  expect_one(check(t), line_of(t, "status = "), "bus.modbus.registers.status.bits", "which bits of the word mean what");
  // 32-bit status words take bits up to 31.
  t = replaced(modbus_, "type = \"u16\", bits = { fault = 0, enabled = 1, comm_lost = 2 }", "type = \"u32\", bits = { fault = 31 }");
  t = replaced(t, "buttons = { table = \"input\", address = 7,", "buttons = { table = \"input\", address = 8,");
  EXPECT_TRUE(check(t).ok()) << dump(check(t));
}

TEST_F(OneError, ModbusEnableResetWatchdogChecks) {
  std::string t = replaced(modbus_, "on = 1, off = 0", "on = 1, off = 1");
  expect_one(check(t), line_of(t, "off = 1"), "bus.modbus.registers.enable.off", "a value other than on");
  t = replaced(modbus_, "on = 1, off = 0", "on = 0x10000, off = 0");
  expect_one(check(t), line_of(t, "0x10000"), "bus.modbus.registers.enable.on", "0x0000..0xFFFF");
  t = replaced(modbus_, "on = 1, off = 0", "on = 1");
  expect_one(check(t), line_of(t, "enable = "), "bus.modbus.registers.enable.off", "missing");
  // A fault reset of its own place is fine; one that overlaps something else is not.
  t = replaced(modbus_, "fault_reset = { table = \"holding\", address = 3,", "fault_reset = { table = \"holding\", address = 9,");
  EXPECT_TRUE(check(t).ok()) << dump(check(t));
  t = replaced(modbus_, "fault_reset = { table = \"holding\", address = 3,", "fault_reset = { table = \"holding\", address = 4,");
  expect_one(check(t), line_of(t, "heartbeat = "), "bus.modbus.registers.heartbeat.address", "not used by bus.modbus.registers.fault_reset.address");
  t = replaced(modbus_, "fault_reset = { table = \"holding\", address = 3, type = \"u16\"", "fault_reset = { table = \"holding\", address = 3, type = \"u32\"");
  const ConfigReport r = check(t);
  ASSERT_EQ(r.errors.size(), 2u) << dump(r);  // not the enable's place exactly: it overlaps it, and the heartbeat
  EXPECT_EQ(r.errors[0].field, "bus.modbus.registers.fault_reset.address") << dump(r);
  EXPECT_NE(r.errors[0].message.find("not used by bus.modbus.registers.enable.address"), std::string::npos) << dump(r);
  t = replaced(modbus_, "fault_reset = { table = \"holding\"", "fault_reset = { table = \"input\"");
  expect_one(check(t), line_of(t, "fault_reset = "), "bus.modbus.registers.fault_reset.table", "\"holding\"");
  // The drive-side watchdog: needs a heartbeat, 0 is off, else at least 4 response timeouts.
  t = replaced(modbus_, "drive_watchdog_ms = 100", "drive_watchdog_ms = 0");
  EXPECT_TRUE(check(t).ok());
  t = replaced(modbus_, "drive_watchdog_ms = 100", "drive_watchdog_ms = 15");
  expect_one(check(t), line_of(t, "drive_watchdog_ms"), "bus.modbus.drive_watchdog_ms", "at least");
  t = replaced(modbus_, "heartbeat = { table = \"holding\", address = 4, type = \"u16\" }\n", "");
  expect_one(check(t), line_of(t, "drive_watchdog_ms"), "bus.modbus.drive_watchdog_ms", "needs bus.modbus.registers.heartbeat");
  t = replaced(modbus_, "heartbeat = { table = \"holding\", address = 4, type = \"u16\" }\n",
               "heartbeat = { table = \"holding\", address = 4, type = \"u16\" }\nwatchdog_timeout = { table = \"holding\", address = 5, type = \"u16\", scale = 0.1 }\n");
  auto loaded = load_arm_config_text(t, "t.toml");
  ASSERT_TRUE(loaded.ok()) << loaded.error().message;
  EXPECT_DOUBLE_EQ(loaded.value().modbus->registers.watchdog_timeout->scale, 0.1);
}

TEST_F(OneError, OldModbusAndUsbKeysSayWhatReplacedThem) {
  // lsb_ma (mA per count) became scale (A per count); the message gives the number.
  std::string t = replaced(modbus_, "type = \"i16\", scale = 0.001 }", "type = \"i16\", lsb_ma = 2.5 }");
  expect_one(check(t), line_of(t, "lsb_ma"), "bus.modbus.registers.current_command.lsb_ma", "\"lsb_ma\" was replaced: scale = 0.0025");
  t = replaced(usb_, "type = \"i16\", scale = 0.001 }", "type = \"i16\", lsb_ma = 1.0 }");
  expect_one(check(t), line_of(t, "lsb_ma"), "bus.usb.out_report.current_command.lsb_ma", "scale = 0.001");
  // control (bit 0 enable, bit 1 fault reset) became enable and fault_reset, written out.
  t = replaced(modbus_, "enable = { table = \"holding\", address = 3, type = \"u16\", on = 1, off = 0 }\n"
                        "fault_reset = { table = \"holding\", address = 3, type = \"u16\", value = 2 }",
               "control = { table = \"holding\", address = 3, type = \"u16\" }");
  expect_one(check(t), line_of(t, "control = "), "bus.modbus.registers.control",
             "enable = { table = \"holding\", address = 3, type = \"u16\", on = 1, off = 0 } and fault_reset = { table = \"holding\", "
             "address = 3, type = \"u16\", value = 2 }");
  t = replaced(usb_, "enable = { offset = 7, type = \"u8\", on = 1, off = 0 }\nfault_reset = { offset = 7, type = \"u8\", value = 2 }",
               "control = { offset = 7, type = \"u8\" }");
  expect_one(check(t), line_of(t, "control = "), "bus.usb.out_report.control", "enable = { offset = 7, type = \"u8\", on = 1, off = 0 }");
  // The value offset is `bias` (a Modbus entry's place is its address).
  t = replaced(modbus_, "address = 0, type = \"i32\" }", "address = 0, type = \"i32\", offset = 5 }");
  expect_one(check(t), line_of(t, "offset = 5"), "bus.modbus.registers.encoder_counts.offset", "bias");
}

TEST_F(OneError, UsbLayoutChecks) {
  // Floats, scales, biases and byte order per field; torque setpoints.
  std::string t = replaced(usb_, "encoder_counts = { offset = 1, type = \"i32\" }",
                           "encoder_counts = { offset = 1, type = \"f32\", byte_order = \"big\", scale = 2, bias = -5 }");
  t = replaced(t, "current_command = { offset = 1, type = \"i16\", scale = 0.001 }", "torque_command = { offset = 20, type = \"f32\", scale = 0.001 }");
  auto loaded = load_arm_config_text(t, "t.toml");
  ASSERT_TRUE(loaded.ok()) << loaded.error().message;
  const UsbBusConfig& u = *loaded.value().usb;
  EXPECT_EQ(u.encoder_counts.type, FieldType::kF32);
  EXPECT_EQ(u.encoder_counts.byte_order, ByteOrder::kBig);
  EXPECT_EQ(u.buttons->byte_order, ByteOrder::kLittle) << "the section's byte order";
  EXPECT_DOUBLE_EQ(u.encoder_counts.bias, -5.0);
  EXPECT_EQ(u.setpoint_kind, SetpointKind::kTorque);
  EXPECT_EQ(u.setpoint.offset, 20u);
  // Status bits, enable values and the heartbeat fit their field.
  t = replaced(usb_, "bits = { fault = 0, comm_lost = 1 }", "bits = { fault = 8 }");
  expect_one(check(t), line_of(t, "fault = 8"), "bus.usb.in_report.status.bits.fault", "0..7");
  t = replaced(usb_, "on = 1, off = 0", "on = 256, off = 0");
  expect_one(check(t), line_of(t, "on = 256"), "bus.usb.out_report.enable.on", "0x0000..0x00FF");
  t = replaced(usb_, "heartbeat = { offset = 8, type = \"u8\" }", "heartbeat = { offset = 7, type = \"u8\" }");
  expect_one(check(t), line_of(t, "heartbeat = "), "bus.usb.out_report.heartbeat.offset", "not used by bus.usb.out_report.enable.offset");
  t = replaced(usb_, "fault_reset = { offset = 7,", "fault_reset = { offset = 9,");
  EXPECT_TRUE(check(t).ok()) << dump(check(t));
  t = replaced(usb_, "heartbeat = { offset = 8, type = \"u8\" }                # counts up in every OUT report\n", "");
  expect_one(check(t), line_of(t, "drive_watchdog_ms"), "bus.usb.drive_watchdog_ms", "needs bus.usb.out_report.heartbeat");
  t = replaced(usb_, "drive_watchdog_ms = 50", "drive_watchdog_ms = 5");
  expect_one(check(t), line_of(t, "drive_watchdog_ms"), "bus.usb.drive_watchdog_ms", "at least 10 ms");
}

TEST_F(OneError, SafetyChecks) {
  std::string t = replaced(sim_, "workspace_max_mm = [100.0, 190.0, 135.0]", "workspace_max_mm = [100.0, -190.0, 135.0]");
  expect_one(check(t), line_of(t, "workspace_max_mm"), "safety.workspace_max_mm[1]", "> workspace_min_mm[1] (-190)");
  t = replaced(sim_, "watchdog_period_ms = 2.0", "watchdog_period_ms = 0");
  expect_one(check(t), line_of(t, "watchdog_period_ms"), "safety.watchdog_period_ms", "(0, ");
  t = replaced(sim_, "watchdog_period_ms = 2.0", "watchdog_period_ms = -3");
  expect_one(check(t), line_of(t, "watchdog_period_ms"), "safety.watchdog_period_ms");
  t = replaced(sim_, "max_joint_torque_nm = [0.75, 0.85, 0.72]", "max_joint_torque_nm = [0.75, 0.0, 0.72]");
  expect_one(check(t), line_of(t, "max_joint_torque_nm"), "safety.max_joint_torque_nm[1]");
  t = replaced(sim_, "max_slew_n_per_s = 2000.0", "max_slew_n_per_s = 0");
  EXPECT_TRUE(check(t).ok()) << "0 means no slew limit";
}

TEST_F(OneError, BusSectionMustMatchTheBackend) {
  // Declared usb, but the file has the sim section (and no usb one).
  std::string t = replaced(sim_, "backend = \"sim\"", "backend = \"usb\"");
  ConfigReport r = check(t);
  ASSERT_EQ(r.errors.size(), 2u) << dump(r);
  EXPECT_EQ(r.errors[0].field, "bus.sim");
  EXPECT_EQ(r.errors[0].line, line_of(t, "[bus.sim]"));
  EXPECT_NE(r.errors[0].message.find("backend = \"usb\""), std::string::npos);
  EXPECT_EQ(r.errors[1].field, "bus.usb");  // missing, reported where [bus] starts
  EXPECT_EQ(r.errors[1].line, line_of(t, "[bus.sim]"));
  // Declared modbus with no [bus] at all.
  t = replaced(replaced(modbus_, "[bus.modbus]", "[bux.modbus]"), "[bus.modbus.registers]", "[bux.modbus.registers]");
  r = check(t);
  std::vector<std::string> fields;
  for (const auto& e : r.errors) fields.push_back(e.field);
  EXPECT_EQ(fields, (std::vector<std::string>{"bus", "bux"})) << dump(r);
  // A second bus section beside the right one.
  t = modbus_ + "\n[bus.canopen]\ninterface = \"can0\"\n";
  expect_one(check(t), line_of(t, "[bus.canopen]"), "bus.canopen", "only [bus.modbus]");
  // Sim without [bus] is fine.
  t = replaced(sim_, "[bus.sim]\nstylus_mass_kg = 0.15\nhand_stiffness_n_per_m = 1500.0\nhand_damping_ns_per_m = 21.0\n"
                     "encoder_noise_counts = 0\n", "");
  EXPECT_TRUE(check(t).ok()) << dump(check(t));
}

TEST_F(OneError, ButtonChecks) {
  std::string t = replaced(sim_, "bit = 1\n", "bit = 0\n");
  expect_one(check(t), line_of(t, "bit = 0\naction = \"clutch\""), "buttons[1].bit", "not used by buttons[0]");
  t = replaced(usb_, "bit = 1\n", "bit = 8\n");
  expect_one(check(t), line_of(t, "bit = 8"), "buttons[1].bit", "0..7");  // u8 button byte
  t = replaced(usb_, "buttons = { offset = 13, type = \"u8\" }\n", "");
  expect_one(check(t), line_of(t, "[[buttons]]"), "buttons", "bus.usb.in_report.buttons");
  t = replaced(sim_, "action = \"clutch\"", "action = \"grab\"");
  expect_one(check(t), line_of(t, "\"grab\""), "buttons[1].action");
  // CANopen buttons need the digital inputs in a TPDO.
  t = replaced(canopen_, "  { index = 0x60FD, subindex = 0, bits = 32 },\n", "  { index = 0x6077, subindex = 0, bits = 16 },\n");
  expect_one(check(t), line_of(t, "[[bus.canopen.tpdo]]"), "bus.canopen.tpdo", "digital_inputs");
}

TEST_F(OneError, KinematicsChecks) {
  std::string t = replaced(sim_, "model = \"phantom\"", "model = \"scara\"");
  ConfigReport r = check(t);
  ASSERT_EQ(r.errors.size(), 1u) << "an unknown model does not cascade into joint errors:\n" << dump(r);
  EXPECT_EQ(r.errors[0].field, "kinematics.model");
  t = replaced(modbus_, "alpha_deg = 90.0", "alpha_deg = 400.0");
  expect_one(check(t), line_of(t, "alpha_deg = 400"), "kinematics.links[0].alpha_deg");
  t = replaced(modbus_, "type = \"revolute\"\na_mm = 250.0", "type = \"rotary\"\na_mm = 250.0");
  r = check(t);
  ASSERT_EQ(r.errors.size(), 1u) << dump(r);
  EXPECT_EQ(r.errors[0].field, "kinematics.links[1].type");
  t = replaced(modbus_, "tool_offset_mm = [25.0, 0.0, 0.0]", "tool_offset_mm = [25.0, 0.0, 0.0]\nl1_mm = 3");
  expect_one(check(t), line_of(t, "l1_mm"), "kinematics.l1_mm", "model = \"phantom\"");
  t = replaced(sim_, "l1_mm = 209.55 ", "l1_mm = 0 ");
  expect_one(check(t), line_of(t, "l1_mm = 0"), "kinematics.l1_mm", "(0, ");
}

TEST_F(OneError, DeltaKinematicsChecks) {
  const std::string delta = delta_text();
  ASSERT_TRUE(check(delta).ok()) << dump(check(delta));
  // A value out of range, with the range in the message.
  std::string t = replaced(delta, "b_mm = 102.5", "b_mm = 0");
  expect_one(check(t), line_of(t, "b_mm = 0"), "kinematics.b_mm", "(0, ");
  t = replaced(delta, "d_mm = 11.25", "d_mm = -1");
  expect_one(check(t), line_of(t, "d_mm = -1"), "kinematics.d_mm", "[0, 10000]");
  // Three leg angles, each within ±360°.
  t = replaced(delta, "leg_angles_deg = [105.0, -15.0, -135.0]", "leg_angles_deg = [105.0, -15.0]");
  ConfigReport r = check(t);
  expect_one(r, line_of(t, "leg_angles_deg"), "kinematics.leg_angles_deg", "an array of 3 numbers");
  EXPECT_EQ(r.errors[0].found, "array of 2");
  t = replaced(delta, "leg_angles_deg = [105.0, -15.0, -135.0]", "leg_angles_deg = [105.0, -15.0, 400.0]");
  expect_one(check(t), line_of(t, "leg_angles_deg"), "kinematics.leg_angles_deg[2]", "[-360, 360]");
  // A missing dimension is reported at the table.
  t = replaced(delta, "r_mm = 40.0\n", "");
  expect_one(check(t), line_of(t, "[kinematics]"), "kinematics.r_mm", "required key is missing");
  // The other models' keys are errors here, and the delta's keys under the other models.
  t = replaced(delta, "a_mm = 60.0", "a_mm = 60.0\nl1_mm = 3");
  expect_one(check(t), line_of(t, "l1_mm"), "kinematics.l1_mm", "model = \"phantom\"");
  t = replaced(delta, "a_mm = 60.0", "a_mm = 60.0\ntool_offset_mm = [0.0, 0.0, 0.0]");
  expect_one(check(t), line_of(t, "tool_offset_mm"), "kinematics.tool_offset_mm", "model = \"dh\"");
  t = replaced(sim_, "l1_mm = 209.55 ", "a_mm = 60.0\nl1_mm = 209.55 ");
  expect_one(check(t), line_of(t, "a_mm"), "kinematics.a_mm", "model = \"delta\"");
  t = replaced(modbus_, "tool_offset_mm = [25.0, 0.0, 0.0]", "tool_offset_mm = [25.0, 0.0, 0.0]\nleg_angles_deg = [0, 120, 240]");
  expect_one(check(t), line_of(t, "leg_angles_deg"), "kinematics.leg_angles_deg", "model = \"delta\"");
  // A geometry whose legs cannot be assembled: reported at [kinematics], saying why.
  t = replaced(delta, "f_mm = -25.0", "f_mm = 200.0");
  r = check(t);
  expect_one(r, line_of(t, "[kinematics]"), "kinematics", "common axis");
  EXPECT_EQ(r.errors[0].expected, "a delta geometry whose legs can be assembled");
  t = replaced(delta, "leg_angles_deg = [105.0, -15.0, -135.0]", "leg_angles_deg = [105.0, -15.0, 105.5]");
  expect_one(check(t), line_of(t, "[kinematics]"), "kinematics", "coincide");
  // The model is named in the choice's message.
  t = replaced(delta, "model = \"delta\"", "model = \"detla\"");
  r = check(t);
  ASSERT_EQ(r.errors.size(), 1u) << dump(r);
  EXPECT_NE(r.errors[0].message.find("did you mean \"delta\"?"), std::string::npos) << dump(r);
}

// --- report format, files, the command --------------------------------------------------------

TEST(ArmConfig, FormatReportLines) {
  ConfigReport r;
  r.file = "a.toml";
  r.errors.push_back({"a.toml", 3, 7, "joints[0].gear_ratio", "a number > 0", "integer 0", "expected a number > 0, found integer 0"});
  r.errors.push_back({"a.toml", 9, 2, "", "valid TOML", "a syntax error", "TOML syntax error: x"});
  EXPECT_EQ(format_report(r),
            "a.toml:3:7: joints[0].gear_ratio: expected a number > 0, found integer 0\n"
            "a.toml:9:2: TOML syntax error: x\n");
  EXPECT_EQ(format_report(ConfigReport{}), "");
}

class ArmConfigFiles : public lancet::test::TempDirTest {};

TEST_F(ArmConfigFiles, UnreadableFile) {
  const std::string missing = (dir_ / "nope.toml").string();
  const ConfigReport r = validate_arm_config_file(missing);
  EXPECT_FALSE(r.readable);
  EXPECT_FALSE(r.ok());
  ASSERT_EQ(r.errors.size(), 1u);
  EXPECT_EQ(format_report(r), missing + ": cannot open: No such file or directory\n");
  auto l = load_arm_config(missing);
  ASSERT_FALSE(l.ok());
  EXPECT_EQ(l.error().code, ErrorCode::kNotFound);
  // A directory is not a config either.
  EXPECT_FALSE(validate_arm_config_file(dir_.string()).readable);
}

std::string run_to_string(const std::string& path, int& rc) {
  std::FILE* f = std::tmpfile();
  rc = tools::run_validate(path, f);
  std::rewind(f);
  std::string out;
  char buf[4096];
  std::size_t n = 0;
  while ((n = std::fread(buf, 1, sizeof buf, f)) > 0) out.append(buf, n);
  std::fclose(f);
  return out;
}

TEST_F(ArmConfigFiles, ValidateCommandExitCodes) {
  int rc = -1;
  std::string out = run_to_string(config_dir() + "sim_3dof.toml", rc);
  EXPECT_EQ(rc, 0) << out;
  EXPECT_NE(out.find(": ok: \"sim-3dof\", backend sim, phantom model, 3 joints, 2 buttons"), std::string::npos) << out;

  const std::string bad = write("bad.toml", kBroken);
  out = run_to_string(bad, rc);
  EXPECT_EQ(rc, 1);
  EXPECT_NE(out.find(bad + ":16:13: joints[0].direction: expected one of -1, 1, found integer 2\n"), std::string::npos) << out;
  EXPECT_NE(out.find(bad + ": 31 errors\n"), std::string::npos) << out;

  const std::string delta = write("delta.toml", delta_text());
  out = run_to_string(delta, rc);
  EXPECT_EQ(rc, 0) << out;
  EXPECT_NE(out.find(": ok: \"sim-3dof\", backend sim, delta model, 3 joints, 2 buttons"), std::string::npos) << out;

  out = run_to_string((dir_ / "missing.toml").string(), rc);
  EXPECT_EQ(rc, 2);
  EXPECT_NE(out.find("cannot open"), std::string::npos) << out;
}

// --- conversions ------------------------------------------------------------------------------

TEST(ArmConfig, JointConversions) {
  JointConfig j;
  j.counts_per_rev = 4000;
  j.gear_ratio = 10;
  j.direction = -1;
  j.offset = 0.1;
  // One output revolution is 40000 counts.
  EXPECT_NEAR(joint_position_from_counts(j, 10000), -std::numbers::pi / 2 + 0.1, 1e-12);
  ActuatorConfig a;
  a.torque_constant = 0.02;
  // 1 N·m at the joint is 0.1 N·m at the motor: 5 A, sign flipped.
  EXPECT_NEAR(motor_current_for_joint_torque(j, a, 1.0), -5.0, 1e-12);
  JointConfig p;
  p.type = JointType::kPrismatic;
  p.counts_per_rev = 1000;
  p.gear_ratio = 1;
  p.direction = 1;
  p.lead = 0.04;
  EXPECT_NEAR(joint_position_from_counts(p, 500), 0.02, 1e-15);
  // 10 N on a 40 mm-lead drum is 10·0.04/2π N·m.
  EXPECT_NEAR(motor_current_for_joint_torque(p, a, 10.0), 10 * 0.04 / (2 * std::numbers::pi) / 0.02, 1e-12);
}

// --- robustness -------------------------------------------------------------------------------

TEST(ArmConfig, MutatedConfigsNeverCrashTheLoader) {
  std::mt19937 rng(0x1a4ce7);
  const std::string noise = "[]{}=\"'.,#\n \t0123456789-+_abcxyz\\\x01\xff\xc3";
  std::size_t valid = 0, invalid = 0;
  for (const std::string& f : shipped()) {
    const std::string base = shipped_text(f);
    for (int i = 0; i < 1000; ++i) {
      std::string t = base;
      std::uniform_int_distribution<int> kind(0, 5);
      const int edits = 1 + i % 4;
      for (int e = 0; e < edits && !t.empty(); ++e) {
        std::uniform_int_distribution<std::size_t> pos(0, t.size() - 1);
        const std::size_t p = pos(rng);
        switch (kind(rng)) {
          case 0: t[p] = static_cast<char>(rng() & 0xff); break;                       // byte flip
          case 1: t[p] = noise[rng() % noise.size()]; break;                           // TOML-ish byte
          case 2: t.erase(p, 1 + rng() % 16); break;                                   // deletion
          case 3: t.insert(p, 1, noise[rng() % noise.size()]); break;                  // insertion
          case 4: t.resize(p); break;                                                  // truncation
          default: t.insert(p, t.substr(p, std::min<std::size_t>(80, t.size() - p))); // duplication
        }
      }
      ConfigReport r;
      EXPECT_NO_THROW(r = validate_arm_config_text(t, f));
      for (const ConfigError& e : r.errors) {
        EXPECT_GE(e.line, 1);
        EXPECT_FALSE(e.message.empty());
      }
      bool loaded = false;
      EXPECT_NO_THROW({
        auto c = load_arm_config_text(t, f);
        loaded = c.ok();
        if (loaded) {
          // Whatever loads must give a usable model.
          auto k = make_kinematics(c.value());
          EXPECT_TRUE(k.ok());
        }
      });
      EXPECT_EQ(loaded, r.ok());
      (r.ok() ? valid : invalid) += 1;
    }
  }
  EXPECT_GT(invalid, 0u);
  EXPECT_GT(valid, 0u) << "some mutations (in comments, say) leave a valid file";
}

}  // namespace
}  // namespace lancet::arm
