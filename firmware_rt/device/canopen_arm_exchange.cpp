// CanopenArm's real-time exchange: frames in and out, the per-SYNC cycle and its verdict, the
// inactive observation by SDO, read() and write(). Everything here is real-time safe.

#include "device/canopen_arm.hpp"

#include <errno.h>
#include <linux/can.h>
#include <linux/can/error.h>
#include <poll.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstring>

#include "device/canopen/socketcan.hpp"
#include "device/canopen_arm_text.hpp"
#include "device/joint_signals.hpp"
#include "lancet/shared_model/units.hpp"

namespace lancet::device {

using canopen_detail::to_timespec;

namespace {

// errno in words without allocating (strerror may format into a buffer of its own).
const char* errno_name(int err) noexcept {
  const char* d = strerrordesc_np(err);
  return d != nullptr ? d : "unknown error";
}

constexpr int kMaxFramesPerDrain = 512;

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
      const int number = canopen::decode_cob_id(cob).pdo_number;
      int want = -1;
      for (int k = 0; k < n_tpdos_; ++k)
        if (tpdos_[static_cast<std::size_t>(k)].number == number) want = tpdos_[static_cast<std::size_t>(k)].size;
      std::snprintf(text, sizeof text, "node %d: frame 0x%03X has %u bytes, its mapping %d", e.node_id, cob,
                    nodes_[static_cast<std::size_t>(i)].bad_len, want);
      break;
    }
    case W::kMissingTpdo: {
      code = cob;
      const int number = canopen::decode_cob_id(cob).pdo_number;
      int divider = 1;
      std::uint64_t since = 0;
      for (int k = 0; k < n_tpdos_; ++k) {
        if (tpdos_[static_cast<std::size_t>(k)].number != number) continue;
        divider = tpdos_[static_cast<std::size_t>(k)].divider;
        since = sync_count_ - nodes_[static_cast<std::size_t>(i)].tpdo_sync[static_cast<std::size_t>(k)];
      }
      if (divider == 1 && !bus_.sync_producer && !sync_seen_) {
        std::snprintf(text, sizeof text, "node %d: TPDO%d (0x%03X) missing: no SYNC from the bus's producer within %.2f ms", e.node_id,
                      number, cob, static_cast<double>(read_budget_ns_) * 1e-6);
      } else if (divider == 1) {
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

IoStatus CanopenArm::send(const canopen::Frame& frame) noexcept {
  const ::can_frame f = canopen::to_can_frame(frame);
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

IoStatus CanopenArm::send_sync() noexcept { return send(canopen::Frame{canopen::kCobSync, 0, {}}); }

void CanopenArm::send_nmt(canopen::NmtCommand cmd, int node_id) noexcept { (void)send(canopen::nmt_frame(cmd, node_id)); }

void CanopenArm::produce_heartbeat(std::int64_t now) noexcept {
  if (master_heartbeat_ns_ <= 0 || fd_ < 0 || now < next_master_heartbeat_ns_) return;
  const ::can_frame f = canopen::to_can_frame(canopen::heartbeat_frame(bus_.master_node_id, canopen::NmtState::kOperational));
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

void CanopenArm::handle(const ::can_frame& raw, std::int64_t now) noexcept {
  if ((raw.can_id & CAN_ERR_FLAG) != 0) {
    if ((raw.can_id & CAN_ERR_BUSOFF) != 0) bus_off_ = true;
    return;
  }
  if ((raw.can_id & (CAN_EFF_FLAG | CAN_RTR_FLAG)) != 0) return;
  const canopen::Frame f = canopen::from_can_frame(raw);
  if (f.cob_id == canopen::kCobSync) {
    // Another master's SYNC (only a consumer's filter takes it): a new cycle. TPDOs not yet seen
    // belong to earlier ones.
    if (!bus_.sync_producer) {
      ++sync_count_;
      cycle_t_ns_ = now;
      sync_seen_ = true;
      for (int j = 0; j < n_; ++j) nodes_[static_cast<std::size_t>(j)].seen_mask = 0;
    }
    return;
  }
  const canopen::CobId cob = canopen::decode_cob_id(f.cob_id);
  const int i = index_of_id_[static_cast<std::size_t>(cob.node_id)];
  if (i < 0 || cob.node_id == 0) return;
  Node& nd = nodes_[static_cast<std::size_t>(i)];
  const auto bad_length = [&] {
    nd.bad_length = true;
    nd.bad_cob = f.cob_id;
    nd.bad_len = f.len;
  };
  switch (cob.function) {
    case canopen::Function::kEmcy: {
      std::optional<canopen::Emcy> e = canopen::decode_emcy(f);
      if (!e) return bad_length();
      e->t_ns = now;
      nd.info.last_emcy = *e;
      ++nd.info.emcys;
      if (e->error_code != canopen::kEmcyErrorReset) nd.emcy_pending = true;  // error reset: no fault
      return;
    }
    case canopen::Function::kTpdo:
      for (int k = 0; k < n_tpdos_; ++k) {
        const PdoPlan& p = tpdos_[static_cast<std::size_t>(k)];
        if (p.number != cob.pdo_number) continue;
        if (f.len != p.size) return bad_length();
        take_tpdo(nd, k, f);
        return;
      }
      return;
    case canopen::Function::kSdoTx:
      if (f.len == 8) {
        nd.sdo_frame = f;
        nd.sdo_reply = true;
      }
      return;
    case canopen::Function::kHeartbeat:  // or boot-up
      if (const std::optional<canopen::NmtState> s = canopen::decode_heartbeat(f)) {
        nd.info.nmt = *s;
        if (nd.info.nmt == canopen::NmtState::kBootUp) nd.boot_seen = true;
        nd.info.last_heartbeat_ns = now;
        ++nd.info.heartbeats;
      }
      return;
    default: return;
  }
}

void CanopenArm::take_tpdo(Node& nd, int k, const canopen::Frame& f) noexcept {
  const PdoPlan& p = tpdos_[static_cast<std::size_t>(k)];
  const std::uint8_t* d = f.data.data();
  if (p.statusword.present) nd.info.statusword = static_cast<std::uint16_t>(canopen::get_le(d + p.statusword.offset, 2));
  if (p.inputs.present) nd.inputs = canopen::get_le(d + p.inputs.offset, 4);
  if (p.position.present) take_position(nd, static_cast<std::int32_t>(canopen::get_le(d + p.position.offset, 4)));
  nd.tpdo_sync[static_cast<std::size_t>(k)] = sync_count_;
  // Only an operational node sends PDOs: this overrides a heartbeat sent before it started
  // (frames of one node arrive in order, so a later heartbeat still says what follows).
  nd.info.nmt = canopen::NmtState::kOperational;
  nd.seen_mask = static_cast<std::uint8_t>(nd.seen_mask | (1u << k));
  ++nd.info.tpdos;
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
  if (!bus_.sync_producer) return exchange_without_sync(wait_ns);
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
    if (cycle_complete()) return IoStatus::kOk;
    if (now >= deadline) return IoStatus::kOk;  // evaluate() says what is missing
    wait_frames(deadline);
    if (socket_failed_) return IoStatus::kDisconnected;
  }
}

bool CanopenArm::cycle_complete() const noexcept {
  for (int j = 0; j < n_; ++j) {
    const Node& nd = nodes_[static_cast<std::size_t>(j)];
    if ((nd.seen_mask & expected_mask_) != expected_mask_ || nd.bad_length) return false;
  }
  return true;
}

void CanopenArm::keep_sync() noexcept {
  if (!pdo_running_ || !bus_.sync_producer || fd_ < 0) return;
  (void)drain(monotonic_ns());
  if (send_sync() == IoStatus::kOk) ++sync_count_;
}

IoStatus CanopenArm::exchange_without_sync(std::int64_t wait_ns) noexcept {
  // What came since the last read counts only from the newest SYNC on (handle() resets the cycle
  // at each); with none yet, nothing counts: wait for the producer's SYNC and the TPDOs after it.
  for (int j = 0; j < n_; ++j) nodes_[static_cast<std::size_t>(j)].seen_mask = 0;
  sync_seen_ = false;
  const std::int64_t start = monotonic_ns();
  for (;;) {
    const std::int64_t now = monotonic_ns();  // before the drain, as in exchange()
    if (!drain(now)) return IoStatus::kDisconnected;
    if (sync_seen_ && cycle_complete()) return IoStatus::kOk;
    // From the SYNC when one came (its TPDOs get the whole budget), else from the read's start.
    const std::int64_t deadline = (sync_seen_ ? cycle_t_ns_ : start) + wait_ns;
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
      report(IoStatus::kDeviceFault, W::kEmcy, j, canopen::emcy_cob_id(nd.info.node_id), 0, now);
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
    const std::uint32_t hb_cob = canopen::heartbeat_cob_id(nd.info.node_id);
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
      canopen::Frame f{canopen::rpdo_cob_id(p.number, info.node_id), p.size, {}};
      std::uint8_t* d = f.data.data();
      if (p.controlword.present) canopen::put_le(d + p.controlword.offset, info.controlword, 2);
      if (p.target_torque.present) canopen::put_le(d + p.target_torque.offset, static_cast<std::uint16_t>(info.target_torque), 2);
      if (p.mode.present) d[p.mode.offset] = static_cast<std::uint8_t>(mode);
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

CanopenArm::SdoReply CanopenArm::sdo_request(int i, const canopen::Frame& request, std::uint16_t index, std::uint8_t sub,
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
      const canopen::SdoResponse r = canopen::decode_sdo_response(nd.sdo_frame, index, sub, upload);
      switch (r.kind) {
        case canopen::SdoResponse::Kind::kOk: return {K::kOk, r.value};
        case canopen::SdoResponse::Kind::kAbort: return {K::kAbort, r.value};
        case canopen::SdoResponse::Kind::kSegmented: return {K::kSegmented, 0};
        case canopen::SdoResponse::Kind::kNotThis: break;  // a late answer to an earlier request: keep waiting
      }
    }
    if (now >= deadline) return {K::kTimeout, 0};
    wait_frames(deadline);
    if (socket_failed_) return {K::kSocket, 0};
  }
}

IoStatus CanopenArm::sdo_read(int i, std::uint16_t index, std::uint8_t sub, std::uint32_t& value) noexcept {
  using K = SdoReply::Kind;
  const NodeInfo& info = nodes_[static_cast<std::size_t>(i)].info;
  const SdoReply r = sdo_request(i, canopen::sdo_upload_request(info.node_id, index, sub), index, sub, true);
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

}  // namespace lancet::device
