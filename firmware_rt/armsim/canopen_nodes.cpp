#include "armsim/canopen_nodes.hpp"

#include <errno.h>
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>

#include "device/canopen/codec.hpp"
#include "device/canopen/socketcan.hpp"

namespace lancet::armsim {

namespace {

std::int64_t mono_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

using device::canopen::Cia402State;
using device::canopen::NmtState;
namespace canopen = device::canopen;
namespace od = device::canopen::od;

// The modes of operation the emulated drives support (0 clears the mode).
bool supported_mode(std::int8_t m) { return m == canopen::kModeNone || m == canopen::kModeProfileTorque || m == canopen::kModeCyclicSyncTorque; }
bool torque_mode(std::int8_t m) { return m == canopen::kModeProfileTorque || m == canopen::kModeCyclicSyncTorque; }

}  // namespace

CanopenNodeSet::CanopenNodeSet(const arm::ArmConfig& config, Options options, std::unique_ptr<device::ArmPhysics> physics)
    : config_(config), options_(options), physics_(std::move(physics)) {}

Result<std::unique_ptr<CanopenNodeSet>> CanopenNodeSet::start(const arm::ArmConfig& config, Options options) {
  if (!config.canopen) return Error{ErrorCode::kInvalid, "CanopenNodeSet: the config has no [bus.canopen]"};
  auto physics = device::ArmPhysics::create(config);
  if (!physics.ok()) return physics.error();
  std::unique_ptr<CanopenNodeSet> s(new CanopenNodeSet(config, options, std::move(physics).value()));
  const auto& bus = *config.canopen;
  s->sync_period_ = bus.sync_period;
  s->n_ = static_cast<int>(bus.node_ids.size());

  const std::string& ifname = bus.interface_name;
  s->fd_ = ::socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW);
  if (s->fd_ < 0) return Error{ErrorCode::kSystem, "CanopenNodeSet: socket(PF_CAN): " + std::string(std::strerror(errno))};
  ifreq ifr{};
  std::snprintf(ifr.ifr_name, sizeof ifr.ifr_name, "%s", ifname.c_str());
  if (::ioctl(s->fd_, SIOCGIFINDEX, &ifr) < 0) {
    return Error{ErrorCode::kSystem, "CanopenNodeSet: interface " + ifname + ": " + std::strerror(errno)};
  }
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = ifr.ifr_ifindex;
  if (::bind(s->fd_, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) < 0) {
    return Error{ErrorCode::kSystem, "CanopenNodeSet: bind " + ifname + ": " + std::strerror(errno)};
  }
  s->stop_fd_ = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
  if (s->stop_fd_ < 0) return Error{ErrorCode::kSystem, "CanopenNodeSet: eventfd: " + std::string(std::strerror(errno))};

  const std::int64_t now = mono_ns();
  for (int j = 0; j < s->n_; ++j) {
    Emu& e = s->nodes_[static_cast<std::size_t>(j)];
    e.id = bus.node_ids[static_cast<std::size_t>(j)];
    e.joint = j;
    e.tpdo_delay_ns = std::max<std::int64_t>(0, options.tpdo_delay_us) * 1000;
    s->reset_application(e);
    s->reset_communication(e);
    e.nmt = NmtState::kPreOperational;
    if (options.boot_up_at_start) s->boot(e, now);
  }
  s->thread_ = std::thread([p = s.get()] { p->run(); });
  return s;
}

CanopenNodeSet::~CanopenNodeSet() {
  if (thread_.joinable()) {
    const std::uint64_t one = 1;
    (void)!::write(stop_fd_, &one, sizeof one);
    thread_.join();
  }
  if (fd_ >= 0) ::close(fd_);
  if (stop_fd_ >= 0) ::close(stop_fd_);
}

void CanopenNodeSet::run() {
  for (;;) {
    std::int64_t wait_ns = 5'000'000;
    {
      std::lock_guard<std::mutex> lock(mu_);
      const std::int64_t now = mono_ns();
      for (int j = 0; j < n_; ++j) {
        Emu& e = nodes_[static_cast<std::size_t>(j)];
        if (e.heartbeat_ms == 0 || !e.heartbeat_on || e.silent) continue;
        if (now >= e.next_heartbeat_ns) {
          send(canopen::heartbeat_frame(e.id, e.nmt));
          ++e.heartbeats;
          e.next_heartbeat_ns += static_cast<std::int64_t>(e.heartbeat_ms) * 1'000'000;
          if (e.next_heartbeat_ns < now) e.next_heartbeat_ns = now + static_cast<std::int64_t>(e.heartbeat_ms) * 1'000'000;
        }
        wait_ns = std::min(wait_ns, e.next_heartbeat_ns - now);
      }
      wait_ns = std::min(wait_ns, check_consumers(now));
      wait_ns = std::min(wait_ns, send_delayed(now));
    }
    pollfd p[2] = {{fd_, POLLIN, 0}, {stop_fd_, POLLIN, 0}};
    timespec ts{};
    wait_ns = std::max<std::int64_t>(wait_ns, 0);
    ts.tv_sec = static_cast<time_t>(wait_ns / 1'000'000'000);
    ts.tv_nsec = static_cast<long>(wait_ns % 1'000'000'000);
    (void)::ppoll(p, 2, &ts, nullptr);
    if ((p[1].revents & POLLIN) != 0) return;
    for (;;) {
      can_frame f{};
      const ssize_t r = ::read(fd_, &f, sizeof f);
      if (r != static_cast<ssize_t>(sizeof f)) break;
      if ((f.can_id & (CAN_EFF_FLAG | CAN_RTR_FLAG | CAN_ERR_FLAG)) != 0) continue;
      std::lock_guard<std::mutex> lock(mu_);
      handle(canopen::from_can_frame(f), mono_ns());
    }
  }
}

CanopenNodeSet::Emu* CanopenNodeSet::find(int node_id) {
  for (int j = 0; j < n_; ++j)
    if (nodes_[static_cast<std::size_t>(j)].id == node_id) return &nodes_[static_cast<std::size_t>(j)];
  return nullptr;
}

const CanopenNodeSet::Emu* CanopenNodeSet::find(int node_id) const {
  for (int j = 0; j < n_; ++j)
    if (nodes_[static_cast<std::size_t>(j)].id == node_id) return &nodes_[static_cast<std::size_t>(j)];
  return nullptr;
}

void CanopenNodeSet::send(const canopen::Frame& frame) {
  const can_frame f = canopen::to_can_frame(frame);
  (void)!::write(fd_, &f, sizeof f);
}

void CanopenNodeSet::send_emcy(Emu& e, std::uint16_t code, std::uint8_t reg) {
  if (e.silent || e.nmt == NmtState::kStopped) return;
  send(canopen::emcy_frame(e.id, code, reg));
  ++e.emcys;
  e.last_emcy = code;
}

void CanopenNodeSet::on_heartbeat(int producer, std::int64_t now) {
  for (int j = 0; j < n_; ++j) {
    Emu& e = nodes_[static_cast<std::size_t>(j)];
    // An unplugged node hears nothing; a consumer entry with node id or time 0 is off (CiA 301).
    if (e.silent || canopen::consumer_time_ms(e.consumer) == 0 || canopen::consumer_producer_id(e.consumer) != producer) continue;
    if (e.consumer_armed) {
      e.max_gap_ms = std::max(e.max_gap_ms, static_cast<double>(now - e.producer_seen_ns) * 1e-6);
    } else if (options_.on_event) {
      char line[120];
      std::snprintf(line, sizeof line, "node %d: watching the master heartbeat (0x%03X, consumer time %u ms)", e.id,
                    canopen::heartbeat_cob_id(producer), canopen::consumer_time_ms(e.consumer));
      options_.on_event(line);
    }
    e.consumer_armed = true;
    e.producer_seen_ns = now;
    ++e.master_heartbeats;
  }
}

std::int64_t CanopenNodeSet::check_consumers(std::int64_t now) {
  std::int64_t wait = 5'000'000;
  for (int j = 0; j < n_; ++j) {
    Emu& e = nodes_[static_cast<std::size_t>(j)];
    if (!e.consumer_armed) continue;
    const std::int64_t limit = static_cast<std::int64_t>(canopen::consumer_time_ms(e.consumer)) * 1'000'000;
    const std::int64_t late = now - e.producer_seen_ns;
    if (late <= limit) {
      wait = std::min(wait, limit - late + 1);
      continue;
    }
    // Heartbeat event: disarmed until the producer is heard again; EMCY 0x8130 with the
    // communication bit; a drive in operation enabled applies its abort connection option.
    e.consumer_armed = false;
    ++e.heartbeat_losses;
    e.last_loss_ms = static_cast<double>(late) * 1e-6;
    const bool enabled = e.drive == Cia402State::kOperationEnabled;
    const char* reaction = "drive not enabled, no reaction";
    if (enabled) {
      switch (e.abort_option) {
        case canopen::kAbortConnectionFault: e.drive = Cia402State::kFault, reaction = "torque off, fault (0x6007 = 1)"; break;
        case canopen::kAbortConnectionDisableVoltage:
          e.drive = Cia402State::kSwitchOnDisabled, reaction = "torque off, disable voltage (0x6007 = 2)";
          break;
        case canopen::kAbortConnectionQuickStop: e.drive = Cia402State::kQuickStopActive, reaction = "torque off, quick stop (0x6007 = 3)"; break;
        default: reaction = "no action (0x6007 = 0): torque stays on"; break;
      }
      if (e.drive != Cia402State::kOperationEnabled) e.torque_actual = 0;
    }
    e.error_register = static_cast<std::uint8_t>(e.error_register | canopen::kErrorRegisterGeneric | canopen::kErrorRegisterCommunication);
    send_emcy(e, canopen::kEmcyHeartbeat, e.error_register);
    if (options_.on_event) {
      char line[200];
      std::snprintf(line, sizeof line, "node %d: master heartbeat (0x%03X) lost after %.0f ms (consumer time %u ms): %s, EMCY 0x8130",
                    e.id, canopen::heartbeat_cob_id(canopen::consumer_producer_id(e.consumer)), e.last_loss_ms,
                    canopen::consumer_time_ms(e.consumer), reaction);
      options_.on_event(line);
    }
  }
  return wait;
}

std::int64_t CanopenNodeSet::send_delayed(std::int64_t now) {
  std::int64_t wait = 5'000'000;
  int kept = 0;
  for (int k = 0; k < n_delayed_; ++k) {
    const Delayed& d = delayed_[static_cast<std::size_t>(k)];
    if (d.due_ns <= now) {
      send(d.frame);
      Pdo& p = nodes_[static_cast<std::size_t>(d.node)].tpdo[static_cast<std::size_t>(d.pdo)];
      p.answered_sync = d.answered_sync;
      p.sent_ns = mono_ns();
    } else {
      wait = std::min(wait, d.due_ns - now);
      delayed_[static_cast<std::size_t>(kept++)] = d;
    }
  }
  n_delayed_ = kept;
  return wait;
}

void CanopenNodeSet::boot(Emu& e, std::int64_t now) {
  e.nmt = NmtState::kPreOperational;
  if (!e.silent) send(canopen::heartbeat_frame(e.id, NmtState::kBootUp));
  e.next_heartbeat_ns = now + static_cast<std::int64_t>(e.heartbeat_ms) * 1'000'000;
}

void CanopenNodeSet::reset_communication(Emu& e) {
  e.heartbeat_ms = 0;
  e.consumer = 0;
  e.consumer_armed = false;
  e.cycle_period_us = 0;
  for (int number = 1; number <= canopen::kMaxPdos; ++number) {
    const auto uk = static_cast<std::size_t>(number - 1);
    e.tpdo[uk] = Pdo{};
    e.tpdo[uk].cob_id = canopen::kPdoInvalid | canopen::tpdo_cob_id(number, e.id);
    e.rpdo[uk] = Pdo{};
    e.rpdo[uk].cob_id = canopen::kPdoInvalid | canopen::rpdo_cob_id(number, e.id);
  }
  e.has_cw = e.has_tt = e.has_mode = false;
}

void CanopenNodeSet::reset_application(Emu& e) {
  e.drive = Cia402State::kSwitchOnDisabled;
  e.controlword = 0;
  e.target_torque = 0;
  e.torque_actual = 0;
  e.mode = canopen::kModeNone;
  e.mode_requested = canopen::kModeNone;
  e.max_torque = 1000;
  e.rated_mnm = 1000;
  e.error_register = 0;
  e.abort_option = canopen::kAbortConnectionFault;  // the CiA 402 default
  e.ip_value = 1;
  e.ip_index = -3;
}

std::uint16_t CanopenNodeSet::statusword(const Emu& e) const {
  return static_cast<std::uint16_t>(canopen::kSwRemote | canopen::statusword_of(e.drive));
}

void CanopenNodeSet::apply_controlword(Emu& e, std::uint16_t cw) {
  const Cia402State before = e.drive;
  e.drive = canopen::drive_transition(e.drive, cw, e.controlword);
  e.controlword = cw;
  if (before == Cia402State::kFault && e.drive != Cia402State::kFault) {
    e.error_register = 0;
    ++e.fault_resets;
    send_emcy(e, canopen::kEmcyErrorReset, 0);
  }
}

int CanopenNodeSet::mappable_bits(std::uint16_t index, bool rpdo) {
  switch (index) {
    case od::kControlword: return 16;
    case od::kModesOfOperation: return 8;
    case od::kTargetTorque: return 16;
    case od::kStatusword: return rpdo ? 0 : 16;
    case od::kModesOfOperationDisplay: return rpdo ? 0 : 8;
    case od::kPositionActual: return rpdo ? 0 : 32;
    case od::kTorqueActual: return rpdo ? 0 : 16;
    case od::kDigitalInputs: return rpdo ? 0 : 32;
    default: return 0;
  }
}

std::uint32_t CanopenNodeSet::read_object(Emu& e, std::uint16_t index, std::uint8_t sub, std::uint32_t& v, int& bytes) {
  auto give = [&](std::uint32_t value, int size) -> std::uint32_t {
    v = value;
    bytes = size;
    return 0;
  };
  auto single = [&](std::uint32_t value, int size) -> std::uint32_t { return sub != 0 ? canopen::kAbortNoSubindex : give(value, size); };
  if (const std::optional<canopen::PdoParameter> pp = canopen::pdo_parameter(index)) {
    const Pdo& p = pdo(e, *pp);
    if (pp->mapping) {
      if (sub == 0) return give(p.count, 1);
      if (sub <= canopen::kMaxMappedObjects) return give(p.map[sub - 1u], 4);
      return canopen::kAbortNoSubindex;
    }
    if (sub == 0) return give(2, 1);
    if (sub == 1) return give(p.cob_id, 4);
    if (sub == 2) return give(p.type, 1);
    return canopen::kAbortNoSubindex;
  }
  switch (index) {
    case od::kDeviceType: return single(options_.device_type, 4);
    case od::kErrorRegister: return single(e.error_register, 1);
    case od::kCommunicationCyclePeriod: return single(e.cycle_period_us, 4);
    case od::kConsumerHeartbeatTime:
      if (sub == 0) return give(1, 1);
      if (sub == 1) return give(e.consumer, 4);
      return canopen::kAbortNoSubindex;
    case od::kProducerHeartbeatTime: return single(e.heartbeat_ms, 2);
    case od::kAbortConnectionOption: return single(static_cast<std::uint16_t>(e.abort_option), 2);
    case od::kInterpolationTimePeriod:
      if (sub == 0) return give(2, 1);
      if (sub == 1) return give(e.ip_value, 1);
      if (sub == 2) return give(static_cast<std::uint8_t>(e.ip_index), 1);
      return canopen::kAbortNoSubindex;
    case od::kIdentity:
      if (sub == 0) return give(4, 1);
      if (sub == 1) return give(options_.vendor_id, 4);
      if (sub == 2) return give(0x402, 4);  // product code
      if (sub == 3) return give(1, 4);
      if (sub == 4) return give(static_cast<std::uint32_t>(e.id), 4);
      return canopen::kAbortNoSubindex;
    case od::kControlword: return single(e.controlword, 2);
    case od::kStatusword: return single(statusword(e), 2);
    case od::kModesOfOperation: return single(static_cast<std::uint8_t>(e.mode_requested), 1);
    case od::kModesOfOperationDisplay: return single(static_cast<std::uint8_t>(e.mode), 1);
    case od::kPositionActual: return single(static_cast<std::uint32_t>(physics_->encoder_counts(e.joint)), 4);
    case od::kTargetTorque: return single(static_cast<std::uint16_t>(e.target_torque), 2);
    case od::kMaxTorque: return single(e.max_torque, 2);
    case od::kMotorRatedTorque: return single(e.rated_mnm, 4);
    case od::kTorqueActual: return single(static_cast<std::uint16_t>(e.torque_actual), 2);
    case od::kDigitalInputs: return single(e.inputs, 4);
    case od::kSupportedDriveModes:
      return single(canopen::supported_mode_bit(canopen::kModeProfileTorque) | canopen::supported_mode_bit(canopen::kModeCyclicSyncTorque), 4);
    default: return canopen::kAbortNoObject;
  }
}

CanopenNodeSet::Pdo& CanopenNodeSet::pdo(Emu& e, const device::canopen::PdoParameter& pp) {
  return (pp.tpdo ? e.tpdo : e.rpdo)[static_cast<std::size_t>(pp.number - 1)];
}

const CanopenNodeSet::Pdo& CanopenNodeSet::pdo(const Emu& e, const device::canopen::PdoParameter& pp) {
  return (pp.tpdo ? e.tpdo : e.rpdo)[static_cast<std::size_t>(pp.number - 1)];
}

std::uint32_t CanopenNodeSet::write_pdo_parameter(Emu& e, const device::canopen::PdoParameter& pp, std::uint8_t sub, std::uint32_t v,
                                                  int bytes) {
  Pdo& p = pdo(e, pp);
  constexpr std::uint32_t kInvalid = canopen::kPdoInvalid;
  if (!pp.mapping) {
    // Communication parameter.
    if (sub == 0) return canopen::kAbortReadOnly;
    if (sub == 1) {
      if (bytes != 4) return canopen::kAbortLength;
      // A valid PDO's COB-ID may not change: invalidate it first (bit 31).
      const std::uint32_t cob = v & canopen::kCobIdMask;
      if ((p.cob_id & kInvalid) == 0 && (v & kInvalid) == 0 && cob != (p.cob_id & canopen::kCobIdMask)) return canopen::kAbortValue;
      p.cob_id = v & (kInvalid | canopen::kCobIdMask);
      p.syncs = 0;
      return 0;
    }
    if (sub == 2) {
      if (bytes != 1) return canopen::kAbortLength;
      if (v > canopen::kMaxSyncTransmissionType && v < 252) return canopen::kAbortValue;  // reserved types
      p.type = static_cast<std::uint8_t>(v);
      return 0;
    }
    return canopen::kAbortNoSubindex;
  }
  // Mapping parameter (CiA 301: only while the PDO is invalid, entries only while sub 0 is 0).
  if (sub > canopen::kMaxMappedObjects) return canopen::kAbortNoSubindex;
  if ((p.cob_id & kInvalid) == 0) return canopen::kAbortUnsupported;
  if (sub == 0) {
    if (bytes != 1) return canopen::kAbortLength;
    if (v > static_cast<std::uint32_t>(canopen::kMaxMappedObjects)) return canopen::kAbortPdoLength;
    for (std::uint32_t k = 0; k < v; ++k)
      if (p.map[k] == 0) return canopen::kAbortNotMappable;
    if (canopen::mapped_bits(p.map.data(), static_cast<int>(v)) > 64) return canopen::kAbortPdoLength;
    p.count = static_cast<std::uint8_t>(v);
    return 0;
  }
  if (bytes != 4) return canopen::kAbortLength;
  if (p.count != 0) return canopen::kAbortDeviceState;
  const canopen::MappingEntry m = canopen::decode_mapping(v);
  const int bits = mappable_bits(m.index, !pp.tpdo);
  if (m.sub != 0 || bits == 0 || bits != m.bits) return canopen::kAbortNotMappable;
  p.map[sub - 1u] = v;
  return 0;
}

void CanopenNodeSet::request_mode(Emu& e, std::int8_t m) {
  e.mode_requested = m;
  // A refused mode is taken (no abort) but not entered: only 0x6061 tells.
  if (e.refused_mode == 0 || m != e.refused_mode) e.mode = m;
}

std::uint32_t CanopenNodeSet::write_object(Emu& e, std::uint16_t index, std::uint8_t sub, std::uint32_t v, int bytes, std::int64_t now) {
  if (const std::optional<canopen::PdoParameter> pp = canopen::pdo_parameter(index)) return write_pdo_parameter(e, *pp, sub, v, bytes);
  auto size_ok = [&](int want) { return sub == 0 && bytes == want; };
  switch (index) {
    case od::kDeviceType:
    case od::kErrorRegister:
    case od::kIdentity:
    case od::kStatusword:
    case od::kModesOfOperationDisplay:
    case od::kPositionActual:
    case od::kTorqueActual:
    case od::kDigitalInputs:
    case od::kSupportedDriveModes: return canopen::kAbortReadOnly;
    case od::kProducerHeartbeatTime:
      if (!size_ok(2)) return sub != 0 ? canopen::kAbortNoSubindex : canopen::kAbortLength;
      e.heartbeat_ms = static_cast<std::uint16_t>(v);
      e.next_heartbeat_ns = now + static_cast<std::int64_t>(e.heartbeat_ms) * 1'000'000;
      return 0;
    case od::kCommunicationCyclePeriod:
      if (!size_ok(4)) return sub != 0 ? canopen::kAbortNoSubindex : canopen::kAbortLength;
      e.cycle_period_us = v;
      return 0;
    case od::kConsumerHeartbeatTime:
      if (sub == 0) return canopen::kAbortReadOnly;
      if (sub != 1) return canopen::kAbortNoSubindex;
      if (bytes != 4) return canopen::kAbortLength;
      if (canopen::consumer_producer_id(v) == e.id && canopen::consumer_time_ms(v) != 0) return canopen::kAbortValue;  // itself
      e.consumer = canopen::heartbeat_consumer_entry(canopen::consumer_producer_id(v), canopen::consumer_time_ms(v));
      e.consumer_armed = false;  // until the producer's next heartbeat
      e.max_gap_ms = 0;
      return 0;
    case od::kAbortConnectionOption: {
      if (!size_ok(2)) return sub != 0 ? canopen::kAbortNoSubindex : canopen::kAbortLength;
      const auto option = static_cast<std::int16_t>(v);
      if (option > canopen::kAbortConnectionQuickStop) return canopen::kAbortValue;
      e.abort_option = option;
      return 0;
    }
    case od::kInterpolationTimePeriod:
      if (sub == 0) return canopen::kAbortReadOnly;
      if (sub > 2) return canopen::kAbortNoSubindex;
      if (bytes != 1) return canopen::kAbortLength;
      if (sub == 1) e.ip_value = static_cast<std::uint8_t>(v);
      if (sub == 2) e.ip_index = static_cast<std::int8_t>(v);
      return 0;
    case od::kControlword:
      if (!size_ok(2)) return sub != 0 ? canopen::kAbortNoSubindex : canopen::kAbortLength;
      apply_controlword(e, static_cast<std::uint16_t>(v));
      return 0;
    case od::kModesOfOperation: {
      if (!size_ok(1)) return sub != 0 ? canopen::kAbortNoSubindex : canopen::kAbortLength;
      const auto m = static_cast<std::int8_t>(v);
      if (!supported_mode(m)) return canopen::kAbortValue;
      request_mode(e, m);
      return 0;
    }
    case od::kTargetTorque:
      if (!size_ok(2)) return sub != 0 ? canopen::kAbortNoSubindex : canopen::kAbortLength;
      e.target_torque = static_cast<std::int16_t>(v);
      return 0;
    case od::kMaxTorque:
      if (!size_ok(2)) return sub != 0 ? canopen::kAbortNoSubindex : canopen::kAbortLength;
      e.max_torque = static_cast<std::uint16_t>(v);
      return 0;
    case od::kMotorRatedTorque:
      if (!size_ok(4)) return sub != 0 ? canopen::kAbortNoSubindex : canopen::kAbortLength;
      if (v == 0) return canopen::kAbortValue;
      e.rated_mnm = v;
      return 0;
    default: return canopen::kAbortNoObject;
  }
}

void CanopenNodeSet::on_sdo(Emu& e, const device::canopen::SdoRequest& rq, std::int64_t now) {
  using K = canopen::SdoRequest::Kind;
  ++e.sdo_requests;
  std::uint32_t abort = canopen::kAbortCommand;  // segmented transfers and other services: not here
  if (rq.kind == K::kDownload || rq.kind == K::kSegmentedDownload) ++e.sdo_downloads;
  if (rq.kind == K::kDownload) {
    abort = write_object(e, rq.index, rq.sub, rq.value, rq.bytes, now);
    if (abort == 0) return send(canopen::sdo_download_response(e.id, rq.index, rq.sub));
  } else if (rq.kind == K::kUpload) {
    std::uint32_t v = 0;
    int bytes = 0;
    abort = read_object(e, rq.index, rq.sub, v, bytes);
    if (abort == 0) return send(canopen::sdo_upload_response(e.id, rq.index, rq.sub, v, bytes));
  }
  send(canopen::sdo_abort_response(e.id, rq.index, rq.sub, abort));
}

void CanopenNodeSet::on_rpdo(Emu& e, int k, const device::canopen::Frame& f) {
  const Pdo& p = e.rpdo[static_cast<std::size_t>(k)];
  if (f.len < canopen::mapped_bits(p.map.data(), p.count) / 8) return;  // CiA 301: not processed (a real drive would send EMCY 0x8210)
  ++e.rpdos;
  int offset = 0;
  for (int m = 0; m < p.count; ++m) {
    const std::uint32_t entry = p.map[static_cast<std::size_t>(m)];
    const int bytes = canopen::mapped_bytes(entry);
    const std::uint32_t v = canopen::get_le(f.data.data() + offset, bytes);
    switch (canopen::decode_mapping(entry).index) {
      case od::kControlword: e.has_cw = true, e.pending_cw = static_cast<std::uint16_t>(v); break;
      case od::kTargetTorque: e.has_tt = true, e.pending_tt = static_cast<std::int16_t>(v); break;
      case od::kModesOfOperation: e.has_mode = true, e.pending_mode = static_cast<std::int8_t>(v); break;
      default: break;
    }
    offset += bytes;
  }
}

void CanopenNodeSet::on_nmt(const device::canopen::NmtRequest& rq, std::int64_t now) {
  using C = canopen::NmtCommand;
  for (int j = 0; j < n_; ++j) {
    Emu& e = nodes_[static_cast<std::size_t>(j)];
    if ((rq.node_id != 0 && rq.node_id != e.id) || e.silent) continue;
    ++e.nmt_commands;
    switch (rq.command) {
      case C::kStart:
        if (e.nmt != NmtState::kOperational)
          for (auto& p : e.tpdo) p.syncs = 0;
        e.nmt = NmtState::kOperational;
        break;
      case C::kStop: e.nmt = NmtState::kStopped; break;
      case C::kEnterPreOperational: e.nmt = NmtState::kPreOperational; break;
      case C::kResetNode:
        reset_application(e);
        reset_communication(e);
        boot(e, now);
        break;
      case C::kResetCommunication:
        reset_communication(e);
        boot(e, now);
        break;
      default: break;
    }
  }
}

void CanopenNodeSet::on_sync(std::int64_t now) {
  double dt = options_.fixed_dt;
  if (!(dt > 0)) {
    dt = last_sync_ns_ == 0 ? sync_period_ : std::clamp(static_cast<double>(now - last_sync_ns_) * 1e-9, 0.0, 5 * sync_period_);
  }
  last_sync_ns_ = now;
  device::JointCommand cmd{};
  cmd.n = physics_->joint_count();
  for (int j = 0; j < n_; ++j) {
    Emu& e = nodes_[static_cast<std::size_t>(j)];
    if (e.silent) {
      e.torque_actual = 0;
      continue;
    }
    if (e.nmt == NmtState::kOperational) {
      // Synchronous RPDOs take effect now.
      if (e.has_mode && supported_mode(e.pending_mode)) request_mode(e, e.pending_mode);
      if (e.has_tt) e.target_torque = e.pending_tt;
      if (e.has_cw) apply_controlword(e, e.pending_cw);
      e.has_cw = e.has_tt = e.has_mode = false;
      ++e.syncs;
    }
    const bool torque_on = e.nmt == NmtState::kOperational && e.drive == Cia402State::kOperationEnabled && torque_mode(e.mode);
    const int lim = std::min<int>(e.max_torque, 32767);
    e.torque_actual = torque_on ? static_cast<std::int16_t>(std::clamp<int>(e.target_torque, -lim, lim)) : std::int16_t{0};
    const auto uj = static_cast<std::size_t>(e.joint);
    cmd.tau[uj] = canopen::joint_torque_from_per_mille(config_.joints[uj], config_.actuators[uj], e.rated_mnm, e.torque_actual);
  }
  physics_->step(cmd, dt);
  for (int j = 0; j < n_; ++j) send_tpdos(j, now);
}

void CanopenNodeSet::send_tpdos(int j, std::int64_t now) {
  Emu& e = nodes_[static_cast<std::size_t>(j)];
  if (e.silent || e.nmt != NmtState::kOperational) return;
  for (int k = 0; k < canopen::kMaxPdos; ++k) {
    Pdo& p = e.tpdo[static_cast<std::size_t>(k)];
    if ((p.cob_id & canopen::kPdoInvalid) != 0 || p.type == 0 || p.type > canopen::kMaxSyncTransmissionType) continue;
    if (++p.syncs % p.type != 0) continue;
    if (e.drop_tpdos) continue;
    canopen::Frame f{p.cob_id & canopen::kCobIdMask, 0, {}};
    int offset = 0;
    for (int m = 0; m < p.count; ++m) {
      const std::uint32_t entry = p.map[static_cast<std::size_t>(m)];
      std::uint32_t v = 0;
      int bytes = 0;
      if (read_object(e, canopen::decode_mapping(entry).index, 0, v, bytes) != 0) bytes = canopen::mapped_bytes(entry);
      canopen::put_le(f.data.data() + offset, v, bytes);
      offset += bytes;
    }
    if (e.corrupt > 0) {
      --e.corrupt;
      offset = std::max(0, offset - 1);
    }
    f.len = static_cast<std::uint8_t>(offset);
    ++e.tpdos;
    if (e.tpdo_delay_ns > 0 && n_delayed_ < static_cast<int>(delayed_.size())) {
      delayed_[static_cast<std::size_t>(n_delayed_++)] = Delayed{now + e.tpdo_delay_ns, j, k, syncs_heard_, f};
      continue;
    }
    send(f);
    p.answered_sync = syncs_heard_;
    p.sent_ns = mono_ns();
  }
}

void CanopenNodeSet::handle(const device::canopen::Frame& f, std::int64_t now) {
  const canopen::CobId cob = canopen::decode_cob_id(f.cob_id);
  if (cob.function == canopen::Function::kNmt) {
    if (const std::optional<canopen::NmtRequest> rq = canopen::decode_nmt(f)) on_nmt(*rq, now);
    return;
  }
  if (cob.function == canopen::Function::kSync) {
    ++syncs_heard_;
    on_sync(now);
    return;
  }
  if (cob.function == canopen::Function::kHeartbeat) on_heartbeat(cob.node_id, now);
  Emu* e = find(cob.node_id);
  if (e == nullptr || e->silent) return;
  if (cob.function == canopen::Function::kSdoRx) {
    if (e->nmt == NmtState::kStopped) return;
    if (const std::optional<canopen::SdoRequest> rq = canopen::decode_sdo_request(f)) on_sdo(*e, *rq, now);
    return;
  }
  if (e->nmt != NmtState::kOperational) return;
  for (int k = 0; k < canopen::kMaxPdos; ++k) {
    const Pdo& p = e->rpdo[static_cast<std::size_t>(k)];
    if ((p.cob_id & canopen::kPdoInvalid) == 0 && (p.cob_id & canopen::kCobIdMask) == f.cob_id) {
      on_rpdo(*e, k, f);
      return;
    }
  }
}

// ---- injection and observation ----

void CanopenNodeSet::set_silent(int node_id, bool silent) {
  std::lock_guard<std::mutex> lock(mu_);
  if (Emu* e = find(node_id)) {
    e->silent = silent;
    e->next_heartbeat_ns = mono_ns();
  }
}

void CanopenNodeSet::set_drop_tpdos(int node_id, bool drop) {
  std::lock_guard<std::mutex> lock(mu_);
  if (Emu* e = find(node_id)) e->drop_tpdos = drop;
}

void CanopenNodeSet::corrupt_next_tpdos(int node_id, int count) {
  std::lock_guard<std::mutex> lock(mu_);
  if (Emu* e = find(node_id)) e->corrupt = count;
}

void CanopenNodeSet::set_heartbeat_enabled(int node_id, bool on) {
  std::lock_guard<std::mutex> lock(mu_);
  if (Emu* e = find(node_id)) {
    e->heartbeat_on = on;
    e->next_heartbeat_ns = mono_ns();
  }
}

void CanopenNodeSet::inject_fault(int node_id, std::uint16_t error_code, std::uint8_t error_register, bool emcy) {
  std::lock_guard<std::mutex> lock(mu_);
  if (Emu* e = find(node_id)) {
    e->drive = Cia402State::kFault;
    e->torque_actual = 0;
    e->error_register = error_register;
    if (emcy) send_emcy(*e, error_code, error_register);
  }
}

void CanopenNodeSet::set_refused_mode(int node_id, std::int8_t mode) {
  std::lock_guard<std::mutex> lock(mu_);
  if (Emu* e = find(node_id)) e->refused_mode = mode;
}

void CanopenNodeSet::set_tpdo_delay_us(int node_id, std::int64_t delay_us) {
  std::lock_guard<std::mutex> lock(mu_);
  if (Emu* e = find(node_id)) e->tpdo_delay_ns = std::max<std::int64_t>(0, delay_us) * 1000;
}

void CanopenNodeSet::set_digital_inputs(int node_id, std::uint32_t inputs) {
  std::lock_guard<std::mutex> lock(mu_);
  if (Emu* e = find(node_id)) e->inputs = inputs;
}

void CanopenNodeSet::power_cycle(int node_id) {
  std::lock_guard<std::mutex> lock(mu_);
  if (Emu* e = find(node_id)) {
    reset_application(*e);
    reset_communication(*e);
    boot(*e, mono_ns());
  }
}

CanopenNodeSet::NodeView CanopenNodeSet::node(int node_id) const {
  std::lock_guard<std::mutex> lock(mu_);
  NodeView v{};
  const Emu* e = find(node_id);
  if (e == nullptr) return v;
  v.node_id = e->id;
  v.nmt = static_cast<std::uint8_t>(e->nmt);
  v.statusword = statusword(*e);
  v.controlword = e->controlword;
  v.target_torque = e->target_torque;
  v.torque_actual = e->torque_actual;
  v.mode = e->mode;
  v.mode_requested = e->mode_requested;
  v.rated_torque_mnm = e->rated_mnm;
  v.max_torque = e->max_torque;
  v.heartbeat_ms = e->heartbeat_ms;
  v.consumer = e->consumer;
  v.abort_option = e->abort_option;
  v.cycle_period_us = e->cycle_period_us;
  v.ip_value = e->ip_value;
  v.ip_index = e->ip_index;
  for (std::size_t k = 0; k < 4; ++k) {
    v.tpdo[k] = {e->tpdo[k].cob_id, e->tpdo[k].type, e->tpdo[k].count, e->tpdo[k].map, e->tpdo[k].answered_sync, e->tpdo[k].sent_ns};
    v.rpdo[k] = {e->rpdo[k].cob_id, e->rpdo[k].type, e->rpdo[k].count, e->rpdo[k].map, 0, 0};
  }
  v.syncs = e->syncs;
  v.rpdos = e->rpdos;
  v.tpdos = e->tpdos;
  v.sdo_requests = e->sdo_requests;
  v.fault_resets = e->fault_resets;
  v.heartbeats = e->heartbeats;
  v.sdo_downloads = e->sdo_downloads;
  v.nmt_commands = e->nmt_commands;
  v.master_heartbeats = e->master_heartbeats;
  v.watching = e->consumer_armed;
  v.heartbeat_losses = e->heartbeat_losses;
  v.last_loss_ms = e->last_loss_ms;
  v.max_gap_ms = e->max_gap_ms;
  v.emcys = e->emcys;
  v.last_emcy = e->last_emcy;
  return v;
}

std::uint64_t CanopenNodeSet::syncs_heard() const {
  std::lock_guard<std::mutex> lock(mu_);
  return syncs_heard_;
}

}  // namespace lancet::armsim
