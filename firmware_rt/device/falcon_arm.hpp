#pragma once
// The `falcon` backend: a Novint Falcon (3-DOF delta arm, FTDI USB-serial chip 0403:cb48) over
// libusb, through our own FTDI layer (device/ftdi.hpp) and the Falcon's protocol
// (device/falcon_protocol.hpp). Config: [bus.falcon] in hw_configs/README.md; the shipped one is
// hw_configs/novint_falcon.toml (kinematics model = "delta").
//
//   configure()  open the index-th 0403:cb48, reset the chip, UART mode, 8N1, no flow control;
//                normal mode (1.5 Mbaud, latency 1 ms); when upload = "when_needed" and a zero
//                command is answered, the firmware is already running; otherwise the loader
//                handshake, the firmware upload with each chunk's echo checked, normal mode again,
//                and a zero command that must be answered. Then homing mode on (red LED) until the
//                three home switches have been passed. Every step's failure is named: no device,
//                another product id, the loader's silence or wrong answer, an echo mismatch (which
//                byte), no reply after the upload.
//   activate()   waits (≤ homing_timeout) for the three home switches, exchanging zero commands;
//                then green LED, torque allowed. Fails naming the motors not yet homed.
//   read()       sends a zero command first when no write() has gone since the last read (the
//                Falcon answers commands only: reading while inactive still exchanges a packet),
//                then waits ≤ timeout for the reply: encoder counts (int16, unwrapped) → q, q̇,
//                grip buttons, status (homed bits 0..2, homing mode bit 3).
//   write()      τ (N·m per thigh) → motor command = direction · motor_command_per_nm · τ, rounded,
//                clamped to int16; one asynchronous bulk OUT of 16 bytes.
//   deactivate() zero commands, blue LED.
//   a fault      (the Device base trips it) zero commands, red LED.
//   reconnect()  (fault only) reopen the Falcon wherever it is now; a replugged Falcon has lost
//                its firmware, so this uploads it again; zero commands.
//   rearm()      reconnect when the link is gone, then activate.
//
// IoStatus: no reply by the timeout → kTimeout (a late reply is counted stale and skipped); a
// packet that fails to decode (framing or nibble) → kProtocolError (the scan resynchronises on the
// next '<'); the device gone (NO_DEVICE) → kDisconnected. Each is described with note_error().
// When homing changes a motor's counts from relative to absolute, the encoder plausibility check
// starts again (that jump is not a glitch).
//
// Real-time notes: read() and write() allocate nothing in this class and throw nothing; libusb
// allocates one URB descriptor per submitted transfer (device/ftdi.hpp). Not thread-safe: one
// thread drives the lifecycle and the I/O.

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "arm/arm_config.hpp"
#include "device/device.hpp"
#include "device/falcon_protocol.hpp"
#include "device/joint_signals.hpp"

namespace lancet::device {

namespace ftdi {
class Port;
}

class FalconArm final : public Device {
 public:
  /// Validates that the config has a [bus.falcon] section and three joints with an actuator each;
  /// opens nothing (that is configure()). kInvalid otherwise.
  [[nodiscard]] static Result<std::unique_ptr<FalconArm>> create(const arm::ArmConfig& config, FaultPolicy policy = {});
  ~FalconArm() override;

  [[nodiscard]] int joint_count() const noexcept override { return 3; }
  /// "bus 001 address 002" of the open Falcon, empty when none is open.
  [[nodiscard]] std::string device_location() const;
  /// Bounds every exchange from the next one on by `seconds` (> 0 and finite, else ignored). For
  /// tools and tests; not to be called while another thread drives the arm.
  void set_timeout(double seconds) noexcept;
  /// The homed bits of the last reply (bit i: motor i passed its home switch).
  [[nodiscard]] std::uint8_t homed() const noexcept { return last_.homed; }

  struct Stats {
    std::uint64_t uploads = 0;           ///< firmware uploads done
    std::uint64_t found_running = 0;     ///< configure/reconnect found the firmware already running
    std::uint64_t commands = 0, replies = 0, stale_replies = 0, malformed = 0;
  };
  [[nodiscard]] const Stats& stats() const noexcept { return stats_; }
  /// The FTDI layer's own figures (for benches and tests); nullptr while nothing is open.
  [[nodiscard]] const ftdi::Port* port() const noexcept { return port_.get(); }

 protected:
  Result<void> on_configure() override;
  Result<void> on_activate() override;
  Result<void> on_deactivate() override;
  Result<void> on_rearm() override;
  Result<void> on_reconnect() override;
  IoStatus on_read(JointState& out) noexcept override;
  IoStatus on_write(const JointCommand& cmd) noexcept override;
  void on_fault() noexcept override;  // torque off, red LED from the next command on

 private:
  FalconArm(const arm::ArmConfig& config, FaultPolicy policy);

  Result<void> bring_up();                   // open, chip setup, firmware (upload when needed), homing mode
  Result<void> normal_mode();                // latency 1 ms, 1.5 Mbaud, purge, stream
  Result<bool> firmware_answers(double window_s);  // a zero command answered within the window
  Result<void> upload_firmware();            // loader handshake, chunks with echo, normal mode, answered
  Result<void> loader_handshake();
  /// Zero commands, each answered or given up on, until done() or the window passes (kNotReady,
  /// saying `what`); an error when the Falcon goes away. Not real-time.
  Result<void> exchange_until(double window_s, const std::function<bool()>& done, const char* what);
  IoStatus send(const falcon::Command& c) noexcept;
  IoStatus await_reply(std::int64_t deadline_ns) noexcept;
  void decode(JointState& out) noexcept;
  [[nodiscard]] falcon::Command zero_command() const noexcept;
  std::string error_prefix() const;

  arm::ArmConfig config_;
  arm::FalconBusConfig bus_;
  std::string firmware_path_;
  std::int64_t timeout_ns_ = 2'000'000;
  std::unique_ptr<ftdi::Port> port_;

  falcon::Command sent_{};
  falcon::Reply last_{};
  bool have_reply_ = false;
  bool written_since_read_ = false;
  bool torque_on_ = false;
  std::uint8_t leds_ = falcon::kLedRed;
  std::int64_t reply_ns_ = 0;

  // Encoder unwrapping (int16 on the wire) and the velocity estimate.
  bool have_sample_ = false;
  std::uint8_t homed_seen_ = 0;
  std::array<std::int64_t, 3> raw_{};
  std::array<std::int16_t, 3> last_wire_{};
  VelocityEstimator velocity_{200.0, 50'000'000};

  Stats stats_{};
};

}  // namespace lancet::device
