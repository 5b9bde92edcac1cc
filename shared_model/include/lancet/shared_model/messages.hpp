#pragma once
// Messages that cross the lancet-rt <-> lancet-viz boundary. Every type here is a flat POD:
// trivially copyable, standard-layout, fixed capacity, no pointers (static_asserted below), so
// copying one is a memcpy. Units are SI and stated on every field; frames are the world frame of
// the tissue unless stated. A change to any of these types changes the layout hash
// (shared_state.hpp) so that a mismatched peer refuses to attach.

#include <cstddef>
#include <cstdint>
#include <string_view>
#include <type_traits>

#include "lancet/shared_model/device_codes.hpp"
#include "lancet/shared_model/geometry.hpp"

namespace lancet {

/// Most joints any arm may have (DH chains up to 8 joints).
inline constexpr int kMaxJoints = 8;
/// Triangles a TissuePatch can carry (a radius of about 50 mm of a 1 mm-cell surface). Only the
/// n_triangles in use cross the segment (tissue_patch_bytes).
inline constexpr std::uint32_t kPatchCapacity = 16384;
/// Edge length, in voxels, of the cubic voxel brick carried by a TissuePatch.
inline constexpr std::uint32_t kBrickDim = 16;

/// What the stylus is being used as. The swab (suction) touches like the probe and removes the
/// blood it touches (the visualizer's business: lancet-rt renders it as a probe).
enum class ToolMode : std::uint8_t { kProbe = 0, kScalpel = 1, kRetractor = 2, kDrill = 3, kSwab = 4 };
inline constexpr std::size_t kToolCount = 5;

/// Each tool's name as people type it (command-line options, trajectory files), in ToolMode order.
inline constexpr const char* kToolNames[kToolCount] = {"probe", "scalpel", "retractor", "drill", "swab"};

constexpr const char* tool_name(ToolMode m) noexcept {
  return static_cast<std::size_t>(m) < kToolCount ? kToolNames[static_cast<std::size_t>(m)] : "?";
}

namespace detail {
/// The enumerator whose name (names[i], in enumerator order) is `name`; false when none is.
template <class E, std::size_t N>
constexpr bool from_name(const char* const (&names)[N], std::string_view name, E& out) noexcept {
  for (std::size_t i = 0; i < N; ++i) {
    if (name == names[i]) {
      out = static_cast<E>(i);
      return true;
    }
  }
  return false;
}
}  // namespace detail

/// The tool called `name`; false when no tool is.
constexpr bool tool_from_name(std::string_view name, ToolMode& out) noexcept { return detail::from_name(kToolNames, name, out); }

/// Interaction stage of the haptic step (ALGORITHMS.md §2).
enum class Stage : std::uint8_t {
  kFree = 0,      ///< no contact
  kDeform = 1,    ///< in contact, tissue deforms elastically (Hooke)
  kRupture = 2,   ///< the yield force was exceeded this tick
  kCutting = 3,   ///< blade inside the tissue, directional friction
  kPulling = 4,   ///< retractor holding and pulling
  kDrilling = 5,  ///< drill removing voxels
};

/// The hand that holds a tool. The right hand is hand 0: a one-handed session, and every recording
/// made before there were two, is the right hand's.
enum class Hand : std::uint8_t { kRight = 0, kLeft = 1 };
inline constexpr std::size_t kHandCount = 2;

/// Each hand's name as people type it (command-line options, trajectory files), in Hand order.
inline constexpr const char* kHandNames[kHandCount] = {"right", "left"};

constexpr const char* hand_name(Hand h) noexcept {
  return static_cast<std::size_t>(h) < kHandCount ? kHandNames[static_cast<std::size_t>(h)] : "?";
}
constexpr std::size_t hand_index(Hand h) noexcept { return static_cast<std::size_t>(h); }
/// hand_index of a hand read from somewhere unchecked (a file, a peer): a value that names no
/// hand counts as the right hand's, so an index into a per-hand array is always in range.
constexpr std::size_t hand_slot(Hand h) noexcept { return hand_index(h) < kHandCount ? hand_index(h) : 0; }

/// The hand called `name`; false when no hand is.
constexpr bool hand_from_name(std::string_view name, Hand& out) noexcept { return detail::from_name(kHandNames, name, out); }

/// Event bits of ToolSample::events. Several may be set in one tick; the payload describes the
/// most significant one (the highest bit set).
namespace event {
inline constexpr std::uint32_t kContactBegin = 1u << 0;
inline constexpr std::uint32_t kContactEnd = 1u << 1;
inline constexpr std::uint32_t kRupture = 1u << 2;      ///< payload: position, normal, blade direction
inline constexpr std::uint32_t kCutProgress = 1u << 3;  ///< every 0.5 mm of cut; payload: proxy position on the cut path
inline constexpr std::uint32_t kGrab = 1u << 4;         ///< payload: control point
inline constexpr std::uint32_t kPull = 1u << 5;         ///< payload: control point, displacement (m)
inline constexpr std::uint32_t kRelease = 1u << 6;
inline constexpr std::uint32_t kDrillRemove = 1u << 7;  ///< payload: centre, magnitude = radius (m)
inline constexpr std::uint32_t kForceClamped = 1u << 8; ///< the safety layer limited the force
inline constexpr std::uint32_t kForceFaded = 1u << 9;   ///< force scaled down: viz or patch stale
inline constexpr std::uint32_t kFault = 1u << 10;       ///< watchdog or device fault: zero force
}  // namespace event

/// Data attached to the events of one tick.
struct EventPayload {
  Vec3 position;      ///< m
  double magnitude;   ///< event-specific scalar (m for radius/displacement, N for force)
};

/// Bits of ToolSample::inputs: what the servo step was given this tick besides the reading.
namespace input {
inline constexpr std::uint32_t kVizAlive = 1u << 0;         ///< the visualizer's heartbeat was fresh
inline constexpr std::uint32_t kWatchdogTripped = 1u << 1;  ///< the loop's watchdog had tripped
inline constexpr std::uint32_t kOperatorRearm = 1u << 2;    ///< an operator's re-arm request arrived
inline constexpr std::uint32_t kDeviceHeld = 1u << 3;       ///< the supervisor held the device: not read or written
inline constexpr std::uint32_t kCommandsCut = 1u << 4;      ///< more commands arrived than `commands` holds (not replayable)
inline constexpr std::uint32_t kKnown = (1u << 5) - 1;
}  // namespace input

/// ToolSample::reset_mode on a tick without a reset.
inline constexpr std::uint8_t kNoReset = 0xff;

/// Commands one ToolSample records (a tick applies at most this many).
inline constexpr std::uint32_t kSampleCommands = 16;

/// One hand's servo tick, pushed by lancet-rt once per tick and hand on the ToolSample ring (the
/// right hand's first, then the left's, both with the tick's seq). It carries the
/// servo step's inputs (the device reading, the commands applied, the liveness flags, the patch
/// version used) as well as its outputs, so a recording of the samples replays the step exactly
/// (firmware_rt/servo/servo_step.hpp).
struct ToolSample {
  std::uint64_t seq;              ///< tick number since lancet-rt started, +1 per tick
  std::int64_t t_ns;              ///< CLOCK_MONOTONIC deadline of this tick (ns)
  std::int64_t woke_ns;           ///< CLOCK_MONOTONIC when the tick woke (ns): ages count from it
  std::uint32_t n_joints;         ///< valid entries in q, qd, tau
  ToolMode mode;                  ///< tool mode in force this tick
  Stage stage;                    ///< interaction stage
  IoStatus read_status;           ///< what the device read came back with
  IoStatus write_status;          ///< what the device write came back with
  double q[kMaxJoints];           ///< joint positions read (rad, or m for prismatic) (n_joints)
  double qd[kMaxJoints];          ///< joint velocities read (rad/s or m/s) (n_joints)
  double tau[kMaxJoints];         ///< commanded joint torques (N·m, or N) (n_joints)
  Pose tool;                      ///< tool tip (haptic interface point) pose
  Pose proxy;                     ///< proxy pose (equals tool when free)
  Vec3 force;                     ///< force commanded on the hand, after safety and fade (N)
  std::uint64_t patch_version;    ///< TissuePatch version this force used (0: none)
  std::uint32_t events;           ///< event:: bits
  std::uint32_t inputs;           ///< input:: bits
  EventPayload payload;           ///< see event::
  std::uint32_t buttons;          ///< the device's buttons read (bit i: button i)
  std::uint16_t n_commands;       ///< valid entries in commands
  std::uint8_t reset_mode;        ///< the tool (ToolMode) kept through this tick's reset; kNoReset: none
  Hand hand;                      ///< whose tick this is
  std::uint8_t commands[kSampleCommands];  ///< commands applied this tick, in order: kind << 4 | mode
  std::uint64_t state_hash;       ///< hash of the servo's state after this tick; 0 on ticks it is not taken
};

/// Kinds of Command.
enum class CommandKind : std::uint8_t {
  kNone = 0,
  kSetToolMode = 1,  ///< use Command::mode from now on
  kReset = 3,        ///< start afresh: the servo's state as a new servo's (stage, proxy, fade, counters); the tool stays
  kRearm = 4,        ///< re-arm a tripped watchdog (force stays zero until this arrives)
};

/// Mechanical parameters of one tissue material (ALGORITHMS.md §1–2).
struct MaterialParams {
  double stiffness;          ///< N/m, contact spring k
  double damping;            ///< N·s/m, contact damper D
  double yield_force;        ///< N, force at which the surface ruptures
  double friction_static;    ///< static friction coefficient (dimensionless)
  double friction_dynamic;   ///< dynamic friction coefficient (dimensionless)
  double cut_drag_along;     ///< N·s/m, viscous drag along the blade while cutting
  double cut_drag_across;    ///< N·s/m, viscous drag across the blade while cutting
  double density;            ///< kg/m³, for drilling resistance
};

/// lancet-viz → lancet-rt on the Command ring.
struct Command {
  std::uint64_t seq;         ///< sender's counter, +1 per command
  std::int64_t t_ns;         ///< CLOCK_MONOTONIC when sent (ns)
  CommandKind kind;
  ToolMode mode;             ///< kSetToolMode
  Hand hand;                 ///< the hand it is for (kRearm re-arms the loop's watchdog too)
  std::uint8_t reserved;
  std::uint32_t check;       ///< command_check(*this): garbage in the ring is never taken for a command
};

/// One triangle of the local tissue surface. Vertices counter-clockwise seen from outside, so
/// (v1-v0)x(v2-v0) points out of the tissue.
struct PatchTriangle {
  Vec3f v[3];                ///< vertex positions (m)
  std::uint16_t material;    ///< material id
  std::uint16_t flags;       ///< kTriangleOnCutEdge, ...
  /// The surface's own id of this face, the same in every patch while the face exists: lancet-rt
  /// carries the proxy with the face it rests on when a newer patch moves it.
  std::uint32_t id;
};
inline constexpr std::uint16_t kTriangleOnCutEdge = 1u << 0;

/// Small cube of CT densities around the tool, for volume haptics and drilling.
struct VoxelBrick {
  std::uint32_t valid;       ///< 1 when hu holds data
  std::uint32_t dim;         ///< edge length in voxels (kBrickDim)
  Vec3 origin;               ///< centre of voxel (0,0,0) (m)
  Vec3 spacing;              ///< voxel spacing along x, y, z (m)
  std::int16_t hu[kBrickDim * kBrickDim * kBrickDim];  ///< Hounsfield units, x fastest
};

/// lancet-viz → lancet-rt (seqlock): the tissue near the tool. Triangles come in an order that
/// keeps neighbours together (the viz's BVH order): lancet-rt groups runs of them into the leaves
/// of its search tree (haptics/patch_bvh.hpp), so a scattered order costs time, never
/// correctness. The triangles come last, so a reader copies only the ones in use.
struct TissuePatch {
  std::uint64_t seq;         ///< viz frame counter when built
  std::int64_t t_ns;         ///< CLOCK_MONOTONIC when built (ns)
  /// seq of the newest ToolSample whose events this patch reflects (0: none yet): lancet-rt
  /// re-applies to the brick the drill removals it made after that sample.
  std::uint64_t samples_applied;
  std::uint32_t n_triangles; ///< valid entries in triangles
  Hand hand;                 ///< the hand whose tool it was cut out around (each hand has its own)
  std::uint8_t reserved0[3];
  VoxelBrick brick;
  PatchTriangle triangles[kPatchCapacity];  ///< (n_triangles)
};

/// Bytes of `p` in use: everything up to and including its n_triangles triangles (capped at the
/// capacity, whatever n_triangles says). What the patch's seqlock copies.
constexpr std::size_t tissue_patch_bytes(const TissuePatch& p) noexcept {
  const std::size_t n = p.n_triangles < kPatchCapacity ? p.n_triangles : kPatchCapacity;
  return offsetof(TissuePatch, triangles) + n * sizeof(PatchTriangle);
}

/// lancet-viz → lancet-rt (seqlock): where the simulated arm's stylus should go (mouse, script).
struct StylusTarget {
  std::uint64_t seq;         ///< sender's counter
  std::int64_t t_ns;         ///< CLOCK_MONOTONIC when sent (ns)
  Pose target;               ///< desired stylus pose
  std::uint32_t active;      ///< 1: follow this target; 0: lancet-rt uses its own script
  Hand hand;                 ///< whose stylus (each hand has its own target)
  std::uint8_t reserved[3];
};

/// What the arm's bus has done so far, by kind (device::IoCounters on the wire).
struct BusCounters {
  std::uint64_t reads, writes, ok;
  std::uint64_t timeouts, crc_errors, protocol_errors, disconnects, device_faults;
  std::uint64_t glitches;        ///< implausible encoder readings
  std::uint64_t stale_replies;   ///< late replies recognised and discarded
  std::uint64_t faults;          ///< times the arm entered its fault state
  std::uint64_t reconnects;      ///< lost links reopened
  std::int64_t max_io_ns;        ///< slowest read or write (ns)
};

/// What lancet-rt rejected or repaired of what its peers wrote into the segment (counts since
/// start). A sane viz never causes any of these.
struct SegmentHealth {
  std::uint64_t ring_resets;        ///< command ring indices found impossible and reset
  std::uint64_t commands_rejected;  ///< commands that failed validation (unknown kind, bad check, ...)
  std::uint64_t commands_deferred;  ///< ticks that left commands queued because the per-tick cap was hit
  std::uint64_t patches_rejected;   ///< TissuePatches that failed validation (kept the previous one)
  std::uint64_t targets_rejected;   ///< StylusTargets that failed validation
  std::uint64_t sample_ring_resets; ///< ToolSample ring indices found impossible and reset
  std::uint64_t patches_unreadable; ///< TissuePatch reads that got no whole copy (the claimed slot was written into)
};

/// Fixed text on the wire, always NUL-terminated by its writer (readers check).
inline constexpr std::size_t kStatusTextSize = 112;

/// The wake-up latency histogram's bins in RtStatus: bin i counts wake-ups with latency in
/// [kWakeBinLowerUs[i], kWakeBinLowerUs[i + 1]) µs, the last bin everything from 2 ms up.
inline constexpr std::size_t kWakeBins = 16;
inline constexpr std::uint32_t kWakeBinLowerUs[kWakeBins] = {0, 2, 5, 10, 20, 35, 50, 75, 100, 150, 200, 300, 500, 750, 1000, 2000};

/// One hand in RtStatus: its force, tool and device.
struct HandStatus {
  Vec3 force;                      ///< last commanded force (N)
  double force_scale;              ///< fade factor applied (1 = full, 0 = faded out)
  std::uint64_t patch_version;     ///< this hand's TissuePatch version in use (0: none)
  std::uint32_t contact;           ///< 1 while the tool touches the patch
  ToolMode mode;                   ///< the tool in use
  Stage stage;                     ///< its stage
  std::uint8_t reserved0[2];
  Vec3 tool;                       ///< tool position, tissue frame (m)
  std::uint64_t clamped_ticks;     ///< ticks the safety clamp limited the force
  DeviceLifecycle device_state;    ///< the arm's lifecycle (kUnconfigured with the built-in stylus)
  IoStatus device_fault_cause;     ///< what tripped the arm's fault (kOk: none)
  std::uint8_t reserved_cause[3];
  std::uint64_t device_errors;     ///< ticks at zero force because the arm could not be read or written
  std::uint32_t has_arm;           ///< 1 when lancet-rt drives an arm from a config (0: built-in stylus)
  std::uint32_t link_lost;         ///< 1 while the arm's bus link is down (lancet-rt reconnects on its own)
  std::int32_t fault_node;         ///< node, unit or joint the fault names (-1: the bus or none)
  std::uint32_t fault_code;        ///< the backend's code for it (CANopen EMCY code, drive status bits, ...)
  char fault_text[kStatusTextSize];///< the fault in words ("" when none)
  char error_text[kStatusTextSize];///< the arm's last error of any kind, in words ("" when none)
  BusCounters bus;                 ///< the arm's bus counters
  std::uint32_t rearm_pending;     ///< 1 while a requested re-arm of this arm is under way
  std::uint32_t reserved1;
  std::uint64_t rearm_failures;    ///< re-arms of the arm that failed (rearm_text says why)
  char rearm_text[kStatusTextSize];///< outcome of the last re-arm of the arm ("" when none)
};

/// lancet-rt → anyone (seqlock): live figures of the servo loop and of each hand, for the viz
/// overlay, lancetctl and test rigs.
struct RtStatus {
  std::uint64_t tick;              ///< ticks run
  std::int64_t t_ns;               ///< deadline of the last tick (ns)
  std::int64_t period_ns;          ///< nominal period (ns)
  std::uint64_t overruns;          ///< deadlines skipped because a tick ran past the next one
  std::uint64_t missed;            ///< missed deadlines (late ticks plus skipped deadlines)
  std::int64_t wake_p50_ns;        ///< wake-up latency percentiles so far (ns), refreshed every 100 ms
  std::int64_t wake_p99_ns;
  std::int64_t wake_max_ns;
  std::int64_t compute_p99_ns;     ///< tick computation time p99 (ns)
  std::int64_t longest_stall_ns;   ///< longest gap between two wake-ups (ns)
  std::uint32_t watchdog_tripped;  ///< 1 while the watchdog holds every hand's force at zero
  std::uint32_t fifo;              ///< 1 when the loop runs SCHED_FIFO
  std::uint32_t viz_alive;         ///< 1 while the viz heartbeat is fresh
  std::uint32_t hands;             ///< hands the loop drives (1 or 2): hand[0 .. hands-1] are in use
  std::uint64_t samples_pushed;    ///< ToolSamples pushed
  std::uint64_t samples_dropped;   ///< ToolSamples refused because the ring was full
  std::int64_t viz_last_beat_ns;   ///< last viz heartbeat seen (ns; 0: never)
  std::int64_t force_zero_ns;      ///< first tick with every hand at zero force after the viz was lost (ns; 0: n/a)
  WatchdogReason watchdog_reason;  ///< why the watchdog tripped (kNone: it has not)
  std::uint32_t reserved0;
  std::uint64_t rearms;            ///< re-arms done (watchdog and arms)
  std::uint64_t operator_requests; ///< re-arm requests taken from lancetctl (OperatorRequest)
  SegmentHealth health;            ///< what lancet-rt rejected of its peers' writes
  std::uint64_t wake_histogram[kWakeBins]; ///< wake-ups per latency bin since start (kWakeBinLowerUs), refreshed with the percentiles
  HandStatus hand[kHandCount];     ///< by Hand
};

/// An operator's request to lancet-rt outside the viz (lancetctl rearm), through its own seqlock
/// so that it never shares the viz's single-producer command ring. Garbage is never a request:
/// check must equal operator_request_check(*this).
struct OperatorRequest {
  std::uint64_t seq;         ///< the requester's counter: a new seq is a new request
  std::int64_t t_ns;         ///< CLOCK_MONOTONIC when asked (ns); older than 2 s is ignored
  std::uint32_t kind;        ///< 1: re-arm
  std::int32_t pid;          ///< who asked
  std::uint8_t hands;        ///< bit h: hand h (Hand) is meant; 0 is no request
  std::uint8_t reserved[7];
  std::uint64_t check;       ///< operator_request_check(*this)
};
inline constexpr std::uint32_t kOperatorRearm = 1;

/// Bytes of an arm's configuration file an ArmConfigText carries.
inline constexpr std::uint32_t kArmConfigCapacity = 16384;

/// lancet-rt → anyone, once at start, per hand: the text of the hand's arm configuration file (and of its
/// calibration file, appended), for recordings. size 0: the built-in simulated stylus.
struct ArmConfigText {
  std::uint32_t size;       ///< valid bytes of text (<= kArmConfigCapacity)
  std::uint32_t truncated;  ///< 1 when the file was longer than the capacity
  char text[kArmConfigCapacity];
};

/// Bytes a ServoModelBlob can carry.
inline constexpr std::uint32_t kServoModelCapacity = 4096;

/// lancet-rt → anyone, once at start, per hand: the hand's servo model (firmware_rt/servo's ServoModel, its bytes
/// as they are: both processes are one build, which the layout hash checks) so that a recording
/// can replay the servo step exactly. layout is servo::kServoModelLayout of the writer; a reader
/// checks it, the size and every value (servo::model_from_blob) before using any of it.
struct ServoModelBlob {
  std::uint64_t layout;    ///< the writer's servo::kServoModelLayout
  std::uint32_t size;      ///< valid bytes
  std::uint32_t reserved;
  std::uint8_t bytes[kServoModelCapacity];
};

#define LANCET_ASSERT_WIRE_TYPE(T)                                                        \
  static_assert(std::is_trivially_copyable_v<T>, #T " must be trivially copyable");       \
  static_assert(std::is_standard_layout_v<T>, #T " must be standard-layout")
LANCET_ASSERT_WIRE_TYPE(EventPayload);
LANCET_ASSERT_WIRE_TYPE(ToolSample);
LANCET_ASSERT_WIRE_TYPE(MaterialParams);
LANCET_ASSERT_WIRE_TYPE(Command);
LANCET_ASSERT_WIRE_TYPE(PatchTriangle);
LANCET_ASSERT_WIRE_TYPE(VoxelBrick);
LANCET_ASSERT_WIRE_TYPE(TissuePatch);
LANCET_ASSERT_WIRE_TYPE(StylusTarget);
LANCET_ASSERT_WIRE_TYPE(RtStatus);
LANCET_ASSERT_WIRE_TYPE(HandStatus);
LANCET_ASSERT_WIRE_TYPE(BusCounters);
LANCET_ASSERT_WIRE_TYPE(SegmentHealth);
LANCET_ASSERT_WIRE_TYPE(OperatorRequest);
LANCET_ASSERT_WIRE_TYPE(ServoModelBlob);
LANCET_ASSERT_WIRE_TYPE(ArmConfigText);
#undef LANCET_ASSERT_WIRE_TYPE

}  // namespace lancet
