#pragma once
// The `usb` backend: a haptic arm that streams one interrupt report each way per tick over
// libusb-1.0 (report layout: [bus.usb] in hw_configs/README.md).
//
//   configure()  fresh libusb context, find VID:PID, check both endpoints exist as interrupt
//                endpoints of the configured direction, open, detach a kernel driver (usbhid) if
//                one is bound, claim the interface, allocate both transfers (their buffers are
//                allocated once, at create()), and wait up to 200 ms for one well-formed IN report.
//   activate()   (a fault reset report when the status names a fault,) one OUT report with zero
//                setpoints and enable `on`, then IN reports until the status bits settle (ready,
//                enabled, no fault; ≤ 200 ms, else disabled again with the bits named).
//   read()       one interrupt IN transfer of in_size bytes → counts (scale · raw + bias), q, q̇,
//                buttons, status (also while inactive: the interface stays claimed from
//                configure() on).
//   write()      τ → motor current (clamped to the actuator's peak current) → setpoint as current
//                (A) or motor torque (N·m), raw = (physical − bias) / scale (clamped to the
//                field's type), enable `on`, heartbeat + 1; one interrupt OUT transfer.
//   deactivate() zero setpoints, enable `off` (the interface stays claimed for read(); it is
//                released, and a detached kernel driver re-attached, when the UsbArm is destroyed).
//   rearm()      reopen the device if it went away (it may come back at a new bus address) or
//                the bus failed, re-claim; a fault-reset report, enable, wait for the status.
//   reconnect()  (fault only) reopen the device wherever it is now and send zero setpoints with
//                enable `off`: the drives stay off until rearm().
//
// Every OUT report carries the heartbeat field (when the layout has one), one more than the last:
// the firmware's keep-alive, which makes the arm torque-free when it stops changing for the
// device's watchdog time (bus.usb.drive_watchdog_ms).
//
// IoStatus from libusb: a transfer timeout → kTimeout; LIBUSB_ERROR_NO_DEVICE, LIBUSB_ERROR_IO, or
// a stalled endpoint whose halt cannot be cleared → kDisconnected (trips kFault at once); a short
// report, a wrong report id, an overflow or a stall that was cleared → kProtocolError; while the
// drives are enabled, the status' named bits (fault, e-stop, comm_lost; not ready, not enabled) →
// kDeviceFault (the report's values are still delivered, with the status word). On any other error
// `out` is left untouched: no value from a bad report is used. Every error is described with
// note_error(): the bus address, the endpoint and what happened.
//
// Encoder counts are unwrapped across the field's range (a narrow incremental counter that wraps
// keeps q continuous); the first report after configure(), activate() or rearm() is taken as is. q̇ is the finite
// difference of q between successful reads (CLOCK_MONOTONIC at each reply), through a first-order
// low-pass of velocity_cutoff_hz(); a gap of more than 50 ms restarts it at zero.
//
// Real-time notes: read() and write() allocate nothing in this class and throw nothing; each waits
// at most timeout + 2 × max(timeout, 1 ms): libusb's own timeout, a margin for its cancellation to
// come back, and one more after a second cancel (then the transfer is left to finish later and
// the call reports kTimeout). A timeout normally returns just after the configured time, which
// is rounded up to whole milliseconds (libusb's unit). libusb's
// Linux backend (1.0.26) callocs one URB descriptor per submitted transfer and frees it on
// completion: one malloc/free pair per read() and per write() that this class cannot avoid without
// bypassing libusb. Clearing a stalled endpoint is a synchronous control request (kernel timeout
// 5 s); stalls do not happen in normal operation.
//
// Not thread-safe: one thread drives the lifecycle and the I/O (libusb events are handled inside
// read() and write()).

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "arm/arm_config.hpp"
#include "device/device.hpp"
#include "device/joint_signals.hpp"

struct libusb_context;
struct libusb_device_handle;
struct libusb_transfer;

namespace lancet::device {

class UsbArm final : public Device {
 public:
  /// Validates that the config has a [bus.usb] section and 1..kMaxJoints joints with one actuator
  /// each; opens nothing (that is configure()). kInvalid otherwise.
  [[nodiscard]] static Result<std::unique_ptr<UsbArm>> create(const arm::ArmConfig& config, FaultPolicy policy = {});
  ~UsbArm() override;

  [[nodiscard]] int joint_count() const noexcept override { return n_; }
  [[nodiscard]] const arm::UsbBusConfig& bus() const noexcept { return usb_; }
  /// "bus 001 address 002" of the open device, empty when none is open.
  [[nodiscard]] std::string device_location() const;
  /// The transfer timeout (s): bus.usb.timeout_ms, rounded up to whole ms, until set_timeout().
  [[nodiscard]] double timeout() const noexcept { return static_cast<double>(timeout_ns_) * 1e-9; }
  /// Bounds every transfer from the next one on by `seconds` (> 0 and finite, else ignored;
  /// rounded up to whole ms). For tools and tests (a short timeout while a reply is withheld on
  /// purpose, a generous one otherwise); not to be called while another thread drives the arm.
  void set_timeout(double seconds) noexcept;
  /// Cutoff of the velocity low-pass (Hz, > 0; default 200). Not real-time: call while inactive.
  void set_velocity_cutoff_hz(double hz) noexcept;
  [[nodiscard]] double velocity_cutoff_hz() const noexcept { return velocity_.cutoff_hz(); }

  /// Transfer bookkeeping for diagnostics and tests (updated by every transfer, not real-time
  /// safe to read from another thread). cancelled_late counts transfers that libusb's own timeout
  /// did not bring back within the margin (then cancelled again and left to finish later).
  struct TransferStats {
    std::uint64_t submitted = 0, completed = 0, cancelled_late = 0, clear_halts = 0;
  };
  [[nodiscard]] const TransferStats& transfer_stats() const noexcept { return stats_; }

 protected:
  Result<void> on_configure() override;
  Result<void> on_activate() override;
  Result<void> on_deactivate() override;
  Result<void> on_rearm() override;
  Result<void> on_reconnect() override;
  IoStatus on_read(JointState& out) noexcept override;
  IoStatus on_write(const JointCommand& cmd) noexcept override;

 private:
  /// One preallocated transfer and what its callback reported.
  struct Slot {
    libusb_transfer* transfer = nullptr;
    std::vector<std::uint8_t> buffer;  ///< sized once in the constructor
    int completed = 0;                 ///< set by the callback (libusb's completion flag)
    bool in_flight = false;            ///< submitted and not yet called back
    int status = 0;                    ///< libusb_transfer_status of the last completion
    int actual_length = 0;
    std::int64_t done_ns = 0;          ///< CLOCK_MONOTONIC when the callback ran
  };

  UsbArm(const arm::ArmConfig& config, FaultPolicy policy);

  Result<void> open_and_claim();   // find, open, detach, claim, check endpoints, bind the transfers
  Result<void> reopen();           // close, fresh libusb context, open_and_claim()
  void close_device() noexcept;  // cancel what is in flight, release, close (context kept)
  Result<void> send_report(std::uint32_t enable_word, bool reset, const char* what);  // zero setpoints; not real-time
  Result<void> read_report(const std::string& what);  // one well-formed IN report; not real-time
  Result<void> enable_drives(const std::string& step, bool always_reset);
  [[nodiscard]] std::uint32_t status_in_report() const noexcept;  // of the last IN report
  IoStatus transfer(Slot& slot, unsigned char endpoint) noexcept;  // submit and wait, bounded
  IoStatus finish_in_flight(Slot& slot) noexcept;                   // drain a late completion
  void pump_until(Slot& slot, std::int64_t deadline_ns) noexcept;
  IoStatus status_from_completion(Slot& slot, unsigned char endpoint) noexcept;
  IoStatus status_from_error(int libusb_error) noexcept;
  IoStatus io_error(IoStatus s, unsigned char endpoint, const char* what) noexcept;  // note_error, then s
  void encode_out(const JointCommand* cmd, std::uint32_t enable_word, bool reset) noexcept;
  void reset_estimator() noexcept;

  arm::ArmConfig config_;
  arm::UsbBusConfig usb_;
  int n_ = 0;
  unsigned int timeout_ms_ = 2;   ///< libusb transfer timeout (≥ 1: 0 would mean none)
  std::int64_t timeout_ns_ = 2'000'000;

  libusb_context* ctx_ = nullptr;
  libusb_device_handle* handle_ = nullptr;
  bool claimed_ = false;
  bool detached_driver_ = false;  ///< we detached a kernel driver: re-attach it when done
  bool lost_ = false;             ///< the device went away: only a reopen helps
  std::uint8_t bus_number_ = 0, address_ = 0;
  Slot in_, out_;
  std::uint32_t enable_word_ = 0;  ///< what the enable field of every OUT report says (on / off)
  std::uint32_t heartbeat_ = 0;    ///< the heartbeat field of the last OUT report
  bool drives_on_ = false;         ///< enabled by activate() / rearm(): the status bits are enforced
  const char* detail_ = "";        ///< what the last transfer error was, in words (a static string)

  // Estimator state (per joint).
  bool have_sample_ = false;  ///< raw_ continues from a previous report (unwrapping)
  std::array<std::int64_t, kMaxJoints> last_raw_{}, raw_{};  ///< the field's last value; unwrapped
  /// 200 Hz low-pass; after a 50 ms gap (a pause, a fault) it restarts at zero.
  VelocityEstimator velocity_{200.0, 50'000'000};

  TransferStats stats_{};
};

}  // namespace lancet::device
