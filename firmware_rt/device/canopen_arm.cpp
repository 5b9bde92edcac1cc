#include "device/canopen_arm.hpp"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "device/canopen_arm_text.hpp"

namespace lancet::device {

using canopen_detail::hex;
using canopen_detail::ns_of;
using canopen_detail::errno_text;

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

  if (std::optional<Error> e = a->plan_pdo_map(where)) return *e;

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

std::optional<Error> CanopenArm::plan_pdos(const std::string& where, const std::vector<arm::PdoConfig>& pdos,
                                           std::array<PdoPlan, 4>& out, int& count, const char* key) const {
  const arm::Cia402Objects& obj = bus_.objects;
  if (pdos.size() > static_cast<std::size_t>(canopen::kMaxPdos)) return Error{ErrorCode::kInvalid, where + ": bus.canopen." + key + ": at most 4 PDOs"};
  count = 0;
  for (const arm::PdoConfig& pc : pdos) {
    if (pc.number < 1 || pc.number > canopen::kMaxPdos || pc.sync_divider < 1 || pc.sync_divider > canopen::kMaxSyncTransmissionType) {
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
        if (e.index == canopen::od::kModesOfOperation && bytes == 1) p.mode = s;
      }
      offset += bytes;
    }
    p.size = static_cast<std::uint8_t>(offset);
  }
  return std::nullopt;
}

std::optional<Error> CanopenArm::plan_pdo_map(const std::string& where) {
  if (auto e = plan_pdos(where, bus_.tpdos, tpdos_, n_tpdos_, "tpdo")) return e;
  if (auto e = plan_pdos(where, bus_.rpdos, rpdos_, n_rpdos_, "rpdo")) return e;
  auto has = [](const std::array<PdoPlan, 4>& plans, int count, Slot PdoPlan::*slot) {
    for (int k = 0; k < count; ++k)
      if ((plans[static_cast<std::size_t>(k)].*slot).present) return true;
    return false;
  };
  const arm::Cia402Objects& obj = bus_.objects;
  std::string missing;
  if (!has(tpdos_, n_tpdos_, &PdoPlan::statusword)) missing += " statusword (" + hex(obj.statusword, 4) + ", 16 bits, TPDO);";
  if (!has(tpdos_, n_tpdos_, &PdoPlan::position)) missing += " position_actual (" + hex(obj.position_actual, 4) + ", 32 bits, TPDO);";
  if (!has(rpdos_, n_rpdos_, &PdoPlan::controlword)) missing += " controlword (" + hex(obj.controlword, 4) + ", 16 bits, RPDO);";
  if (!has(rpdos_, n_rpdos_, &PdoPlan::target_torque)) missing += " target_torque (" + hex(obj.target_torque, 4) + ", 16 bits, RPDO);";
  if (!config_.buttons.empty() && !has(tpdos_, n_tpdos_, &PdoPlan::inputs)) {
    missing += " digital_inputs (" + hex(obj.digital_inputs, 4) + ", 32 bits, TPDO: the config has buttons);";
  }
  if (!missing.empty()) {
    missing.pop_back();
    return Error{ErrorCode::kInvalid, where + ": bus.canopen: the PDO map lacks objects the driver needs:" + missing};
  }
  for (int k = 0; k < n_tpdos_; ++k)
    if (tpdos_[static_cast<std::size_t>(k)].divider == 1) expected_mask_ |= static_cast<std::uint8_t>(1u << k);
  return std::nullopt;
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
