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

namespace lancet::armsim {

namespace {

std::int64_t mono_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

std::uint32_t le(const std::uint8_t* p, int bytes) {
  std::uint32_t v = 0;
  for (int b = 0; b < bytes; ++b) v |= static_cast<std::uint32_t>(p[b]) << (8 * b);
  return v;
}

void put(std::uint8_t* p, std::uint32_t v, int bytes) {
  for (int b = 0; b < bytes; ++b) p[b] = static_cast<std::uint8_t>(v >> (8 * b));
}

// CiA 301 SDO abort codes the nodes use.
constexpr std::uint32_t kAbortCommand = 0x05040001;
constexpr std::uint32_t kAbortUnsupported = 0x06010000;
constexpr std::uint32_t kAbortReadOnly = 0x06010002;
constexpr std::uint32_t kAbortNoObject = 0x06020000;
constexpr std::uint32_t kAbortNotMappable = 0x06040041;
constexpr std::uint32_t kAbortPdoLength = 0x06040042;
constexpr std::uint32_t kAbortLength = 0x06070010;
constexpr std::uint32_t kAbortNoSub = 0x06090011;
constexpr std::uint32_t kAbortValue = 0x06090030;
constexpr std::uint32_t kAbortState = 0x08000022;

constexpr std::uint32_t kInvalid = 0x8000'0000u;

std::uint32_t default_tpdo_cob(int k, int id) { return static_cast<std::uint32_t>(0x180 + 0x100 * k + id); }
std::uint32_t default_rpdo_cob(int k, int id) { return static_cast<std::uint32_t>(0x200 + 0x100 * k + id); }

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
    e.nmt = 0x7F;
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
          const std::uint8_t state = e.nmt;
          send(0x700u + static_cast<std::uint32_t>(e.id), &state, 1);
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
      std::lock_guard<std::mutex> lock(mu_);
      handle(&f, mono_ns());
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

void CanopenNodeSet::send(std::uint32_t cob, const std::uint8_t* data, int len) {
  can_frame f{};
  f.can_id = cob;
  f.len = static_cast<std::uint8_t>(len);
  if (len > 0) std::memcpy(f.data, data, static_cast<std::size_t>(len));
  (void)!::write(fd_, &f, sizeof f);
}

void CanopenNodeSet::send_emcy(Emu& e, std::uint16_t code, std::uint8_t reg) {
  if (e.silent || e.nmt == 0x04) return;
  std::uint8_t d[8] = {};
  put(d, code, 2);
  d[2] = reg;
  send(0x080u + static_cast<std::uint32_t>(e.id), d, 8);
  ++e.emcys;
  e.last_emcy = code;
}

void CanopenNodeSet::on_heartbeat(int producer, std::int64_t now) {
  for (int j = 0; j < n_; ++j) {
    Emu& e = nodes_[static_cast<std::size_t>(j)];
    // An unplugged node hears nothing; a consumer entry with node id or time 0 is off (CiA 301).
    if (e.silent || (e.consumer & 0xFFFF) == 0 || static_cast<int>((e.consumer >> 16) & 0x7F) != producer) continue;
    if (e.consumer_armed) {
      e.max_gap_ms = std::max(e.max_gap_ms, static_cast<double>(now - e.producer_seen_ns) * 1e-6);
    } else if (options_.on_event) {
      char line[120];
      std::snprintf(line, sizeof line, "node %d: watching the master heartbeat (0x%03X, consumer time %u ms)", e.id,
                    0x700u + static_cast<unsigned>(producer), e.consumer & 0xFFFF);
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
    const std::int64_t limit = static_cast<std::int64_t>(e.consumer & 0xFFFF) * 1'000'000;
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
    const bool enabled = e.drive == Drive::kEnabled;
    const char* reaction = "drive not enabled, no reaction";
    if (enabled) {
      switch (e.abort_option) {
        case 1: e.drive = Drive::kFault, reaction = "torque off, fault (0x6007 = 1)"; break;
        case 2: e.drive = Drive::kSwitchOnDisabled, reaction = "torque off, disable voltage (0x6007 = 2)"; break;
        case 3: e.drive = Drive::kQuickStop, reaction = "torque off, quick stop (0x6007 = 3)"; break;
        default: reaction = "no action (0x6007 = 0): torque stays on"; break;
      }
      if (e.drive != Drive::kEnabled) e.torque_actual = 0;
    }
    e.error_register = static_cast<std::uint8_t>(e.error_register | 0x11);  // generic + communication
    send_emcy(e, 0x8130, e.error_register);
    if (options_.on_event) {
      char line[200];
      std::snprintf(line, sizeof line, "node %d: master heartbeat (0x%03X) lost after %.0f ms (consumer time %u ms): %s, EMCY 0x8130",
                    e.id, 0x700u + ((e.consumer >> 16) & 0x7F), e.last_loss_ms, e.consumer & 0xFFFF, reaction);
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
      send(d.cob, d.data.data(), d.len);
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
  e.nmt = 0x7F;
  const std::uint8_t zero = 0;
  if (!e.silent) send(0x700u + static_cast<std::uint32_t>(e.id), &zero, 1);
  e.next_heartbeat_ns = now + static_cast<std::int64_t>(e.heartbeat_ms) * 1'000'000;
}

void CanopenNodeSet::reset_communication(Emu& e) {
  e.heartbeat_ms = 0;
  e.consumer = 0;
  e.consumer_armed = false;
  e.cycle_period_us = 0;
  for (int k = 0; k < 4; ++k) {
    const auto uk = static_cast<std::size_t>(k);
    e.tpdo[uk] = Pdo{};
    e.tpdo[uk].cob_id = kInvalid | default_tpdo_cob(k, e.id);
    e.rpdo[uk] = Pdo{};
    e.rpdo[uk].cob_id = kInvalid | default_rpdo_cob(k, e.id);
  }
  e.has_cw = e.has_tt = e.has_mode = false;
}

void CanopenNodeSet::reset_application(Emu& e) {
  e.drive = Drive::kSwitchOnDisabled;
  e.controlword = 0;
  e.target_torque = 0;
  e.torque_actual = 0;
  e.mode = 0;
  e.mode_requested = 0;
  e.max_torque = 1000;
  e.rated_mnm = 1000;
  e.error_register = 0;
  e.abort_option = 1;  // the CiA 402 default: fault
  e.ip_value = 1;
  e.ip_index = -3;
}

std::uint16_t CanopenNodeSet::statusword(const Emu& e) const {
  constexpr std::uint16_t kRemote = 0x0200;
  switch (e.drive) {
    case Drive::kNotReady: return kRemote;
    case Drive::kSwitchOnDisabled: return kRemote | 0x0050;
    case Drive::kReady: return kRemote | 0x0031;
    case Drive::kSwitchedOn: return kRemote | 0x0033;
    case Drive::kEnabled: return kRemote | 0x0037;
    case Drive::kQuickStop: return kRemote | 0x0017;
    case Drive::kFault: return kRemote | 0x0018;
  }
  return kRemote;
}

void CanopenNodeSet::apply_controlword(Emu& e, std::uint16_t cw) {
  const bool reset_edge = (cw & 0x80) != 0 && (e.controlword & 0x80) == 0;
  e.controlword = cw;
  if (e.drive == Drive::kFault) {
    if (reset_edge) {
      e.drive = Drive::kSwitchOnDisabled;
      e.error_register = 0;
      ++e.fault_resets;
      send_emcy(e, 0x0000, 0);  // error reset
    }
    return;
  }
  if (e.drive == Drive::kNotReady) return;
  const bool voltage_off = (cw & 0x02) == 0;
  const bool quick_stop = (cw & 0x06) == 0x02;
  const bool shutdown = (cw & 0x07) == 0x06;
  const bool switch_on = (cw & 0x0F) == 0x07;
  const bool enable = (cw & 0x0F) == 0x0F;
  switch (e.drive) {
    case Drive::kSwitchOnDisabled:
      if (shutdown) e.drive = Drive::kReady;
      break;
    case Drive::kReady:
      if (voltage_off || quick_stop) e.drive = Drive::kSwitchOnDisabled;
      else if (switch_on) e.drive = Drive::kSwitchedOn;
      else if (enable) e.drive = Drive::kEnabled;  // transitions 3 and 4 at once
      break;
    case Drive::kSwitchedOn:
      if (voltage_off || quick_stop) e.drive = Drive::kSwitchOnDisabled;
      else if (shutdown) e.drive = Drive::kReady;
      else if (enable) e.drive = Drive::kEnabled;
      break;
    case Drive::kEnabled:
      if (voltage_off) e.drive = Drive::kSwitchOnDisabled;
      else if (quick_stop) e.drive = Drive::kQuickStop;
      else if (shutdown) e.drive = Drive::kReady;
      else if (switch_on) e.drive = Drive::kSwitchedOn;
      break;
    case Drive::kQuickStop:
      if (voltage_off) e.drive = Drive::kSwitchOnDisabled;
      break;
    case Drive::kNotReady:
    case Drive::kFault: break;
  }
}

int CanopenNodeSet::mappable_bits(std::uint16_t index, bool rpdo) {
  switch (index) {
    case 0x6040: return 16;
    case 0x6060: return 8;
    case 0x6071: return 16;
    case 0x6041: return rpdo ? 0 : 16;
    case 0x6061: return rpdo ? 0 : 8;
    case 0x6064: return rpdo ? 0 : 32;
    case 0x6077: return rpdo ? 0 : 16;
    case 0x60FD: return rpdo ? 0 : 32;
    default: return 0;
  }
}

std::uint32_t CanopenNodeSet::read_object(Emu& e, std::uint16_t index, std::uint8_t sub, std::uint32_t& v, int& bytes) {
  auto give = [&](std::uint32_t value, int size) -> std::uint32_t {
    v = value;
    bytes = size;
    return 0;
  };
  auto single = [&](std::uint32_t value, int size) -> std::uint32_t { return sub != 0 ? kAbortNoSub : give(value, size); };
  if ((index >= 0x1400 && index <= 0x1403) || (index >= 0x1800 && index <= 0x1803)) {
    const Pdo& p = index >= 0x1800 ? e.tpdo[index - 0x1800u] : e.rpdo[index - 0x1400u];
    if (sub == 0) return give(2, 1);
    if (sub == 1) return give(p.cob_id, 4);
    if (sub == 2) return give(p.type, 1);
    return kAbortNoSub;
  }
  if ((index >= 0x1600 && index <= 0x1603) || (index >= 0x1A00 && index <= 0x1A03)) {
    const Pdo& p = index >= 0x1A00 ? e.tpdo[index - 0x1A00u] : e.rpdo[index - 0x1600u];
    if (sub == 0) return give(p.count, 1);
    if (sub <= 8) return give(p.map[sub - 1u], 4);
    return kAbortNoSub;
  }
  switch (index) {
    case 0x1000: return single(options_.device_type, 4);
    case 0x1001: return single(e.error_register, 1);
    case 0x1006: return single(e.cycle_period_us, 4);
    case 0x1016:
      if (sub == 0) return give(1, 1);
      if (sub == 1) return give(e.consumer, 4);
      return kAbortNoSub;
    case 0x1017: return single(e.heartbeat_ms, 2);
    case 0x6007: return single(static_cast<std::uint16_t>(e.abort_option), 2);
    case 0x60C2:
      if (sub == 0) return give(2, 1);
      if (sub == 1) return give(e.ip_value, 1);
      if (sub == 2) return give(static_cast<std::uint8_t>(e.ip_index), 1);
      return kAbortNoSub;
    case 0x1018:
      if (sub == 0) return give(4, 1);
      if (sub == 1) return give(options_.vendor_id, 4);
      if (sub == 2) return give(0x402, 4);
      if (sub == 3) return give(1, 4);
      if (sub == 4) return give(static_cast<std::uint32_t>(e.id), 4);
      return kAbortNoSub;
    case 0x6040: return single(e.controlword, 2);
    case 0x6041: return single(statusword(e), 2);
    case 0x6060: return single(static_cast<std::uint8_t>(e.mode_requested), 1);
    case 0x6061: return single(static_cast<std::uint8_t>(e.mode), 1);
    case 0x6064: return single(static_cast<std::uint32_t>(physics_->encoder_counts(e.joint)), 4);
    case 0x6071: return single(static_cast<std::uint16_t>(e.target_torque), 2);
    case 0x6072: return single(e.max_torque, 2);
    case 0x6076: return single(e.rated_mnm, 4);
    case 0x6077: return single(static_cast<std::uint16_t>(e.torque_actual), 2);
    case 0x60FD: return single(e.inputs, 4);
    case 0x6502: return single((1u << 3) | (1u << 9), 4);  // profile torque, cyclic synchronous torque
    default: return kAbortNoObject;
  }
}

std::uint32_t CanopenNodeSet::write_object(Emu& e, std::uint16_t index, std::uint8_t sub, std::uint32_t v, int bytes, std::int64_t now) {
  // PDO communication parameters.
  if ((index >= 0x1400 && index <= 0x1403) || (index >= 0x1800 && index <= 0x1803)) {
    Pdo& p = index >= 0x1800 ? e.tpdo[index - 0x1800u] : e.rpdo[index - 0x1400u];
    if (sub == 0) return kAbortReadOnly;
    if (sub == 1) {
      if (bytes != 4) return kAbortLength;
      // A valid PDO's COB-ID may not change: invalidate it first (bit 31).
      if ((p.cob_id & kInvalid) == 0 && (v & kInvalid) == 0 && (v & 0x7FF) != (p.cob_id & 0x7FF)) return kAbortValue;
      p.cob_id = v & (kInvalid | 0x7FF);
      p.syncs = 0;
      return 0;
    }
    if (sub == 2) {
      if (bytes != 1) return kAbortLength;
      if (v > 240 && v < 252) return kAbortValue;
      p.type = static_cast<std::uint8_t>(v);
      return 0;
    }
    return kAbortNoSub;
  }
  // PDO mapping parameters (CiA 301: only while the PDO is invalid, entries only while sub 0 is 0).
  if ((index >= 0x1600 && index <= 0x1603) || (index >= 0x1A00 && index <= 0x1A03)) {
    const bool rpdo = index < 0x1A00;
    Pdo& p = rpdo ? e.rpdo[index - 0x1600u] : e.tpdo[index - 0x1A00u];
    if (sub > 8) return kAbortNoSub;
    if ((p.cob_id & kInvalid) == 0) return kAbortUnsupported;
    if (sub == 0) {
      if (bytes != 1) return kAbortLength;
      if (v > 8) return kAbortPdoLength;
      int bits = 0;
      for (std::uint32_t k = 0; k < v; ++k) {
        if (p.map[k] == 0) return kAbortNotMappable;
        bits += static_cast<int>(p.map[k] & 0xFF);
      }
      if (bits > 64) return kAbortPdoLength;
      p.count = static_cast<std::uint8_t>(v);
      return 0;
    }
    if (bytes != 4) return kAbortLength;
    if (p.count != 0) return kAbortState;
    const auto obj = static_cast<std::uint16_t>(v >> 16);
    const auto obj_sub = static_cast<std::uint8_t>(v >> 8);
    const int bits = static_cast<int>(v & 0xFF);
    if (obj_sub != 0 || mappable_bits(obj, rpdo) == 0 || mappable_bits(obj, rpdo) != bits) return kAbortNotMappable;
    p.map[sub - 1u] = v;
    return 0;
  }
  auto size_ok = [&](int want) { return sub == 0 && bytes == want; };
  switch (index) {
    case 0x1000:
    case 0x1001:
    case 0x1018:
    case 0x6041:
    case 0x6061:
    case 0x6064:
    case 0x6077:
    case 0x60FD:
    case 0x6502: return kAbortReadOnly;
    case 0x1017:
      if (!size_ok(2)) return sub != 0 ? kAbortNoSub : kAbortLength;
      e.heartbeat_ms = static_cast<std::uint16_t>(v);
      e.next_heartbeat_ns = now + static_cast<std::int64_t>(e.heartbeat_ms) * 1'000'000;
      return 0;
    case 0x1006:
      if (!size_ok(4)) return sub != 0 ? kAbortNoSub : kAbortLength;
      e.cycle_period_us = v;
      return 0;
    case 0x1016:
      if (sub == 0) return kAbortReadOnly;
      if (sub != 1) return kAbortNoSub;
      if (bytes != 4) return kAbortLength;
      if (((v >> 16) & 0x7F) == static_cast<std::uint32_t>(e.id) && (v & 0xFFFF) != 0) return kAbortValue;  // itself
      e.consumer = v & 0x007FFFFF;
      e.consumer_armed = false;  // until the producer's next heartbeat
      e.max_gap_ms = 0;
      return 0;
    case 0x6007: {
      if (!size_ok(2)) return sub != 0 ? kAbortNoSub : kAbortLength;
      const auto option = static_cast<std::int16_t>(v);
      if (option > 3) return kAbortValue;
      e.abort_option = option;
      return 0;
    }
    case 0x60C2:
      if (sub == 0) return kAbortReadOnly;
      if (sub > 2) return kAbortNoSub;
      if (bytes != 1) return kAbortLength;
      if (sub == 1) e.ip_value = static_cast<std::uint8_t>(v);
      if (sub == 2) e.ip_index = static_cast<std::int8_t>(v);
      return 0;
    case 0x6040:
      if (!size_ok(2)) return sub != 0 ? kAbortNoSub : kAbortLength;
      apply_controlword(e, static_cast<std::uint16_t>(v));
      return 0;
    case 0x6060: {
      if (!size_ok(1)) return sub != 0 ? kAbortNoSub : kAbortLength;
      const auto m = static_cast<std::int8_t>(v);
      if (m != 0 && m != 4 && m != 10) return kAbortValue;
      e.mode_requested = m;
      // A refused mode is taken (no abort) but not entered: only 0x6061 tells.
      if (e.refused_mode == 0 || m != e.refused_mode) e.mode = m;
      return 0;
    }
    case 0x6071:
      if (!size_ok(2)) return sub != 0 ? kAbortNoSub : kAbortLength;
      e.target_torque = static_cast<std::int16_t>(v);
      return 0;
    case 0x6072:
      if (!size_ok(2)) return sub != 0 ? kAbortNoSub : kAbortLength;
      e.max_torque = static_cast<std::uint16_t>(v);
      return 0;
    case 0x6076:
      if (!size_ok(4)) return sub != 0 ? kAbortNoSub : kAbortLength;
      if (v == 0) return kAbortValue;
      e.rated_mnm = v;
      return 0;
    default: return kAbortNoObject;
  }
}

void CanopenNodeSet::on_sdo(Emu& e, const std::uint8_t* d, std::int64_t now) {
  ++e.sdo_requests;
  const int ccs = d[0] >> 5;
  const auto index = static_cast<std::uint16_t>(le(d + 1, 2));
  const std::uint8_t sub = d[3];
  std::uint8_t r[8] = {};
  put(r + 1, index, 2);
  r[3] = sub;
  std::uint32_t abort = 0;
  if (ccs == 1) {  // initiate download
    ++e.sdo_downloads;
    if ((d[0] & 0x02) == 0) {
      abort = kAbortCommand;  // segmented: not supported here
    } else {
      const int bytes = (d[0] & 0x01) != 0 ? 4 - ((d[0] >> 2) & 0x03) : 4;
      abort = write_object(e, index, sub, le(d + 4, bytes), bytes, now);
      if (abort == 0) r[0] = 0x60;
    }
  } else if (ccs == 2) {  // initiate upload
    std::uint32_t v = 0;
    int bytes = 0;
    abort = read_object(e, index, sub, v, bytes);
    if (abort == 0) {
      r[0] = static_cast<std::uint8_t>(0x43 | ((4 - bytes) << 2));
      put(r + 4, v, bytes);
    }
  } else {
    abort = kAbortCommand;
  }
  if (abort != 0) {
    r[0] = 0x80;
    put(r + 4, abort, 4);
  }
  send(0x580u + static_cast<std::uint32_t>(e.id), r, 8);
}

void CanopenNodeSet::on_rpdo(Emu& e, int k, const std::uint8_t* d, int len) {
  const Pdo& p = e.rpdo[static_cast<std::size_t>(k)];
  int bits = 0;
  for (int m = 0; m < p.count; ++m) bits += static_cast<int>(p.map[static_cast<std::size_t>(m)] & 0xFF);
  if (len < bits / 8) return;  // CiA 301: not processed (a real drive would send EMCY 0x8210)
  ++e.rpdos;
  int offset = 0;
  for (int m = 0; m < p.count; ++m) {
    const std::uint32_t entry = p.map[static_cast<std::size_t>(m)];
    const int bytes = static_cast<int>(entry & 0xFF) / 8;
    const std::uint32_t v = le(d + offset, bytes);
    switch (entry >> 16) {
      case 0x6040: e.has_cw = true, e.pending_cw = static_cast<std::uint16_t>(v); break;
      case 0x6071: e.has_tt = true, e.pending_tt = static_cast<std::int16_t>(v); break;
      case 0x6060: e.has_mode = true, e.pending_mode = static_cast<std::int8_t>(v); break;
      default: break;
    }
    offset += bytes;
  }
}

void CanopenNodeSet::on_nmt(std::uint8_t cs, int target, std::int64_t now) {
  for (int j = 0; j < n_; ++j) {
    Emu& e = nodes_[static_cast<std::size_t>(j)];
    if ((target != 0 && target != e.id) || e.silent) continue;
    ++e.nmt_commands;
    switch (cs) {
      case 0x01:
        if (e.nmt != 0x05)
          for (auto& p : e.tpdo) p.syncs = 0;
        e.nmt = 0x05;
        break;
      case 0x02: e.nmt = 0x04; break;
      case 0x80: e.nmt = 0x7F; break;
      case 0x81:
        reset_application(e);
        reset_communication(e);
        boot(e, now);
        break;
      case 0x82:
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
    if (e.nmt == 0x05) {
      // Synchronous RPDOs take effect now.
      if (e.has_mode && (e.pending_mode == 0 || e.pending_mode == 4 || e.pending_mode == 10)) {
        e.mode_requested = e.pending_mode;
        if (e.refused_mode == 0 || e.pending_mode != e.refused_mode) e.mode = e.pending_mode;
      }
      if (e.has_tt) e.target_torque = e.pending_tt;
      if (e.has_cw) apply_controlword(e, e.pending_cw);
      e.has_cw = e.has_tt = e.has_mode = false;
      ++e.syncs;
    }
    const bool torque_on = e.nmt == 0x05 && e.drive == Drive::kEnabled && (e.mode == 4 || e.mode == 10);
    const int lim = std::min<int>(e.max_torque, 32767);
    e.torque_actual = torque_on ? static_cast<std::int16_t>(std::clamp<int>(e.target_torque, -lim, lim)) : std::int16_t{0};
    // ‰ of the rated torque → motor torque → current → joint torque through the transmission.
    const auto uj = static_cast<std::size_t>(e.joint);
    const arm::ActuatorConfig& act = config_.actuators[uj];
    const double motor_nm = e.torque_actual * 1e-3 * static_cast<double>(e.rated_mnm) * 1e-3;
    const double amps = motor_nm / act.torque_constant;
    const double amps_per_unit = arm::motor_current_for_joint_torque(config_.joints[uj], act, 1.0);
    cmd.tau[uj] = amps_per_unit != 0 ? amps / amps_per_unit : 0.0;
  }
  physics_->step(cmd, dt);

  for (int j = 0; j < n_; ++j) {
    Emu& e = nodes_[static_cast<std::size_t>(j)];
    if (e.silent || e.nmt != 0x05) continue;
    for (int k = 0; k < 4; ++k) {
      Pdo& p = e.tpdo[static_cast<std::size_t>(k)];
      if ((p.cob_id & kInvalid) != 0 || p.type == 0 || p.type > 240) continue;
      if (++p.syncs % p.type != 0) continue;
      if (e.drop_tpdos) continue;
      std::uint8_t d[8] = {};
      int offset = 0;
      for (int m = 0; m < p.count; ++m) {
        const std::uint32_t entry = p.map[static_cast<std::size_t>(m)];
        std::uint32_t v = 0;
        int bytes = 0;
        if (read_object(e, static_cast<std::uint16_t>(entry >> 16), 0, v, bytes) != 0) bytes = static_cast<int>(entry & 0xFF) / 8;
        put(d + offset, v, bytes);
        offset += bytes;
      }
      if (e.corrupt > 0) {
        --e.corrupt;
        offset = std::max(0, offset - 1);
      }
      ++e.tpdos;
      if (e.tpdo_delay_ns > 0 && n_delayed_ < static_cast<int>(delayed_.size())) {
        Delayed& late = delayed_[static_cast<std::size_t>(n_delayed_++)];
        late.due_ns = now + e.tpdo_delay_ns;
        late.node = j;
        late.pdo = k;
        late.answered_sync = syncs_heard_;
        late.cob = p.cob_id & 0x7FF;
        late.len = static_cast<std::uint8_t>(offset);
        std::memcpy(late.data.data(), d, sizeof d);
        continue;
      }
      send(p.cob_id & 0x7FF, d, offset);
      p.answered_sync = syncs_heard_;
      p.sent_ns = mono_ns();
    }
  }
}

void CanopenNodeSet::handle(const void* frame, std::int64_t now) {
  const auto& f = *static_cast<const can_frame*>(frame);
  if ((f.can_id & (CAN_EFF_FLAG | CAN_RTR_FLAG | CAN_ERR_FLAG)) != 0) return;
  const std::uint32_t cob = f.can_id & CAN_SFF_MASK;
  if (cob == 0x000) {
    if (f.len >= 2) on_nmt(f.data[0], f.data[1], now);
    return;
  }
  if (cob == 0x080) {
    ++syncs_heard_;
    on_sync(now);
    return;
  }
  if ((cob & 0x780) == 0x700) on_heartbeat(static_cast<int>(cob & 0x7F), now);
  const int id = static_cast<int>(cob & 0x7F);
  Emu* e = find(id);
  if (e == nullptr || e->silent) return;
  if ((cob & 0x780) == 0x600) {
    if (f.len == 8 && e->nmt != 0x04) on_sdo(*e, f.data, now);
    return;
  }
  if (e->nmt != 0x05) return;
  for (int k = 0; k < 4; ++k) {
    const Pdo& p = e->rpdo[static_cast<std::size_t>(k)];
    if ((p.cob_id & kInvalid) == 0 && (p.cob_id & 0x7FF) == cob) {
      on_rpdo(*e, k, f.data, f.len);
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
    e->drive = Drive::kFault;
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
  v.nmt = e->nmt;
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
