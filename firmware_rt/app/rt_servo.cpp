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
// Every hand steps at the loop's period, and the haptic model's time step is that period.
RtModel with_period(RtModel m) {
  if (m.hands < 1 || m.hands > kHandCount) throw std::invalid_argument("RtServo: hands must be 1 or 2, not " + std::to_string(m.hands));
  for (HandModel& h : m.hand) {
    h.servo.period_ns = m.period_ns;
    h.servo.haptic.dt = static_cast<double>(m.period_ns) * 1e-9;
  }
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

RtServo::RtServo(const RtModel& model, SharedState& shared, std::int64_t start_ns, std::array<device::Device*, kHandCount> arms)
    : model_(with_period(model)), shared_(shared), data_(std::make_unique<RtData>()) {
  RtData& d = *data_;
  d.pid = static_cast<std::int32_t>(getpid());
  for (std::size_t h = 0; h < model_.hands; ++h) {
    const auto hand = static_cast<Hand>(h);
    HandModel& hm = model_.hand[h];
    d.hand[h].start_ns = start_ns;
    device::Device* const arm = arms[h];
    if (arm != nullptr) {
      if (arm->joint_count() != hm.servo.kinematics.joint_count())
        throw std::invalid_argument("RtServo: the " + std::string(hand_name(hand)) + " arm " + arm->name() + " has " +
                                    std::to_string(arm->joint_count()) + " joints, its kinematics " +
                                    std::to_string(hm.servo.kinematics.joint_count()));
      device_[h] = arm;
      has_arm_[h] = true;
    } else {
      // The built-in stylus: a Device like the arms, at the hand's script's start, Cartesian.
      const double dt = static_cast<double>(model_.period_ns) * 1e-9;
      stylus_[h] = std::make_unique<device::SimStylus>(hm.stylus, dt, device::scripted_target(hand, 0.0, hm.script_depth));
      if (!stylus_[h]->configure().ok() || !stylus_[h]->activate().ok()) throw std::logic_error("RtServo: the built-in stylus did not start");
      device_[h] = stylus_[h].get();
      hm.servo.kinematics = arm::Kinematics::cartesian();
      hm.servo.device_origin = {};
      hm.servo.max_joint_torque.fill(0.0);
      for (std::size_t j = 0; j < 3; ++j) hm.servo.max_joint_torque[j] = hm.servo.haptic.safety.max_force;
    }
    intake_[h] = std::make_unique<PatchIntake>(shared, model_.period_ns, hand);
    // The model, for whoever records the session (a replay needs exactly it).
    shared_.servo_model[h].write(servo::to_blob(hm.servo));
  }
  // Requests made before this servo existed are not for it.
  OperatorRequest r{};
  if (shared_.operator_request.try_read_if_newer(r, d.request_version) == ReadStatus::kOk) d.request_seq = r.seq;
}

std::string RtServo::start_patch_intake(bool fifo, int priority, int avoid_cpu) {
  std::string line;
  for (std::size_t h = 0; h < model_.hands; ++h) {
    if (!line.empty()) line += "; ";
    line += std::string(hand_name(static_cast<Hand>(h))) + " hand: " + intake_[h]->start_thread(fifo, priority, avoid_cpu);
  }
  return line;
}

bool RtServo::supervise(std::int64_t now_ns) {
  bool any = false;
  for (std::size_t h = 0; h < model_.hands; ++h) {
    if (has_arm_[h] && supervise_hand(h, now_ns)) any = true;
  }
  return any;
}

bool RtServo::supervise_hand(std::size_t h, std::int64_t now_ns) {
  device::Device* const arm = device_[h];
  HandData& d = data_->hand[h];
  const auto phase = static_cast<Handover>(d.handover.load(std::memory_order_acquire));
  if (phase == Handover::kIdle) {
    // Decide from the servo's own published status: the device itself belongs to the servo now.
    RtStatus st{};
    if (data_->own_status.try_read(st, 1000) != ReadStatus::kOk) return false;
    const HandStatus& hs = st.hand[h];
    const bool faulted = hs.device_state == device::Lifecycle::kFault;
    DeviceJob job = DeviceJob::kNone;
    if (d.rearm_wanted.exchange(false, std::memory_order_acq_rel) && faulted) {
      job = DeviceJob::kRearm;
    } else if (faulted && hs.link_lost != 0 && now_ns >= d.next_reconnect_ns) {
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

void RtServo::drain_commands(std::int64_t now_ns) noexcept {
  RtData& d = *data_;
  for (std::size_t h = 0; h < model_.hands; ++h) {
    d.hand[h].n_commands = 0;
    d.hand[h].commands_cut = false;
    d.hand[h].operator_rearm = false;
  }
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
    if (hand_index(c.hand) >= model_.hands) {
      reject(d.health.commands_rejected, "command.hand: a hand this lancet-rt does not drive (RtStatus::hands)");
      continue;
    }
    // Sealed commands in stale slots (a corrupted index replays them) are not new: every command
    // is stamped later than the one before it, and not in the future.
    if (c.t_ns <= d.last_command_t_ns || c.t_ns - now_ns > wire::kFutureSlackNs) {
      reject(d.health.commands_rejected, "command.t_ns: not after the last command, or in the future (a replay?)");
      continue;
    }
    d.last_command_t_ns = c.t_ns;
    HandData& hd = d.hand[hand_index(c.hand)];
    hd.commands[hd.n_commands++] = servo::pack_command(c.kind, c.mode);  // cap <= kSampleCommands: always room
  }
  if (n == cap && !shared_.commands.empty_approx()) ++d.health.commands_deferred;

  // An operator's re-arm request (lancetctl rearm), through its own seqlock, for the hands it names.
  if (shared_.operator_request.try_read_if_newer(d.request, d.request_version, 2) == ReadStatus::kOk) {
    if (const char* why = wire::check(d.request, now_ns)) {
      reject(d.health.commands_rejected, why);
    } else if (d.request.seq != d.request_seq) {
      d.request_seq = d.request.seq;
      if (now_ns - d.request.t_ns <= model_.operator_request_max_age_ns) {
        ++d.operator_requests;
        for (std::size_t h = 0; h < model_.hands; ++h) {
          if ((d.request.hands >> h & 1u) != 0) d.hand[h].operator_rearm = true;
        }
      }
    }
  }
}

bool RtServo::take_device(std::size_t h) noexcept {
  if (!has_arm_[h]) return true;  // the built-in stylus needs no supervisor
  HandData& d = data_->hand[h];
  auto phase = static_cast<Handover>(d.handover.load(std::memory_order_acquire));
  if (phase == Handover::kRequested) {
    d.handover.store(static_cast<int>(Handover::kGranted), std::memory_order_release);
    return false;
  }
  if (phase == Handover::kDone) {
    // The supervisor's results are visible after the acquire above.
    if (d.job.load(std::memory_order_relaxed) == static_cast<int>(DeviceJob::kRearm) && d.job_ok) ++data_->rearms;
    d.handover.store(static_cast<int>(Handover::kIdle), std::memory_order_release);
    phase = Handover::kIdle;
  }
  return phase == Handover::kIdle;
}

Vec3 RtServo::hand_target(std::size_t h, std::int64_t now_ns, double t) noexcept {
  RtData& d = *data_;
  HandData& hd = d.hand[h];
  const HandModel& hm = model_.hand[h];
  if (shared_.stylus_target[h].try_read_if_newer(hd.target_scratch, hd.target_version, 2) == ReadStatus::kOk) {
    if (const char* why = wire::check(hd.target_scratch, now_ns)) {
      reject(d.health.targets_rejected, why);
    } else if (hand_index(hd.target_scratch.hand) != h) {
      reject(d.health.targets_rejected, "stylus_target.hand: not the hand whose slot it came in");
    } else {
      hd.target = hd.target_scratch;
    }
  }
  const bool target_fresh = hd.target.active != 0 && now_ns - hd.target.t_ns <= model_.target_timeout_ns;
  if (target_fresh) return hd.target.target.position;
  if (hm.trajectory != nullptr) return hm.trajectory->at(t);
  return device::scripted_target(static_cast<Hand>(h), t, hm.script_depth);
}

void RtServo::tick(const rt::TickContext& ctx) noexcept {
  RtData& d = *data_;
  const std::size_t hands = model_.hands;
  const std::int64_t deadline_ns = ctx.deadline_ns;
  const std::int64_t now_ns = ctx.woke_ns;

  // The device handovers first: a requested device is granted before anything else touches it.
  for (std::size_t h = 0; h < hands; ++h) d.hand[h].device_owned = take_device(h);

  // Commands: the ring's, routed by hand, then each script's tool changes, each when its time
  // comes (a later key in the viz wins until the script's next change).
  drain_commands(now_ns);
  std::array<Vec3, kHandCount> target{};
  std::array<const ReadyPatch*, kHandCount> ready{};
  for (std::size_t h = 0; h < hands; ++h) {
    HandData& hd = d.hand[h];
    const HandModel& hm = model_.hand[h];
    // The hand's script clock (held at its start until its tissue is there, when asked to wait).
    if (model_.script_waits_for_tissue && hd.patch_version == 0) hd.start_ns = deadline_ns;
    const double t = static_cast<double>(deadline_ns - hd.start_ns) * 1e-9;
    if (hm.trajectory != nullptr) {
      const auto& changes = hm.trajectory->tools;
      while (hd.next_tool_change < changes.size() && changes[hd.next_tool_change].t <= t) {
        if (hd.n_commands < hd.commands.size()) {
          hd.commands[hd.n_commands++] = servo::pack_command(CommandKind::kSetToolMode, changes[hd.next_tool_change].mode);
        } else {
          hd.commands_cut = true;
        }
        ++hd.next_tool_change;
      }
    }
    // Where the hand pulls its stylus: the viz's target while it is fresh, else the script.
    target[h] = hand_target(h, now_ns, t);
  }

  // Each hand's newest patch its intake has ready (copied, checked, its tree built): the intake's
  // helper thread's work, or, without one, done here.
  d.health.patches_rejected = 0;
  d.health.patches_unreadable = 0;
  for (std::size_t h = 0; h < hands; ++h) {
    HandData& hd = d.hand[h];
    PatchIntake& intake = *intake_[h];
    if (!intake.threaded()) (void)intake.poll(now_ns);
    ready[h] = intake.take();
    if (ready[h] != nullptr && ready[h]->version != hd.patch_version) {
      hd.patch_version = ready[h]->version;
      ++hd.patches_received;
    }
    const IntakeCounters& ic = intake.counters();
    const std::uint64_t rejected = ic.rejected.load(std::memory_order_relaxed);
    d.health.patches_rejected += rejected;
    d.health.patches_unreadable += ic.busy.load(std::memory_order_relaxed);
    if (rejected != hd.patches_rejected_seen) {
      hd.patches_rejected_seen = rejected;
      d.last_reject.store(ic.last_reject.load(std::memory_order_relaxed), std::memory_order_relaxed);
    }
  }

  // The viz owns the tissue: its heartbeat says whether the patches can be trusted.
  const std::int64_t beat = shared_.viz_heartbeat.last_ns();
  const bool alive = shared_.viz_heartbeat.fresh(now_ns, model_.hand[0].servo.fade.timeout_ns);
  if (d.viz_alive && !alive) {
    d.viz_lost_at_beat_ns = d.viz_last_beat_ns;
    d.force_zero_ns = 0;
  }
  d.viz_alive = alive;
  if (alive) d.viz_last_beat_ns = beat;

  // Read every device (the hand steering a simulated one first). While the supervisor holds one
  // the servo keeps its hands off it; a device that cannot be read zeroes its own hand only.
  for (std::size_t h = 0; h < hands; ++h) {
    HandData& hd = d.hand[h];
    if (hd.device_owned) device_[h]->steer_hand(target[h] + model_.hand[h].servo.device_origin);
    hd.last_read = hd.device_owned ? device_[h]->read(hd.joints) : device::IoStatus::kFault;
  }

  // Step every hand. The watchdog is the loop's: both hands see the state it had when the tick
  // began, and a re-arm (any hand's kRearm, or the operator's) re-arms it after the steps.
  const bool tripped = ctx.watchdog.tripped();
  bool rearm = false;
  bool all_zero = true;
  for (std::size_t h = 0; h < hands; ++h) {
    HandData& hd = d.hand[h];
    servo::ServoInput in;
    in.hand = static_cast<Hand>(h);
    in.commands = std::span<const std::uint8_t>(hd.commands.data(), hd.n_commands);
    in.commands_cut = hd.commands_cut;
    in.operator_rearm = hd.operator_rearm;
    in.deadline_ns = deadline_ns;
    in.woke_ns = now_ns;
    in.reading = hd.joints;
    in.read_status = hd.last_read;
    in.device_held = !hd.device_owned;
    in.patch = ready[h] != nullptr ? &ready[h]->patch : nullptr;
    in.patch_version = ready[h] != nullptr ? ready[h]->version : 0;
    in.patch_tree = ready[h] != nullptr ? &ready[h]->tree : nullptr;
    in.viz_alive = alive;
    in.watchdog_tripped = tripped;
    servo::servo_step(model_.hand[h].servo, hd.servo, in, hd.out);
    if (hd.out.rearm) {
      rearm = true;
      if (has_arm_[h]) hd.rearm_wanted.store(true, std::memory_order_release);
    }
    all_zero = all_zero && hd.servo.force == Vec3{};
  }
  if (rearm) {
    if (tripped) ++d.rearms;
    ctx.watchdog.rearm();
  }
  if (!alive && d.viz_lost_at_beat_ns != 0 && d.force_zero_ns == 0 && all_zero) d.force_zero_ns = deadline_ns;

  // Write every device. (Ownership cannot change within a tick: only this thread grants, at the
  // start of the tick.)
  for (std::size_t h = 0; h < hands; ++h) {
    HandData& hd = d.hand[h];
    hd.last_write = hd.device_owned ? device_[h]->write(hd.out.command) : device::IoStatus::kFault;
    ToolSample& s = hd.out.sample;
    s.write_status = hd.last_write;
    if (hd.last_write != device::IoStatus::kOk) s.events |= event::kFault;
  }

  // The samples: right, then left, both with the tick's seq.
  for (std::size_t h = 0; h < hands; ++h) {
    bool reset = false;
    (void)shared_.samples.try_push(d.hand[h].out.sample, &reset);  // a full ring is counted by the ring itself
    if (reset) reject(d.health.sample_ring_resets, "samples ring: indices impossible, reset");
  }

  publish_status(ctx);
  shared_.rt_heartbeat.beat(now_ns, d.pid);
}

void RtServo::publish_status(const rt::TickContext& ctx) noexcept {
  RtData& d = *data_;
  const bool alive = d.viz_alive;
  RtStatus& st = d.status;
  st.tick = d.hand[0].servo.tick;
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
  st.watchdog_reason = ctx.watchdog.reason();
  st.fifo = d.fifo ? 1u : 0u;
  st.viz_alive = alive ? 1u : 0u;
  st.hands = static_cast<std::uint32_t>(model_.hands);
  st.samples_pushed = shared_.samples.pushed_count();
  st.samples_dropped = shared_.samples.overflow_count();
  st.viz_last_beat_ns = alive ? d.viz_last_beat_ns : d.viz_lost_at_beat_ns;
  st.force_zero_ns = d.force_zero_ns;
  st.rearms = d.rearms;
  st.operator_requests = d.operator_requests;
  st.health = d.health;
  for (std::size_t h = 0; h < model_.hands; ++h) {
    const HandData& hd = d.hand[h];
    HandStatus& hs = st.hand[h];
    hs.force = hd.servo.force;
    hs.force_scale = hd.out.fade_scale;
    hs.patch_version = hd.patch_version;
    hs.contact = hd.servo.contact ? 1u : 0u;
    hs.mode = hd.servo.mode;
    hs.stage = hd.out.haptic.stage;
    hs.tool = hd.servo.tool;
    hs.clamped_ticks = hd.servo.haptic.safety.clamps;
    hs.has_arm = has_arm_[h] ? 1u : 0u;
    if (has_arm_[h] && hd.device_owned) {
      const device::Device* const arm = device_[h];
      // The device is this thread's now: its state, counters and words are safe to copy.
      const device::FaultDetail& fd = arm->fault_detail();
      hs.device_state = arm->state();
      hs.device_fault_cause = arm->fault_cause();
      hs.link_lost = arm->link_lost() ? 1u : 0u;
      hs.fault_node = fd.node;
      hs.fault_code = fd.code;
      copy_text(hs.fault_text, sizeof hs.fault_text, fd.status == device::IoStatus::kOk ? "" : fd.c_str());
      const device::FaultDetail& le = arm->last_error();
      copy_text(hs.error_text, sizeof hs.error_text, le.status == device::IoStatus::kOk ? "" : le.c_str());
      hs.bus = to_wire(arm->counters());
      hs.rearm_failures = hd.rearm_failures;
      copy_text(hs.rearm_text, sizeof hs.rearm_text, hd.rearm_text.data());
    }
    hs.rearm_pending = hd.handover.load(std::memory_order_relaxed) != static_cast<int>(Handover::kIdle) ||
                               hd.rearm_wanted.load(std::memory_order_relaxed)
                           ? 1u
                           : 0u;
    hs.device_errors = hd.servo.device_error_ticks;
  }
  shared_.rt_status.write(st);
  d.own_status.write(st);
}

}  // namespace lancet::app
