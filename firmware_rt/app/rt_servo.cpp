#include "rt_servo.hpp"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <string>

#include "lancet/shared_model/validate.hpp"

namespace lancet::app {

namespace {
// The haptic model's time step is the servo period.
RtModel with_period(RtModel m) {
  m.servo.haptic.dt = static_cast<double>(m.servo.period_ns) * 1e-9;
  return m;
}

BusCounters to_wire(const device::IoCounters& c) noexcept {
  BusCounters b{};
  b.reads = c.reads, b.writes = c.writes, b.ok = c.ok;
  b.timeouts = c.timeouts, b.crc_errors = c.crc_errors, b.protocol_errors = c.protocol_errors;
  b.disconnects = c.disconnects, b.device_faults = c.device_faults, b.glitches = c.glitches;
  b.stale_replies = c.stale_replies, b.faults = c.faults, b.reconnects = c.reconnects;
  b.max_io_ns = c.max_io_ns;
  return b;
}

}  // namespace

void copy_text(char* dst, std::size_t size, const char* src) noexcept {
  if (size == 0) return;
  std::size_t n = 0;
  if (src != nullptr) {
    for (; n + 1 < size && src[n] != '\0'; ++n) {
      const auto c = static_cast<unsigned char>(src[n]);
      dst[n] = c >= 0x20 && c <= 0x7e ? src[n] : '?';  // printable only: the text crosses to a terminal
    }
  }
  dst[n] = '\0';
}

RtServo::RtServo(const RtModel& model, SharedState& shared, std::int64_t start_ns, device::Device* arm)
    : model_(with_period(model)),
      shared_(shared),
      device_(arm),
      has_arm_(arm != nullptr),
      data_(std::make_unique<RtData>()),
      intake_(std::make_unique<PatchIntake>(shared, model_.servo.period_ns)) {
  RtData& d = *data_;
  d.start_ns = start_ns;
  d.pid = static_cast<std::int32_t>(getpid());
  if (has_arm_) {
    if (arm->joint_count() != model_.servo.kinematics.joint_count())
      throw std::invalid_argument("RtServo: the arm " + arm->name() + " has " + std::to_string(arm->joint_count()) +
                                  " joints, its kinematics " + std::to_string(model_.servo.kinematics.joint_count()));
  } else {
    // The built-in stylus: a Device like the arms, at the script's start, Cartesian.
    const double dt = static_cast<double>(model_.servo.period_ns) * 1e-9;
    stylus_ = std::make_unique<device::SimStylus>(model_.stylus, dt, device::scripted_target(0.0, model_.script_depth));
    if (!stylus_->configure().ok() || !stylus_->activate().ok()) throw std::logic_error("RtServo: the built-in stylus did not start");
    device_ = stylus_.get();
    model_.servo.kinematics = arm::Kinematics::cartesian();
    model_.servo.device_origin = {};
    model_.servo.max_joint_torque.fill(0.0);
    for (std::size_t j = 0; j < 3; ++j) model_.servo.max_joint_torque[j] = model_.servo.haptic.safety.max_force;
  }
  // The model, for whoever records the session (a replay needs exactly it).
  shared_.servo_model.write(servo::to_blob(model_.servo));
  // Requests made before this servo existed are not for it.
  OperatorRequest r{};
  if (shared_.operator_request.try_read_if_newer(r, d.request_version) == ReadStatus::kOk) d.request_seq = r.seq;
}

bool RtServo::supervise(std::int64_t now_ns) {
  if (!has_arm_) return false;
  device::Device* const arm = device_;
  RtData& d = *data_;
  const auto phase = static_cast<Handover>(d.handover.load(std::memory_order_acquire));
  if (phase == Handover::kIdle) {
    // Decide from the servo's own published status: the device itself belongs to the servo now.
    RtStatus st{};
    if (d.own_status.try_read(st, 1000) != ReadStatus::kOk) return false;
    const bool faulted = st.device_state == device::Lifecycle::kFault;
    DeviceJob job = DeviceJob::kNone;
    if (d.rearm_wanted.exchange(false, std::memory_order_acq_rel) && faulted) {
      job = DeviceJob::kRearm;
    } else if (faulted && st.link_lost != 0 && now_ns >= d.next_reconnect_ns) {
      job = DeviceJob::kReconnect;
      d.next_reconnect_ns = now_ns + model_.reconnect_interval_ns;
    }
    if (job == DeviceJob::kNone) return false;
    d.job.store(static_cast<int>(job), std::memory_order_relaxed);
    d.handover.store(static_cast<int>(Handover::kRequested), std::memory_order_release);
    return false;
  }
  if (phase != Handover::kGranted) return false;  // the servo has not granted yet, or not taken it back
  // The servo keeps off the device until kDone.
  const auto job = static_cast<DeviceJob>(d.job.load(std::memory_order_relaxed));
  bool ok = false;
  if (job == DeviceJob::kRearm) {
    if (arm->state() == device::Lifecycle::kFault) {
      const Result<void> o = arm->rearm();
      ok = o.ok();
      if (ok) {
        copy_text(d.rearm_text.data(), d.rearm_text.size(), "re-armed");
      } else {
        ++d.rearm_failures;
        copy_text(d.rearm_text.data(), d.rearm_text.size(), o.error().message.c_str());
      }
    }
  } else if (job == DeviceJob::kReconnect) {
    if (arm->state() == device::Lifecycle::kFault && arm->link_lost()) {
      const Result<void> o = arm->reconnect();
      ok = o.ok();
      copy_text(d.rearm_text.data(), d.rearm_text.size(),
                ok ? "bus link reopened; the arm stays faulted until re-armed" : o.error().message.c_str());
    }
  }
  d.job_ok = ok;
  d.handover.store(static_cast<int>(Handover::kDone), std::memory_order_release);
  return ok;
}

void RtServo::reject(std::uint64_t& counter, const char* why) noexcept {
  ++counter;
  data_->last_reject.store(why, std::memory_order_relaxed);
}

std::size_t RtServo::drain_commands(std::int64_t now_ns, bool& operator_rearm) noexcept {
  RtData& d = *data_;
  // At most one bounded batch per tick, whatever the ring's indices say; each command checked.
  const std::size_t cap = std::min(model_.max_commands_per_tick, d.command_batch.size());
  bool reset = false;
  const std::size_t n = shared_.commands.try_pop_n(d.command_batch.data(), cap, &reset);
  if (reset) reject(d.health.ring_resets, "commands ring: indices impossible, reset");
  std::size_t taken = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const Command& c = d.command_batch[i];
    if (const char* why = wire::check(c)) {
      reject(d.health.commands_rejected, why);
      continue;
    }
    // Sealed commands in stale slots (a corrupted index replays them) are not new: every command
    // is stamped later than the one before it, and not in the future.
    if (c.t_ns <= d.last_command_t_ns || c.t_ns - now_ns > wire::kFutureSlackNs) {
      reject(d.health.commands_rejected, "command.t_ns: not after the last command, or in the future (a replay?)");
      continue;
    }
    d.last_command_t_ns = c.t_ns;
    d.commands[taken++] = servo::pack_command(c.kind, c.mode);
  }
  if (n == cap && !shared_.commands.empty_approx()) ++d.health.commands_deferred;

  // An operator's re-arm request (lancetctl rearm), through its own seqlock.
  operator_rearm = false;
  if (shared_.operator_request.try_read_if_newer(d.request, d.request_version, 2) == ReadStatus::kOk) {
    if (const char* why = wire::check(d.request, now_ns)) {
      reject(d.health.commands_rejected, why);
    } else if (d.request.seq != d.request_seq) {
      d.request_seq = d.request.seq;
      if (now_ns - d.request.t_ns <= model_.operator_request_max_age_ns) {
        ++d.operator_requests;
        operator_rearm = true;
      }
    }
  }
  return taken;
}

bool RtServo::take_device() noexcept {
  if (!has_arm_) return true;  // the built-in stylus needs no supervisor
  RtData& d = *data_;
  auto phase = static_cast<Handover>(d.handover.load(std::memory_order_acquire));
  if (phase == Handover::kRequested) {
    d.handover.store(static_cast<int>(Handover::kGranted), std::memory_order_release);
    return false;
  }
  if (phase == Handover::kDone) {
    // The supervisor's results are visible after the acquire above.
    if (d.job.load(std::memory_order_relaxed) == static_cast<int>(DeviceJob::kRearm) && d.job_ok) ++d.rearms;
    d.handover.store(static_cast<int>(Handover::kIdle), std::memory_order_release);
    phase = Handover::kIdle;
  }
  return phase == Handover::kIdle;
}

void RtServo::tick(const rt::TickContext& ctx) noexcept {
  RtData& d = *data_;
  const std::int64_t deadline_ns = ctx.deadline_ns;
  const std::int64_t now_ns = ctx.woke_ns;
  // The script's clock (held at its start until the tissue is there, when asked to wait for it).
  if (model_.script_waits_for_tissue && d.patch_version == 0) d.start_ns = deadline_ns;
  const double t = static_cast<double>(deadline_ns - d.start_ns) * 1e-9;

  // The device handover first: a requested device is granted before anything else touches it.
  const bool device_owned = take_device();

  // Commands: the ring's, then the script's tool changes, each when its time comes (a later key
  // in the viz wins until the script's next change).
  servo::ServoInput in;
  std::size_t n = drain_commands(now_ns, in.operator_rearm);
  if (model_.trajectory != nullptr) {
    const auto& changes = model_.trajectory->tools;
    while (d.next_tool_change < changes.size() && changes[d.next_tool_change].t <= t) {
      if (n < d.commands.size()) {
        d.commands[n++] = servo::pack_command(CommandKind::kSetToolMode, changes[d.next_tool_change].mode);
      } else {
        in.commands_cut = true;
      }
      ++d.next_tool_change;
    }
  }
  in.commands = std::span<const std::uint8_t>(d.commands.data(), n);

  // Where the hand pulls the stylus: the viz's target while it is fresh, else the script.
  if (shared_.stylus_target.try_read_if_newer(d.target_scratch, d.target_version, 2) == ReadStatus::kOk) {
    if (const char* why = wire::check(d.target_scratch, now_ns)) {
      reject(d.health.targets_rejected, why);
    } else {
      d.target = d.target_scratch;
    }
  }
  const bool target_fresh = d.target.active != 0 && now_ns - d.target.t_ns <= model_.target_timeout_ns;
  const Vec3 target = target_fresh              ? d.target.target.position
                      : model_.trajectory != nullptr ? model_.trajectory->at(t)
                                                     : device::scripted_target(t, model_.script_depth);

  // The newest patch the intake has ready (copied, checked, its tree built): its helper thread's
  // work, or, without one, done here.
  if (!intake_->threaded()) (void)intake_->poll(now_ns);
  const ReadyPatch* const ready = intake_->take();
  if (ready != nullptr && ready->version != d.patch_version) {
    d.patch_version = ready->version;
    ++d.patches_received;
  }
  const IntakeCounters& ic = intake_->counters();
  d.health.patches_rejected = ic.rejected.load(std::memory_order_relaxed);
  d.health.patches_unreadable = ic.busy.load(std::memory_order_relaxed);
  if (d.health.patches_rejected != d.patches_rejected_seen) {
    d.patches_rejected_seen = d.health.patches_rejected;
    d.last_reject.store(ic.last_reject.load(std::memory_order_relaxed), std::memory_order_relaxed);
  }

  // Read the device (the hand steering a simulated one first). While the supervisor holds it the
  // servo keeps its hands off.
  if (device_owned) device_->steer_hand(target + model_.servo.device_origin);
  d.last_read = device_owned ? device_->read(d.joints) : device::IoStatus::kFault;

  // The viz owns the tissue: its heartbeat says whether the patch can be trusted.
  const std::int64_t beat = shared_.viz_heartbeat.last_ns();
  const bool alive = shared_.viz_heartbeat.fresh(now_ns, model_.servo.fade.timeout_ns);
  if (d.viz_alive && !alive) {
    d.viz_lost_at_beat_ns = d.viz_last_beat_ns;
    d.force_zero_ns = 0;
  }
  d.viz_alive = alive;
  if (alive) d.viz_last_beat_ns = beat;

  // The step.
  in.deadline_ns = deadline_ns;
  in.woke_ns = now_ns;
  in.reading = d.joints;
  in.read_status = d.last_read;
  in.device_held = !device_owned;
  in.patch = ready != nullptr ? &ready->patch : nullptr;
  in.patch_version = ready != nullptr ? ready->version : 0;
  in.patch_tree = ready != nullptr ? &ready->tree : nullptr;
  in.viz_alive = alive;
  in.watchdog_tripped = ctx.watchdog.tripped();
  servo::ServoOutput& out = d.out;
  servo::servo_step(model_.servo, d.servo, in, out);
  if (out.rearm) {
    if (ctx.watchdog.tripped()) ++d.rearms;
    ctx.watchdog.rearm();
    if (has_arm_) d.rearm_wanted.store(true, std::memory_order_release);
  }
  if (!alive && d.viz_lost_at_beat_ns != 0 && d.force_zero_ns == 0 && d.servo.force == Vec3{}) d.force_zero_ns = deadline_ns;

  // Write the device. (Ownership cannot change within a tick: only this thread grants, at the
  // start of the tick.)
  d.last_write = device_owned ? device_->write(out.command) : device::IoStatus::kFault;
  ToolSample& s = out.sample;
  s.write_status = d.last_write;
  if (d.last_write != device::IoStatus::kOk) s.events |= event::kFault;

  bool reset = false;
  (void)shared_.samples.try_push(s, &reset);  // a full ring is counted by the ring itself
  if (reset) reject(d.health.sample_ring_resets, "samples ring: indices impossible, reset");

  publish_status(ctx, device_owned);
  shared_.rt_heartbeat.beat(now_ns, d.pid);
}

void RtServo::publish_status(const rt::TickContext& ctx, bool device_owned) noexcept {
  RtData& d = *data_;
  const bool alive = d.viz_alive;
  RtStatus& st = d.status;
  st.tick = d.servo.tick;
  st.t_ns = ctx.deadline_ns;
  st.period_ns = model_.servo.period_ns;
  st.overruns = ctx.live.overruns;
  st.missed = ctx.live.missed;
  st.wake_p50_ns = ctx.live.wake_p50_ns;
  st.wake_p99_ns = ctx.live.wake_p99_ns;
  st.wake_max_ns = ctx.live.wake_max_ns;
  st.compute_p99_ns = ctx.live.compute_p99_ns;
  st.longest_stall_ns = ctx.live.longest_stall_ns;
  for (std::size_t i = 0; i < kWakeBins; ++i) st.wake_histogram[i] = ctx.live.wake_histogram[i];
  st.watchdog_tripped = ctx.watchdog.tripped() ? 1u : 0u;
  st.watchdog_reason = ctx.watchdog.reason();
  st.fifo = d.fifo ? 1u : 0u;
  st.force = d.servo.force;
  st.force_scale = d.out.fade_scale;
  st.patch_version = d.patch_version;
  st.viz_alive = alive ? 1u : 0u;
  st.contact = d.servo.contact ? 1u : 0u;
  st.samples_pushed = shared_.samples.pushed_count();
  st.samples_dropped = shared_.samples.overflow_count();
  st.viz_last_beat_ns = alive ? d.viz_last_beat_ns : d.viz_lost_at_beat_ns;
  st.force_zero_ns = d.force_zero_ns;
  st.tool = d.servo.tool;
  st.has_arm = has_arm_ ? 1u : 0u;
  if (has_arm_ && device_owned) {
    const device::Device* const arm = device_;
    // The device is this thread's now: its state, counters and words are safe to copy.
    const device::FaultDetail& fd = arm->fault_detail();
    st.device_state = arm->state();
    st.device_fault_cause = arm->fault_cause();
    st.link_lost = arm->link_lost() ? 1u : 0u;
    st.fault_node = fd.node;
    st.fault_code = fd.code;
    copy_text(st.fault_text, sizeof st.fault_text, fd.status == device::IoStatus::kOk ? "" : fd.c_str());
    const device::FaultDetail& le = arm->last_error();
    copy_text(st.error_text, sizeof st.error_text, le.status == device::IoStatus::kOk ? "" : le.c_str());
    st.bus = to_wire(arm->counters());
    st.rearm_failures = d.rearm_failures;
    copy_text(st.rearm_text, sizeof st.rearm_text, d.rearm_text.data());
  }
  st.rearm_pending = d.handover.load(std::memory_order_relaxed) != static_cast<int>(Handover::kIdle) ||
                             d.rearm_wanted.load(std::memory_order_relaxed)
                         ? 1u
                         : 0u;
  st.rearms = d.rearms;
  st.operator_requests = d.operator_requests;
  st.device_errors = d.servo.device_error_ticks;
  st.health = d.health;
  shared_.rt_status.write(st);
  d.own_status.write(st);
}

}  // namespace lancet::app
