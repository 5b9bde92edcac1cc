// CanopenArm's set-up: the socket, the SDO client, each node's configuration (objects, PDO
// communication and mapping, the drive-side watchdog), NMT, and the CiA 402 state machine to
// operation enabled and back; the lifecycle steps built from them. Not real-time: these allocate
// and wait.

#include "device/canopen_arm.hpp"

#include <errno.h>
#include <linux/can.h>
#include <linux/can/error.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include "device/canopen/socketcan.hpp"
#include "device/canopen_arm_text.hpp"
#include "lancet/shared_model/units.hpp"

namespace lancet::device {

using canopen_detail::errno_text;
using canopen_detail::hex;
using canopen_detail::ms_text;
using canopen_detail::ns_of;
using canopen_detail::object_name;
using canopen_detail::sleep_until;
namespace od = canopen::od;

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
    add(canopen::emcy_cob_id(id));
    add(canopen::sdo_tx_cob_id(id));
    add(canopen::heartbeat_cob_id(id));
    for (int k = 0; k < n_tpdos_; ++k) add(canopen::tpdo_cob_id(tpdos_[static_cast<std::size_t>(k)].number, id));
  }
  // Another master's SYNC starts this arm's cycles (sync_producer = false).
  if (!bus_.sync_producer) filters.push_back({canopen::kCobSync, CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG});
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


Result<std::uint32_t> CanopenArm::sdo_transfer(int i, const canopen::Frame& request, std::uint16_t index, std::uint8_t sub, bool upload,
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
  const canopen::Frame f = canopen::sdo_download_request(nodes_[static_cast<std::size_t>(i)].info.node_id, index, sub, value, bytes);
  auto r = sdo_transfer(i, f, index, sub, false, "download " + object_name(index, sub) + " = " + std::to_string(value));
  if (!r.ok()) return r.error();
  return Result<void>::success();
}

Result<std::uint32_t> CanopenArm::sdo_upload(int i, std::uint16_t index, std::uint8_t sub) {
  const canopen::Frame f = canopen::sdo_upload_request(nodes_[static_cast<std::size_t>(i)].info.node_id, index, sub);
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
  auto type = sdo_upload(i, od::kDeviceType, 0);
  if (!type.ok()) return type.error();
  if ((type.value() & 0xFFFF) != od::kProfileCia402) {
    return Result<void>::failure(ErrorCode::kMismatch, name() + ": node " + std::to_string(nd.info.node_id) + ": device type (0x1000) is " +
                                                      hex(type.value(), 8) + ", not a CiA 402 drive (402 = 0x0192 in the low 16 bits)");
  }
  auto vendor = sdo_upload(i, od::kIdentity, 1);
  if (!vendor.ok()) return vendor.error();
  nd.info.vendor_id = vendor.value();
  return Result<void>::success();
}

Result<void> CanopenArm::set_mode(int i) {
  Node& nd = nodes_[static_cast<std::size_t>(i)];
  const std::int8_t mode = bus_.mode == arm::Cia402Mode::kCyclicSyncTorque ? canopen::kModeCyclicSyncTorque : canopen::kModeProfileTorque;
  if (Result<void> r = sdo_download(i, od::kModesOfOperation, 0, static_cast<std::uint8_t>(mode), 1); !r.ok()) return r;
  // A drive may take a moment to switch; one that cannot says so only in 0x6061.
  const std::int64_t deadline = monotonic_ns() + ns_of(timing_.mode_timeout);
  for (;;) {
    auto shown = sdo_upload(i, od::kModesOfOperationDisplay, 0);
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
      {od::kProducerHeartbeatTime, 0, hb_ms, 2},
      {od::kCommunicationCyclePeriod, 0, period_us, 4},  // the SYNC the drive can expect
  };
  for (const Write& w : basics) {
    if (Result<void> r = sdo_download(i, w.index, w.sub, w.value, w.bytes); !r.ok()) return r;
  }
  nd.info.controlword = canopen::kCwDisableVoltage;
  nd.info.target_torque = 0;
  if (interpolation_) {
    // Interpolation time period (cyclic synchronous modes): value · 10^index s, the SYNC period.
    if (Result<void> r = sdo_download(i, od::kInterpolationTimePeriod, 1, interpolation_->value, 1); !r.ok()) return r;
    const auto index = static_cast<std::uint8_t>(interpolation_->index);
    if (Result<void> r = sdo_download(i, od::kInterpolationTimePeriod, 2, index, 1); !r.ok()) return r;
  }
  if (Result<void> r = set_mode(i); !r.ok()) return r;
  const Write torques[] = {
      {od::kMotorRatedTorque, 0, nd.info.rated_torque_mnm, 4},  // the unit of the target torque
      {od::kMaxTorque, 0, static_cast<std::uint16_t>(nd.info.max_torque), 2},
  };
  for (const Write& w : torques) {
    if (Result<void> r = sdo_download(i, w.index, w.sub, w.value, w.bytes); !r.ok()) return r;
  }

  if (Result<void> r = configure_pdos(i); !r.ok()) return r;

  // The drive-side watchdog: the reaction first (disable voltage: torque-free at once), then the
  // consumer, which starts watching at the master's next heartbeat (the master is producing).
  if (master_heartbeat_ns_ > 0) {
    const auto watchdog_ms = static_cast<std::uint32_t>(std::llround(bus_.drive_watchdog * 1e3));
    const auto option = static_cast<std::uint16_t>(canopen::kAbortConnectionDisableVoltage);
    if (Result<void> r = sdo_download(i, od::kAbortConnectionOption, 0, option, 2); !r.ok()) return r;
    const std::uint32_t consumer = canopen::heartbeat_consumer_entry(bus_.master_node_id, watchdog_ms);
    if (Result<void> r = sdo_download(i, od::kConsumerHeartbeatTime, 1, consumer, 4); !r.ok()) return r;
    nd.consumer_set = true;
  }
  auto sw = sdo_upload(i, o.statusword, 0);
  if (!sw.ok()) return sw.error();
  nd.info.statusword = static_cast<std::uint16_t>(sw.value());
  nd.boot_seen = false;
  return Result<void>::success();
}

Result<void> CanopenArm::configure_pdos(int i) {
  // CiA 301: invalidate, transmission type, clear the mapping, map, count, validate. The PDO
  // numbers the config does not use are left invalid.
  const int id = nodes_[static_cast<std::size_t>(i)].info.node_id;
  for (const bool tx : {true, false}) {
    const std::vector<arm::PdoConfig>& pdos = tx ? bus_.tpdos : bus_.rpdos;
    for (int number = 1; number <= canopen::kMaxPdos; ++number) {
      const std::uint16_t comm = tx ? canopen::tpdo_communication_index(number) : canopen::rpdo_communication_index(number);
      const std::uint16_t map = tx ? canopen::tpdo_mapping_index(number) : canopen::rpdo_mapping_index(number);
      const std::uint32_t cob = tx ? canopen::tpdo_cob_id(number, id) : canopen::rpdo_cob_id(number, id);
      if (Result<void> r = sdo_download(i, comm, 1, canopen::kPdoInvalid | cob, 4); !r.ok()) return r;
      const auto it = std::find_if(pdos.begin(), pdos.end(), [&](const arm::PdoConfig& p) { return p.number == number; });
      if (it == pdos.end()) continue;
      if (Result<void> r = sdo_download(i, comm, 2, static_cast<std::uint32_t>(it->sync_divider), 1); !r.ok()) return r;
      if (Result<void> r = sdo_download(i, map, 0, 0, 1); !r.ok()) return r;
      for (std::size_t e = 0; e < it->entries.size(); ++e) {
        const arm::PdoEntry& en = it->entries[e];
        const std::uint32_t v = canopen::encode_mapping({en.index, en.subindex, static_cast<std::uint8_t>(en.bits)});
        if (Result<void> r = sdo_download(i, map, static_cast<std::uint8_t>(e + 1), v, 4); !r.ok()) return r;
      }
      if (Result<void> r = sdo_download(i, map, 0, static_cast<std::uint32_t>(it->entries.size()), 1); !r.ok()) return r;
      if (Result<void> r = sdo_download(i, comm, 1, cob, 4); !r.ok()) return r;
    }
  }
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
    if (Result<void> r = sdo_download(j, od::kConsumerHeartbeatTime, 1, 0, 4); !r.ok() && result.ok()) result = r;
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

}  // namespace lancet::device
