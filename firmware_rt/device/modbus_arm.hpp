#pragma once
// ModbusArm: a haptic arm whose drives sit behind a Modbus TCP server or on a Modbus RTU serial
// line, driven through libmodbus with the register map of the arm's config ([bus.modbus] in
// hw_configs/*.toml; schema and the status / control bits in hw_configs/README.md).
//
//   configure()  create the libmodbus context (unit id, response timeout), connect / open the
//                serial device, read the encoder registers once: an error names the endpoint
//                (host:port or device) and what failed
//   activate()   (reconnect if the link broke while inactive,) zero the current commands, then
//                set the control register's enable bit (bit 0)
//   read()       encoders (+ status, buttons) in as few read transactions as the map allows;
//                q from the counts, qd a finite difference through a 100 Hz first-order low-pass;
//                status bit 0 (drive fault) → kDeviceFault (the data is still filled in)
//   write()      joint torques → motor currents (clamped at ± peak current) → registers by the
//                field's lsb (clamped to the type's range), one write-multiple per contiguous
//                run, plus the heartbeat register (counts up each write) when the map has one
//   deactivate() zero the current commands, clear the enable bit
//   rearm()      reconnect if the link broke (over TCP also after timeouts and garbled replies, so
//                late bytes cannot poison the new stream), zero the currents, write the fault-reset
//                bit (bit 1), enable again, and read until the drive fault clears (≤ 100 ms)
//
// read() and write() are real-time safe: they never allocate (checked with the malloc guard,
// libmodbus included) or throw, and each libmodbus transaction is bounded by the config's
// response_timeout (the byte timeout is off, so the whole reply must arrive within it). After an
// error the next transaction first flushes whatever stale bytes have arrived. Reads and writes are
// planned once at create(): registers of the same table that are contiguous are merged into one
// transaction (at most 125 registers per read, 123 per write). libmodbus errno → IoStatus as in
// modbus::io_status_from_errno. Not thread-safe: one thread drives a ModbusArm.

#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "arm/arm_config.hpp"
#include "device/device.hpp"
#include "device/joint_signals.hpp"

struct _modbus;  // libmodbus's context (modbus_t), kept out of this header

namespace lancet::device {

// ---------------------------------------------------------------------------------------------
// Register codec and error mapping (shared with lancet-armsim). All real-time safe.

namespace modbus {

/// Bits of the map's `status` register the driver interprets.
inline constexpr std::uint32_t kStatusDriveFault = 1u << 0;  ///< the drive has faulted: read() → kDeviceFault
inline constexpr std::uint32_t kStatusEnabled = 1u << 1;     ///< the drives are enabled (informational)
/// Bits of the map's `control` register the driver writes.
inline constexpr std::uint32_t kControlEnable = 1u << 0;      ///< drives on (level: held while active)
inline constexpr std::uint32_t kControlFaultReset = 1u << 1;  ///< clear a latched drive fault (pulsed by rearm)

/// Registers one value of the type takes: 1 for u16/i16, 2 for u32/i32 (0 for 8-bit types, which
/// Modbus maps do not use).
[[nodiscard]] int register_count(arm::FieldType type) noexcept;

/// The value of `type` stored in regs[0, register_count(type)); 32-bit values in the given word
/// order, signed types sign-extended. Precondition: regs is long enough (asserted).
[[nodiscard]] std::int64_t decode_registers(arm::FieldType type, bool high_word_first,
                                            std::span<const std::uint16_t> regs) noexcept;

/// Writes v into regs[0, register_count(type)), clamped first to the type's range; returns
/// whether v had to be clamped. Precondition: regs is long enough (asserted).
bool encode_registers(arm::FieldType type, bool high_word_first, std::int64_t v, std::span<std::uint16_t> regs) noexcept;

/// What a libmodbus errno means for the device: ETIMEDOUT → kTimeout, EMBBADCRC → kCrcError,
/// ECONNRESET / EPIPE / ECONNREFUSED / EBADF / ENOTCONN / EIO (and other link errors) →
/// kDisconnected, EMBBADDATA / EMBBADEXC / EMBMDATA / EMBBADSLAVE / Modbus exception codes
/// (EMBX*) and anything else → kProtocolError. 0 maps to kOk.
[[nodiscard]] IoStatus io_status_from_errno(int err) noexcept;

/// One libmodbus transaction: `count` registers of one table from `address`, kept at
/// buffer[offset, offset + count) in the caller's register buffer.
struct RegisterBlock {
  arm::RegisterTable table = arm::RegisterTable::kInput;
  std::uint16_t address = 0;
  std::uint16_t count = 0;
  std::uint16_t offset = 0;
};

/// A register range of one entry of the map (address, registers).
struct RegisterSpan {
  arm::RegisterTable table = arm::RegisterTable::kInput;
  std::uint16_t address = 0;
  std::uint16_t count = 0;
};

/// Merges register ranges into as few blocks as possible: ranges of the same table that touch
/// (one ends where the next begins) join, up to `max_registers` per block. Blocks come out sorted
/// by table, then address, with offsets packed back to back. Allocates (configure time).
[[nodiscard]] std::vector<RegisterBlock> plan_blocks(std::vector<RegisterSpan> spans, int max_registers);

}  // namespace modbus

// ---------------------------------------------------------------------------------------------

class ModbusArm final : public Device {
 public:
  /// From a loaded config with a [bus.modbus] section (kInvalid otherwise, or when a register
  /// entry the driver needs is malformed). Makes no connection yet: configure() does.
  [[nodiscard]] static Result<std::unique_ptr<ModbusArm>> create(const arm::ArmConfig& config, FaultPolicy policy = {});
  ~ModbusArm() override;

  [[nodiscard]] int joint_count() const noexcept override { return n_; }
  /// Where the arm is: "127.0.0.1:1502" (tcp) or "/dev/ttyUSB0" (rtu), as used in error messages.
  [[nodiscard]] const std::string& endpoint() const noexcept { return endpoint_; }
  /// libmodbus transactions one read() / write() makes (after merging contiguous registers).
  [[nodiscard]] int read_transactions() const noexcept { return static_cast<int>(read_blocks_.size()); }
  [[nodiscard]] int write_transactions() const noexcept { return static_cast<int>(write_blocks_.size()); }
  /// errno of the last failed libmodbus call (0 when none failed yet).
  [[nodiscard]] int last_errno() const noexcept { return last_errno_; }
  /// Current commands clamped at ± the actuator's peak current, or to the register type's range.
  [[nodiscard]] std::uint64_t current_clamps() const noexcept { return current_clamps_; }
  /// The last current command sent per joint (A), after the clamps and the lsb quantisation.
  [[nodiscard]] double commanded_current(int j) const noexcept { return sent_current_[static_cast<std::size_t>(j)]; }

 protected:
  Outcome on_configure() override;
  Outcome on_activate() override;
  Outcome on_deactivate() override;
  Outcome on_rearm() override;
  IoStatus on_read(JointState& out) noexcept override;
  IoStatus on_write(const JointCommand& cmd) noexcept override;

 private:
  struct ContextDeleter {
    void operator()(::_modbus* ctx) const noexcept;
  };
  /// Where one map entry lives in the read or write buffer.
  struct Slot {
    bool present = false;
    arm::FieldType type = arm::FieldType::kU16;
    std::uint16_t offset = 0;  // into rbuf_ / wbuf_
  };

  ModbusArm(const arm::ArmConfig& config, FaultPolicy policy);

  [[nodiscard]] static bool bus_is_tcp(arm::ModbusTransport t) noexcept;

  // Configure-time steps (may allocate); failures name the endpoint and what failed.
  Outcome connect(const std::string& what);
  Outcome reconnect_if_needed(const std::string& step);
  Outcome fail(const std::string& what, int err) const;
  Outcome write_control(std::uint32_t word, const std::string& what);
  Outcome write_zero_current(const std::string& what);
  Outcome check_read(const std::string& what);

  // Real-time path.
  IoStatus io_error(int err) noexcept;
  IoStatus read_blocks() noexcept;
  IoStatus write_blocks() noexcept;
  void encode_currents(const JointCommand& cmd) noexcept;
  void reset_velocity() noexcept;

  arm::ArmConfig config_;
  arm::ModbusBusConfig bus_;
  std::string endpoint_;
  int n_ = 0;
  std::unique_ptr<::_modbus, ContextDeleter> ctx_;

  std::vector<modbus::RegisterBlock> read_blocks_, write_blocks_;
  std::vector<std::uint16_t> rbuf_, wbuf_;  // sized at create(), never resized
  Slot encoders_, status_, buttons_;        // in rbuf_
  Slot currents_, heartbeat_, control_;     // in wbuf_ (control_: only when it merges with the others)

  std::uint32_t control_word_ = 0;
  std::uint32_t heartbeat_count_ = 0;
  bool need_flush_ = false;   // an error may have left stale bytes: flush before the next request
  bool link_broken_ = false;  // the last error was a disconnect: rearm reconnects
  int last_errno_ = 0;
  std::uint64_t current_clamps_ = 0;
  std::array<double, kMaxJoints> sent_current_{};

  // Velocity estimate: finite difference through a first-order low-pass.
  VelocityEstimator velocity_{100.0};  ///< a light low-pass (100 Hz) on the finite difference
};

}  // namespace lancet::device
