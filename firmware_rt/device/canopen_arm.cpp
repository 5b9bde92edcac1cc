#include "device/canopen_arm.hpp"

#include "device/joint_signals.hpp"

#include "lancet/shared_model/units.hpp"

#include <errno.h>
#include <fcntl.h>
#include <linux/can.h>
#include <linux/can/error.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <vector>

namespace lancet::device {

namespace {

timespec to_timespec(std::int64_t ns) noexcept {
  if (ns < 0) ns = 0;
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(ns / 1'000'000'000);
  ts.tv_nsec = static_cast<long>(ns % 1'000'000'000);
  return ts;
}

void sleep_until(std::int64_t t_ns) noexcept {
  const timespec ts = to_timespec(t_ns);
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
}

void put_le(std::uint8_t* p, std::uint32_t v, int bytes) noexcept {
  for (int b = 0; b < bytes; ++b) p[b] = static_cast<std::uint8_t>(v >> (8 * b));
}

std::uint32_t get_le(const std::uint8_t* p, int bytes) noexcept {
  std::uint32_t v = 0;
  for (int b = 0; b < bytes; ++b) v |= static_cast<std::uint32_t>(p[b]) << (8 * b);
  return v;
}

std::string hex(std::uint32_t v, int digits) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "0x%0*X", digits, v);
  return buf;
}

std::string object_name(std::uint16_t index, std::uint8_t sub) { return hex(index, 4) + ":" + [&] {
  char buf[4];
  std::snprintf(buf, sizeof buf, "%02X", sub);
  return std::string(buf);
}(); }

std::string errno_text(int err) { return std::string(std::strerror(err)) + " (errno " + std::to_string(err) + ")"; }

std::string ms_text(double s) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.0f ms", s * 1e3);
  return buf;
}

canopen::NmtState nmt_from_byte(std::uint8_t b) noexcept {
  switch (b & 0x7F) {
    case 0x00: return canopen::NmtState::kBootUp;
    case 0x04: return canopen::NmtState::kStopped;
    case 0x05: return canopen::NmtState::kOperational;
    case 0x7F: return canopen::NmtState::kPreOperational;
    default: return canopen::NmtState::kUnknown;
  }
}

constexpr int kMaxFramesPerDrain = 512;

std::int64_t ns_of(double seconds) noexcept { return static_cast<std::int64_t>(std::llround(seconds * 1e9)); }

}  // namespace

// ---------------------------------------------------------------------------------------------
// Codec

namespace canopen {

Cia402State cia402_state(std::uint16_t sw) noexcept {
  if ((sw & 0x4F) == 0x00) return Cia402State::kNotReadyToSwitchOn;
  if ((sw & 0x4F) == 0x40) return Cia402State::kSwitchOnDisabled;
  if ((sw & 0x6F) == 0x21) return Cia402State::kReadyToSwitchOn;
  if ((sw & 0x6F) == 0x23) return Cia402State::kSwitchedOn;
  if ((sw & 0x6F) == 0x27) return Cia402State::kOperationEnabled;
  if ((sw & 0x6F) == 0x07) return Cia402State::kQuickStopActive;
  if ((sw & 0x4F) == 0x0F) return Cia402State::kFaultReactionActive;
  if ((sw & 0x4F) == 0x08) return Cia402State::kFault;
  return Cia402State::kUnknown;
}

const char* to_string(Cia402State s) noexcept {
  switch (s) {
    case Cia402State::kNotReadyToSwitchOn: return "not ready to switch on";
    case Cia402State::kSwitchOnDisabled: return "switch on disabled";
    case Cia402State::kReadyToSwitchOn: return "ready to switch on";
    case Cia402State::kSwitchedOn: return "switched on";
    case Cia402State::kOperationEnabled: return "operation enabled";
    case Cia402State::kQuickStopActive: return "quick stop active";
    case Cia402State::kFaultReactionActive: return "fault reaction active";
    case Cia402State::kFault: return "fault";
    case Cia402State::kUnknown: return "unknown";
  }
  return "?";
}

const char* to_string(NmtState s) noexcept {
  switch (s) {
    case NmtState::kBootUp: return "boot-up";
    case NmtState::kStopped: return "stopped";
    case NmtState::kOperational: return "operational";
    case NmtState::kPreOperational: return "pre-operational";
    case NmtState::kUnknown: return "unknown";
  }
  return "?";
}

std::uint16_t controlword_toward_enabled(std::uint16_t statusword, std::uint16_t previous) noexcept {
  switch (cia402_state(statusword)) {
    case Cia402State::kFault:
      // Fault reset acts on the rising edge of bit 7: drop it first if it is still set.
      return (previous & kCwFaultReset) != 0 ? kCwDisableVoltage : kCwFaultReset;
    case Cia402State::kSwitchOnDisabled: return kCwShutdown;
    case Cia402State::kReadyToSwitchOn: return kCwSwitchOn;
    case Cia402State::kSwitchedOn:
    case Cia402State::kOperationEnabled: return kCwEnableOperation;
    case Cia402State::kQuickStopActive:  // back through switch on disabled
    case Cia402State::kNotReadyToSwitchOn:
    case Cia402State::kFaultReactionActive:
    case Cia402State::kUnknown: return kCwDisableVoltage;
  }
  return kCwDisableVoltage;
}

std::uint32_t rated_torque_mnm(const arm::ActuatorConfig& actuator) noexcept {
  const double mnm = actuator.continuous_torque() * 1e3;
  if (!(mnm >= 0.5) || !std::isfinite(mnm)) return 0;
  if (mnm >= 4.0e9) return std::numeric_limits<std::uint32_t>::max();
  return static_cast<std::uint32_t>(std::llround(mnm));
}

std::int16_t torque_per_mille(const arm::JointConfig& joint, const arm::ActuatorConfig& actuator, std::uint32_t rated_mnm,
                              std::int16_t limit, double tau) noexcept {
  if (!std::isfinite(tau) || rated_mnm == 0) return 0;
  // Motor-shaft torque (mN·m) through the gear, direction and lead, then per mille of the rated torque.
  const double motor_mnm = arm::motor_current_for_joint_torque(joint, actuator, tau) * actuator.torque_constant * 1e3;
  const double lim = std::min<double>(std::abs(static_cast<int>(limit)), 32767.0);
  const double pm = std::clamp(motor_mnm * 1e3 / static_cast<double>(rated_mnm), -lim, lim);
  return static_cast<std::int16_t>(std::lround(pm));
}

const char* sdo_abort_text(std::uint32_t code) noexcept {
  switch (code) {
    case 0x05030000: return "toggle bit not alternated";
    case 0x05040000: return "SDO protocol timed out";
    case 0x05040001: return "client/server command specifier not valid or unknown";
    case 0x05040005: return "out of memory";
    case 0x06010000: return "unsupported access to an object";
    case 0x06010001: return "attempt to read a write-only object";
    case 0x06010002: return "attempt to write a read-only object";
    case 0x06020000: return "object does not exist in the object dictionary";
    case 0x06040041: return "object cannot be mapped to the PDO";
    case 0x06040042: return "the number and length of the objects to be mapped would exceed the PDO length";
    case 0x06040043: return "general parameter incompatibility";
    case 0x06040047: return "general internal incompatibility in the device";
    case 0x06060000: return "access failed due to a hardware error";
    case 0x06070010: return "data type does not match, length of service parameter does not match";
    case 0x06070012: return "data type does not match, length of service parameter too high";
    case 0x06070013: return "data type does not match, length of service parameter too low";
    case 0x06090011: return "sub-index does not exist";
    case 0x06090030: return "invalid value for parameter";
    case 0x06090031: return "value of parameter written too high";
    case 0x06090032: return "value of parameter written too low";
    case 0x08000000: return "general error";
    case 0x08000020: return "data cannot be transferred or stored to the application";
    case 0x08000021: return "data cannot be transferred because of local control";
    case 0x08000022: return "data cannot be transferred because of the present device state";
    default: return "unknown abort code";
  }
}

const char* mode_name(std::int8_t mode) noexcept {
  switch (mode) {
    case 0: return "no mode";
    case kModeProfileTorque: return "profile torque";
    case kModeCyclicSyncTorque: return "cyclic synchronous torque";
    case 1: return "profile position";
    case 3: return "profile velocity";
    case 6: return "homing";
    case 8: return "cyclic synchronous position";
    case 9: return "cyclic synchronous velocity";
    default: return "another mode";
  }
}

std::optional<InterpolationPeriod> interpolation_period(std::int64_t period_us) noexcept {
  if (period_us <= 0) return std::nullopt;
  std::int64_t value = period_us;
  int index = -6;
  while (value % 10 == 0 && index < 0) {
    value /= 10;
    ++index;
  }
  if (value > 255) return std::nullopt;
  return InterpolationPeriod{static_cast<std::uint8_t>(value), static_cast<std::int8_t>(index)};
}

namespace {

struct EmcyEntry {
  std::uint16_t code;
  const char* text;
};

// The common codes of CiA 301 (communication) and CiA 402 / IEC 61800-7 (drives).
constexpr EmcyEntry kEmcyCodes[] = {
    {0x0000, "error reset or no error"},
    {0x1000, "generic error"},
    {0x2110, "short circuit / earth leakage (input side)"},
    {0x2120, "earth leakage (input side)"},
    {0x2130, "short circuit (input side)"},
    {0x2230, "short circuit / earth leakage (inside the device)"},
    {0x2300, "current, device output side"},
    {0x2310, "continuous over-current (output side)"},
    {0x2311, "continuous over-current no. 1 (output side)"},
    {0x2312, "continuous over-current no. 2 (output side)"},
    {0x2320, "short circuit / earth leakage (motor side)"},
    {0x2330, "earth leakage (motor side)"},
    {0x2340, "short circuit (motor side)"},
    {0x3110, "mains over-voltage"},
    {0x3120, "mains under-voltage"},
    {0x3130, "mains phase failure"},
    {0x3210, "DC link over-voltage"},
    {0x3220, "DC link under-voltage"},
    {0x3230, "DC link load error"},
    {0x3310, "output over-voltage"},
    {0x4110, "excess ambient temperature"},
    {0x4120, "too low ambient temperature"},
    {0x4210, "excess device temperature"},
    {0x4220, "too low device temperature"},
    {0x4300, "drive temperature"},
    {0x4310, "drive over-temperature"},
    {0x4320, "too low drive temperature"},
    {0x4410, "excess supply temperature"},
    {0x5111, "control supply ±15 V"},
    {0x5112, "control supply +24 V"},
    {0x5113, "control supply +5 V"},
    {0x5210, "measurement circuit"},
    {0x5220, "computing circuit"},
    {0x5400, "power section"},
    {0x5410, "output stages"},
    {0x5420, "chopper"},
    {0x5430, "input stages"},
    {0x5440, "contactors"},
    {0x5441, "contactor 1 (manufacturer-specific)"},
    {0x5450, "fuses"},
    {0x5530, "flash memory"},
    {0x6010, "software reset (watchdog)"},
    {0x6100, "internal software"},
    {0x6200, "user software"},
    {0x6300, "data set"},
    {0x6320, "parameter error"},
    {0x7110, "brake chopper"},
    {0x7111, "brake chopper failure"},
    {0x7112, "brake chopper over-current"},
    {0x7120, "motor"},
    {0x7121, "motor blocked"},
    {0x7122, "motor error or commutation malfunction"},
    {0x7123, "motor tilted"},
    {0x7300, "sensor"},
    {0x7303, "resolver 1 fault"},
    {0x7304, "resolver 2 fault"},
    {0x7305, "incremental encoder 1 fault"},
    {0x7306, "incremental encoder 2 fault"},
    {0x7310, "speed sensor"},
    {0x7320, "position sensor"},
    {0x8100, "communication"},
    {0x8110, "CAN overrun (objects lost)"},
    {0x8120, "CAN in error passive mode"},
    {0x8130, "heartbeat / life guard error"},
    {0x8140, "recovered from bus off"},
    {0x8150, "CAN-ID collision"},
    {0x8200, "protocol error"},
    {0x8210, "PDO not processed: length error"},
    {0x8220, "PDO length exceeded"},
    {0x8240, "unexpected SYNC data length"},
    {0x8250, "RPDO timeout"},
    {0x8300, "torque control"},
    {0x8311, "excess torque"},
    {0x8312, "difficult start-up"},
    {0x8313, "standstill torque"},
    {0x8321, "insufficient torque"},
    {0x8331, "torque fault"},
    {0x8400, "velocity / speed controller"},
    {0x8500, "position controller"},
    {0x8600, "positioning controller"},
    {0x8611, "following error"},
    {0x8612, "reference limit"},
    {0x8700, "sync controller"},
    {0x8800, "winding controller"},
    {0x9000, "external error"},
    {0xF000, "additional functions"},
    {0xFF00, "device-specific"},
};

// Classes by the high byte, then by the high nibble.
constexpr EmcyEntry kEmcyByteClasses[] = {
    {0x00, "error reset or no error"},  {0x10, "generic error"},
    {0x20, "current"},                  {0x21, "current, device input side"},
    {0x22, "current inside the device"}, {0x23, "current, device output side"},
    {0x30, "voltage"},                  {0x31, "mains voltage"},
    {0x32, "voltage inside the device"}, {0x33, "output voltage"},
    {0x40, "temperature"},              {0x41, "ambient temperature"},
    {0x42, "device temperature"},       {0x43, "drive temperature"},
    {0x44, "supply temperature"},       {0x50, "device hardware"},
    {0x51, "supply"},                   {0x52, "control"},
    {0x53, "operating unit"},           {0x54, "power section"},
    {0x55, "data storage"},             {0x60, "device software"},
    {0x61, "internal software"},        {0x62, "user software"},
    {0x63, "data set"},                 {0x70, "additional modules"},
    {0x71, "power"},                    {0x72, "measurement circuit"},
    {0x73, "sensor"},                   {0x74, "computation circuit"},
    {0x75, "communication"},            {0x76, "data storage"},
    {0x80, "monitoring"},               {0x81, "monitoring: communication"},
    {0x82, "monitoring: protocol error"}, {0x83, "torque control"},
    {0x84, "velocity / speed controller"}, {0x85, "position controller"},
    {0x86, "positioning controller"},   {0x87, "sync controller"},
    {0x88, "winding controller"},       {0x90, "external error"},
    {0xF0, "additional functions"},     {0xFF, "device-specific"},
};
constexpr const char* kEmcyNibbleClasses[16] = {
    "error reset or no error", "generic error", "current", "voltage", "temperature", "device hardware",
    "device software", "additional modules", "monitoring", "external error", "reserved class", "reserved class",
    "reserved class", "reserved class", "reserved class", "additional functions",
};

}  // namespace

EmcyMeaning emcy_meaning(std::uint16_t code) noexcept {
  for (const EmcyEntry& e : kEmcyCodes)
    if (e.code == code) return {e.text, true};
  for (const EmcyEntry& e : kEmcyByteClasses)
    if (e.code == (code >> 8)) return {e.text, false};
  return {kEmcyNibbleClasses[code >> 12], false};
}

const char* format_emcy(char* buf, std::size_t size, const Emcy& e) noexcept {
  if (buf == nullptr || size == 0) return buf;
  const EmcyMeaning m = emcy_meaning(e.error_code);
  bool by_byte = false;
  for (const EmcyEntry& c : kEmcyByteClasses) by_byte = by_byte || c.code == (e.error_code >> 8);
  if (m.specific) {
    std::snprintf(buf, size, "node %d: EMCY 0x%04X %s, error register 0x%02X", e.node_id, e.error_code, m.text, e.error_register);
  } else if (by_byte) {
    std::snprintf(buf, size, "node %d: EMCY 0x%04X (0x%02Xxx %s), error register 0x%02X", e.node_id, e.error_code,
                  e.error_code >> 8, m.text, e.error_register);
  } else {
    std::snprintf(buf, size, "node %d: EMCY 0x%04X (0x%Xxxx %s), error register 0x%02X", e.node_id, e.error_code,
                  e.error_code >> 12, m.text, e.error_register);
  }
  return buf;
}

}  // namespace canopen

// ---------------------------------------------------------------------------------------------
// Construction

CanopenArm::CanopenArm(const arm::ArmConfig& config, FaultPolicy policy, CanopenTiming timing)
    : Device("canopen arm '" + config.name + "' on " + config.canopen->interface_name, policy),
      config_(config),
      bus_(*config.canopen),
      timing_(timing) {}

Result<std::unique_ptr<CanopenArm>> CanopenArm::create(const arm::ArmConfig& config, FaultPolicy policy, CanopenTiming timing) {
  const std::string where = config.source.empty() ? std::string("arm config") : config.source;
  if (!config.canopen) {
    return Error{ErrorCode::kInvalid, where + ": CanopenArm needs a [bus.canopen] section (backend = \"canopen\"); this config has none"};
  }
  const arm::CanopenBusConfig& bus = *config.canopen;
  const int n = config.joint_count();
  if (n < 1 || n > kMaxJoints || static_cast<int>(bus.node_ids.size()) != n || static_cast<int>(config.joints.size()) != n ||
      static_cast<int>(config.actuators.size()) != n) {
    return Error{ErrorCode::kInvalid, where + ": bus.canopen: expected 1.." + std::to_string(kMaxJoints) +
                                          " joints with one node id, joint and actuator each, found " + std::to_string(n) +
                                          " joints, " + std::to_string(bus.node_ids.size()) + " node ids, " +
                                          std::to_string(config.joints.size()) + " joint and " +
                                          std::to_string(config.actuators.size()) + " actuator entries"};
  }
  if (!(bus.sync_period > 0) || !(timing.read_budget_fraction > 0) || !(timing.sdo_timeout > 0) ||
      !(timing.state_timeout > 0) || !(timing.mode_timeout > 0) || !(timing.heartbeat_timeout_factor >= 1)) {
    return Error{ErrorCode::kInvalid, where + ": bus.canopen: sync period and timeouts must be > 0 (heartbeat factor >= 1)"};
  }
  // 0x1006 is whole µs; cyclic synchronous mode also writes the period to 0x60C2.
  const double period_us = bus.sync_period * 1e6;
  const auto whole_us = static_cast<std::int64_t>(std::llround(period_us));
  std::optional<canopen::InterpolationPeriod> interpolation = canopen::interpolation_period(whole_us);
  if (std::abs(period_us - static_cast<double>(whole_us)) > 1e-6 ||
      (bus.mode == arm::Cia402Mode::kCyclicSyncTorque && !interpolation)) {
    return Error{ErrorCode::kInvalid, where + ": bus.canopen.sync_period_us: " + std::to_string(period_us) +
                                          " µs is not a whole number of µs that 0x60C2 can express (value 1..255 · 10^index s)"};
  }
  if (bus.master_node_id < 1 || bus.master_node_id > 127 ||
      std::find(bus.node_ids.begin(), bus.node_ids.end(), bus.master_node_id) != bus.node_ids.end()) {
    return Error{ErrorCode::kInvalid, where + ": bus.canopen.master_node_id: expected 1..127 and none of node_ids, found " +
                                          std::to_string(bus.master_node_id)};
  }
  if (!(bus.drive_watchdog >= 0) || bus.drive_watchdog > 65.535 ||
      (bus.drive_watchdog > 0 && bus.drive_watchdog < 4 * bus.sync_period)) {
    return Error{ErrorCode::kInvalid, where + ": bus.canopen.drive_watchdog_ms: expected 0 or 4 SYNC periods .. 65535 ms, found " +
                                          std::to_string(bus.drive_watchdog * 1e3) + " ms"};
  }

  std::unique_ptr<CanopenArm> a(new CanopenArm(config, policy, timing));
  a->n_ = n;
  a->index_of_id_.fill(-1);

  // PDO plans: where the driver's objects sit in each PDO (the same on every node).
  const arm::Cia402Objects& obj = bus.objects;
  auto plan = [&](const std::vector<arm::PdoConfig>& pdos, std::array<PdoPlan, 4>& out, int& count,
                  const char* key) -> std::optional<Error> {
    if (pdos.size() > 4) return Error{ErrorCode::kInvalid, where + ": bus.canopen." + key + ": at most 4 PDOs"};
    count = 0;
    for (const arm::PdoConfig& pc : pdos) {
      if (pc.number < 1 || pc.number > 4 || pc.sync_divider < 1 || pc.sync_divider > 240) {
        return Error{ErrorCode::kInvalid, where + ": bus.canopen." + key + ": number must be 1..4 and sync_divider 1..240"};
      }
      PdoPlan& p = out[static_cast<std::size_t>(count++)];
      p.number = pc.number;
      p.divider = pc.sync_divider;
      int offset = 0;
      for (const arm::PdoEntry& e : pc.entries) {
        const int bytes = e.bits / 8;
        if (bytes < 1 || e.bits % 8 != 0 || offset + bytes > 8) {
          return Error{ErrorCode::kInvalid, where + ": bus.canopen." + key + " " + std::to_string(pc.number) +
                                                ": entries must be whole bytes and fit in 8 bytes"};
        }
        const Slot s{true, static_cast<std::uint8_t>(offset), static_cast<std::uint8_t>(bytes)};
        if (e.subindex == 0) {
          if (e.index == obj.statusword && bytes == 2) p.statusword = s;
          if (e.index == obj.position_actual && bytes == 4) p.position = s;
          if (e.index == obj.digital_inputs && bytes == 4) p.inputs = s;
          if (e.index == obj.controlword && bytes == 2) p.controlword = s;
          if (e.index == obj.target_torque && bytes == 2) p.target_torque = s;
          if (e.index == 0x6060 && bytes == 1) p.mode = s;
        }
        offset += bytes;
      }
      p.size = static_cast<std::uint8_t>(offset);
    }
    return std::nullopt;
  };
  if (auto e = plan(bus.tpdos, a->tpdos_, a->n_tpdos_, "tpdo")) return *e;
  if (auto e = plan(bus.rpdos, a->rpdos_, a->n_rpdos_, "rpdo")) return *e;
  auto has = [](const std::array<PdoPlan, 4>& plans, int count, Slot PdoPlan::*slot) {
    for (int k = 0; k < count; ++k)
      if ((plans[static_cast<std::size_t>(k)].*slot).present) return true;
    return false;
  };
  std::string missing;
  if (!has(a->tpdos_, a->n_tpdos_, &PdoPlan::statusword)) missing += " statusword (" + hex(obj.statusword, 4) + ", 16 bits, TPDO);";
  if (!has(a->tpdos_, a->n_tpdos_, &PdoPlan::position)) missing += " position_actual (" + hex(obj.position_actual, 4) + ", 32 bits, TPDO);";
  if (!has(a->rpdos_, a->n_rpdos_, &PdoPlan::controlword)) missing += " controlword (" + hex(obj.controlword, 4) + ", 16 bits, RPDO);";
  if (!has(a->rpdos_, a->n_rpdos_, &PdoPlan::target_torque)) missing += " target_torque (" + hex(obj.target_torque, 4) + ", 16 bits, RPDO);";
  if (!config.buttons.empty() && !has(a->tpdos_, a->n_tpdos_, &PdoPlan::inputs)) {
    missing += " digital_inputs (" + hex(obj.digital_inputs, 4) + ", 32 bits, TPDO: the config has buttons);";
  }
  if (!missing.empty()) {
    missing.pop_back();
    return Error{ErrorCode::kInvalid, where + ": bus.canopen: the PDO map lacks objects the driver needs:" + missing};
  }
  for (int k = 0; k < a->n_tpdos_; ++k)
    if (a->tpdos_[static_cast<std::size_t>(k)].divider == 1) a->expected_mask_ |= static_cast<std::uint8_t>(1u << k);

  for (int j = 0; j < n; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const int id = bus.node_ids[uj];
    if (id < 1 || id > 127 || a->index_of_id_[static_cast<std::size_t>(id)] >= 0) {
      return Error{ErrorCode::kInvalid, where + ": bus.canopen.node_ids[" + std::to_string(j) + "]: expected a unique node id 1..127, found " +
                                            std::to_string(id)};
    }
    a->index_of_id_[static_cast<std::size_t>(id)] = static_cast<std::int8_t>(j);
    Node& nd = a->nodes_[uj];
    nd.info.node_id = id;
    const arm::ActuatorConfig& act = config.actuators[uj];
    nd.info.rated_torque_mnm = canopen::rated_torque_mnm(act);
    if (nd.info.rated_torque_mnm == 0) {
      return Error{ErrorCode::kInvalid, where + ": actuators[" + std::to_string(j) +
                                            "]: the continuous torque (torque constant × continuous current) rounds to 0 mN·m, "
                                            "the unit of the rated torque 0x6076"};
    }
    const double peak_pm = act.peak_torque() * 1e6 / static_cast<double>(nd.info.rated_torque_mnm);
    nd.info.max_torque = static_cast<std::int16_t>(std::clamp(std::floor(peak_pm), 1.0, 32767.0));
  }
  const int bnode = bus.buttons_node.value_or(bus.node_ids[0]);
  a->buttons_joint_ = std::max(0, static_cast<int>(a->index_of_id_[static_cast<std::size_t>(std::clamp(bnode, 0, 127))]));

  a->sync_period_ns_ = ns_of(bus.sync_period);
  a->read_budget_ns_ = std::max<std::int64_t>(1000, ns_of(bus.sync_period * timing.read_budget_fraction));
  a->heartbeat_timeout_ns_ = bus.heartbeat_period > 0 ? ns_of(bus.heartbeat_period * timing.heartbeat_timeout_factor) : 0;
  a->sdo_timeout_ns_ = ns_of(timing.sdo_timeout);
  a->master_heartbeat_ns_ = bus.drive_watchdog > 0 ? ns_of(bus.drive_watchdog / 4) : 0;
  if (bus.mode == arm::Cia402Mode::kCyclicSyncTorque) a->interpolation_ = interpolation;
  return a;
}

CanopenArm::~CanopenArm() {
  if (fd_ < 0) return;
  if (pdo_running_) {
    // Best effort: zero torque and shutdown (applied at the SYNC that follows), then pre-operational.
    for (int j = 0; j < n_; ++j) {
      nodes_[static_cast<std::size_t>(j)].info.target_torque = 0;
      nodes_[static_cast<std::size_t>(j)].info.controlword = canopen::kCwShutdown;
    }
    (void)send_rpdos(true);
    (void)send_sync();
    for (int j = 0; j < n_; ++j) send_nmt(canopen::NmtCommand::kEnterPreOperational, nodes_[static_cast<std::size_t>(j)].info.node_id);
  }
  ::close(fd_);
}

// ---------------------------------------------------------------------------------------------
// Frames (real-time safe)

namespace {

// errno in words without allocating (strerror may format into a buffer of its own).
const char* errno_name(int err) noexcept {
  const char* d = strerrordesc_np(err);
  return d != nullptr ? d : "unknown error";
}

::can_frame sdo_upload_frame(int node_id, std::uint16_t index, std::uint8_t sub) noexcept {
  ::can_frame f{};
  f.can_id = canopen::kCobSdoRx + static_cast<std::uint32_t>(node_id);
  f.len = 8;
  f.data[0] = 0x40;
  put_le(f.data + 1, index, 2);
  f.data[3] = sub;
  return f;
}

}  // namespace

void CanopenArm::note(IoStatus s, CanopenEvent::What what, int i, std::uint32_t cob, int err_no, std::int64_t now) noexcept {
  CanopenEvent e{};
  e.status = s;
  e.what = what;
  e.cob_id = cob;
  e.err_no = err_no;
  e.t_ns = now;
  if (i >= 0) {
    const NodeInfo& info = nodes_[static_cast<std::size_t>(i)].info;
    e.node_id = info.node_id;
    e.statusword = info.statusword;
    e.nmt = info.nmt;
    e.emcy = info.last_emcy;
  }
  last_event_ = e;
}

void CanopenArm::report(IoStatus s, CanopenEvent::What what, int i, std::uint32_t cob, int err_no, std::int64_t now) noexcept {
  using W = CanopenEvent::What;
  note(s, what, i, cob, err_no, now);
  const CanopenEvent& e = last_event_;
  const char* bus = bus_.interface_name.c_str();
  char text[112];
  std::uint32_t code = 0;
  switch (what) {
    case W::kNone: std::snprintf(text, sizeof text, "bus %s: %s", bus, to_string(s)); break;
    case W::kSocket:
      code = static_cast<std::uint32_t>(err_no);
      if (s == IoStatus::kTimeout) {
        std::snprintf(text, sizeof text, "bus %s: transmit queue full (%s): no node acknowledges frames", bus, errno_name(err_no));
      } else {
        std::snprintf(text, sizeof text, "bus %s: socket: %s (errno %d)", bus, errno_name(err_no), err_no);
      }
      break;
    case W::kBusOff: std::snprintf(text, sizeof text, "bus %s: the CAN controller went bus-off (wiring, termination, bitrate?)", bus); break;
    case W::kNotSetUp: std::snprintf(text, sizeof text, "bus %s: the nodes are not set up since the link was lost (reconnect pending)", bus); break;
    case W::kHeartbeatLost: {
      code = cob;
      const NodeInfo& info = nodes_[static_cast<std::size_t>(i)].info;
      std::snprintf(text, sizeof text, "node %d: heartbeat 0x%03X overdue: none for %.0f ms (every %.0f ms)", e.node_id, cob,
                    static_cast<double>(now - info.last_heartbeat_ns) * 1e-6, bus_.heartbeat_period * 1e3);
      break;
    }
    case W::kNotOperational:
      code = static_cast<std::uint32_t>(e.nmt);
      if (nodes_[static_cast<std::size_t>(i)].boot_seen) {
        std::snprintf(text, sizeof text, "node %d: boot-up message (0x%03X): the node rebooted", e.node_id, cob);
      } else {
        std::snprintf(text, sizeof text, "node %d: NMT %s (heartbeat 0x%03X): it left operational", e.node_id, canopen::to_string(e.nmt), cob);
      }
      break;
    case W::kEmcy:
      code = e.emcy.error_code;
      (void)canopen::format_emcy(text, sizeof text, e.emcy);
      break;
    case W::kFaultBit:
      code = e.statusword;
      std::snprintf(text, sizeof text, "node %d: statusword 0x%04X has the fault bit ('%s')", e.node_id, e.statusword,
                    canopen::to_string(canopen::cia402_state(e.statusword)));
      break;
    case W::kNotEnabled:
      code = e.statusword;
      std::snprintf(text, sizeof text, "node %d: left operation enabled: now '%s' (statusword 0x%04X)", e.node_id,
                    canopen::to_string(canopen::cia402_state(e.statusword)), e.statusword);
      break;
    case W::kBadLength: {
      code = cob;
      const int number = static_cast<int>(((cob & 0x780u) - 0x080u) / 0x100u);
      int want = -1;
      for (int k = 0; k < n_tpdos_; ++k)
        if (tpdos_[static_cast<std::size_t>(k)].number == number) want = tpdos_[static_cast<std::size_t>(k)].size;
      std::snprintf(text, sizeof text, "node %d: frame 0x%03X has %u bytes, its mapping %d", e.node_id, cob,
                    nodes_[static_cast<std::size_t>(i)].bad_len, want);
      break;
    }
    case W::kMissingTpdo: {
      code = cob;
      const int number = static_cast<int>(((cob & 0x780u) - 0x080u) / 0x100u);
      int divider = 1;
      std::uint64_t since = 0;
      for (int k = 0; k < n_tpdos_; ++k) {
        if (tpdos_[static_cast<std::size_t>(k)].number != number) continue;
        divider = tpdos_[static_cast<std::size_t>(k)].divider;
        since = sync_count_ - nodes_[static_cast<std::size_t>(i)].tpdo_sync[static_cast<std::size_t>(k)];
      }
      if (divider == 1) {
        std::snprintf(text, sizeof text, "node %d: TPDO%d (0x%03X) missing: not within %.2f ms of the SYNC", e.node_id, number, cob,
                      static_cast<double>(read_budget_ns_) * 1e-6);
      } else {
        std::snprintf(text, sizeof text, "node %d: TPDO%d (0x%03X, every %d SYNCs) missing for %llu SYNCs", e.node_id, number, cob,
                      divider, static_cast<unsigned long long>(since));
      }
      break;
    }
  }
  note_error(s, e.node_id > 0 ? e.node_id : -1, code, text);
}

IoStatus CanopenArm::report_send_failure(IoStatus s) noexcept {
  const bool dead = socket_failed_;
  const IoStatus status = dead ? IoStatus::kDisconnected : s;
  report(status, CanopenEvent::What::kSocket, -1, last_event_.cob_id, dead ? socket_errno_ : last_event_.err_no, monotonic_ns());
  return status;
}

IoStatus CanopenArm::send(const ::can_frame& f) noexcept {
  for (;;) {
    const ssize_t r = ::write(fd_, &f, sizeof f);
    if (r == static_cast<ssize_t>(sizeof f)) return IoStatus::kOk;
    const int err = r < 0 ? errno : EIO;
    if (err == EINTR) continue;
    // A full transmit queue means nothing on the bus takes our frames (no node acknowledges).
    const bool full = err == EAGAIN || err == EWOULDBLOCK || err == ENOBUFS;
    if (!full) {
      socket_failed_ = true;
      socket_errno_ = err;
    }
    const IoStatus s = full ? IoStatus::kTimeout : IoStatus::kDisconnected;
    note(s, CanopenEvent::What::kSocket, -1, f.can_id & CAN_SFF_MASK, err, monotonic_ns());
    return s;
  }
}

IoStatus CanopenArm::send_sync() noexcept {
  ::can_frame f{};
  f.can_id = canopen::kCobSync;
  f.len = 0;
  return send(f);
}

void CanopenArm::send_nmt(canopen::NmtCommand cmd, int node_id) noexcept {
  ::can_frame f{};
  f.can_id = canopen::kCobNmt;
  f.len = 2;
  f.data[0] = static_cast<std::uint8_t>(cmd);
  f.data[1] = static_cast<std::uint8_t>(node_id);
  (void)send(f);
}

void CanopenArm::produce_heartbeat(std::int64_t now) noexcept {
  if (master_heartbeat_ns_ <= 0 || fd_ < 0 || now < next_master_heartbeat_ns_) return;
  ::can_frame f{};
  f.can_id = canopen::kCobHeartbeat + static_cast<std::uint32_t>(bus_.master_node_id);
  f.len = 1;
  f.data[0] = static_cast<std::uint8_t>(canopen::NmtState::kOperational);
  // Not through send(): a failure here is the socket's or the queue's, and the SYNC or SDO request
  // that follows reports it. Until one goes out, every drain tries again.
  if (::write(fd_, &f, sizeof f) != static_cast<ssize_t>(sizeof f)) return;
  ++master_heartbeats_;
  next_master_heartbeat_ns_ += master_heartbeat_ns_;
  if (next_master_heartbeat_ns_ <= now) next_master_heartbeat_ns_ = now + master_heartbeat_ns_;
}

void CanopenArm::wait_frames(std::int64_t deadline) noexcept {
  const std::int64_t now = monotonic_ns();
  std::int64_t until = deadline;
  if (producing_ && master_heartbeat_ns_ > 0) {
    until = std::min(until, next_master_heartbeat_ns_);
    // A heartbeat that could not go out is retried at the next drain, not in a busy loop.
    if (until <= now) until = std::min(deadline, now + 200'000);
  }
  if (until <= now) return;
  pollfd p{fd_, POLLIN, 0};
  const timespec ts = to_timespec(until - now);
  if (::ppoll(&p, 1, &ts, nullptr) < 0 && errno != EINTR) {
    socket_failed_ = true;
    socket_errno_ = errno;
  }
}

void CanopenArm::take_position(Node& nd, std::int32_t raw) noexcept {
  if (nd.have_position) {
    // Unwrap the 32-bit counter: the difference taken modulo 2^32 is the motion since last time.
    nd.counts += static_cast<std::int32_t>(static_cast<std::uint32_t>(raw) - static_cast<std::uint32_t>(nd.last_raw));
  } else {
    nd.counts = raw;
    nd.have_position = true;
  }
  nd.last_raw = raw;
}

void CanopenArm::handle(const ::can_frame& f, std::int64_t now) noexcept {
  if ((f.can_id & CAN_ERR_FLAG) != 0) {
    if ((f.can_id & CAN_ERR_BUSOFF) != 0) bus_off_ = true;
    return;
  }
  if ((f.can_id & (CAN_EFF_FLAG | CAN_RTR_FLAG)) != 0) return;
  const std::uint32_t cob = f.can_id & CAN_SFF_MASK;
  const std::uint32_t id = cob & 0x7F;
  const std::uint32_t fn = cob & 0x780;
  const int i = index_of_id_[id];
  if (i < 0 || id == 0) return;
  Node& nd = nodes_[static_cast<std::size_t>(i)];
  switch (fn) {
    case 0x080: {  // EMCY
      if (f.len < 3) {
        nd.bad_length = true;
        nd.bad_cob = cob;
        nd.bad_len = f.len;
        return;
      }
      canopen::Emcy e{};
      e.node_id = static_cast<int>(id);
      e.error_code = static_cast<std::uint16_t>(get_le(f.data, 2));
      e.error_register = f.data[2];
      for (std::size_t b = 0; b < e.vendor.size(); ++b) e.vendor[b] = b + 3 < f.len ? f.data[b + 3] : 0;
      e.t_ns = now;
      nd.info.last_emcy = e;
      ++nd.info.emcys;
      if (e.error_code != 0) nd.emcy_pending = true;  // 0x0000: error reset, no fault
      return;
    }
    case 0x180:
    case 0x280:
    case 0x380:
    case 0x480: {
      const int number = static_cast<int>((fn - 0x080) / 0x100);
      for (int k = 0; k < n_tpdos_; ++k) {
        const PdoPlan& p = tpdos_[static_cast<std::size_t>(k)];
        if (p.number != number) continue;
        if (f.len != p.size) {
          nd.bad_length = true;
          nd.bad_cob = cob;
          nd.bad_len = f.len;
          return;
        }
        if (p.statusword.present) nd.info.statusword = static_cast<std::uint16_t>(get_le(f.data + p.statusword.offset, 2));
        if (p.inputs.present) nd.inputs = get_le(f.data + p.inputs.offset, 4);
        if (p.position.present) take_position(nd, static_cast<std::int32_t>(get_le(f.data + p.position.offset, 4)));
        nd.tpdo_sync[static_cast<std::size_t>(k)] = sync_count_;
        // Only an operational node sends PDOs: this overrides a heartbeat sent before it started
        // (frames of one node arrive in order, so a later heartbeat still says what follows).
        nd.info.nmt = canopen::NmtState::kOperational;
        nd.seen_mask = static_cast<std::uint8_t>(nd.seen_mask | (1u << k));
        ++nd.info.tpdos;
        return;
      }
      return;
    }
    case 0x580:  // SDO reply
      if (f.len == 8) {
        std::memcpy(nd.sdo_data.data(), f.data, 8);
        nd.sdo_reply = true;
      }
      return;
    case 0x700:  // heartbeat or boot-up
      if (f.len >= 1) {
        nd.info.nmt = nmt_from_byte(f.data[0]);
        if (nd.info.nmt == canopen::NmtState::kBootUp) nd.boot_seen = true;
        nd.info.last_heartbeat_ns = now;
        ++nd.info.heartbeats;
      }
      return;
    default: return;
  }
}

bool CanopenArm::drain(std::int64_t now) noexcept {
  if (producing_) produce_heartbeat(now);
  for (int k = 0; k < kMaxFramesPerDrain; ++k) {
    ::can_frame f{};
    const ssize_t r = ::read(fd_, &f, sizeof f);
    if (r < 0) {
      if (errno == EAGAIN || errno == EWOULDBLOCK) return true;
      if (errno == EINTR) continue;
      socket_failed_ = true;
      socket_errno_ = errno;
      return false;
    }
    if (r == static_cast<ssize_t>(sizeof f)) handle(f, now);
  }
  return true;  // more may wait: the next drain takes them
}

IoStatus CanopenArm::exchange(std::int64_t wait_ns) noexcept {
  socket_failed_ = false;
  for (int j = 0; j < n_; ++j) nodes_[static_cast<std::size_t>(j)].bad_length = false;
  // Frames still waiting belong to earlier cycles (late TPDOs, heartbeats, EMCY): take them now
  // so that only what follows this SYNC counts for it (a late malformed one is still reported).
  if (!drain(monotonic_ns())) return IoStatus::kDisconnected;
  for (int j = 0; j < n_; ++j) nodes_[static_cast<std::size_t>(j)].seen_mask = 0;
  cycle_t_ns_ = monotonic_ns();
  if (const IoStatus s = send_sync(); s != IoStatus::kOk) return s;
  ++sync_count_;
  const std::int64_t deadline = cycle_t_ns_ + wait_ns;
  for (;;) {
    // The clock is read before the drain: the last drain comes after the deadline, so a frame
    // that arrived in time is never left in the socket while a preempted read gives up.
    const std::int64_t now = monotonic_ns();
    if (!drain(now)) return IoStatus::kDisconnected;
    bool all = true;
    for (int j = 0; j < n_ && all; ++j) {
      const Node& nd = nodes_[static_cast<std::size_t>(j)];
      all = (nd.seen_mask & expected_mask_) == expected_mask_ && !nd.bad_length;
    }
    if (all) return IoStatus::kOk;
    if (now >= deadline) return IoStatus::kOk;  // evaluate() says what is missing
    wait_frames(deadline);
    if (socket_failed_) return IoStatus::kDisconnected;
  }
}

IoStatus CanopenArm::evaluate(std::int64_t now, bool require_enabled) noexcept {
  using W = CanopenEvent::What;
  if (socket_failed_) {
    report(IoStatus::kDisconnected, W::kSocket, -1, 0, socket_errno_, now);
    return IoStatus::kDisconnected;
  }
  if (bus_off_) {
    report(IoStatus::kDisconnected, W::kBusOff, -1, 0, 0, now);
    return IoStatus::kDisconnected;
  }
  for (int j = 0; j < n_; ++j) {
    Node& nd = nodes_[static_cast<std::size_t>(j)];
    if (nd.emcy_pending) {
      nd.emcy_pending = false;
      report(IoStatus::kDeviceFault, W::kEmcy, j, canopen::kCobEmcy + static_cast<std::uint32_t>(nd.info.node_id), 0, now);
      return IoStatus::kDeviceFault;
    }
  }
  for (int j = 0; j < n_; ++j) {
    const Node& nd = nodes_[static_cast<std::size_t>(j)];
    if ((nd.info.statusword & canopen::kSwFault) != 0) {
      report(IoStatus::kDeviceFault, W::kFaultBit, j, 0, 0, now);
      return IoStatus::kDeviceFault;
    }
  }
  for (int j = 0; j < n_; ++j) {
    const Node& nd = nodes_[static_cast<std::size_t>(j)];
    const std::uint32_t hb_cob = canopen::kCobHeartbeat + static_cast<std::uint32_t>(nd.info.node_id);
    if (heartbeat_timeout_ns_ > 0 && now - nd.info.last_heartbeat_ns > heartbeat_timeout_ns_) {
      report(IoStatus::kDisconnected, W::kHeartbeatLost, j, hb_cob, 0, now);
      return IoStatus::kDisconnected;
    }
    if (nd.boot_seen || (nd.info.nmt != canopen::NmtState::kOperational && nd.info.nmt != canopen::NmtState::kUnknown)) {
      report(IoStatus::kDisconnected, W::kNotOperational, j, hb_cob, 0, now);
      return IoStatus::kDisconnected;
    }
  }
  for (int j = 0; j < n_; ++j) {
    const Node& nd = nodes_[static_cast<std::size_t>(j)];
    if (nd.bad_length) {
      report(IoStatus::kProtocolError, W::kBadLength, j, nd.bad_cob, 0, now);
      return IoStatus::kProtocolError;
    }
  }
  for (int j = 0; j < n_; ++j) {
    const Node& nd = nodes_[static_cast<std::size_t>(j)];
    for (int k = 0; k < n_tpdos_; ++k) {
      const PdoPlan& p = tpdos_[static_cast<std::size_t>(k)];
      bool missing = false;
      if (p.divider == 1) {
        missing = (nd.seen_mask & (1u << k)) == 0;
      } else {
        // Sent every nth SYNC from a count of its own: allow two periods and one SYNC of slack.
        const auto slack = static_cast<std::uint64_t>(2 * p.divider + 1);
        missing = sync_count_ - tracking_since_ > slack && sync_count_ - nd.tpdo_sync[static_cast<std::size_t>(k)] > slack;
      }
      if (missing) {
        report(IoStatus::kTimeout, W::kMissingTpdo, j, canopen::tpdo_cob_id(p.number, nd.info.node_id), 0, now);
        return IoStatus::kTimeout;
      }
    }
  }
  if (require_enabled) {
    for (int j = 0; j < n_; ++j) {
      const Node& nd = nodes_[static_cast<std::size_t>(j)];
      if (canopen::cia402_state(nd.info.statusword) != canopen::Cia402State::kOperationEnabled) {
        report(IoStatus::kDeviceFault, W::kNotEnabled, j, 0, 0, now);
        return IoStatus::kDeviceFault;
      }
    }
  }
  return IoStatus::kOk;
}

IoStatus CanopenArm::send_rpdos(bool all) noexcept {
  const std::int8_t mode = bus_.mode == arm::Cia402Mode::kCyclicSyncTorque ? canopen::kModeCyclicSyncTorque : canopen::kModeProfileTorque;
  IoStatus result = IoStatus::kOk;
  for (int k = 0; k < n_rpdos_; ++k) {
    const PdoPlan& p = rpdos_[static_cast<std::size_t>(k)];
    // An RPDO with divider n goes out on the SYNCs a TPDO with divider n would.
    if (!all && p.divider > 1 && sync_count_ > 0 && (sync_count_ - 1) % static_cast<std::uint64_t>(p.divider) != 0) continue;
    for (int j = 0; j < n_; ++j) {
      const NodeInfo& info = nodes_[static_cast<std::size_t>(j)].info;
      ::can_frame f{};
      f.can_id = canopen::rpdo_cob_id(p.number, info.node_id);
      f.len = p.size;
      if (p.controlword.present) put_le(f.data + p.controlword.offset, info.controlword, 2);
      if (p.target_torque.present) put_le(f.data + p.target_torque.offset, static_cast<std::uint16_t>(info.target_torque), 2);
      if (p.mode.present) f.data[p.mode.offset] = static_cast<std::uint8_t>(mode);
      const IoStatus s = send(f);
      if (s != IoStatus::kOk && result == IoStatus::kOk) result = s;
    }
  }
  return result;
}

void CanopenArm::send_zero_torque() noexcept {
  for (int j = 0; j < n_; ++j) nodes_[static_cast<std::size_t>(j)].info.target_torque = 0;
  (void)send_rpdos(true);
}

void CanopenArm::restart_tracking(std::int64_t now) noexcept {
  tracking_since_ = sync_count_;
  prev_good_t_ns_ = 0;
  for (int j = 0; j < n_; ++j) {
    Node& nd = nodes_[static_cast<std::size_t>(j)];
    nd.info.last_heartbeat_ns = now;
    nd.tpdo_sync.fill(sync_count_);
  }
}

void CanopenArm::fill_state(JointState& out, std::int64_t t_ns) noexcept {
  out.n = n_;
  const double dt = prev_good_t_ns_ > 0 ? static_cast<double>(t_ns - prev_good_t_ns_) * 1e-9 : 0.0;
  out.status = 0;
  for (int j = 0; j < n_; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    Node& nd = nodes_[uj];
    out.counts[uj] = nd.counts;
    out.q[uj] = arm::joint_position_from_counts(config_.joints[uj], nd.counts);
    out.qd[uj] = dt > 0 ? (out.q[uj] - nd.q_prev) / dt : 0.0;
    nd.q_prev = out.q[uj];
    const std::uint16_t sw = nd.info.statusword;
    if (canopen::cia402_state(sw) == canopen::Cia402State::kOperationEnabled) out.status |= 1u << j;
    if ((sw & canopen::kSwFault) != 0) out.status |= 1u << (8 + j);
    if ((sw & canopen::kSwWarning) != 0) out.status |= 1u << (16 + j);
  }
  prev_good_t_ns_ = t_ns;
  const std::uint32_t raw = nodes_[static_cast<std::size_t>(buttons_joint_)].inputs;
  out.buttons = pressed_buttons(config_.buttons, raw);
}

CanopenArm::SdoReply CanopenArm::sdo_request(int i, const ::can_frame& request, std::uint16_t index, std::uint8_t sub,
                                            bool upload) noexcept {
  using K = SdoReply::Kind;
  Node& nd = nodes_[static_cast<std::size_t>(i)];
  socket_failed_ = false;
  if (!drain(monotonic_ns())) return {K::kSocket, 0};
  nd.sdo_reply = false;
  if (send(request) != IoStatus::kOk) return {K::kSocket, 0};
  const std::int64_t deadline = monotonic_ns() + sdo_timeout_ns_;
  for (;;) {
    const std::int64_t now = monotonic_ns();  // before the drain, as in exchange()
    if (!drain(now)) return {K::kSocket, 0};
    if (nd.sdo_reply) {
      nd.sdo_reply = false;
      const std::uint8_t* d = nd.sdo_data.data();
      const bool same = get_le(d + 1, 2) == index && d[3] == sub;
      if (same && d[0] == 0x80) return {K::kAbort, get_le(d + 4, 4)};
      if (same && !upload && d[0] == 0x60) return {K::kOk, 0};
      if (same && upload && (d[0] & 0xE0) == 0x40) {
        if ((d[0] & 0x02) == 0) return {K::kSegmented, 0};
        const int bytes = (d[0] & 0x01) != 0 ? 4 - ((d[0] >> 2) & 0x03) : 4;
        return {K::kOk, get_le(d + 4, bytes)};
      }
      // Anything else is not the answer to this request (a late one): keep waiting.
    }
    if (now >= deadline) return {K::kTimeout, 0};
    wait_frames(deadline);
    if (socket_failed_) return {K::kSocket, 0};
  }
}

IoStatus CanopenArm::sdo_read(int i, std::uint16_t index, std::uint8_t sub, std::uint32_t& value) noexcept {
  using K = SdoReply::Kind;
  const NodeInfo& info = nodes_[static_cast<std::size_t>(i)].info;
  const SdoReply r = sdo_request(i, sdo_upload_frame(info.node_id, index, sub), index, sub, true);
  char text[112];
  switch (r.kind) {
    case K::kOk: value = r.value; return IoStatus::kOk;
    case K::kAbort:
      std::snprintf(text, sizeof text, "node %d: SDO upload 0x%04X:%02X aborted: 0x%08X %s", info.node_id, index, sub, r.value,
                    canopen::sdo_abort_text(r.value));
      note_error(IoStatus::kProtocolError, info.node_id, r.value, text);
      return IoStatus::kProtocolError;
    case K::kSegmented:
      std::snprintf(text, sizeof text, "node %d: SDO upload 0x%04X:%02X: a segmented answer (this driver does expedited only)",
                    info.node_id, index, sub);
      note_error(IoStatus::kProtocolError, info.node_id, 0, text);
      return IoStatus::kProtocolError;
    case K::kTimeout:
      std::snprintf(text, sizeof text, "node %d: no SDO reply to upload 0x%04X:%02X within %.0f ms%s", info.node_id, index, sub,
                    static_cast<double>(sdo_timeout_ns_) * 1e-6,
                    info.nmt == canopen::NmtState::kStopped ? " (its heartbeat says NMT stopped: no SDO then)" : "");
      note_error(IoStatus::kTimeout, info.node_id, static_cast<std::uint32_t>(index) << 8 | sub, text);
      return IoStatus::kTimeout;
    case K::kSocket: break;
  }
  return report_send_failure(IoStatus::kTimeout);
}

IoStatus CanopenArm::observe(JointState& out) noexcept {
  const arm::Cia402Objects& o = bus_.objects;
  const std::int64_t t0 = monotonic_ns();
  for (int j = 0; j < n_; ++j) {
    Node& nd = nodes_[static_cast<std::size_t>(j)];
    std::uint32_t sw = 0, pos = 0;
    if (const IoStatus s = sdo_read(j, o.statusword, 0, sw); s != IoStatus::kOk) return s;
    if (const IoStatus s = sdo_read(j, o.position_actual, 0, pos); s != IoStatus::kOk) return s;
    nd.info.statusword = static_cast<std::uint16_t>(sw);
    take_position(nd, static_cast<std::int32_t>(pos));
  }
  if (!config_.buttons.empty()) {
    std::uint32_t inputs = 0;
    if (const IoStatus s = sdo_read(buttons_joint_, o.digital_inputs, 0, inputs); s != IoStatus::kOk) return s;
    nodes_[static_cast<std::size_t>(buttons_joint_)].inputs = inputs;
  }
  fill_state(out, t0);
  return IoStatus::kOk;
}

IoStatus CanopenArm::on_read(JointState& out) noexcept {
  if (!pdo_running_) {
    // Inactive: observe by SDO, moving nothing. In fault with no bus set up (a reconnect that did
    // not get through yet): nothing to read, and the link is still lost.
    if (state() == Lifecycle::kInactive) return observe(out);
    report(IoStatus::kDisconnected, CanopenEvent::What::kNotSetUp, -1, 0, 0, monotonic_ns());
    return IoStatus::kDisconnected;
  }
  IoStatus s = exchange(read_budget_ns_);
  s = s != IoStatus::kOk ? report_send_failure(s) : evaluate(monotonic_ns(), state() == Lifecycle::kActive);
  if (s == IoStatus::kDisconnected || s == IoStatus::kDeviceFault) send_zero_torque();  // both trip kFault at once
  if (s != IoStatus::kOk) return s;
  fill_state(out, cycle_t_ns_);
  return IoStatus::kOk;
}

IoStatus CanopenArm::on_write(const JointCommand& cmd) noexcept {
  if (!pdo_running_) return IoStatus::kNotActive;
  for (int j = 0; j < n_; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    NodeInfo& info = nodes_[uj].info;
    const double tau = j < cmd.n ? cmd.tau[uj] : 0.0;
    info.target_torque = canopen::torque_per_mille(config_.joints[uj], config_.actuators[uj], info.rated_torque_mnm, info.max_torque, tau);
  }
  const IoStatus s = send_rpdos();
  return s == IoStatus::kOk ? s : report_send_failure(s);
}

// ---------------------------------------------------------------------------------------------
// Configure-time steps

Result<void> CanopenArm::fail(const std::string& what) const { return Result<void>::failure(ErrorCode::kSystem, name() + ": " + what); }

Result<void> CanopenArm::open_socket() {
  if (fd_ >= 0) {
    ::close(fd_);
    fd_ = -1;
  }
  const std::string& ifname = bus_.interface_name;
  const int fd = ::socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW);
  if (fd < 0) {
    const int err = errno;
    if (err == EAFNOSUPPORT || err == EPROTONOSUPPORT) {
      return fail("cannot open a CAN socket for interface '" + ifname + "': this kernel has no SocketCAN raw sockets (socket(PF_CAN, SOCK_RAW, CAN_RAW): " +
                  errno_text(err) + "); load the modules: modprobe can_raw");
    }
    return fail("cannot open a CAN socket for interface '" + ifname + "': socket(PF_CAN, SOCK_RAW, CAN_RAW): " + errno_text(err));
  }
  auto give_up = [&](const std::string& msg) {
    ::close(fd);
    return fail(msg);
  };
  ifreq ifr{};
  std::snprintf(ifr.ifr_name, sizeof ifr.ifr_name, "%s", ifname.c_str());
  if (::ioctl(fd, SIOCGIFINDEX, &ifr) < 0) {
    const int err = errno;
    if (err == ENODEV) {
      return give_up("CAN interface '" + ifname + "' does not exist (SIOCGIFINDEX: " + errno_text(err) +
                     "); list them with `ip -details link show type can` (virtual: ip link add dev " + ifname + " type vcan)");
    }
    return give_up("CAN interface '" + ifname + "': SIOCGIFINDEX: " + errno_text(err));
  }
  const int ifindex = ifr.ifr_ifindex;
  if (::ioctl(fd, SIOCGIFFLAGS, &ifr) < 0) {
    const int err = errno;
    return give_up("CAN interface '" + ifname + "': SIOCGIFFLAGS: " + errno_text(err));
  }
  if ((ifr.ifr_flags & IFF_UP) == 0) {
    return give_up("CAN interface '" + ifname + "' is down; bring it up: ip link set " + ifname + " up type can bitrate " +
                   std::to_string(bus_.bitrate));
  }
  // Only what the driver consumes: each node's EMCY, TPDOs, SDO replies and heartbeats.
  std::vector<can_filter> filters;
  for (int j = 0; j < n_; ++j) {
    const int id = nodes_[static_cast<std::size_t>(j)].info.node_id;
    const auto add = [&](std::uint32_t cob) { filters.push_back({cob, CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG}); };
    add(canopen::kCobEmcy + static_cast<std::uint32_t>(id));
    add(canopen::kCobSdoTx + static_cast<std::uint32_t>(id));
    add(canopen::kCobHeartbeat + static_cast<std::uint32_t>(id));
    for (int k = 0; k < n_tpdos_; ++k) add(canopen::tpdo_cob_id(tpdos_[static_cast<std::size_t>(k)].number, id));
  }
  if (::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FILTER, filters.data(), static_cast<socklen_t>(filters.size() * sizeof(can_filter))) < 0) {
    const int err = errno;
    return give_up("CAN interface '" + ifname + "': setsockopt(CAN_RAW_FILTER): " + errno_text(err));
  }
  const can_err_mask_t err_mask = CAN_ERR_BUSOFF;
  (void)::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &err_mask, sizeof err_mask);
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = ifindex;
  if (::bind(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) < 0) {
    const int err = errno;
    return give_up("CAN interface '" + ifname + "': bind: " + errno_text(err));
  }
  fd_ = fd;
  return Result<void>::success();
}


Result<std::uint32_t> CanopenArm::sdo_transfer(int i, const ::can_frame& request, std::uint16_t index, std::uint8_t sub, bool upload,
                                               const std::string& what) {
  using K = SdoReply::Kind;
  const Node& nd = nodes_[static_cast<std::size_t>(i)];
  const std::string who = "node " + std::to_string(nd.info.node_id) + ": SDO " + what;
  const SdoReply r = sdo_request(i, request, index, sub, upload);
  switch (r.kind) {
    case K::kOk: return r.value;
    case K::kAbort:
      return Error{ErrorCode::kInvalid, name() + ": " + who + ": aborted with " + hex(r.value, 8) + " (" + canopen::sdo_abort_text(r.value) + ")"};
    case K::kSegmented:
      return Error{ErrorCode::kInvalid, name() + ": " + who + ": the node answered with a segmented transfer, which this driver does not do"};
    case K::kSocket:
      if (socket_failed_) return Error{ErrorCode::kSystem, name() + ": " + who + ": " + errno_text(socket_errno_)};
      return Error{ErrorCode::kSystem, name() + ": " + who + ": cannot send: " + errno_text(last_event_.err_no)};
    case K::kTimeout: break;
  }
  std::string msg = name() + ": node " + std::to_string(nd.info.node_id) + " does not answer: SDO " + what + " got no reply within " +
                    ms_text(timing_.sdo_timeout);
  if (nd.info.nmt == canopen::NmtState::kStopped) {
    msg += " (its heartbeat says NMT stopped, a state without SDO: power-cycle it or send it NMT pre-operational)";
  } else if (!nd.boot_seen && nd.info.heartbeats == 0) {
    msg += " (it sent no boot-up or heartbeat either)";
  }
  msg += "; check the node id, its power, the wiring, the bitrate (" + std::to_string(bus_.bitrate) + " bit/s) and the termination";
  return Error{ErrorCode::kSystem, std::move(msg)};
}

Result<void> CanopenArm::sdo_download(int i, std::uint16_t index, std::uint8_t sub, std::uint32_t value, int bytes) {
  ::can_frame f{};
  f.can_id = canopen::kCobSdoRx + static_cast<std::uint32_t>(nodes_[static_cast<std::size_t>(i)].info.node_id);
  f.len = 8;
  f.data[0] = static_cast<std::uint8_t>(0x23 | ((4 - bytes) << 2));  // expedited, size indicated
  put_le(f.data + 1, index, 2);
  f.data[3] = sub;
  put_le(f.data + 4, value, bytes);
  auto r = sdo_transfer(i, f, index, sub, false, "download " + object_name(index, sub) + " = " + std::to_string(value));
  if (!r.ok()) return r.error();
  return Result<void>::success();
}

Result<std::uint32_t> CanopenArm::sdo_upload(int i, std::uint16_t index, std::uint8_t sub) {
  const ::can_frame f = sdo_upload_frame(nodes_[static_cast<std::size_t>(i)].info.node_id, index, sub);
  return sdo_transfer(i, f, index, sub, true, "upload " + object_name(index, sub));
}

void CanopenArm::wait_boot_ups(double timeout_s, std::uint32_t node_mask) {
  const std::int64_t deadline = monotonic_ns() + ns_of(timeout_s);
  for (;;) {
    const std::int64_t now = monotonic_ns();  // before the drain, as in exchange()
    (void)drain(now);
    bool all = true;
    for (int j = 0; j < n_; ++j)
      if ((node_mask & (1u << j)) != 0 && !nodes_[static_cast<std::size_t>(j)].boot_seen) all = false;
    if (all || now >= deadline) return;
    wait_frames(deadline);
  }
}

Result<void> CanopenArm::identify_node(int i) {
  Node& nd = nodes_[static_cast<std::size_t>(i)];
  auto type = sdo_upload(i, 0x1000, 0);
  if (!type.ok()) return type.error();
  if ((type.value() & 0xFFFF) != 402) {
    return Result<void>::failure(ErrorCode::kMismatch, name() + ": node " + std::to_string(nd.info.node_id) + ": device type (0x1000) is " +
                                                      hex(type.value(), 8) + ", not a CiA 402 drive (402 = 0x0192 in the low 16 bits)");
  }
  auto vendor = sdo_upload(i, 0x1018, 1);
  if (!vendor.ok()) return vendor.error();
  nd.info.vendor_id = vendor.value();
  return Result<void>::success();
}

Result<void> CanopenArm::set_mode(int i) {
  Node& nd = nodes_[static_cast<std::size_t>(i)];
  const std::int8_t mode = bus_.mode == arm::Cia402Mode::kCyclicSyncTorque ? canopen::kModeCyclicSyncTorque : canopen::kModeProfileTorque;
  if (Result<void> r = sdo_download(i, 0x6060, 0, static_cast<std::uint8_t>(mode), 1); !r.ok()) return r;
  // A drive may take a moment to switch; one that cannot says so only in 0x6061.
  const std::int64_t deadline = monotonic_ns() + ns_of(timing_.mode_timeout);
  for (;;) {
    auto shown = sdo_upload(i, 0x6061, 0);
    if (!shown.ok()) return shown.error();
    nd.info.mode_display = static_cast<std::int8_t>(shown.value());
    if (nd.info.mode_display == mode) return Result<void>::success();
    if (monotonic_ns() >= deadline) break;
    sleep_until(monotonic_ns() + 1'000'000);
  }
  return Result<void>::failure(ErrorCode::kMismatch,
                          name() + ": node " + std::to_string(nd.info.node_id) + ": modes of operation display (0x6061) reads " +
                              std::to_string(nd.info.mode_display) + " (" + canopen::mode_name(nd.info.mode_display) +
                              ") after modes of operation (0x6060) = " + std::to_string(mode) + " (" + canopen::mode_name(mode) +
                              ") for " + ms_text(timing_.mode_timeout) +
                              ": the drive refused the mode; check its supported drive modes (0x6502) and the config's mode");
}

Result<void> CanopenArm::configure_node(int i) {
  Node& nd = nodes_[static_cast<std::size_t>(i)];
  if (Result<void> o = identify_node(i); !o.ok()) return o;
  const auto& o = bus_.objects;
  const auto hb_ms = static_cast<std::uint32_t>(std::lround(bus_.heartbeat_period * 1e3));
  const auto period_us = static_cast<std::uint32_t>(std::llround(bus_.sync_period * 1e6));
  struct Write {
    std::uint16_t index;
    std::uint8_t sub;
    std::uint32_t value;
    int bytes;
  };
  // A drive left enabled (by a host that died) is switched off before anything else.
  const Write basics[] = {
      {o.controlword, 0, canopen::kCwDisableVoltage, 2},
      {o.target_torque, 0, 0, 2},
      {0x1017, 0, hb_ms, 2},      // producer heartbeat time (ms)
      {0x1006, 0, period_us, 4},  // communication cycle period (µs): the SYNC the drive can expect
  };
  for (const Write& w : basics) {
    if (Result<void> r = sdo_download(i, w.index, w.sub, w.value, w.bytes); !r.ok()) return r;
  }
  nd.info.controlword = canopen::kCwDisableVoltage;
  nd.info.target_torque = 0;
  if (interpolation_) {
    // Interpolation time period (cyclic synchronous modes): value · 10^index s, the SYNC period.
    if (Result<void> r = sdo_download(i, 0x60C2, 1, interpolation_->value, 1); !r.ok()) return r;
    if (Result<void> r = sdo_download(i, 0x60C2, 2, static_cast<std::uint8_t>(interpolation_->index), 1); !r.ok()) return r;
  }
  if (Result<void> r = set_mode(i); !r.ok()) return r;
  const Write torques[] = {
      {0x6076, 0, nd.info.rated_torque_mnm, 4},                         // motor rated torque (mN·m): the unit of 0x6071
      {0x6072, 0, static_cast<std::uint16_t>(nd.info.max_torque), 2},  // max torque (‰)
  };
  for (const Write& w : torques) {
    if (Result<void> r = sdo_download(i, w.index, w.sub, w.value, w.bytes); !r.ok()) return r;
  }

  // PDOs (CiA 301): invalidate, transmission type, clear the mapping, map, count, validate. The
  // PDO numbers the config does not use are left invalid.
  for (int dir = 0; dir < 2; ++dir) {
    const bool tx = dir == 0;
    const std::vector<arm::PdoConfig>& pdos = tx ? bus_.tpdos : bus_.rpdos;
    for (int number = 1; number <= 4; ++number) {
      const auto comm = static_cast<std::uint16_t>((tx ? 0x1800 : 0x1400) + number - 1);
      const auto map = static_cast<std::uint16_t>((tx ? 0x1A00 : 0x1600) + number - 1);
      const std::uint32_t cob = tx ? canopen::tpdo_cob_id(number, nd.info.node_id) : canopen::rpdo_cob_id(number, nd.info.node_id);
      if (Result<void> r = sdo_download(i, comm, 1, 0x8000'0000u | cob, 4); !r.ok()) return r;
      const auto it = std::find_if(pdos.begin(), pdos.end(), [&](const arm::PdoConfig& p) { return p.number == number; });
      if (it == pdos.end()) continue;
      if (Result<void> r = sdo_download(i, comm, 2, static_cast<std::uint32_t>(it->sync_divider), 1); !r.ok()) return r;
      if (Result<void> r = sdo_download(i, map, 0, 0, 1); !r.ok()) return r;
      for (std::size_t e = 0; e < it->entries.size(); ++e) {
        const arm::PdoEntry& en = it->entries[e];
        const std::uint32_t v = static_cast<std::uint32_t>(en.index) << 16 | static_cast<std::uint32_t>(en.subindex) << 8 | en.bits;
        if (Result<void> r = sdo_download(i, map, static_cast<std::uint8_t>(e + 1), v, 4); !r.ok()) return r;
      }
      if (Result<void> r = sdo_download(i, map, 0, static_cast<std::uint32_t>(it->entries.size()), 1); !r.ok()) return r;
      if (Result<void> r = sdo_download(i, comm, 1, cob, 4); !r.ok()) return r;
    }
  }

  // The drive-side watchdog: the reaction first (disable voltage: torque-free at once), then the
  // consumer, which starts watching at the master's next heartbeat (the master is producing).
  if (master_heartbeat_ns_ > 0) {
    const auto watchdog_ms = static_cast<std::uint32_t>(std::llround(bus_.drive_watchdog * 1e3));
    if (Result<void> r = sdo_download(i, 0x6007, 0, static_cast<std::uint16_t>(canopen::kAbortConnectionDisableVoltage), 2); !r.ok()) return r;
    if (Result<void> r = sdo_download(i, 0x1016, 1, static_cast<std::uint32_t>(bus_.master_node_id) << 16 | watchdog_ms, 4); !r.ok()) return r;
    nd.consumer_set = true;
  }
  auto sw = sdo_upload(i, o.statusword, 0);
  if (!sw.ok()) return sw.error();
  nd.info.statusword = static_cast<std::uint16_t>(sw.value());
  nd.boot_seen = false;
  return Result<void>::success();
}

void CanopenArm::start_nodes(std::uint32_t node_mask) {
  (void)drain(monotonic_ns());
  for (int j = 0; j < n_; ++j) {
    if ((node_mask & (1u << j)) == 0) continue;
    Node& nd = nodes_[static_cast<std::size_t>(j)];
    send_nmt(canopen::NmtCommand::kStart, nd.info.node_id);
    // The next heartbeat confirms it (one already on its way may still say pre-operational: the
    // wait below and evaluate() look at the ones that follow).
    nd.info.nmt = bus_.heartbeat_period > 0 ? canopen::NmtState::kUnknown : canopen::NmtState::kOperational;
    nd.boot_seen = false;
  }
  pdo_running_ = true;
}


template <class NextCw, class Done>
Result<void> CanopenArm::drive_states(NextCw next_cw, Done done, const std::string& goal) {
  const std::int64_t deadline = monotonic_ns() + ns_of(timing_.state_timeout);
  const std::int64_t wait = std::max(read_budget_ns_, sync_period_ns_ / 2);
  for (;;) {
    const std::int64_t t0 = monotonic_ns();
    (void)exchange(wait);
    if (socket_failed_) return fail("the bus failed while bringing the drives to " + goal + ": " + errno_text(socket_errno_));
    bool all = true;
    for (int j = 0; j < n_; ++j) {
      Node& nd = nodes_[static_cast<std::size_t>(j)];
      const bool fresh = (nd.seen_mask & expected_mask_) == expected_mask_;
      if (!fresh || !done(nd.info.statusword)) all = false;
      if (fresh) nd.info.controlword = next_cw(nd.info.statusword, nd.info.controlword);
      nd.info.target_torque = 0;
    }
    if (all) return Result<void>::success();
    if (monotonic_ns() >= deadline) {
      std::string msg = "the drives did not reach " + goal + " within " + ms_text(timing_.state_timeout) + ":";
      for (int j = 0; j < n_; ++j) {
        const Node& nd = nodes_[static_cast<std::size_t>(j)];
        const bool fresh = (nd.seen_mask & expected_mask_) == expected_mask_;
        if (fresh && done(nd.info.statusword)) continue;
        msg += " node " + std::to_string(nd.info.node_id);
        if (!fresh) {
          msg += " sends no TPDOs (NMT " + std::string(canopen::to_string(nd.info.nmt)) + ");";
          continue;
        }
        msg += " is in '" + std::string(canopen::to_string(canopen::cia402_state(nd.info.statusword))) + "' (statusword " +
               hex(nd.info.statusword, 4) + ")";
        if (nd.info.last_emcy.error_code != 0) {
          msg += ", last EMCY " + hex(nd.info.last_emcy.error_code, 4) + " (error register " + hex(nd.info.last_emcy.error_register, 2) + ")";
        }
        msg += ";";
      }
      msg.pop_back();
      return fail(msg);
    }
    (void)send_rpdos();
    sleep_until(t0 + sync_period_ns_);  // SYNC at the configured period: drives may watch it
  }
}

void CanopenArm::reset_nodes() noexcept {
  for (int j = 0; j < n_; ++j) {
    Node& nd = nodes_[static_cast<std::size_t>(j)];
    const NodeInfo keep = nd.info;
    nd = Node{};
    nd.info.node_id = keep.node_id;
    nd.info.rated_torque_mnm = keep.rated_torque_mnm;
    nd.info.max_torque = keep.max_torque;
    nd.info.vendor_id = keep.vendor_id;
  }
}

Result<void> CanopenArm::on_configure() {
  if (Result<void> o = open_socket(); !o.ok()) return o;
  pdo_running_ = false;
  producing_ = false;
  sync_count_ = 0;
  master_heartbeats_ = 0;
  bus_off_ = false;
  reset_nodes();
  restart_tracking(monotonic_ns());
  // Observe only: what each node is, and its state. No download, no NMT command.
  (void)drain(monotonic_ns());
  for (int j = 0; j < n_; ++j) {
    if (Result<void> o = identify_node(j); !o.ok()) return o;
    auto sw = sdo_upload(j, bus_.objects.statusword, 0);
    if (!sw.ok()) return sw.error();
    nodes_[static_cast<std::size_t>(j)].info.statusword = static_cast<std::uint16_t>(sw.value());
  }
  return Result<void>::success();
}

Result<void> CanopenArm::setup_bus() {
  pdo_running_ = false;
  bus_off_ = false;
  reset_nodes();
  const std::uint32_t all = (1u << n_) - 1;
  // The master's heartbeat from now on: each drive's consumer starts at the first one after 0x1016.
  producing_ = master_heartbeat_ns_ > 0;
  next_master_heartbeat_ns_ = monotonic_ns();
  (void)drain(monotonic_ns());
  // Reset communication: every node comes back pre-operational with its default PDOs and says so.
  for (int j = 0; j < n_; ++j) send_nmt(canopen::NmtCommand::kResetCommunication, nodes_[static_cast<std::size_t>(j)].info.node_id);
  wait_boot_ups(timing_.boot_timeout, all);
  for (int j = 0; j < n_; ++j) send_nmt(canopen::NmtCommand::kEnterPreOperational, nodes_[static_cast<std::size_t>(j)].info.node_id);
  for (int j = 0; j < n_; ++j) {
    if (Result<void> o = configure_node(j); !o.ok()) return o;
  }
  std::array<std::uint64_t, kMaxJoints> heartbeats_before{};
  for (int j = 0; j < n_; ++j) heartbeats_before[static_cast<std::size_t>(j)] = nodes_[static_cast<std::size_t>(j)].info.heartbeats;
  start_nodes(all);
  restart_tracking(monotonic_ns());

  // Every node's TPDOs must follow a SYNC, and with heartbeats on, a heartbeat must come (0x1017 took).
  const std::int64_t deadline = monotonic_ns() + ns_of(std::max(timing_.boot_timeout, 3 * bus_.heartbeat_period));
  const std::int64_t wait = std::max(read_budget_ns_, ns_of(timing_.sdo_timeout));
  for (;;) {
    const std::int64_t t0 = monotonic_ns();
    (void)exchange(wait);
    if (socket_failed_) {
      pdo_running_ = false;
      return fail("the bus failed after NMT start: " + errno_text(socket_errno_));
    }
    std::string missing;
    for (int j = 0; j < n_; ++j) {
      const Node& nd = nodes_[static_cast<std::size_t>(j)];
      for (int k = 0; k < n_tpdos_; ++k) {
        if ((expected_mask_ & (1u << k)) == 0 || (nd.seen_mask & (1u << k)) != 0) continue;
        const int number = tpdos_[static_cast<std::size_t>(k)].number;
        missing += " node " + std::to_string(nd.info.node_id) + " sent no TPDO" + std::to_string(number) + " (" +
                   hex(canopen::tpdo_cob_id(number, nd.info.node_id), 3) + ");";
      }
      if (bus_.heartbeat_period > 0 && nd.info.heartbeats == heartbeats_before[static_cast<std::size_t>(j)]) {
        missing += " node " + std::to_string(nd.info.node_id) + " sent no heartbeat;";
      } else if (nd.info.nmt != canopen::NmtState::kOperational && nd.info.nmt != canopen::NmtState::kUnknown) {
        missing += " node " + std::to_string(nd.info.node_id) + " is " + canopen::to_string(nd.info.nmt) + ";";
      }
    }
    if (missing.empty()) break;
    if (monotonic_ns() >= deadline) {
      missing.pop_back();
      return fail("after NMT start and SYNC:" + missing + " (check the nodes' PDO support and that they went operational)");
    }
    sleep_until(t0 + sync_period_ns_);
  }
  restart_tracking(monotonic_ns());
  return Result<void>::success();
}

Result<void> CanopenArm::stop_bus() {
  Result<void> result = Result<void>::success();
  if (pdo_running_) {
    send_zero_torque();
    result = drive_states([](std::uint16_t, std::uint16_t) { return canopen::kCwShutdown; },
                          [](std::uint16_t sw) {
                            const auto s = canopen::cia402_state(sw);
                            return s == canopen::Cia402State::kSwitchOnDisabled || s == canopen::Cia402State::kReadyToSwitchOn ||
                                   s == canopen::Cia402State::kFault || s == canopen::Cia402State::kNotReadyToSwitchOn;
                          },
                          "a disabled state (shutdown)");
    for (int j = 0; j < n_; ++j) send_nmt(canopen::NmtCommand::kEnterPreOperational, nodes_[static_cast<std::size_t>(j)].info.node_id);
    pdo_running_ = false;
  }
  // A master that stops on purpose turns the drives' watchdog off first: no heartbeat error behind.
  for (int j = 0; j < n_; ++j) {
    Node& nd = nodes_[static_cast<std::size_t>(j)];
    if (!nd.consumer_set) continue;
    nd.consumer_set = false;
    if (Result<void> r = sdo_download(j, 0x1016, 1, 0, 4); !r.ok() && result.ok()) result = r;
  }
  producing_ = false;
  restart_tracking(monotonic_ns());
  return result;
}

Result<void> CanopenArm::on_activate() {
  Result<void> o = setup_bus();
  if (o.ok()) {
    for (int j = 0; j < n_; ++j) nodes_[static_cast<std::size_t>(j)].emcy_pending = false;
    o = enable_drives("operation enabled");
  }
  // Back to observing: drives shut down, their watchdog off, no heartbeat.
  if (!o.ok()) (void)stop_bus();
  return o;
}

// Every drive through the CiA 402 state machine to operation enabled; zero torque on failure.
Result<void> CanopenArm::enable_drives(const char* goal) {
  Result<void> o = drive_states([](std::uint16_t sw, std::uint16_t prev) { return canopen::controlword_toward_enabled(sw, prev); },
                           [](std::uint16_t sw) { return canopen::cia402_state(sw) == canopen::Cia402State::kOperationEnabled; },
                           goal);
  if (!o.ok()) {
    send_zero_torque();
    return o;
  }
  for (int j = 0; j < n_; ++j) {
    Node& nd = nodes_[static_cast<std::size_t>(j)];
    nd.info.controlword = canopen::kCwEnableOperation;
    nd.emcy_pending = false;
  }
  restart_tracking(monotonic_ns());
  return Result<void>::success();
}

Result<void> CanopenArm::on_rearm() {
  bus_off_ = false;
  socket_failed_ = false;
  // No bus set up (a reconnect did not get through): set it up first, drives disabled.
  if (!pdo_running_) {
    if (fd_ < 0) {
      if (Result<void> o = open_socket(); !o.ok()) return o;
    }
    if (Result<void> o = setup_bus(); !o.ok()) return o;
  }
  send_zero_torque();
  // Every node must answer; one that rebooted or left operational is configured again.
  std::uint32_t restart = 0;
  for (int j = 0; j < n_; ++j) {
    Node& nd = nodes_[static_cast<std::size_t>(j)];
    auto sw = sdo_upload(j, bus_.objects.statusword, 0);
    if (!sw.ok()) return sw.error();
    nd.info.statusword = static_cast<std::uint16_t>(sw.value());
    if (nd.boot_seen || (nd.info.nmt != canopen::NmtState::kOperational && nd.info.nmt != canopen::NmtState::kUnknown)) {
      send_nmt(canopen::NmtCommand::kEnterPreOperational, nd.info.node_id);
      if (Result<void> o = configure_node(j); !o.ok()) return o;
      restart |= 1u << j;
    }
  }
  if (restart != 0) start_nodes(restart);
  restart_tracking(monotonic_ns());
  for (int j = 0; j < n_; ++j) nodes_[static_cast<std::size_t>(j)].emcy_pending = false;
  return enable_drives("operation enabled after a fault reset");
}

Result<void> CanopenArm::on_reconnect() {
  pdo_running_ = false;
  producing_ = false;
  if (Result<void> o = open_socket(); !o.ok()) return o;
  socket_failed_ = false;
  socket_errno_ = 0;
  // The whole set-up again (a node may have lost power, or its watchdog fired meanwhile); each
  // drive gets controlword 0 and zero torque and stays disabled: only rearm() enables.
  if (Result<void> o = setup_bus(); !o.ok()) {
    producing_ = false;
    return o;
  }
  for (int j = 0; j < n_; ++j) nodes_[static_cast<std::size_t>(j)].emcy_pending = false;
  return Result<void>::success();
}

Result<void> CanopenArm::on_deactivate() { return stop_bus(); }

// ---------------------------------------------------------------------------------------------

std::string CanopenArm::describe(const CanopenEvent& e) const {
  using W = CanopenEvent::What;
  std::string s = name() + ": " + to_string(e.status);
  const std::string node = e.node_id > 0 ? " node " + std::to_string(e.node_id) : std::string();
  switch (e.what) {
    case W::kNone: return s + ": nothing went wrong yet";
    case W::kSocket: return s + ": socket: " + errno_text(e.err_no);
    case W::kBusOff: return s + ": the CAN controller went bus-off";
    case W::kNotSetUp: return s + ": the nodes are not set up since the link was lost (reconnect pending)";
    case W::kHeartbeatLost: return s + ":" + node + ": heartbeat (" + hex(e.cob_id, 3) + ") overdue";
    case W::kNotOperational: return s + ":" + node + " is " + canopen::to_string(e.nmt) + " (it rebooted or was stopped)";
    case W::kEmcy: {
      char buf[160];
      return s + ": " + canopen::format_emcy(buf, sizeof buf, e.emcy);
    }
    case W::kFaultBit: return s + ":" + node + ": statusword " + hex(e.statusword, 4) + " has the fault bit";
    case W::kNotEnabled:
      return s + ":" + node + " left operation enabled: '" + canopen::to_string(canopen::cia402_state(e.statusword)) + "' (statusword " +
             hex(e.statusword, 4) + ")";
    case W::kBadLength: return s + ":" + node + ": frame " + hex(e.cob_id, 3) + " has the wrong length";
    case W::kMissingTpdo: return s + ":" + node + ": TPDO " + hex(e.cob_id, 3) + " did not arrive in time";
  }
  return s;
}

}  // namespace lancet::device
