#include "device/device.hpp"

#include "lancet/shared_model/units.hpp"

#include <time.h>

namespace lancet::device {

namespace {

Outcome wrong_state(const std::string& name, const char* step, Lifecycle s) {
  return Outcome::failure(ErrorCode::kInvalid, name + ": cannot " + step + " from state " + to_string(s));
}

}  // namespace

const char* to_string(IoStatus s) noexcept {
  switch (s) {
    case IoStatus::kOk: return "ok";
    case IoStatus::kTimeout: return "timeout";
    case IoStatus::kCrcError: return "crc error";
    case IoStatus::kProtocolError: return "protocol error";
    case IoStatus::kDisconnected: return "disconnected";
    case IoStatus::kDeviceFault: return "device fault";
    case IoStatus::kNotActive: return "not active";
    case IoStatus::kFault: return "fault";
  }
  return "?";
}

const char* to_string(Lifecycle s) noexcept {
  switch (s) {
    case Lifecycle::kUnconfigured: return "unconfigured";
    case Lifecycle::kInactive: return "inactive";
    case Lifecycle::kActive: return "active";
    case Lifecycle::kFault: return "fault";
  }
  return "?";
}

Outcome Device::configure() {
  if (state_ != Lifecycle::kUnconfigured) return wrong_state(name_, "configure", state_);
  Outcome o = on_configure();
  if (o.ok()) state_ = Lifecycle::kInactive;
  return o;
}

Outcome Device::activate() {
  if (state_ != Lifecycle::kInactive) return wrong_state(name_, "activate", state_);
  Outcome o = on_activate();
  if (o.ok()) {
    state_ = Lifecycle::kActive;
    counters_.consecutive_errors = 0;
  }
  return o;
}

Outcome Device::deactivate() {
  if (state_ != Lifecycle::kActive && state_ != Lifecycle::kFault) return wrong_state(name_, "deactivate", state_);
  Outcome o = on_deactivate();
  state_ = Lifecycle::kInactive;  // whatever the bus said, we no longer drive it
  return o;
}

Outcome Device::rearm() {
  if (state_ != Lifecycle::kFault) return wrong_state(name_, "rearm", state_);
  Outcome o = on_rearm();
  if (!o.ok()) return o;
  state_ = Lifecycle::kActive;
  counters_.consecutive_errors = 0;
  fault_cause_ = IoStatus::kOk;
  return o;
}

void Device::account(IoStatus s, std::int64_t t0_ns, bool is_read) noexcept {
  const std::int64_t dt = monotonic_ns() - t0_ns;
  counters_.last_io_ns = dt;
  if (dt > counters_.max_io_ns) counters_.max_io_ns = dt;
  switch (s) {
    case IoStatus::kOk:
      ++counters_.ok;
      // A good read proves the device answers; a write that went out does not (many buses do not
      // confirm writes), so it does not clear a run of failed reads.
      if (is_read) counters_.consecutive_errors = 0;
      return;
    case IoStatus::kTimeout: ++counters_.timeouts; break;
    case IoStatus::kCrcError: ++counters_.crc_errors; break;
    case IoStatus::kProtocolError: ++counters_.protocol_errors; break;
    case IoStatus::kDisconnected: ++counters_.disconnects; break;
    case IoStatus::kDeviceFault: ++counters_.device_faults; break;
    case IoStatus::kNotActive:
    case IoStatus::kFault: return;
  }
  ++counters_.consecutive_errors;
  const bool trip = s == IoStatus::kDisconnected || s == IoStatus::kDeviceFault ||
                    counters_.consecutive_errors >= policy_.max_consecutive_errors;
  if (trip && state_ == Lifecycle::kActive) {
    state_ = Lifecycle::kFault;
    fault_cause_ = s;
    ++counters_.faults;
  }
}

IoStatus Device::read(JointState& out) noexcept {
  if (state_ == Lifecycle::kUnconfigured) return IoStatus::kNotActive;
  ++counters_.reads;
  const std::int64_t t0 = monotonic_ns();
  const IoStatus s = on_read(out);
  if (s == IoStatus::kOk) out.t_ns = t0;
  account(s, t0, true);
  return state_ == Lifecycle::kFault ? IoStatus::kFault : s;
}

IoStatus Device::write(const JointCommand& cmd) noexcept {
  if (state_ != Lifecycle::kActive && state_ != Lifecycle::kFault) return IoStatus::kNotActive;
  ++counters_.writes;
  const std::int64_t t0 = monotonic_ns();
  if (state_ == Lifecycle::kFault) {
    JointCommand zero{};
    zero.n = cmd.n;
    (void)on_write(zero);  // best effort: the drives should hold no torque
    return IoStatus::kFault;
  }
  const IoStatus s = on_write(cmd);
  account(s, t0, false);
  return state_ == Lifecycle::kFault ? IoStatus::kFault : s;
}

}  // namespace lancet::device
