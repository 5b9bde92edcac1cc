#include "servo/servo_step.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <new>
#include <string>
#include <type_traits>

#include "lancet/shared_model/word_hasher.hpp"

namespace lancet::servo {

namespace {

// A session starts afresh (kReset): everything but the tick count and the tool in hand. Built in
// place: ServoData is ~150 KB (the patch's search tree, the proxy's planes, the drill's brick),
// too much for a temporary on the servo thread's prefaulted stack.
static_assert(std::is_trivially_destructible_v<ServoData>);
void reset(ServoData& d) noexcept {
  const std::uint64_t tick = d.tick;
  const ToolMode mode = d.mode;
  new (&d) ServoData{};
  d.tick = tick;
  d.mode = mode;
}

void apply_commands(ServoData& d, const ServoInput& in, bool& rearm, std::uint8_t& reset_mode) noexcept {
  for (const std::uint8_t c : in.commands) {
    ++d.commands_applied;
    const auto kind = static_cast<CommandKind>(c >> 4);
    const auto mode = static_cast<ToolMode>(c & 0xfu);
    switch (kind) {
      case CommandKind::kSetToolMode:
        if (static_cast<std::size_t>(mode) < kToolCount) d.mode = mode;
        break;
      case CommandKind::kReset:
        reset_mode = static_cast<std::uint8_t>(d.mode);
        reset(d);
        break;
      case CommandKind::kRearm: rearm = true; break;
      case CommandKind::kNone: break;
    }
  }
}

void fill_sample(const ServoData& d, const ServoInput& in, const ServoOutput& out, std::uint32_t events, std::uint8_t reset_mode,
                 ToolSample& s) noexcept {
  s = ToolSample{};
  s.reset_mode = reset_mode;
  s.hand = in.hand;
  s.seq = d.tick;
  s.t_ns = in.deadline_ns;
  s.woke_ns = in.woke_ns;
  s.mode = d.mode;
  s.stage = out.haptic.stage;
  s.read_status = in.read_status;
  const int n = std::clamp(in.reading.n, 0, kMaxJoints);
  s.n_joints = static_cast<std::uint32_t>(n);
  for (int j = 0; j < n; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    s.q[uj] = in.reading.q[uj], s.qd[uj] = in.reading.qd[uj], s.tau[uj] = out.command.tau[uj];
  }
  s.buttons = in.reading.buttons;
  s.tool = Pose{d.tool, Quat{}};
  s.proxy = Pose{out.haptic.proxy, Quat{}};
  s.force = d.force;
  s.patch_version = in.patch != nullptr ? in.patch_version : 0;
  s.events = events;
  s.payload = out.haptic.payload;
  s.inputs = (in.viz_alive ? input::kVizAlive : 0u) | (in.watchdog_tripped ? input::kWatchdogTripped : 0u) |
             (in.operator_rearm ? input::kOperatorRearm : 0u) | (in.device_held ? input::kDeviceHeld : 0u) |
             (in.commands_cut ? input::kCommandsCut : 0u);
  s.n_commands = static_cast<std::uint16_t>(std::min<std::size_t>(in.commands.size(), kSampleCommands));
  for (std::uint32_t i = 0; i < s.n_commands; ++i) s.commands[i] = in.commands[i];
}


}  // namespace

std::uint64_t state_hash(const ServoData& d) noexcept {
  WordHasher h;
  h.word(d.tick), h.word(static_cast<std::uint64_t>(d.mode));
  d.haptic.hash(h);
  h.f(d.fade.scale()), h.word(static_cast<std::uint64_t>(d.last_deadline_ns));
  h.v(d.tool), h.v(d.tool_velocity);
  h.word(static_cast<std::uint64_t>(d.jacobian.n));
  for (const Vec3& c : d.jacobian.column) h.v(c);
  h.v(d.force), h.b(d.contact), h.f(d.max_force_seen);
  h.word(d.contact_ticks), h.word(d.commands_applied), h.word(d.faded_ticks);
  h.word(d.watchdog_faulted_ticks), h.word(d.device_error_ticks);
  return h.value();
}

void servo_step(const ServoModel& m, ServoData& d, const ServoInput& in, ServoOutput& out) noexcept {
  ++d.tick;
  out.rearm = in.operator_rearm;
  std::uint8_t reset_mode = kNoReset;
  apply_commands(d, in, out.rearm, reset_mode);
  // A re-arm this tick acts before the force is judged (the watchdog is re-armed with it).
  const bool tripped = in.watchdog_tripped && !out.rearm;

  // Sense: the reading → forward kinematics → the tool in the tissue frame.
  const bool device_ok = in.read_status == device::IoStatus::kOk && !in.device_held;
  if (device_ok) {
    const std::span<const double> q(in.reading.q.data(), static_cast<std::size_t>(std::clamp(in.reading.n, 0, kMaxJoints)));
    Vec3 tool{};
    d.jacobian = m.kinematics.position_and_jacobian(q, tool);
    d.tool = tool - m.device_origin;
    Vec3 v{};
    for (int j = 0; j < d.jacobian.n && j < in.reading.n; ++j)
      v += d.jacobian.column[static_cast<std::size_t>(j)] * in.reading.qd[static_cast<std::size_t>(j)];
    d.tool_velocity = v;
  }

  // Haptics: the tool's step against the patch, the stages, force safety.
  haptics::HapticInput hin;
  hin.device = d.tool;
  hin.velocity = d.tool_velocity;
  hin.orientation = Quat{};  // position-only devices: the blade points along +x
  hin.mode = d.mode;
  hin.patch = in.patch;
  hin.patch_version = in.patch != nullptr ? in.patch_version : 0;
  hin.tree = in.patch != nullptr ? in.patch_tree : nullptr;
  hin.tick = d.tick;
  haptics::haptic_step(m.haptic, d.haptic, hin, out.haptic);
  std::uint32_t events = out.haptic.events;
  d.contact = out.haptic.contact;
  if (d.contact) ++d.contact_ticks;

  // Fade and watchdog: they only ever shrink the force the safety layer made safe.
  // Fading out counts the servo's own time, deadlines skipped while the host stalled included, so
  // the force is zero within timeout + fade of the loss whatever the host does; fading in counts
  // ticks, so a stall never turns into a step up of the force.
  const std::int64_t patch_age = in.patch != nullptr ? in.woke_ns - in.patch->t_ns : -1;
  const bool trusted = haptics::ForceFade::trusted(m.fade, in.viz_alive, patch_age);
  const std::int64_t since_last = d.last_deadline_ns != 0 ? in.deadline_ns - d.last_deadline_ns : m.period_ns;
  const std::int64_t fade_dt = trusted ? m.period_ns : std::clamp(since_last, m.period_ns, std::max(m.period_ns, m.fade.fade_ns));
  d.last_deadline_ns = in.deadline_ns;
  out.fade_scale = d.fade.update(trusted, fade_dt, m.fade);
  if (out.fade_scale < 1.0) {
    events |= event::kForceFaded;
    ++d.faded_ticks;
  }
  Vec3 f = out.fade_scale * out.haptic.force;
  if (tripped) {
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

  // Actuate: joint torques τ = Jᵀ F within each joint's limit.
  const auto tau = arm::joint_torques(d.jacobian, f);
  out.command.n = m.kinematics.joint_count();
  for (int j = 0; j < out.command.n; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const double lim = std::max(0.0, m.max_joint_torque[uj]);
    out.command.tau[uj] = device_ok ? std::clamp(tau[uj], -lim, lim) : 0.0;
  }

  // Publish: the tick's sample.
  fill_sample(d, in, out, events, reset_mode, out.sample);
  if (d.tick % kServoHashEvery == 0) out.sample.state_hash = state_hash(d);
}

ServoModelBlob to_blob(const ServoModel& m) noexcept {
  ServoModelBlob b{};
  b.layout = kServoModelLayout;
  b.size = static_cast<std::uint32_t>(sizeof(ServoModel));
  std::memcpy(b.bytes, &m, sizeof(ServoModel));
  return b;
}

Result<ServoModel> model_from_blob(const ServoModelBlob& b) {
  const auto bad = [](const std::string& what) { return Error{ErrorCode::kInvalid, "servo model: " + what}; };
  if (b.layout != kServoModelLayout)
    return Error{ErrorCode::kMismatch, "servo model: layout " + std::to_string(b.layout) + " was written by another build (this one's is " +
                                           std::to_string(kServoModelLayout) + ")"};
  if (b.size != sizeof(ServoModel))
    return bad("size: expected " + std::to_string(sizeof(ServoModel)) + " bytes, found " + std::to_string(b.size));
  // A bool holding anything but 0 or 1 is undefined behaviour once read: its byte is checked first.
  constexpr std::size_t kPassivityAt =
      offsetof(ServoModel, haptic) + offsetof(haptics::HapticModel, safety) + offsetof(haptics::SafetyParams, passivity);
  static_assert(sizeof(haptics::SafetyParams::passivity) == 1);
  if (b.bytes[kPassivityAt] > 1)
    return bad("haptic.safety.passivity: expected 0 or 1, found " + std::to_string(static_cast<unsigned>(b.bytes[kPassivityAt])));
  ServoModel m;
  std::memcpy(&m, b.bytes, sizeof(ServoModel));
  const auto fin = [](double x) { return std::isfinite(x); };
  const auto pos = [&](double x) { return fin(x) && x > 0; };
  if (!(m.period_ns > 0 && m.period_ns <= 1'000'000'000)) return bad("period_ns: expected (0, 1 s], found " + std::to_string(m.period_ns));
  const haptics::HapticModel& h = m.haptic;
  if (!pos(h.dt) || !pos(h.proxy_radius) || !pos(h.capture_depth) || !pos(h.snap_distance) || !pos(h.elastic_limit) ||
      !pos(h.release_factor) || !fin(h.drill_iso_hu) || !pos(h.drill_stiffness) || !pos(h.drill_burr_radius) ||
      !fin(h.drill_min_force) || !fin(h.drill_rate) || !is_finite(h.blade_axis))
    return bad("haptic: a proxy, retractor or drill parameter is not finite or not positive");
  for (std::size_t i = 0; i < h.materials.size(); ++i) {
    const MaterialParams& p = h.materials[i];
    for (const double x : {p.stiffness, p.damping, p.yield_force, p.friction_static, p.friction_dynamic, p.cut_drag_along,
                           p.cut_drag_across, p.density})
      if (!fin(x) || x < 0) return bad("haptic.materials[" + std::to_string(i) + "]: a value is negative or not finite");
  }
  if (!pos(h.safety.max_force) || !fin(h.safety.max_slew) || h.safety.max_slew < 0) return bad("haptic.safety: max_force or max_slew");
  if (!pos(h.safety.max_passivity_damping))
    return bad("haptic.safety.max_passivity_damping: expected a finite number > 0 N·s/m, found " +
               std::to_string(h.safety.max_passivity_damping));
  if (m.fade.timeout_ns < 0 || m.fade.stale_after_ns < 0 || m.fade.fade_ns < 0) return bad("fade: a negative time");
  const int n = m.kinematics.joint_count();
  const auto kind = static_cast<unsigned>(m.kinematics.model());
  if (kind > static_cast<unsigned>(arm::KinematicModel::kDelta) || n < 1 || n > kMaxJoints)
    return bad("kinematics: model " + std::to_string(kind) + " with " + std::to_string(n) + " joints");
  if (const arm::DeltaArm* delta = m.kinematics.delta(); delta != nullptr) {
    if (const char* problem = arm::delta_geometry_problem(delta->geometry())) return bad(std::string("kinematics (delta): ") + problem);
    if (!is_finite(delta->base_offset())) return bad("kinematics (delta): base_offset not finite");
  }
  if (!is_finite(m.device_origin)) return bad("device_origin: not finite");
  for (const double t : m.max_joint_torque)
    if (!fin(t) || t < 0) return bad("max_joint_torque: negative or not finite");
  return m;
}

ServoInput input_from_sample(const ToolSample& s) noexcept {
  ServoInput in;
  in.deadline_ns = s.t_ns;
  in.woke_ns = s.woke_ns;
  in.commands = std::span<const std::uint8_t>(s.commands, std::min<std::size_t>(s.n_commands, std::size_t{kSampleCommands}));
  in.commands_cut = (s.inputs & input::kCommandsCut) != 0;
  in.operator_rearm = (s.inputs & input::kOperatorRearm) != 0;
  in.reading.n = static_cast<int>(std::min<std::uint32_t>(s.n_joints, kMaxJoints));
  for (int j = 0; j < in.reading.n; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    in.reading.q[uj] = s.q[uj], in.reading.qd[uj] = s.qd[uj];
  }
  in.reading.buttons = s.buttons;
  in.read_status = s.read_status;
  in.device_held = (s.inputs & input::kDeviceHeld) != 0;
  in.patch_version = s.patch_version;
  in.viz_alive = (s.inputs & input::kVizAlive) != 0;
  in.watchdog_tripped = (s.inputs & input::kWatchdogTripped) != 0;
  in.hand = s.hand;
  return in;
}

}  // namespace lancet::servo
