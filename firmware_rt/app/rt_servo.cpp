#include "rt_servo.hpp"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <memory>

namespace lancet::app {

namespace {
// The haptic model's time step is the servo period.
RtModel with_period(RtModel m) {
  m.haptic.dt = static_cast<double>(m.period_ns) * 1e-9;
  return m;
}
}  // namespace

RtServo::RtServo(const RtModel& model, SharedState& shared, std::int64_t start_ns, device::Device* arm, device::ArmPhysics* hand)
    : model_(with_period(model)), shared_(shared), arm_(model.kinematics != nullptr ? arm : nullptr), hand_(hand),
      data_(std::make_unique<RtData>()) {
  data_->start_ns = start_ns;
  data_->pid = static_cast<std::int32_t>(getpid());
  data_->stylus.position = device::scripted_target(0.0, model_.script_depth);
  if (arm_ != nullptr) data_->command.n = arm_->joint_count();
}

bool RtServo::supervise() {
  if (arm_ == nullptr) return false;
  int expected = static_cast<int>(RearmPhase::kRequested);
  if (!data_->rearm_phase.compare_exchange_strong(expected, static_cast<int>(RearmPhase::kRunning), std::memory_order_acq_rel))
    return false;
  // The servo thread does not touch the device until kDone.
  bool done = false;
  if (arm_->state() == device::Lifecycle::kFault) done = arm_->rearm().ok();
  data_->rearm_phase.store(static_cast<int>(RearmPhase::kDone), std::memory_order_release);
  return done;
}

void RtServo::apply(const Command& c, rt::Watchdog& watchdog) noexcept {
  RtData& d = *data_;
  ++d.commands_applied;
  switch (c.kind) {
    case CommandKind::kSetToolMode: d.mode = c.mode; break;
    case CommandKind::kReset: d.mode = ToolMode::kProbe; break;
    case CommandKind::kRearm:
      watchdog.rearm();
      if (arm_ != nullptr && d.rearm_phase.load(std::memory_order_acquire) == static_cast<int>(RearmPhase::kIdle) &&
          arm_->state() == device::Lifecycle::kFault)
        d.rearm_phase.store(static_cast<int>(RearmPhase::kRequested), std::memory_order_release);
      break;
    case CommandKind::kSetMaterial:  // materials arrive with the haptic core; the penalty model ignores them
    case CommandKind::kNone: break;
  }
}

void RtServo::tick(const rt::TickContext& ctx) noexcept {
  RtData& d = *data_;
  const std::int64_t deadline_ns = ctx.deadline_ns;
  const std::int64_t now_ns = ctx.woke_ns;
  const double dt = static_cast<double>(model_.period_ns) * 1e-9;
  const double t = static_cast<double>(deadline_ns - d.start_ns) * 1e-9;
  ++d.tick;

  // Commands from the viz.
  for (;;) {
    const std::size_t n = shared_.commands.try_pop_n(d.command_batch.data(), d.command_batch.size());
    for (std::size_t i = 0; i < n; ++i) apply(d.command_batch[i], ctx.watchdog);
    if (n < d.command_batch.size()) break;
  }

  // Where the hand pulls the stylus: the viz's target while it is fresh, else the script.
  (void)shared_.stylus_target.try_read_if_newer(d.target, d.target_version);
  const bool target_fresh = d.target.active != 0 && now_ns - d.target.t_ns <= model_.target_timeout_ns;
  const Vec3 target = target_fresh              ? d.target.target.position
                      : model_.trajectory != nullptr ? model_.trajectory->at(t)
                                                     : device::scripted_target(t, model_.script_depth);

  // Newest patch, into the back buffer; swap only on a consistent read.
  TissuePatch& back = d.patches[static_cast<std::size_t>(1 - d.front)];
  if (shared_.patch.try_read_if_newer(back, d.patch_version) == ReadStatus::kOk) {
    d.front = 1 - d.front;
    ++d.patches_received;
  }
  const TissuePatch& patch = d.patches[static_cast<std::size_t>(d.front)];

  // Read the arm: encoders → forward kinematics → the tool in the tissue frame. While a re-arm is
  // pending the servo keeps its hands off the device (the supervisor thread owns it).
  bool device_ok = true;
  bool device_owned = true;  // false while a re-arm is pending: the supervisor owns the device
  if (arm_ != nullptr) {
    int phase = d.rearm_phase.load(std::memory_order_acquire);
    if (phase == static_cast<int>(RearmPhase::kDone)) {
      d.rearm_phase.store(static_cast<int>(RearmPhase::kIdle), std::memory_order_relaxed);
      phase = static_cast<int>(RearmPhase::kIdle);
    }
    device_owned = phase == static_cast<int>(RearmPhase::kIdle);
    if (hand_ != nullptr) hand_->set_hand_target(target + model_.device_origin);
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
    // (The phase cannot leave kIdle within a tick: only this thread requests, before the read.)
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
  (void)shared_.samples.try_push(s);  // a full ring is counted by the ring itself

  RtStatus& st = d.status;
  st.tick = d.tick;
  st.t_ns = deadline_ns;
  st.period_ns = model_.period_ns;
  st.overruns = ctx.live.overruns;
  st.missed = ctx.live.missed;
  st.wake_p50_ns = ctx.live.wake_p50_ns;
  st.wake_p99_ns = ctx.live.wake_p99_ns;
  st.wake_max_ns = ctx.live.wake_max_ns;
  st.compute_p99_ns = ctx.live.compute_p99_ns;
  st.longest_stall_ns = ctx.live.longest_stall_ns;
  st.watchdog_tripped = ctx.watchdog.tripped() ? 1u : 0u;
  st.fifo = d.fifo ? 1u : 0u;
  st.force = f;
  st.force_scale = scale;
  st.patch_version = d.patch_version;
  st.viz_alive = alive ? 1u : 0u;
  st.contact = h.contact ? 1u : 0u;
  st.samples_pushed = shared_.samples.pushed_count();
  st.samples_dropped = shared_.samples.overflow_count();
  st.viz_last_beat_ns = alive ? d.viz_last_beat_ns : d.viz_lost_at_beat_ns;
  st.force_zero_ns = d.force_zero_ns;
  st.tool = d.tool;
  if (arm_ != nullptr && device_owned) {
    st.device_state = static_cast<std::uint32_t>(arm_->state());
    st.device_fault_cause = static_cast<std::uint32_t>(arm_->fault_cause());
  }
  st.device_errors = d.device_error_ticks;
  shared_.rt_status.write(st);
  shared_.rt_heartbeat.beat(now_ns, d.pid);
}

}  // namespace lancet::app
