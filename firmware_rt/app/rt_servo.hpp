#pragma once
// The lancet-rt servo tick in the model/data manner: an immutable RtModel, a preallocated RtData,
// and RtServo::tick(), which never allocates, locks, blocks, throws or logs.
//
// One loop drives one or two hands (RtModel::hands; the right hand is hand 0). Each hand has its
// own device (an arm, or the built-in simulated stylus), servo model and data, patch intake,
// stylus target, script and device handover; the loop has one watchdog, one viz heartbeat, one
// command ring and one sample ring.
//
// One tick: hand each device over if the supervisor asked → commands (at most
// max_commands_per_tick, each checked, routed by Command::hand), the scripts' tool changes and
// operator requests (OperatorRequest::hands) → each hand's target (viz or script; checked) → each
// hand's newest ready patch (app/patch_intake.hpp: copied, checked and with its tree, by the
// intake's helper thread; O(1) here) → read ALL devices → servo::servo_step for ALL hands
// (firmware_rt/servo: sense, haptics, fade and watchdog, actuate, the sample) → write ALL devices →
// push the ToolSamples (right, then left; both with the tick's seq) → publish RtStatus (shared, and
// a private copy for the supervisor) and the heartbeat. The step is a pure function of what this
// wrapper reads; everything it was given goes into the ToolSample, so a recording replays it
// exactly.
//
// The segment is untrusted input: whatever the viz (or anything else) wrote is checked before use
// (lancet/shared_model/validate.hpp), the work it can cause per tick is bounded, and what was
// rejected is counted in RtStatus::health.
//
// Work that may block (re-arming a faulted arm, reconnecting a lost bus) is never done on the
// servo thread. A supervisor thread calls supervise(); each hand's device changes hands through
// its own handshake (one hand's job never holds the other's device) in which only the servo grants: supervisor kIdle → kRequested, servo (at the start of
// its next tick) kRequested → kGranted and from then on keeps off the device, supervisor does the
// job and stores kDone, servo kDone → kIdle and takes the device back.

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>

#include "app/patch_intake.hpp"
#include "device/device.hpp"
#include "device/sim_stylus.hpp"
#include "device/trajectory.hpp"
#include "lancet/shared_model/shared_state.hpp"
#include "rt/rt_loop.hpp"
#include "servo/servo_step.hpp"

namespace lancet::app {

/// One hand's part of the model: its servo, its simulated stylus and its script.
struct HandModel {
  /// The step's model (haptics, fade, kinematics, torque limits). Its period_ns is the loop's
  /// (RtModel::period_ns), set by RtServo.
  servo::ServoModel servo{};
  /// Without an arm: the built-in simulated stylus (a Device like the others, Cartesian).
  device::SimStylusParams stylus{};
  double script_depth = 0.004;                     ///< m below z = 0 the right hand's script presses to
  const device::Trajectory* trajectory = nullptr;  ///< replayed instead of the built-in script (optional)
};

/// Immutable configuration of lancet-rt's servo (built once at start-up): each hand's step model
/// and what the I/O around the steps needs.
struct RtModel {
  std::size_t hands = 1;                         ///< hands driven: 1 (right) or 2 (right and left)
  std::int64_t period_ns = 1'000'000;            ///< the loop's period; every hand's servo.period_ns
  std::array<HandModel, kHandCount> hand{};      ///< by Hand; hand[h] for h >= hands is unused
  std::int64_t target_timeout_ns = 250'000'000;  ///< a StylusTarget older than this is ignored
  /// A hand's script (or trajectory) clock starts at its first patch: until the tissue is there
  /// the hand holds its starting point.
  bool script_waits_for_tissue = false;
  /// Commands taken from the ring per tick at most, all hands together (the rest wait for the
  /// next tick): whatever the ring's indices say, a tick's work stays bounded. At most
  /// kSampleCommands (every command a tick applies is recorded in its hand's ToolSample).
  std::size_t max_commands_per_tick = 16;
  /// An operator request (lancetctl rearm) older than this when seen is ignored.
  std::int64_t operator_request_max_age_ns = 2'000'000'000;
  /// While an arm's link is lost, the supervisor tries to reconnect it this often.
  std::int64_t reconnect_interval_ns = 1'000'000'000;
};

/// Who holds a hand's device (see the header comment).
enum class Handover : int { kIdle = 0, kRequested = 1, kGranted = 2, kDone = 3 };
/// What the supervisor does with the device once granted.
enum class DeviceJob : int { kNone = 0, kRearm = 1, kReconnect = 2 };

/// One hand's part of the data: its step's state and its I/O's.
struct HandData {
  servo::ServoData servo{};              ///< the step's state (what a recording replays)
  servo::ServoOutput out{};              ///< the step's output this tick
  std::size_t next_tool_change = 0;      ///< the trajectory's next tool change not yet applied
  std::int64_t start_ns = 0;             ///< the script's clock starts here
  StylusTarget target{};                 ///< the last valid target
  StylusTarget target_scratch{};         ///< read from the segment, checked before it is taken
  std::uint64_t target_version = 0;
  std::uint64_t patch_version = 0;       ///< version of the patch in use (0: none)
  std::uint64_t patches_received = 0;    ///< patches the servo started using
  std::uint64_t patches_rejected_seen = 0;  ///< the intake's rejected count, last looked at
  std::array<std::uint8_t, kSampleCommands> commands{};  ///< this tick's, packed for the step
  std::size_t n_commands = 0;            ///< this tick's
  bool commands_cut = false;             ///< this tick's: more than `commands` holds
  bool operator_rearm = false;           ///< this tick's: an operator asked to re-arm this hand
  // The device (the arm, or the built-in stylus).
  device::JointState joints{};
  device::IoStatus last_read = device::IoStatus::kOk, last_write = device::IoStatus::kOk;
  bool device_owned = true;              ///< this tick's: the servo holds the device
  // The device handover (see the header comment).
  std::atomic<int> handover{0};          ///< Handover
  std::atomic<int> job{0};               ///< DeviceJob, set by the supervisor before kRequested
  std::atomic<bool> rearm_wanted{false}; ///< set by the servo when a re-arm is asked for
  // Written by the supervisor before it stores kDone, read by the servo after it sees kDone.
  bool job_ok = false;
  std::uint64_t rearm_failures = 0;
  std::array<char, kStatusTextSize> rearm_text{};
  std::int64_t next_reconnect_ns = 0;    ///< supervisor only
};

/// Everything the tick reads and writes, allocated once: the loop's data and each hand's.
struct RtData {
  std::array<HandData, kHandCount> hand{};  ///< by Hand; hand[h] for h >= RtModel::hands is unused
  std::int32_t pid = 0;
  bool viz_alive = false;
  std::int64_t viz_last_beat_ns = 0;
  std::int64_t viz_lost_at_beat_ns = 0;  ///< last beat seen before the viz was judged lost
  std::int64_t force_zero_ns = 0;        ///< first tick with every hand at zero force after the loss
  std::uint64_t rearms = 0;              ///< re-arms done (the watchdog, and the arms by the supervisor)
  bool fifo = false;                     ///< reported in RtStatus
  RtStatus status{};
  SegmentHealth health{};                ///< all hands together
  /// The check that rejected the last bad message (a static string; nullptr: none yet). Read by the
  /// supervisor for its log line.
  std::atomic<const char*> last_reject{nullptr};
  OperatorRequest request{};
  std::uint64_t request_version = 0;
  std::uint64_t request_seq = 0;         ///< seq of the last operator request taken
  std::uint64_t operator_requests = 0;
  std::array<Command, kSampleCommands> command_batch{};
  std::int64_t last_command_t_ns = 0;    ///< stamp of the last command applied (commands must be newer)
  /// The servo's RtStatus in this process's own memory, for the supervisor: unlike the segment's
  /// copy nobody else can write it.
  Seqlock<RtStatus> own_status;
};

class RtServo {
 public:
  /// shared must outlive the servo. Not real-time safe (it is the configure step). Hand h (h <
  /// model.hands) drives arms[h] when given (configured and activated; model.hand[h].servo.kinematics
  /// its kinematics: the joint counts must agree, or std::invalid_argument), else a built-in
  /// simulated stylus (Cartesian kinematics, the force limit as its joint limits) of its own.
  /// Either way the viz's target or the hand's script steers the simulated hand
  /// (Device::steer_hand; real arms ignore it). Publishes each hand's servo model
  /// (SharedState::servo_model[h]).
  RtServo(const RtModel& model, SharedState& shared, std::int64_t start_ns, std::array<device::Device*, kHandCount> arms);
  /// One hand (or two, by model.hands) with at most the right hand's arm.
  RtServo(const RtModel& model, SharedState& shared, std::int64_t start_ns, device::Device* right_arm = nullptr)
      : RtServo(model, shared, start_ns, std::array<device::Device*, kHandCount>{right_arm, nullptr}) {}

  /// The supervisor's side of each hand's device handover: call from one non-real-time thread,
  /// repeatedly (every few ms). For each hand with an arm: asks for its device when a re-arm was
  /// requested (and the arm is faulted) or when the arm's link is lost (every
  /// reconnect_interval_ns), runs the job once the servo has granted the device (this call then
  /// blocks for the job's duration), and hands it back. Returns true when a job succeeded in
  /// this call.
  bool supervise(std::int64_t now_ns);
  bool supervise() { return supervise(monotonic_ns()); }

  /// One servo tick for every hand (called by RtLoop). A tripped watchdog holds every hand's
  /// force at zero until a kRearm command (for any hand) re-arms it. Real-time safe.
  void tick(const rt::TickContext& ctx) noexcept;

  /// Whether the loop thread runs SCHED_FIFO (reported in RtStatus).
  void set_fifo(bool fifo) noexcept { data_->fifo = fifo; }

  /// Takes patches on helper threads from now on, one per hand (SCHED_FIFO at `priority` when
  /// `fifo`, off CPU `avoid_cpu`: the servo's) instead of in the tick. Call before the loop
  /// starts. Returns a line saying what each got. Without it, the tick takes patches itself
  /// (tests, deterministic tools).
  std::string start_patch_intake(bool fifo, int priority, int avoid_cpu);
  /// Hand h's intake (h < hands).
  [[nodiscard]] const PatchIntake& patch_intake(Hand h = Hand::kRight) const noexcept { return *intake_[hand_index(h)]; }

  /// The latest published status, from the servo's private copy (any thread). kEmpty before the
  /// first tick.
  [[nodiscard]] ReadStatus read_status(RtStatus& out) const noexcept { return data_->own_status.try_read(out, 1000); }

  [[nodiscard]] const RtData& data() const noexcept { return *data_; }
  [[nodiscard]] const HandData& hand(Hand h) const noexcept { return data_->hand[hand_index(h)]; }
  [[nodiscard]] const RtModel& model() const noexcept { return model_; }
  [[nodiscard]] std::size_t hands() const noexcept { return model_.hands; }
  /// Hand h's arm given to the constructor (null: its built-in stylus is in use).
  [[nodiscard]] device::Device* arm(Hand h = Hand::kRight) const noexcept {
    return has_arm_[hand_index(h)] ? device_[hand_index(h)] : nullptr;
  }
  /// The device hand h drives: its arm, or its built-in stylus (h < hands).
  [[nodiscard]] device::Device& device(Hand h = Hand::kRight) const noexcept { return *device_[hand_index(h)]; }

 private:
  void reject(std::uint64_t& counter, const char* why) noexcept;
  /// Takes this tick's checked commands from the ring, routed by hand into each HandData's
  /// commands (packed), and the operator's re-arm request into each meant hand's operator_rearm.
  void drain_commands(std::int64_t now_ns) noexcept;
  /// Hand h's device handover, at the start of a tick. Returns whether the servo owns it now.
  bool take_device(std::size_t h) noexcept;
  /// Hand h's supervisor side (see supervise()).
  bool supervise_hand(std::size_t h, std::int64_t now_ns);
  /// Hand h's target this tick: the viz's while fresh, else its trajectory or script. `t` is the
  /// hand's script time (s).
  Vec3 hand_target(std::size_t h, std::int64_t now_ns, double t) noexcept;
  void publish_status(const rt::TickContext& ctx) noexcept;

  RtModel model_;
  SharedState& shared_;
  std::array<std::unique_ptr<device::SimStylus>, kHandCount> stylus_;  // the built-in styluses, for hands without an arm
  std::array<device::Device*, kHandCount> device_{};                   // each hand's arm, or its stylus
  std::array<bool, kHandCount> has_arm_{};
  std::unique_ptr<RtData> data_;  // large: on the heap, allocated once here
  std::array<std::unique_ptr<PatchIntake>, kHandCount> intake_;       // one per driven hand
};

/// Copies a C string into a fixed status text, truncated and NUL-terminated. Real-time safe.
void copy_text(char* dst, std::size_t size, const char* src) noexcept;

}  // namespace lancet::app
