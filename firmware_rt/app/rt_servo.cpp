#include "rt_servo.hpp"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <memory>

#include "lancet/shared_model/validate.hpp"

namespace lancet::app {

namespace {
// The haptic model's time step is the servo period.
RtModel with_period(RtModel m) {
  m.haptic.dt = static_cast<double>(m.period_ns) * 1e-9;
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

RtServo::RtServo(const RtModel& model, SharedState& shared, std::int64_t start_ns, device::Device* arm, device::ArmPhysics* hand)
    : model_(with_period(model)), shared_(shared), arm_(model.kinematics != nullptr ? arm : nullptr), hand_(hand),
      data_(std::make_unique<RtData>()) {
  data_->start_ns = start_ns;
  data_->pid = static_cast<std::int32_t>(getpid());
  data_->stylus.position = device::scripted_target(0.0, model_.script_depth);
  if (arm_ != nullptr) data_->command.n = arm_->joint_count();
  // Requests made before this servo existed are not for it.
  OperatorRequest r{};
  if (shared_.operator_request.try_read_if_newer(r, data_->request_version) == ReadStatus::kOk) data_->request_seq = r.seq;
}

bool RtServo::supervise(std::int64_t now_ns) {
  if (arm_ == nullptr) return false;
  RtData& d = *data_;
  const auto phase = static_cast<Handover>(d.handover.load(std::memory_order_acquire));
  if (phase == Handover::kIdle) {
    // Decide from the servo's own published status: the device itself belongs to the servo now.
    RtStatus st{};
    if (d.own_status.try_read(st, 1000) != ReadStatus::kOk) return false;
    const bool faulted = st.device_state == static_cast<std::uint32_t>(device::Lifecycle::kFault);
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
    if (arm_->state() == device::Lifecycle::kFault) {
      const device::Outcome o = arm_->rearm();
      ok = o.ok();
      if (ok) {
        copy_text(d.rearm_text.data(), d.rearm_text.size(), "re-armed");
      } else {
        ++d.rearm_failures;
        copy_text(d.rearm_text.data(), d.rearm_text.size(), o.error->message.c_str());
      }
    }
  } else if (job == DeviceJob::kReconnect) {
    if (arm_->state() == device::Lifecycle::kFault && arm_->link_lost()) {
      const device::Outcome o = arm_->reconnect();
      ok = o.ok();
      copy_text(d.rearm_text.data(), d.rearm_text.size(),
                ok ? "bus link reopened; the arm stays faulted until re-armed" : o.error->message.c_str());
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

void RtServo::request_rearm(rt::Watchdog& watchdog) noexcept {
  RtData& d = *data_;
  if (watchdog.tripped()) ++d.rearms;
  watchdog.rearm();
  if (arm_ != nullptr) d.rearm_wanted.store(true, std::memory_order_release);
}

void RtServo::apply(const Command& c, rt::Watchdog& watchdog) noexcept {
  RtData& d = *data_;
  ++d.commands_applied;
  switch (c.kind) {
    case CommandKind::kSetToolMode: d.mode = c.mode; break;
    case CommandKind::kReset: d.mode = ToolMode::kProbe; break;
    case CommandKind::kRearm: request_rearm(watchdog); break;
    case CommandKind::kSetMaterial:  // materials arrive with the haptic core; the penalty model ignores them
    case CommandKind::kNone: break;
  }
}

void RtServo::drain_commands(rt::Watchdog& watchdog, std::int64_t now_ns) noexcept {
  RtData& d = *data_;
  // At most one bounded batch per tick, whatever the ring's indices say; each command checked.
  const std::size_t cap = std::min(model_.max_commands_per_tick, d.command_batch.size());
  bool reset = false;
  const std::size_t n = shared_.commands.try_pop_n(d.command_batch.data(), cap, &reset);
  if (reset) reject(d.health.ring_resets, "commands ring: indices impossible, reset");
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
    apply(c, watchdog);
  }
  if (n == cap && !shared_.commands.empty_approx()) ++d.health.commands_deferred;

  // An operator's re-arm request (lancetctl rearm), through its own seqlock.
  if (shared_.operator_request.try_read_if_newer(d.request, d.request_version, 2) == ReadStatus::kOk) {
    if (const char* why = wire::check(d.request, now_ns)) {
      reject(d.health.commands_rejected, why);
    } else if (d.request.seq != d.request_seq) {
      d.request_seq = d.request.seq;
      if (now_ns - d.request.t_ns <= model_.operator_request_max_age_ns) {
        ++d.operator_requests;
        request_rearm(watchdog);
      }
    }
  }
}

bool RtServo::take_device() noexcept {
  if (arm_ == nullptr) return false;
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
  const double dt = static_cast<double>(model_.period_ns) * 1e-9;
  const double t = static_cast<double>(deadline_ns - d.start_ns) * 1e-9;
  ++d.tick;

  // The device handover first: a requested device is granted before anything else touches it.
  const bool device_owned = take_device();

  drain_commands(ctx.watchdog, now_ns);

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
  // A scripted hand also picks its tools, each when its time comes (a later key in the viz wins
  // until the script's next change).
  if (model_.trajectory != nullptr) {
    const auto& changes = model_.trajectory->tools;
    while (d.next_tool_change < changes.size() && changes[d.next_tool_change].t <= t) {
      d.mode = changes[d.next_tool_change].mode;
      ++d.next_tool_change;
    }
  }

  // Newest patch, into the back buffer; swap only on a consistent read of a valid patch.
  TissuePatch& back = d.patches[static_cast<std::size_t>(1 - d.front)];
  if (shared_.patch.try_read_if_newer(back, d.patch_seen, model_.patch_read_attempts) == ReadStatus::kOk) {
    if (const char* why = wire::check(back, now_ns)) {
      reject(d.health.patches_rejected, why);
    } else {
      d.front = 1 - d.front;
      d.patch_version = d.patch_seen;
      ++d.patches_received;
    }
  }
  const TissuePatch& patch = d.patches[static_cast<std::size_t>(d.front)];

  // Read the arm: encoders → forward kinematics → the tool in the tissue frame. While the
  // supervisor holds the device the servo keeps its hands off it.
  bool device_ok = true;
  if (arm_ != nullptr) {
    if (hand_ != nullptr && device_owned) hand_->set_hand_target(target + model_.device_origin);
    d.last_read = device_owned ? arm_->read(d.joints) : device::IoStatus::kFault;
    device_ok = d.last_read == device::IoStatus::kOk;
    if (device_ok) {
      const std::span<const double> q(d.joints.q.data(), static_cast<std::size_t>(d.joints.n));
      d.jacobian = model_.kinematics->jacobian(q);
      d.tool = model_.kinematics->position(q) - model_.device_origin;
      Vec3 v{};
      for (int j = 0; j < d.joints.n; ++j) v += d.jacobian.column[static_cast<std::size_t>(j)] * d.joints.qd[static_cast<std::size_t>(j)];
      d.tool_velocity = v;
    }
  } else {
    d.tool = d.stylus.position;
    d.tool_velocity = d.stylus.velocity;
  }

  // The haptic step: proxy against the patch, stage machine, cut friction, force safety.
  haptics::HapticInput in;
  in.device = d.tool;
  in.velocity = d.tool_velocity;
  in.orientation = Quat{};  // the simulated stylus does not rotate: the blade points along +x
  in.mode = d.mode;
  in.patch = d.patch_version != 0 ? &patch : nullptr;
  in.tick = d.tick;
  in.patch_age_ns = d.patch_version != 0 ? now_ns - patch.t_ns : -1;
  haptics::HapticOutput& h = d.haptic_out;
  haptics::haptic_step(model_.haptic, d.haptic, in, h);
  std::uint32_t events = h.events;
  d.contact = h.contact;
  if (h.contact) ++d.contact_ticks;

  // The viz owns the tissue: without its heartbeat the patch is stale, so fade the force out.
  const std::int64_t beat = shared_.viz_heartbeat.last_ns();
  const bool alive = shared_.viz_heartbeat.fresh(now_ns, model_.fade.timeout_ns);
  if (d.viz_alive && !alive) {
    d.viz_lost_at_beat_ns = d.viz_last_beat_ns;
    d.force_zero_ns = 0;
  }
  d.viz_alive = alive;
  if (alive) d.viz_last_beat_ns = beat;
  const double scale = d.fade.update(alive, model_.period_ns, model_.fade);
  if (scale < 1.0) events |= event::kForceFaded;

  // The viz fade and the watchdog only ever shrink the force that the safety layer made safe.
  Vec3 f = scale * h.force;
  if (ctx.watchdog.tripped()) {
    f = Vec3{};
    ++d.watchdog_faulted_ticks;
    events |= event::kFault;
  }
  if (!device_ok) {  // no fresh pose: no force (and the device layer counts why)
    f = Vec3{};
    ++d.device_error_ticks;
    events |= event::kFault;
  }
  d.force = f;
  d.max_force_seen = std::max(d.max_force_seen, norm(f));
  if (!alive && d.viz_lost_at_beat_ns != 0 && d.force_zero_ns == 0 && f == Vec3{}) d.force_zero_ns = deadline_ns;

  // Write the device: joint torques τ = Jᵀ F within each joint's limit, or the built-in stylus.
  if (arm_ != nullptr) {
    const auto tau = arm::joint_torques(d.jacobian, f);
    for (int j = 0; j < d.command.n; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      const double lim = model_.max_joint_torque[uj] > 0 ? model_.max_joint_torque[uj] : 0.0;
      d.command.tau[uj] = device_ok ? std::clamp(tau[uj], -lim, lim) : 0.0;
    }
    // (Ownership cannot change within a tick: only this thread grants, at the start of the tick.)
    d.last_write = device_owned ? arm_->write(d.command) : device::IoStatus::kFault;
    if (d.last_write != device::IoStatus::kOk) events |= event::kFault;
  } else {
    device::step_sim_stylus(model_.stylus, d.stylus, target, f, dt);
  }

  // One ToolSample per tick.
  ToolSample& s = d.sample;
  s.seq = d.tick;
  s.t_ns = deadline_ns;
  s.mode = d.mode;
  s.stage = h.stage;
  if (arm_ != nullptr) {
    s.n_joints = static_cast<std::uint32_t>(d.joints.n);
    for (int j = 0; j < d.joints.n; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      s.q[uj] = d.joints.q[uj], s.qd[uj] = d.joints.qd[uj], s.tau[uj] = d.command.tau[uj];
    }
  } else {
    s.n_joints = 3;  // the sim stylus is a Cartesian 3-DOF point: q = position
    s.q[0] = d.stylus.position.x, s.q[1] = d.stylus.position.y, s.q[2] = d.stylus.position.z;
    s.qd[0] = d.stylus.velocity.x, s.qd[1] = d.stylus.velocity.y, s.qd[2] = d.stylus.velocity.z;
    s.tau[0] = f.x, s.tau[1] = f.y, s.tau[2] = f.z;
  }
  s.tool = Pose{d.tool, Quat{}};
  s.proxy = Pose{h.proxy, Quat{}};
  s.force = f;
  s.patch_version = d.patch_version;
  s.events = events;
  s.payload = h.payload;
  bool reset = false;
  (void)shared_.samples.try_push(s, &reset);  // a full ring is counted by the ring itself
  if (reset) reject(d.health.sample_ring_resets, "samples ring: indices impossible, reset");

  publish_status(ctx, h, scale, alive, device_owned);
  shared_.rt_heartbeat.beat(now_ns, d.pid);
}

void RtServo::publish_status(const rt::TickContext& ctx, const haptics::HapticOutput& h, double scale, bool alive,
                             bool device_owned) noexcept {
  RtData& d = *data_;
  RtStatus& st = d.status;
  st.tick = d.tick;
  st.t_ns = ctx.deadline_ns;
  st.period_ns = model_.period_ns;
  st.overruns = ctx.live.overruns;
  st.missed = ctx.live.missed;
  st.wake_p50_ns = ctx.live.wake_p50_ns;
  st.wake_p99_ns = ctx.live.wake_p99_ns;
  st.wake_max_ns = ctx.live.wake_max_ns;
  st.compute_p99_ns = ctx.live.compute_p99_ns;
  st.longest_stall_ns = ctx.live.longest_stall_ns;
  for (std::size_t i = 0; i < kWakeBins; ++i) st.wake_histogram[i] = ctx.live.wake_histogram[i];
  st.watchdog_tripped = ctx.watchdog.tripped() ? 1u : 0u;
  st.watchdog_reason = static_cast<std::uint32_t>(ctx.watchdog.reason());
  st.fifo = d.fifo ? 1u : 0u;
  st.force = d.force;
  st.force_scale = scale;
  st.patch_version = d.patch_version;
  st.viz_alive = alive ? 1u : 0u;
  st.contact = h.contact ? 1u : 0u;
  st.samples_pushed = shared_.samples.pushed_count();
  st.samples_dropped = shared_.samples.overflow_count();
  st.viz_last_beat_ns = alive ? d.viz_last_beat_ns : d.viz_lost_at_beat_ns;
  st.force_zero_ns = d.force_zero_ns;
  st.tool = d.tool;
  st.has_arm = arm_ != nullptr ? 1u : 0u;
  if (arm_ != nullptr && device_owned) {
    // The device is this thread's now: its state, counters and words are safe to copy.
    const device::FaultDetail& fd = arm_->fault_detail();
    st.device_state = static_cast<std::uint32_t>(arm_->state());
    st.device_fault_cause = static_cast<std::uint32_t>(arm_->fault_cause());
    st.link_lost = arm_->link_lost() ? 1u : 0u;
    st.fault_node = fd.node;
    st.fault_code = fd.code;
    copy_text(st.fault_text, sizeof st.fault_text, fd.status == device::IoStatus::kOk ? "" : fd.c_str());
    const device::FaultDetail& le = arm_->last_error();
    copy_text(st.error_text, sizeof st.error_text, le.status == device::IoStatus::kOk ? "" : le.c_str());
    st.bus = to_wire(arm_->counters());
    st.rearm_failures = d.rearm_failures;
    copy_text(st.rearm_text, sizeof st.rearm_text, d.rearm_text.data());
  }
  st.rearm_pending = d.handover.load(std::memory_order_relaxed) != static_cast<int>(Handover::kIdle) ||
                             d.rearm_wanted.load(std::memory_order_relaxed)
                         ? 1u
                         : 0u;
  st.rearms = d.rearms;
  st.operator_requests = d.operator_requests;
  st.device_errors = d.device_error_ticks;
  st.health = d.health;
  shared_.rt_status.write(st);
  d.own_status.write(st);
}

}  // namespace lancet::app
