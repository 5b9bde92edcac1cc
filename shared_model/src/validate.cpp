#include "lancet/shared_model/validate.hpp"

#include <cmath>
#include <cstring>
#include <initializer_list>

namespace lancet::wire {

namespace {

constexpr std::uint32_t kKnownEvents = (event::kFault << 1) - 1;
constexpr std::uint16_t kKnownTriangleFlags = kTriangleOnCutEdge;

bool finite(double v) { return std::isfinite(v); }
bool in(double v, double lo, double hi) { return v >= lo && v <= hi; }  // false for NaN
bool position_ok(Vec3 p) {
  return in(p.x, -kMaxCoordinate, kMaxCoordinate) && in(p.y, -kMaxCoordinate, kMaxCoordinate) &&
         in(p.z, -kMaxCoordinate, kMaxCoordinate);
}
bool position_ok(Vec3f p) { return position_ok(to_vec3(p)); }
bool quat_ok(Quat q) {
  const double n2 = q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z;
  return in(n2, 0.98, 1.02);
}
bool pose_ok(const Pose& p) { return position_ok(p.position) && quat_ok(p.orientation); }
bool force_ok(Vec3 f) { return is_finite(f) && dot(f, f) <= kMaxForce * kMaxForce; }
bool timestamp_ok(std::int64_t t_ns, std::int64_t now_ns) { return t_ns > 0 && t_ns - now_ns <= kFutureSlackNs; }
bool flag_ok(std::uint32_t v) { return v <= 1; }
bool hand_ok(Hand h) { return static_cast<std::size_t>(h) < kHandCount; }
/// NUL-terminated within its array and printable ASCII before that (nothing for a terminal to obey).
bool text_ok(const char (&text)[kStatusTextSize]) {
  for (std::size_t i = 0; i < kStatusTextSize; ++i) {
    const auto c = static_cast<unsigned char>(text[i]);
    if (c == 0) return true;
    if (c < 0x20 || c > 0x7e) return false;
  }
  return false;
}

constexpr std::uint64_t mix(std::uint64_t h, std::uint64_t v) {
  // FNV-1a over the 8 bytes of v, then a final avalanche (splitmix64's).
  for (int i = 0; i < 8; ++i) {
    h ^= (v >> (8 * i)) & 0xffu;
    h *= 0x100000001b3ull;
  }
  return h;
}
constexpr std::uint64_t avalanche(std::uint64_t z) {
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
  return z ^ (z >> 31);
}

}  // namespace

std::uint32_t command_check(const Command& c) noexcept {
  std::uint64_t h = 0x6c616e6365742d63ull;  // "lancet-c"
  h = mix(h, c.seq);
  h = mix(h, static_cast<std::uint64_t>(c.t_ns));
  h = mix(h, static_cast<std::uint64_t>(c.kind) | static_cast<std::uint64_t>(c.mode) << 8 |
                 static_cast<std::uint64_t>(c.hand) << 16 |
                 static_cast<std::uint64_t>(c.reserved) << 24);
  return static_cast<std::uint32_t>(avalanche(h));
}

std::uint64_t operator_request_check(const OperatorRequest& r) noexcept {
  std::uint64_t h = 0x6c616e6365742d6full;  // "lancet-o"
  h = mix(h, r.seq);
  h = mix(h, static_cast<std::uint64_t>(r.t_ns));
  h = mix(h, static_cast<std::uint64_t>(r.kind) | static_cast<std::uint64_t>(static_cast<std::uint32_t>(r.pid)) << 32);
  h = mix(h, r.hands);
  return avalanche(h);
}

const char* check(const Command& c) noexcept {
  if (c.check != command_check(c)) return "command.check: does not match its fields (garbage in the ring?)";
  if (!hand_ok(c.hand)) return "command.hand: neither right nor left";
  switch (c.kind) {
    case CommandKind::kNone:
    case CommandKind::kReset:
    case CommandKind::kRearm: return nullptr;
    case CommandKind::kSetToolMode:
      return static_cast<std::size_t>(c.mode) < kToolCount ? nullptr
                                                                                             : "command.mode: unknown tool";
  }
  return "command.kind: unknown";
}

const char* check(const StylusTarget& t, std::int64_t now_ns) noexcept {
  if (!flag_ok(t.active)) return "stylus_target.active: not 0 or 1";
  if (!hand_ok(t.hand)) return "stylus_target.hand: neither right nor left";
  if (!timestamp_ok(t.t_ns, now_ns)) return "stylus_target.t_ns: not set or in the future";
  if (!pose_ok(t.target)) return "stylus_target.target: not finite, out of range or not a unit quaternion";
  return nullptr;
}

const char* check(const TissuePatch& p, std::int64_t now_ns) noexcept {
  if (p.n_triangles > kPatchCapacity) return "patch.n_triangles: above the capacity";
  if (!hand_ok(p.hand)) return "patch.hand: neither right nor left";
  if (!timestamp_ok(p.t_ns, now_ns)) return "patch.t_ns: not set or in the future";
  for (std::uint32_t i = 0; i < p.n_triangles; ++i) {
    const PatchTriangle& t = p.triangles[i];
    if (!position_ok(t.v[0]) || !position_ok(t.v[1]) || !position_ok(t.v[2]))
      return "patch.triangles[].v: not finite or out of range";
    if (t.material > kMaxMaterialId) return "patch.triangles[].material: beyond the material table";
    if ((t.flags & ~kKnownTriangleFlags) != 0) return "patch.triangles[].flags: unknown bits";
  }
  const VoxelBrick& b = p.brick;
  if (!flag_ok(b.valid)) return "patch.brick.valid: not 0 or 1";
  if (b.valid == 1) {
    if (b.dim != kBrickDim) return "patch.brick.dim: not kBrickDim";
    if (!position_ok(b.origin)) return "patch.brick.origin: not finite or out of range";
    if (!in(b.spacing.x, 1e-6, 0.05) || !in(b.spacing.y, 1e-6, 0.05) || !in(b.spacing.z, 1e-6, 0.05))
      return "patch.brick.spacing: not within 1 um .. 50 mm";
  }
  return nullptr;
}

const char* check(const OperatorRequest& r, std::int64_t now_ns) noexcept {
  if (r.check != operator_request_check(r)) return "operator_request.check: does not match its fields";
  if (r.kind != kOperatorRearm) return "operator_request.kind: unknown";
  if (r.hands == 0 || (r.hands & ~((1u << kHandCount) - 1)) != 0) return "operator_request.hands: no hand, or an unknown one";
  if (!timestamp_ok(r.t_ns, now_ns)) return "operator_request.t_ns: not set or in the future";
  return nullptr;
}

const char* check(const ToolSample& s) noexcept {
  if (s.n_joints > static_cast<std::uint32_t>(kMaxJoints)) return "sample.n_joints: above kMaxJoints";
  if (!hand_ok(s.hand)) return "sample.hand: neither right nor left";
  if (static_cast<std::size_t>(s.mode) >= kToolCount) return "sample.mode: unknown tool";
  if (static_cast<std::uint8_t>(s.stage) > static_cast<std::uint8_t>(Stage::kDrilling)) return "sample.stage: unknown";
  if ((s.events & ~kKnownEvents) != 0) return "sample.events: unknown bits";
  if (!known_code(s.read_status, kLastIoStatus) || !known_code(s.write_status, kLastIoStatus))
    return "sample.read_status/write_status: unknown";
  if ((s.inputs & ~input::kKnown) != 0) return "sample.inputs: unknown bits";
  if (s.n_commands > kSampleCommands) return "sample.n_commands: above kSampleCommands";
  if (s.reset_mode != kNoReset && s.reset_mode >= kToolCount) return "sample.reset_mode: unknown tool";
  for (std::uint32_t j = 0; j < s.n_joints; ++j) {
    if (!finite(s.q[j]) || !finite(s.qd[j]) || !finite(s.tau[j])) return "sample.q/qd/tau: not finite";
  }
  if (!pose_ok(s.tool) || !pose_ok(s.proxy)) return "sample.tool/proxy: not finite, out of range or not a unit quaternion";
  if (!force_ok(s.force)) return "sample.force: not finite or above 1000 N";
  const EventPayload& e = s.payload;
  if (!position_ok(e.position) || !finite(e.magnitude))
    return "sample.payload: not finite or out of range";
  // The work an event causes in the viz is bounded by its payload: a burr of at most 10 mm, a
  // pull of at most 10 cm.
  if ((s.events & event::kDrillRemove) != 0 && !(e.magnitude > 0 && e.magnitude <= 0.01))
    return "sample.payload.magnitude: a drill removal's radius not in (0, 10 mm]";
  if ((s.events & event::kPull) != 0 && !in(e.magnitude, 0, 0.1)) return "sample.payload.magnitude: a pull not in [0, 10 cm]";
  return nullptr;
}

const char* check(const RtStatus& s) noexcept {
  if (s.period_ns <= 0) return "rt_status.period_ns: not positive";
  if (s.wake_p50_ns < 0 || s.wake_p99_ns < 0 || s.wake_max_ns < 0 || s.compute_p99_ns < 0 || s.longest_stall_ns < 0)
    return "rt_status.wake/compute: negative";
  if (s.hands < 1 || s.hands > kHandCount) return "rt_status.hands: not 1 or 2";
  if (!flag_ok(s.watchdog_tripped) || !flag_ok(s.fifo) || !flag_ok(s.viz_alive)) return "rt_status: a flag is not 0 or 1";
  if (!known_code(s.watchdog_reason, kLastWatchdogReason)) return "rt_status.watchdog_reason: unknown";
  for (const HandStatus& h : s.hand) {
    if (!force_ok(h.force)) return "rt_status.hand[].force: not finite or above 1000 N";
    if (!in(h.force_scale, 0, 1)) return "rt_status.hand[].force_scale: not in [0, 1]";
    if (!position_ok(h.tool)) return "rt_status.hand[].tool: not finite or out of range";
    if (static_cast<std::size_t>(h.mode) >= kToolCount) return "rt_status.hand[].mode: unknown tool";
    if (static_cast<std::uint8_t>(h.stage) > static_cast<std::uint8_t>(Stage::kDrilling)) return "rt_status.hand[].stage: unknown";
    if (!flag_ok(h.contact) || !flag_ok(h.has_arm) || !flag_ok(h.link_lost) || !flag_ok(h.rearm_pending))
      return "rt_status.hand[]: a flag is not 0 or 1";
    if (!known_code(h.device_state, kLastDeviceLifecycle)) return "rt_status.hand[].device_state: unknown";
    if (!known_code(h.device_fault_cause, kLastIoStatus)) return "rt_status.hand[].device_fault_cause: unknown";
    if (!text_ok(h.fault_text) || !text_ok(h.error_text) || !text_ok(h.rearm_text))
      return "rt_status.hand[]: a text is not terminated or not printable";
  }
  return nullptr;
}

}  // namespace lancet::wire
