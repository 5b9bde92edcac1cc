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
//
// read() and write() never throw, allocate or block past the backend's timeout; what went wrong
// is a counted IoStatus. Any error counts; `max_consecutive_errors` of them with no good read in
// between, or one disconnect or device fault, put the device in kFault: from then on write() sends zero torque (best effort) and
// returns kFault until someone calls rearm() — a fault never clears by itself.
//
// Backends implement the on_* hooks; the state machine, counters and fault policy live here.

#include <array>
#include <cstdint>
#include <optional>
#include <string>

#include "lancet/shared_model/result.hpp"

namespace lancet::device {

inline constexpr int kMaxJoints = 8;

enum class Lifecycle : std::uint8_t { kUnconfigured, kInactive, kActive, kFault };

enum class IoStatus : std::uint8_t {
  kOk = 0,
  kTimeout,        ///< no reply within the backend's timeout
  kCrcError,       ///< a reply arrived corrupted
  kProtocolError,  ///< a reply arrived but made no sense (exception code, wrong length, bad EMCY…)
  kDisconnected,   ///< the bus or the device went away
  kDeviceFault,    ///< the device reports a fault of its own (drive fault bit, EMCY)
  kNotActive,      ///< read/write outside the active state
  kFault,          ///< the device is in kFault: zero torque until rearm()
};

[[nodiscard]] const char* to_string(IoStatus s) noexcept;
[[nodiscard]] const char* to_string(Lifecycle s) noexcept;

/// What the bus has done so far (real-time safe to update and to copy).
struct IoCounters {
  std::uint64_t reads = 0, writes = 0;
  std::uint64_t ok = 0;
  std::uint64_t timeouts = 0, crc_errors = 0, protocol_errors = 0, disconnects = 0, device_faults = 0;
  std::uint64_t faults = 0;                 ///< times the device entered kFault
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

/// Success, or the error that stopped a lifecycle step.
struct [[nodiscard]] Outcome {
  std::optional<Error> error;
  [[nodiscard]] bool ok() const noexcept { return !error; }
  static Outcome success() { return {}; }
  static Outcome failure(ErrorCode code, std::string message) { return Outcome{Error{code, std::move(message)}}; }
};

struct FaultPolicy {
  std::uint32_t max_consecutive_errors = 3;  ///< errors in a row that trip kFault (1: any error)
};

class Device {
 public:
  explicit Device(std::string name, FaultPolicy policy = {}) : name_(std::move(name)), policy_(policy) {}
  virtual ~Device() = default;
  Device(const Device&) = delete;
  Device& operator=(const Device&) = delete;

  Outcome configure();
  Outcome activate();
  Outcome deactivate();
  Outcome rearm();

  [[nodiscard]] IoStatus read(JointState& out) noexcept;
  [[nodiscard]] IoStatus write(const JointCommand& cmd) noexcept;

  [[nodiscard]] Lifecycle state() const noexcept { return state_; }
  [[nodiscard]] const IoCounters& counters() const noexcept { return counters_; }
  [[nodiscard]] const std::string& name() const noexcept { return name_; }
  /// The status that tripped the last fault (kOk if none yet).
  [[nodiscard]] IoStatus fault_cause() const noexcept { return fault_cause_; }
  [[nodiscard]] virtual int joint_count() const noexcept = 0;

 protected:
  virtual Outcome on_configure() = 0;
  virtual Outcome on_activate() = 0;
  virtual Outcome on_deactivate() = 0;  ///< must leave the drives at zero torque
  virtual Outcome on_rearm() = 0;       ///< clear bus/drive faults; the device is then activated again
  virtual IoStatus on_read(JointState& out) noexcept = 0;
  virtual IoStatus on_write(const JointCommand& cmd) noexcept = 0;

 private:
  void account(IoStatus s, std::int64_t t0_ns, bool is_read) noexcept;

  std::string name_;
  FaultPolicy policy_;
  Lifecycle state_ = Lifecycle::kUnconfigured;
  IoCounters counters_{};
  IoStatus fault_cause_ = IoStatus::kOk;
};

}  // namespace lancet::device
