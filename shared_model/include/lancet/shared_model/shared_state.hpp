#pragma once
// SharedState: everything lancet-rt and lancet-viz share, laid out in one ShmSegment payload, and
// the layout hash that guards it. See ARCHITECTURE.md for the data flow:
//   rt  → viz : ToolSample ring (one per tick), RtStatus (seqlock), rt heartbeat
//   viz → rt  : TissuePatch (triple buffer), StylusTarget (seqlock), Command ring, viz heartbeat

#include <cstddef>
#include <cstdint>
#include <memory>
#include <new>
#include <string>

#include "lancet/shared_model/heartbeat.hpp"
#include "lancet/shared_model/messages.hpp"
#include "lancet/shared_model/seqlock.hpp"
#include "lancet/shared_model/shm_segment.hpp"
#include "lancet/shared_model/spsc_ring.hpp"
#include "lancet/shared_model/triple_buffer.hpp"
#include "lancet/shared_model/units.hpp"

namespace lancet {

/// Bump when the meaning of a field changes without changing the layout.
/// 2: Command::check (was reserved0) must match wire::command_check.
/// 6: RtStatus::wake_histogram; ToolMode::kSwab.
/// 7: ToolSample carries the servo step's inputs (woke_ns, read/write status, inputs, buttons,
///    commands) and state_hash, for recording and exact replay.
/// 8: TissuePatch holds 16384 triangles, each with its surface face id; the brick before the
///    triangles, and only the triangles in use are copied.
/// 9: the TissuePatch travels in a TripleBuffer (no reader is turned away by a busy writer);
///    SegmentHealth::patches_unreadable; a 16 s sample ring.
/// 10: the device, I/O and watchdog codes are typed (device_codes.hpp); Command carries no
///    material and StylusTarget no buttons (neither was read).
/// 11: two hands: ToolSample, Command, StylusTarget and TissuePatch say their hand; a patch, a
///    stylus target, a servo model and an arm config per hand; RtStatus::hand[]; an operator
///    request names its hands; a 32768-sample ring.
inline constexpr std::uint64_t kProtocolVersion = 11;
/// 32768 ToolSamples = 16 s of ticks at 1 kHz for two hands (14 MB): the viz may stall that long
/// without loss (a laptop swapping, a debugger's breakpoint). A longer stall loses ticks: a
/// recording marks the gap and its replay checks the servo up to it (record/replay.hpp).
inline constexpr std::size_t kSampleRingCapacity = 32768;
inline constexpr std::size_t kCommandRingCapacity = 256;
/// Default segment name; processes take --shm to use another.
inline constexpr const char* kDefaultShmName = "/lancet";

struct SharedState {
  SpscRing<ToolSample, kSampleRingCapacity> samples;  ///< rt → viz (both hands, in tick order)
  SpscRing<Command, kCommandRingCapacity> commands;   ///< viz → rt (each names its hand)
  TripleBuffer<TissuePatch> patch[kHandCount];        ///< viz → rt, by Hand (lancet-rt's patch intakes claim)
  Seqlock<StylusTarget> stylus_target[kHandCount];    ///< viz → rt, by Hand
  Seqlock<RtStatus> rt_status;                        ///< rt → anyone
  Heartbeat rt_heartbeat;                             ///< written by lancet-rt every tick
  Heartbeat viz_heartbeat;                            ///< written by lancet-viz every frame
  Seqlock<OperatorRequest> operator_request;          ///< lancetctl → rt (one operator at a time)
  Seqlock<ServoModelBlob> servo_model[kHandCount];    ///< rt → anyone, by Hand, once at start (recordings)
  Seqlock<ArmConfigText> arm_config[kHandCount];      ///< rt → anyone, by Hand, once at start (recordings)
};
static_assert(std::is_standard_layout_v<SharedState>);

namespace detail {
constexpr std::uint64_t fnv1a(std::uint64_t h, std::uint64_t v) {
  for (int i = 0; i < 8; ++i) {
    h ^= (v >> (8 * i)) & 0xffu;
    h *= 0x100000001b3ull;
  }
  return h;
}
template <class... V>
constexpr std::uint64_t fold(std::uint64_t h, V... v) {
  ((h = fnv1a(h, static_cast<std::uint64_t>(v))), ...);
  return h;
}
}  // namespace detail

/// Hash of the layout of what a recording holds: the ToolSample (every field), the TissuePatch
/// with its triangles and brick, and the servo model's blob. A recording replays on any build whose
/// hash is the one it was recorded with, whatever else of the protocol has changed since.
constexpr std::uint64_t recorded_layout_hash() {
  using detail::fold;
  std::uint64_t h = 0xcbf29ce484222325ull;
  h = fold(h, kMaxJoints, kPatchCapacity, kBrickDim);
  h = fold(h, sizeof(ToolSample), alignof(ToolSample), offsetof(ToolSample, seq), offsetof(ToolSample, t_ns),
           offsetof(ToolSample, n_joints), offsetof(ToolSample, mode), offsetof(ToolSample, stage),
           offsetof(ToolSample, q), offsetof(ToolSample, qd), offsetof(ToolSample, tau), offsetof(ToolSample, tool),
           offsetof(ToolSample, proxy), offsetof(ToolSample, force), offsetof(ToolSample, patch_version),
           offsetof(ToolSample, events), offsetof(ToolSample, payload), sizeof(EventPayload), offsetof(ToolSample, woke_ns),
           offsetof(ToolSample, read_status), offsetof(ToolSample, write_status), offsetof(ToolSample, inputs),
           offsetof(ToolSample, buttons), offsetof(ToolSample, n_commands), offsetof(ToolSample, reset_mode), offsetof(ToolSample, hand),
           offsetof(ToolSample, commands),
           offsetof(ToolSample, state_hash), kSampleCommands);
  h = fold(h, sizeof(TissuePatch), offsetof(TissuePatch, samples_applied), offsetof(TissuePatch, n_triangles), offsetof(TissuePatch, hand),
           offsetof(TissuePatch, triangles), offsetof(TissuePatch, brick), sizeof(PatchTriangle),
           offsetof(PatchTriangle, material), offsetof(PatchTriangle, flags), offsetof(PatchTriangle, id), sizeof(VoxelBrick), offsetof(VoxelBrick, hu));
  h = fold(h, sizeof(ServoModelBlob), kServoModelCapacity);
  return h;
}
inline constexpr std::uint64_t kRecordedLayoutHash = recorded_layout_hash();

/// Hash of everything that must agree between peers: protocol version, sizes, alignments and
/// field offsets of every message, ring capacities and the SharedState member offsets.
constexpr std::uint64_t shared_layout_hash() {
  using detail::fold;
  std::uint64_t h = 0xcbf29ce484222325ull;
  h = fold(h, kProtocolVersion, kRecordedLayoutHash, kSampleRingCapacity, kCommandRingCapacity);
  h = fold(h, kHandCount, sizeof(Command), offsetof(Command, kind), offsetof(Command, mode), offsetof(Command, hand), offsetof(Command, check),
           sizeof(MaterialParams), offsetof(MaterialParams, yield_force), offsetof(MaterialParams, density));
  h = fold(h, sizeof(StylusTarget), offsetof(StylusTarget, target), offsetof(StylusTarget, active), offsetof(StylusTarget, hand));
  h = fold(h, sizeof(RtStatus), offsetof(RtStatus, missed), offsetof(RtStatus, wake_p99_ns),
           offsetof(RtStatus, watchdog_tripped), offsetof(RtStatus, viz_alive), offsetof(RtStatus, hands),
           offsetof(RtStatus, force_zero_ns), offsetof(RtStatus, rearms), offsetof(RtStatus, health), sizeof(SegmentHealth),
           offsetof(RtStatus, wake_histogram), kWakeBins, offsetof(RtStatus, hand));
  h = fold(h, sizeof(HandStatus), offsetof(HandStatus, force), offsetof(HandStatus, mode), offsetof(HandStatus, tool),
           offsetof(HandStatus, device_state), offsetof(HandStatus, has_arm), offsetof(HandStatus, fault_text),
           offsetof(HandStatus, error_text), offsetof(HandStatus, bus), offsetof(HandStatus, rearm_pending),
           offsetof(HandStatus, rearm_text), sizeof(BusCounters), kStatusTextSize);
  h = fold(h, sizeof(OperatorRequest), offsetof(OperatorRequest, kind), offsetof(OperatorRequest, hands), offsetof(OperatorRequest, check));
  h = fold(h, sizeof(SharedState), alignof(SharedState), offsetof(SharedState, samples),
           offsetof(SharedState, commands), offsetof(SharedState, patch), offsetof(SharedState, stylus_target),
           offsetof(SharedState, rt_status), offsetof(SharedState, rt_heartbeat),
           offsetof(SharedState, viz_heartbeat), offsetof(SharedState, operator_request),
           offsetof(SharedState, servo_model), sizeof(ServoModelBlob), kServoModelCapacity, offsetof(SharedState, arm_config),
           sizeof(ArmConfigText), kArmConfigCapacity);
  return h;
}
inline constexpr std::uint64_t kSharedLayoutHash = shared_layout_hash();

/// A mapped SharedState and the segment that owns the mapping.
class SharedChannel {
 public:
  /// lancet-rt: creates the segment and constructs a fresh SharedState in it.
  static Result<SharedChannel> create(const std::string& name, const ShmSegment::CreateOptions& options) {
    auto seg = ShmSegment::create(name, sizeof(SharedState), kSharedLayoutHash, options);
    if (!seg) return seg.error();
    SharedChannel ch(std::move(seg).value());
    ch.state_ = new (ch.segment_.payload()) SharedState{};
    ch.segment_.mark_ready();
    return ch;
  }
  /// lancet-viz and monitors: attaches to an existing segment (checked, see ShmSegment::open).
  static Result<SharedChannel> open(const std::string& name) {
    auto seg = ShmSegment::open(name, sizeof(SharedState), kSharedLayoutHash);
    if (!seg) return seg.error();
    SharedChannel ch(std::move(seg).value());
    ch.state_ = std::launder(static_cast<SharedState*>(ch.segment_.payload()));
    return ch;
  }

  [[nodiscard]] SharedState& state() const noexcept { return *state_; }
  [[nodiscard]] ShmSegment& segment() noexcept { return segment_; }
  [[nodiscard]] const ShmSegment& segment() const noexcept { return segment_; }

 private:
  explicit SharedChannel(ShmSegment seg) : segment_(std::move(seg)) {}
  ShmSegment segment_;
  SharedState* state_ = nullptr;
};

}  // namespace lancet
