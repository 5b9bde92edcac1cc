#pragma once
// The lancet-rt servo tick in the model/data manner: an immutable RtModel, a preallocated RtData,
// and RtServo::tick(), which never allocates, locks, blocks, throws or logs.
//
// One tick: drain commands → stylus target (viz or script) → read the simulated device → take the
// newest TissuePatch (seqlock, never waits) → haptic step (proxy, stages, cut friction, force
// safety) → fade by viz liveness → watchdog → write the device → push one ToolSample → publish RtStatus and heartbeat.

#include <array>
#include <cstdint>
#include <memory>

#include <atomic>

#include "arm/kinematics.hpp"
#include "device/arm_physics.hpp"
#include "device/device.hpp"
#include "device/sim_stylus.hpp"
#include "device/trajectory.hpp"
#include "haptics/force_fade.hpp"
#include "haptics/haptic_step.hpp"
#include "lancet/shared_model/shared_state.hpp"
#include "rt/rt_loop.hpp"

namespace lancet::app {

/// Immutable configuration of the servo (built once at start-up).
struct RtModel {
  std::int64_t period_ns = 1'000'000;            ///< 1 kHz
  haptics::HapticModel haptic = haptics::HapticModel::defaults();  ///< materials, proxy, safety
  haptics::ForceFadeParams fade{};
  device::SimStylusParams stylus{};
  double script_depth = 0.004;                   ///< m below z = 0 the script presses to
  std::int64_t target_timeout_ns = 250'000'000;  ///< a StylusTarget older than this is ignored
  const device::Trajectory* trajectory = nullptr;  ///< replayed instead of the script (optional)
  // An arm from hw_configs (optional; RtServo's `arm` argument): its kinematics, the device-frame
  // point that maps to the tissue's origin (the centre of its workspace box) and the per-joint
  // torque limits from its safety section.
  const arm::Kinematics* kinematics = nullptr;
  Vec3 device_origin{};
  std::array<double, device::kMaxJoints> max_joint_torque{};
};

/// Re-arming a faulted arm reconnects its bus: never on the servo thread. The servo asks, stops
/// touching the device, and a supervisor thread (RtServo::supervise) re-arms it.
enum class RearmPhase : int { kIdle = 0, kRequested = 1, kRunning = 2, kDone = 3 };

/// Everything the tick reads and writes, allocated once.
struct RtData {
  std::uint64_t tick = 0;
  std::int32_t pid = 0;
  std::int64_t start_ns = 0;
  device::SimStylusState stylus{};
  StylusTarget target{};
  std::uint64_t target_version = 0;
  // Double-buffered patch: a read that fails (writer busy) must not clobber the one in use.
  std::array<TissuePatch, 2> patches{};
  int front = 0;
  std::uint64_t patch_version = 0;
  std::uint64_t patches_received = 0;
  haptics::ForceFade fade{};
  haptics::HapticData haptic{};
  haptics::HapticOutput haptic_out{};
  bool viz_alive = false;
  bool contact = false;
  ToolMode mode = ToolMode::kProbe;
  Vec3 force{};
  double max_force_seen = 0;
  std::uint64_t contact_ticks = 0;
  std::uint64_t commands_applied = 0;
  std::int64_t viz_last_beat_ns = 0;
  std::int64_t viz_lost_at_beat_ns = 0;  ///< last beat seen before the viz was judged lost
  std::int64_t force_zero_ns = 0;        ///< first tick at zero force after the loss
  std::uint64_t watchdog_faulted_ticks = 0;  ///< ticks rendered at zero force by the watchdog
  bool fifo = false;                         ///< reported in RtStatus
  ToolSample sample{};
  RtStatus status{};
  // The arm, when there is one.
  device::JointState joints{};
  device::JointCommand command{};
  arm::Jacobian jacobian{};              ///< of the last good read
  Vec3 tool{}, tool_velocity{};          ///< tissue frame (m, m/s)
  device::IoStatus last_read = device::IoStatus::kOk, last_write = device::IoStatus::kOk;
  std::uint64_t device_error_ticks = 0;  ///< ticks at zero force because the arm could not be read or written
  std::atomic<int> rearm_phase{0};       ///< RearmPhase
  std::array<Command, 16> command_batch{};
};

class RtServo {
 public:
  /// shared must outlive the servo. Not real-time safe (it is the configure step). With `arm`
  /// (configured and activated, model.kinematics set) the servo reads and writes it instead of the
  /// built-in stylus; with `hand` (the sim backend's physics) the viz target or script steers the
  /// simulated hand.
  RtServo(const RtModel& model, SharedState& shared, std::int64_t start_ns, device::Device* arm = nullptr,
          device::ArmPhysics* hand = nullptr);
  /// Performs a re-arm the servo asked for (call from a non-real-time thread, repeatedly).
  /// Returns true when it re-armed the device this call.
  bool supervise();

  /// One servo tick (called by RtLoop). A tripped watchdog holds the force at zero until a
  /// kRearm command re-arms it. Real-time safe.
  void tick(const rt::TickContext& ctx) noexcept;

  /// Whether the loop thread runs SCHED_FIFO (reported in RtStatus).
  void set_fifo(bool fifo) noexcept { data_->fifo = fifo; }

  [[nodiscard]] const RtData& data() const noexcept { return *data_; }
  [[nodiscard]] const RtModel& model() const noexcept { return model_; }

 private:
  void apply(const Command& c, rt::Watchdog& watchdog) noexcept;

  const RtModel model_;
  SharedState& shared_;
  device::Device* arm_ = nullptr;
  device::ArmPhysics* hand_ = nullptr;
  std::unique_ptr<RtData> data_;  // large (two patches): on the heap, allocated once here
};

}  // namespace lancet::app
