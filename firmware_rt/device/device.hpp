#pragma once
// Device: one haptic arm behind a bus, with the ros2_control hardware-interface lifecycle.
//
//   configure()  unconfigured → inactive   open the bus, check the arm answers (not real-time)
//   activate()   inactive → active          enable the drives (not real-time)
//   read()       inactive|active|fault: encoders, buttons, status        (real-time, bounded)
//                (reading never moves the arm, so probing and monitoring need no activation)
//   write()      active: joint torques out                               (real-time, bounded)
//   deactivate() active|fault → inactive    zero torque, disable the drives (not real-time)
//   rearm()      fault → active             clear the fault on the bus and the drives (explicit)
//   reconnect()  fault → fault              reopen a lost bus link; the device stays faulted
//                (the supervisor calls it on its own; only rearm() ever resumes torque)
//
// read() and write() never throw, allocate or block past the backend's timeout; what went wrong
// is a counted IoStatus. Any error counts; `max_consecutive_errors` of them with no good read in
// between, or one disconnect or device fault, put the device in kFault: from then on write() sends zero torque (best effort) and
// returns kFault until someone calls rearm() — a fault never clears by itself.
//
// Encoder plausibility (here, for every backend): a good read whose joint moved further from the
// last plausible reading than the joint's maximum speed allows (twice max_speed × the time
// between the two reads, plus two counts) is a glitch: read() returns kImplausible, the reading is
// not used and the last plausible one stays the reference. Glitches fill a leaky bucket (one
// drains every `glitch_leak_reads` good reads); `max_glitches` in it is a fault.
//
// Every error a backend reports can carry a FaultDetail (node, code, words: the CANopen EMCY code
// and its meaning, the drive's status bits, a Modbus exception); the one that tripped the fault is
// kept for the operator (RtStatus, --stats, lancetctl).
//
// Backends implement the on_* hooks; the state machine, counters and fault policy live here.

#include <array>
#include <cstdint>
#include <optional>
#include <string>

#include "lancet/shared_model/device_codes.hpp"
#include "lancet/shared_model/messages.hpp"
#include "lancet/shared_model/result.hpp"

namespace lancet::device {

/// Joints per arm: the one limit, shared with the wire (messages.hpp).
using lancet::kMaxJoints;

/// The lifecycle and I/O codes are the wire's (lancet/shared_model/device_codes.hpp): lancet-rt
/// publishes them in RtStatus and ToolSample as they are.
using Lifecycle = ::lancet::DeviceLifecycle;
using IoStatus = ::lancet::IoStatus;
using ::lancet::to_string;

/// What the bus has done so far (real-time safe to update and to copy).
struct IoCounters {
  std::uint64_t reads = 0, writes = 0;
  std::uint64_t ok = 0;
  std::uint64_t timeouts = 0, crc_errors = 0, protocol_errors = 0;
  std::uint64_t disconnects = 0;            ///< times the link was found lost (reads while it stays lost count once)
  std::uint64_t device_faults = 0;          ///< times the drive began reporting a fault (a latched bit counts once)
  std::uint64_t glitches = 0;               ///< implausible encoder readings (kImplausible)
  std::uint64_t stale_replies = 0;          ///< late replies to an earlier request, discarded (backends that can tell)
  std::uint64_t faults = 0;                 ///< times the device entered kFault
  std::uint64_t reconnects = 0;             ///< successful reconnect() calls
  std::uint32_t consecutive_errors = 0;
  std::int64_t last_io_ns = 0, max_io_ns = 0;  ///< duration of the last / slowest read or write
};

struct JointState {
  int n = 0;
  std::array<double, kMaxJoints> q{};                 ///< rad (m for prismatic), from the encoders
  std::array<double, kMaxJoints> qd{};                ///< rad/s (m/s), the backend's estimate
  std::array<std::int64_t, kMaxJoints> counts{};      ///< raw encoder counts
  std::uint32_t buttons = 0;                          ///< bit i = config button i pressed
  std::uint32_t status = 0;                           ///< the device's own status word, raw
  std::int64_t t_ns = 0;                              ///< CLOCK_MONOTONIC when read
};

struct JointCommand {
  int n = 0;
  std::array<double, kMaxJoints> tau{};  ///< N·m at each joint (N for prismatic)
};


struct FaultPolicy {
  std::uint32_t max_consecutive_errors = 3;  ///< errors in a row that trip kFault (1: any error)
  std::uint32_t max_glitches = 3;            ///< glitches in the leaky bucket that trip kFault (0: never)
  std::uint32_t glitch_leak_reads = 100;     ///< good reads that drain one glitch from the bucket
};

/// Per joint, what encoder readings are plausible (configure time; see the header comment).
struct Plausibility {
  int n = 0;                                    ///< joints checked (0: no check)
  std::array<double, kMaxJoints> max_speed{};   ///< rad/s (m/s), > 0
  std::array<double, kMaxJoints> resolution{};  ///< rad (m) per encoder count
};

/// One error, in terms an integrator can act on. Fixed storage: real-time safe to fill and copy.
struct FaultDetail {
  IoStatus status = IoStatus::kOk;
  std::int32_t node = -1;      ///< bus node, unit or joint concerned (-1: the bus or device as a whole)
  std::uint32_t code = 0;      ///< backend code: CANopen EMCY error code, drive status bits, Modbus exception…
  std::int64_t t_ns = 0;       ///< CLOCK_MONOTONIC when it happened
  std::array<char, 112> text{};  ///< one line, e.g. "node 1: EMCY 0x2310 continuous over-current (output side)"
  [[nodiscard]] const char* c_str() const noexcept { return text.data(); }
};

class Device {
 public:
  explicit Device(std::string name, FaultPolicy policy = {}) : name_(std::move(name)), policy_(policy) {}
  virtual ~Device() = default;
  Device(const Device&) = delete;
  Device& operator=(const Device&) = delete;

  Result<void> configure();
  Result<void> activate();
  Result<void> deactivate();
  Result<void> rearm();
  /// fault → fault: reopens a lost bus link (the backend's on_reconnect) so that a later rearm()
  /// finds the arm; never resumes torque. Not real-time. kUnsupported from backends without it.
  Result<void> reconnect();
  /// Whether the last error says the link itself is gone (a disconnect), so reconnect() is due.
  [[nodiscard]] bool link_lost() const noexcept { return link_lost_; }
  /// Encoder plausibility limits (configure time). n = 0 turns the check off.
  void set_plausibility(const Plausibility& p) noexcept { plausibility_ = p; }

  [[nodiscard]] IoStatus read(JointState& out) noexcept;
  [[nodiscard]] IoStatus write(const JointCommand& cmd) noexcept;

  [[nodiscard]] Lifecycle state() const noexcept { return state_; }
  [[nodiscard]] const IoCounters& counters() const noexcept { return counters_; }
  [[nodiscard]] const std::string& name() const noexcept { return name_; }
  /// The status that tripped the last fault (kOk if none yet).
  [[nodiscard]] IoStatus fault_cause() const noexcept { return fault_cause_; }
  /// What tripped the last fault, in words (status kOk: none since the last rearm()).
  [[nodiscard]] const FaultDetail& fault_detail() const noexcept { return fault_detail_; }
  /// The last error of any kind, in words (status kOk: none yet).
  [[nodiscard]] const FaultDetail& last_error() const noexcept { return last_error_; }
  [[nodiscard]] virtual int joint_count() const noexcept = 0;
  /// Where the simulated hand holding a simulated device pulls it (device frame, m): the sim
  /// backends' hand. A real arm has a real hand: the default ignores it. Real-time safe.
  virtual void steer_hand(Vec3 target) noexcept { (void)target; }

 protected:
  virtual Result<void> on_configure() = 0;
  virtual Result<void> on_activate() = 0;
  virtual Result<void> on_deactivate() = 0;  ///< must leave the drives at zero torque
  virtual Result<void> on_rearm() = 0;       ///< clear bus/drive faults; the device is then activated again
  /// Reopen the bus link after a disconnect, leaving the drives disabled (zero torque).
  virtual Result<void> on_reconnect();       ///< default: kUnsupported, "<name>: reconnect is not supported"
  virtual IoStatus on_read(JointState& out) noexcept = 0;
  virtual IoStatus on_write(const JointCommand& cmd) noexcept = 0;
  /// The device has just entered kFault (called inside the read or write that tripped it): what
  /// the backend shows or holds for a fault (an LED). Real-time: must not block or allocate.
  /// Default: nothing (every write from now on is a zero-torque one anyway).
  virtual void on_fault() noexcept {}

  /// Backends: describe the error they are about to return from on_read / on_write (or the
  /// zero-torque write of a fault). `text` is copied (truncated to fit). Real-time safe.
  void note_error(IoStatus status, std::int32_t node, std::uint32_t code, const char* text) noexcept;
  /// Backends: a late reply to an earlier request was recognised and thrown away. Real-time safe.
  void count_stale_reply() noexcept { ++counters_.stale_replies; }
  /// Backends: the encoder counts jumped on purpose (a homing switch made them absolute), so the
  /// next reading is taken as the new reference rather than checked against the old. Real-time safe.
  void restart_plausibility() noexcept { q_ref_ns_ = 0; }

 private:
  void account(IoStatus s, std::int64_t t0_ns, bool is_read) noexcept;
  /// kOk, or kImplausible when `in` jumped from the last plausible reading. Real-time safe.
  IoStatus check_plausible(const JointState& in) noexcept;

  std::string name_;
  FaultPolicy policy_;
  Lifecycle state_ = Lifecycle::kUnconfigured;
  IoCounters counters_{};
  IoStatus fault_cause_ = IoStatus::kOk;
  FaultDetail last_error_{}, fault_detail_{};
  bool noted_ = false;      // the backend described the error being accounted
  IoStatus last_read_ = IoStatus::kOk;  // what the last read reported (latched conditions count once)
  bool link_lost_ = false;
  Plausibility plausibility_{};
  std::array<double, kMaxJoints> q_ref_{};  // last plausible reading
  std::int64_t q_ref_ns_ = 0;               // its time (0: none yet)
  std::uint32_t glitch_bucket_ = 0;         // glitches × glitch_leak_reads, drained by one per good read
};

}  // namespace lancet::device
