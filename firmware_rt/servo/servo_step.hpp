#pragma once
// The servo step: one 1 kHz tick of lancet-rt as a pure function of its model, its data and its
// inputs, in the MuJoCo manner (STYLE.md §1):
//
//   servo_step(const ServoModel&, ServoData&, const ServoInput&, ServoOutput&)
//
//   sense     the commands applied this tick (tool changes, reset, re-arm), the device reading →
//             forward kinematics → the tool in the tissue frame
//   haptics   haptic_step for the tool in use against the patch (haptics/haptic_step.hpp)
//   fade and watchdog
//             one ForceFade by the tissue's trust (visualizer alive, patch fresh); zero force while
//             the watchdog is tripped or the device could not be read
//   actuate   τ = Jᵀ F within each joint's limit → ServoOutput::command (the caller writes it)
//   publish   the tick's ToolSample (inputs and outputs), with the state hash every
//             kServoHashEvery ticks
//
// A kReset command starts a session: the data becomes a new servo's, but for the tick count and
// the tool in hand (ToolSample::reset_mode says which), so a replay of a session recorded from
// its reset starts from ServoData{} with that tool.
//
// Everything the step depends on comes in through ServoInput, and nothing else (no clock, no
// shared memory, no device): lancet-rt's RtServo does the I/O around it, and a recording of the
// ToolSamples replays it exactly (record/replay.hpp) — the same inputs give bit-identical data.
// Real-time safe: no allocation, no locks, no exceptions, bounded work.

#include <array>
#include <cstddef>
#include <type_traits>
#include <cstdint>
#include <span>

#include "arm/kinematics.hpp"
#include "device/device.hpp"
#include "haptics/force_fade.hpp"
#include "haptics/haptic_step.hpp"
#include "lancet/shared_model/messages.hpp"
#include "lancet/shared_model/result.hpp"

namespace lancet::servo {

/// The state hash goes into the ToolSample every this many ticks (0.1 s).
inline constexpr std::uint64_t kServoHashEvery = 100;

/// Immutable: what the servo is (built once at start-up; owns its kinematics by value).
struct ServoModel {
  std::int64_t period_ns = 1'000'000;  ///< 1 kHz; the haptic model's dt must equal it
  haptics::HapticModel haptic = haptics::HapticModel::defaults();  ///< materials, proxy, safety
  haptics::ForceFadeParams fade{};
  /// The device's kinematics: Cartesian for the built-in simulated stylus, the arm's otherwise.
  arm::Kinematics kinematics = arm::Kinematics::cartesian();
  /// The device-frame point that maps to the tissue's origin (the centre of the arm's workspace).
  Vec3 device_origin{};
  /// Per joint, the largest torque (N·m, or N) sent; 0: none.
  std::array<double, kMaxJoints> max_joint_torque{};
};

static_assert(std::is_trivially_copyable_v<ServoModel>, "ServoModel travels as bytes (ServoModelBlob)");

/// A fingerprint of ServoModel's layout: a recording's model is refused by a build that lays it out
/// differently.
inline constexpr std::uint64_t kServoModelLayout = [] {
  std::uint64_t h = 0xcbf29ce484222325ull;
  for (const std::uint64_t v :
       {std::uint64_t{sizeof(ServoModel)}, std::uint64_t{offsetof(ServoModel, haptic)}, std::uint64_t{offsetof(ServoModel, fade)},
        std::uint64_t{offsetof(ServoModel, kinematics)}, std::uint64_t{offsetof(ServoModel, device_origin)},
        std::uint64_t{offsetof(ServoModel, max_joint_torque)}, std::uint64_t{sizeof(haptics::HapticModel)},
        std::uint64_t{sizeof(haptics::SafetyParams)}, std::uint64_t{sizeof(arm::Kinematics)}, std::uint64_t{sizeof(MaterialParams)},
        std::uint64_t{sizeof(haptics::ForceFadeParams)}, std::uint64_t{haptics::kMaxMaterials}, std::uint64_t{kMaxJoints}}) {
    for (int i = 0; i < 8; ++i) h = (h ^ ((v >> (8 * i)) & 0xffu)) * 0x100000001b3ull;
  }
  return h;
}();
static_assert(sizeof(ServoModel) <= kServoModelCapacity, "ServoModelBlob too small for ServoModel");

/// The model as lancet-rt publishes it (SharedState::servo_model) and a recording stores it.
[[nodiscard]] ServoModelBlob to_blob(const ServoModel& m) noexcept;
/// The model a blob carries, checked: the layout, the size, and every value the step relies on
/// (finite, in range; the kinematics' joint count 1..kMaxJoints). Errors say which field.
[[nodiscard]] Result<ServoModel> model_from_blob(const ServoModelBlob& b);

/// The state of one session of the servo (what the state hash covers).
struct ServoData {
  std::uint64_t tick = 0;          ///< ticks stepped (the next sample's seq is tick + 1)
  ToolMode mode = ToolMode::kProbe;
  haptics::HapticData haptic{};
  haptics::ForceFade fade{};
  std::int64_t last_deadline_ns = 0;  ///< the previous tick's deadline (0: none since the reset): the fade's clock
  Vec3 tool{}, tool_velocity{};    ///< tissue frame (m, m/s), of the last good reading
  arm::Jacobian jacobian{};        ///< of the last good reading
  Vec3 force{};                    ///< sent this tick (N)
  bool contact = false;
  double max_force_seen = 0;       ///< N
  std::uint64_t contact_ticks = 0;
  std::uint64_t commands_applied = 0;
  std::uint64_t faded_ticks = 0;   ///< ticks the fade held the force below full
  std::uint64_t watchdog_faulted_ticks = 0;  ///< ticks rendered at zero force by the watchdog
  std::uint64_t device_error_ticks = 0;      ///< ticks at zero force because the device could not be read
};

/// A command as the step takes it and the ToolSample records it: kind << 4 | mode.
[[nodiscard]] constexpr std::uint8_t pack_command(CommandKind kind, ToolMode mode) noexcept {
  return static_cast<std::uint8_t>((static_cast<unsigned>(kind) & 0xfu) << 4 | (static_cast<unsigned>(mode) & 0xfu));
}

/// Everything one tick depends on.
struct ServoInput {
  std::int64_t deadline_ns = 0;    ///< the tick's deadline (the sample's t_ns)
  std::int64_t woke_ns = 0;        ///< when it woke: the patch's age counts from it
  std::span<const std::uint8_t> commands;  ///< checked, in order, packed (pack_command), at most kSampleCommands
  bool commands_cut = false;       ///< more arrived than `commands` holds
  bool operator_rearm = false;     ///< an operator's re-arm request (lancetctl rearm) arrived
  device::JointState reading{};    ///< the device's reading (used when read_status is kOk)
  device::IoStatus read_status = device::IoStatus::kOk;
  bool device_held = false;        ///< the supervisor holds the device (reading not taken)
  const TissuePatch* patch = nullptr;  ///< the patch in use (null: none yet)
  std::uint64_t patch_version = 0; ///< its version (0: none)
  /// Its search tree, built for patch_version off the tick (lancet-rt's patch intake); null: the
  /// step builds it the tick the version changes (a replay). Not recorded: the same patch gives
  /// the same tree.
  const haptics::PatchBvh* patch_tree = nullptr;
  bool viz_alive = false;          ///< the visualizer's heartbeat is fresh
  bool watchdog_tripped = false;   ///< the loop's watchdog has tripped
  Hand hand = Hand::kRight;        ///< whose tick it is: copied into the sample, nothing else depends on it
};

struct ServoOutput {
  device::JointCommand command{};  ///< to write to the device
  bool rearm = false;              ///< a re-arm was asked for: re-arm the watchdog (and the device, if faulted)
  double fade_scale = 0;
  haptics::HapticOutput haptic{};
  ToolSample sample{};             ///< write_status is the caller's to set after the write
};

/// One tick. Real-time safe.
void servo_step(const ServoModel& m, ServoData& d, const ServoInput& in, ServoOutput& out) noexcept;

/// The state hash (never 0): a 64-bit mix of every field of `d` that the next tick depends on
/// (the drill's brick by its source and its carves). Real-time safe, about 200 words.
[[nodiscard]] std::uint64_t state_hash(const ServoData& d) noexcept;

/// The ServoInput a recorded ToolSample holds; the patch (by s.patch_version) is the caller's.
[[nodiscard]] ServoInput input_from_sample(const ToolSample& s) noexcept;

}  // namespace lancet::servo
