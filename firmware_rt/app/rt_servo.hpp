#pragma once
// The lancet-rt servo tick in the model/data manner: an immutable RtModel, a preallocated RtData,
// and RtServo::tick(), which never allocates, locks, blocks, throws or logs.
//
// One tick: hand the device over if the supervisor asked → commands (at most
// max_commands_per_tick, each checked), the script's tool changes and operator requests → the
// hand's target (viz or script; checked)// checked) → the newest ready patch (app/patch_intake.hpp: copied, checked and with its tree, by
// the intake's helper thread; O(1) here) → read the device → servo::servo_step (firmware_rt/servo: sense, haptics, fade and
// watchdog, actuate, the sample) → write the device → push the ToolSample → publish RtStatus
// (shared, and a private copy for the supervisor) and the heartbeat. The step is a pure function
// of what this wrapper reads; everything it was given goes into the ToolSample, so a recording
// replays it exactly.
//
// The segment is untrusted input: whatever the viz (or anything else) wrote is checked before use
// (lancet/shared_model/validate.hpp), the work it can cause per tick is bounded, and what was
// rejected is counted in RtStatus::health.
//
// Work that may block (re-arming a faulted arm, reconnecting a lost bus) is never done on the
// servo thread. A supervisor thread calls supervise(); the device changes hands through a
// handshake in which only the servo grants: supervisor kIdle → kRequested, servo (at the start of
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

/// Immutable configuration of lancet-rt's servo (built once at start-up): the step's model and
/// what the I/O around it needs.
struct RtModel {
  servo::ServoModel servo{};  ///< the step's model (period, haptics, fade, kinematics, torque limits)
  /// Without an arm: the built-in simulated stylus (a Device like the others, Cartesian).
  device::SimStylusParams stylus{};
  double script_depth = 0.004;                   ///< m below z = 0 the script presses to
  std::int64_t target_timeout_ns = 250'000'000;  ///< a StylusTarget older than this is ignored
  const device::Trajectory* trajectory = nullptr;  ///< replayed instead of the script (optional)
  /// The script's (or trajectory's) clock starts at the first patch: until the tissue is there the
  /// hand holds its starting point.
  bool script_waits_for_tissue = false;
  /// Commands taken from the ring per tick at most (the rest wait for the next tick): whatever the
  /// ring's indices say, a tick's work stays bounded. At most kSampleCommands (every command a
  /// tick applies is recorded in its ToolSample).
  std::size_t max_commands_per_tick = 16;
  /// An operator request (lancetctl rearm) older than this when seen is ignored.
  std::int64_t operator_request_max_age_ns = 2'000'000'000;
  /// While the arm's link is lost, the supervisor tries to reconnect this often.
  std::int64_t reconnect_interval_ns = 1'000'000'000;
};

/// Who holds the device (see the header comment).
enum class Handover : int { kIdle = 0, kRequested = 1, kGranted = 2, kDone = 3 };
/// What the supervisor does with the device once granted.
enum class DeviceJob : int { kNone = 0, kRearm = 1, kReconnect = 2 };

/// Everything the tick reads and writes, allocated once: the step's data and the I/O's.
struct RtData {
  servo::ServoData servo{};              ///< the step's state (what a recording replays)
  servo::ServoOutput out{};              ///< the step's output this tick
  std::size_t next_tool_change = 0;      ///< the trajectory's next tool change not yet applied
  std::int32_t pid = 0;
  std::int64_t start_ns = 0;
  StylusTarget target{};                 ///< the last valid target
  StylusTarget target_scratch{};         ///< read from the segment, checked before it is taken
  std::uint64_t target_version = 0;
  std::uint64_t patch_version = 0;       ///< version of the patch in use (0: none)
  std::uint64_t patches_received = 0;    ///< patches the servo started using
  std::uint64_t patches_rejected_seen = 0;  ///< the intake's rejected count, last looked at
  bool viz_alive = false;
  std::int64_t viz_last_beat_ns = 0;
  std::int64_t viz_lost_at_beat_ns = 0;  ///< last beat seen before the viz was judged lost
  std::int64_t force_zero_ns = 0;        ///< first tick at zero force after the loss
  std::uint64_t rearms = 0;              ///< re-arms done (watchdog, and the arm by the supervisor)
  bool fifo = false;                     ///< reported in RtStatus
  RtStatus status{};
  SegmentHealth health{};
  /// The check that rejected the last bad message (a static string; nullptr: none yet). Read by the
  /// supervisor for its log line.
  std::atomic<const char*> last_reject{nullptr};
  OperatorRequest request{};
  std::uint64_t request_version = 0;
  std::uint64_t request_seq = 0;         ///< seq of the last operator request taken
  std::uint64_t operator_requests = 0;
  std::array<Command, kSampleCommands> command_batch{};
  std::array<std::uint8_t, kSampleCommands> commands{};  ///< this tick's, packed for the step
  std::int64_t last_command_t_ns = 0;    ///< stamp of the last command applied (commands must be newer)
  // The device (the arm, or the built-in stylus).
  device::JointState joints{};
  device::IoStatus last_read = device::IoStatus::kOk, last_write = device::IoStatus::kOk;
  // The device handover (see the header comment).
  std::atomic<int> handover{0};          ///< Handover
  std::atomic<int> job{0};               ///< DeviceJob, set by the supervisor before kRequested
  std::atomic<bool> rearm_wanted{false}; ///< set by the servo when a re-arm is asked for
  // Written by the supervisor before it stores kDone, read by the servo after it sees kDone.
  bool job_ok = false;
  std::uint64_t rearm_failures = 0;
  std::array<char, kStatusTextSize> rearm_text{};
  std::int64_t next_reconnect_ns = 0;    ///< supervisor only
  /// The servo's RtStatus in this process's own memory, for the supervisor: unlike the segment's
  /// copy nobody else can write it.
  Seqlock<RtStatus> own_status;
};

class RtServo {
 public:
  /// shared must outlive the servo. Not real-time safe (it is the configure step). With `arm`
  /// (configured and activated; model.servo.kinematics its kinematics: the joint counts must agree,
  /// or std::invalid_argument) the servo reads and writes it; without, it makes the built-in
  /// simulated stylus (Cartesian kinematics, the force limit as its joint limits). Either way the
  /// viz's target or the script steers the simulated hand (Device::steer_hand; real arms ignore it).
  RtServo(const RtModel& model, SharedState& shared, std::int64_t start_ns, device::Device* arm = nullptr);

  /// The supervisor's side of the device handover: call from one non-real-time thread, repeatedly
  /// (every few ms). Asks for the device when a re-arm was requested (and the arm is faulted) or
  /// when the arm's link is lost (every reconnect_interval_ns), runs the job once the servo has
  /// granted the device (this call then blocks for the job's duration), and hands it back. Returns
  /// true when a job succeeded in this call.
  bool supervise(std::int64_t now_ns);
  bool supervise() { return supervise(monotonic_ns()); }

  /// One servo tick (called by RtLoop). A tripped watchdog holds the force at zero until a
  /// kRearm command re-arms it. Real-time safe.
  void tick(const rt::TickContext& ctx) noexcept;

  /// Whether the loop thread runs SCHED_FIFO (reported in RtStatus).
  void set_fifo(bool fifo) noexcept { data_->fifo = fifo; }

  /// Takes patches on a helper thread from now on (SCHED_FIFO at `priority` when `fifo`, off CPU
  /// `avoid_cpu`: the servo's) instead of in the tick. Call before the loop starts. Returns a line
  /// saying what it got. Without it, the tick takes patches itself (tests, deterministic tools).
  std::string start_patch_intake(bool fifo, int priority, int avoid_cpu) { return intake_->start_thread(fifo, priority, avoid_cpu); }
  [[nodiscard]] const PatchIntake& patch_intake() const noexcept { return *intake_; }

  /// The latest published status, from the servo's private copy (any thread). kEmpty before the
  /// first tick.
  [[nodiscard]] ReadStatus read_status(RtStatus& out) const noexcept { return data_->own_status.try_read(out, 1000); }

  [[nodiscard]] const RtData& data() const noexcept { return *data_; }
  [[nodiscard]] const RtModel& model() const noexcept { return model_; }
  /// The arm given to the constructor (null: the built-in stylus is in use).
  [[nodiscard]] device::Device* arm() const noexcept { return has_arm_ ? device_ : nullptr; }
  /// The device the servo drives: the arm, or the built-in stylus.
  [[nodiscard]] device::Device& device() const noexcept { return *device_; }

 private:
  void reject(std::uint64_t& counter, const char* why) noexcept;
  /// Takes this tick's checked commands from the ring (into data_->commands, packed) and the
  /// operator's re-arm request; returns how many commands.
  std::size_t drain_commands(std::int64_t now_ns, bool& operator_rearm) noexcept;
  /// The device handover, at the start of a tick. Returns whether the servo owns the device now.
  bool take_device() noexcept;
  void publish_status(const rt::TickContext& ctx, bool device_owned) noexcept;

  RtModel model_;
  SharedState& shared_;
  std::unique_ptr<device::SimStylus> stylus_;  // the built-in stylus, when no arm was given
  device::Device* device_ = nullptr;           // the arm, or stylus_
  bool has_arm_ = false;
  std::unique_ptr<RtData> data_;  // large: on the heap, allocated once here
  std::unique_ptr<PatchIntake> intake_;
};

/// Copies a C string into a fixed status text, truncated and NUL-terminated. Real-time safe.
void copy_text(char* dst, std::size_t size, const char* src) noexcept;

}  // namespace lancet::app
