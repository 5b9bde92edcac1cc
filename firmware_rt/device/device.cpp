#include "device/device.hpp"

#include "lancet/shared_model/units.hpp"

#include <time.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>

namespace lancet::device {

namespace {

Result<void> wrong_state(const std::string& name, const char* step, Lifecycle s) {
  return Result<void>::failure(ErrorCode::kInvalid, name + ": cannot " + step + " from state " + to_string(s));
}

}  // namespace

Result<void> Device::configure() {
  if (state_ != Lifecycle::kUnconfigured) return wrong_state(name_, "configure", state_);
  Result<void> o = on_configure();
  if (o.ok()) state_ = Lifecycle::kInactive;
  return o;
}

Result<void> Device::activate() {
  if (state_ != Lifecycle::kInactive) return wrong_state(name_, "activate", state_);
  Result<void> o = on_activate();
  if (o.ok()) {
    state_ = Lifecycle::kActive;
    counters_.consecutive_errors = 0;
  }
  return o;
}

Result<void> Device::deactivate() {
  if (state_ != Lifecycle::kActive && state_ != Lifecycle::kFault) return wrong_state(name_, "deactivate", state_);
  Result<void> o = on_deactivate();
  state_ = Lifecycle::kInactive;  // whatever the bus said, we no longer drive it
  return o;
}

Result<void> Device::rearm() {
  if (state_ != Lifecycle::kFault) return wrong_state(name_, "rearm", state_);
  Result<void> o = on_rearm();
  if (!o.ok()) return o;
  state_ = Lifecycle::kActive;
  counters_.consecutive_errors = 0;
  fault_cause_ = IoStatus::kOk;
  fault_detail_ = FaultDetail{};
  link_lost_ = false;
  glitch_bucket_ = 0;
  q_ref_ns_ = 0;  // the arm may have moved while faulted: the next reading is the new reference
  return o;
}

Result<void> Device::reconnect() {
  if (state_ != Lifecycle::kFault) return wrong_state(name_, "reconnect", state_);
  Result<void> o = on_reconnect();
  if (o.ok()) {
    link_lost_ = false;
    ++counters_.reconnects;
    q_ref_ns_ = 0;
  }
  return o;
}

Result<void> Device::on_reconnect() {
  return Result<void>::failure(ErrorCode::kUnsupported, name_ + ": reconnect is not supported by this backend");
}

void Device::note_error(IoStatus status, std::int32_t node, std::uint32_t code, const char* text) noexcept {
  last_error_.status = status;
  last_error_.node = node;
  last_error_.code = code;
  last_error_.t_ns = monotonic_ns();
  const char* t = text != nullptr ? text : to_string(status);
  const std::size_t n = std::min(std::strlen(t), last_error_.text.size() - 1);
  std::memcpy(last_error_.text.data(), t, n);
  last_error_.text[n] = '\0';
  noted_ = true;
}

IoStatus Device::check_plausible(const JointState& in) noexcept {
  const Plausibility& p = plausibility_;
  if (p.n == 0) return IoStatus::kOk;
  const int n = std::min(p.n, in.n);
  if (q_ref_ns_ != 0) {
    const double dt = std::max(static_cast<double>(in.t_ns - q_ref_ns_) * 1e-9, 1e-3);
    for (int j = 0; j < n; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      const double allowed = 2.0 * p.max_speed[uj] * dt + 2.0 * p.resolution[uj];
      const double jump = std::abs(in.q[uj] - q_ref_[uj]);
      if (!(jump <= allowed)) {  // NaN included
        char buf[112];
        std::snprintf(buf, sizeof buf, "joint %d encoder jumped %.4g (allowed %.4g in %.1f ms)", j, jump, allowed, dt * 1e3);
        note_error(IoStatus::kImplausible, j, 0, buf);
        return IoStatus::kImplausible;
      }
    }
  }
  for (int j = 0; j < n; ++j) q_ref_[static_cast<std::size_t>(j)] = in.q[static_cast<std::size_t>(j)];
  q_ref_ns_ = in.t_ns;
  return IoStatus::kOk;
}

void Device::account(IoStatus s, std::int64_t t0_ns, bool is_read) noexcept {
  const std::int64_t dt = monotonic_ns() - t0_ns;
  counters_.last_io_ns = dt;
  if (dt > counters_.max_io_ns) counters_.max_io_ns = dt;
  const bool noted = noted_;
  noted_ = false;
  // A drive's fault bit stays set until it is reset and a lost link stays lost until it is
  // reopened: count when either begins, not every read that finds it still so.
  const bool continues = is_read && s == last_read_;
  if (is_read) last_read_ = s;
  bool trip = false;
  switch (s) {
    case IoStatus::kOk:
      ++counters_.ok;
      // A good read proves the device answers; a write that went out does not (many buses do not
      // confirm writes), so it does not clear a run of failed reads.
      if (is_read) {
        counters_.consecutive_errors = 0;
        if (glitch_bucket_ > 0) --glitch_bucket_;
      }
      return;
    case IoStatus::kImplausible:
      // The bus answered; the reading was wrong. Glitches trip through their own bucket.
      ++counters_.glitches;
      glitch_bucket_ += policy_.glitch_leak_reads;
      trip = policy_.max_glitches > 0 &&
             glitch_bucket_ >= static_cast<std::uint64_t>(policy_.max_glitches) * policy_.glitch_leak_reads;
      break;
    case IoStatus::kTimeout: ++counters_.timeouts; break;
    case IoStatus::kCrcError: ++counters_.crc_errors; break;
    case IoStatus::kProtocolError: ++counters_.protocol_errors; break;
    case IoStatus::kDisconnected:
      if (!continues) ++counters_.disconnects;
      break;
    case IoStatus::kDeviceFault:
      if (!continues) ++counters_.device_faults;
      break;
    case IoStatus::kNotActive:
    case IoStatus::kFault: return;
  }
  if (!noted) note_error(s, -1, 0, nullptr);
  noted_ = false;
  if (s == IoStatus::kDisconnected) link_lost_ = true;
  if (s != IoStatus::kImplausible) {
    ++counters_.consecutive_errors;
    trip = s == IoStatus::kDisconnected || s == IoStatus::kDeviceFault ||
           counters_.consecutive_errors >= policy_.max_consecutive_errors;
  }
  if (trip && state_ == Lifecycle::kActive) {
    state_ = Lifecycle::kFault;
    fault_cause_ = s;
    fault_detail_ = last_error_;
    ++counters_.faults;
    on_fault();
  }
}

IoStatus Device::read(JointState& out) noexcept {
  if (state_ == Lifecycle::kUnconfigured) return IoStatus::kNotActive;
  ++counters_.reads;
  const std::int64_t t0 = monotonic_ns();
  IoStatus s = on_read(out);
  if (s == IoStatus::kOk) {
    out.t_ns = t0;
    s = check_plausible(out);
  }
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
    noted_ = false;        // what that write noted is not an error of this call
    return IoStatus::kFault;
  }
  const IoStatus s = on_write(cmd);
  account(s, t0, false);
  return state_ == Lifecycle::kFault ? IoStatus::kFault : s;
}

}  // namespace lancet::device
