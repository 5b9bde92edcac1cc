#pragma once
// ModbusArm: a haptic arm whose drives sit behind a Modbus TCP server or on a Modbus RTU serial
// line, with the register map of the arm's config ([bus.modbus] in hw_configs/*.toml; the schema,
// with an example map of a foreign device, in hw_configs/README.md).
//
//   configure()  create the libmodbus context (unit id), connect / open the serial device, read
//                the encoder registers once: an error names the endpoint (host:port or device)
//                and what failed. No stale byte is left behind: the receive state starts empty.
//   activate()   (reconnect if the link broke while inactive,) write the drive watchdog time
//                (watchdog_timeout), zero the setpoints, reset a fault the status reports, write
//                enable `on`, and read until the status bits settle (ready, enabled, no fault,
//                ≤ 200 ms; otherwise the drives are switched off again and the bits are named)
//   read()       encoders (+ status, buttons) in as few read transactions as the map allows;
//                counts = scale · raw + bias, q from the counts, qd a finite difference through a
//                100 Hz first-order low-pass; the status' named bits (fault, e-stop, comm_lost,
//                and while enabled: not ready, not enabled) → kDeviceFault, named in the fault
//                detail (the data is still filled in)
//   write()      joint torques → motor currents (clamped at ± peak current) → setpoint, as current
//                (A) or motor torque (N·m, current × torque constant), raw = (physical − bias) /
//                scale (rounded and clamped to the type's range); one write-multiple per
//                contiguous run, plus the heartbeat register (counts up on each write: the
//                drives' watchdog) and the enable register where it costs no extra transaction
//   deactivate() zero the setpoints, write enable `off`
//   rearm()      reconnect if the link broke (or the TCP stream was garbled), zero the setpoints,
//                write the fault-reset value (then 0 when it has its own register), enable again,
//                and read until the status clears (≤ 200 ms)
//   reconnect()  (fault only) close and reopen the link (TCP connect / serial reopen), zero the
//                setpoints and write enable `off`: the drives stay disabled until rearm()
//
// Late replies. The driver remembers the requests that timed out and are still owed a reply (up
// to kMaxLateRequests, oldest first). Over TCP the driver frames Modbus itself on libmodbus's
// socket: every request has its own MBAP transaction id, so a reply that arrives after its request
// timed out is recognised by its id (in whatever order the server answers), thrown away and
// counted (IoCounters::stale_replies), never taken for the answer to a later request; a frame cut
// by a timeout is finished on the next transaction. Over RTU (no id) the line keeps order: a
// reply answers the oldest owed request it fits (function code, byte count; a write's echo also
// its address and count). Those owed replies are thrown away and counted as they come, however
// many timed out in a row; a reply that fits no owed request but the current one is the current
// one's, and the owed requests before it are taken as never answered. When an owed request and
// the current one look alike (same function and length) the reply is taken for the owed one: at
// worst the current request times out (counted), never is a stale reading taken for a fresh one.
// Only garbled replies (bad framing, CRC) flush the line; opening the link (configure, reconnect,
// a rearm or activate that reconnects) starts with nothing owed.
//
// read() and write() are real-time safe: they never allocate (checked with the malloc guard,
// libmodbus included) or throw, and each transaction is bounded by the config's response_timeout
// (the whole reply must arrive within it). Every error they return is described with note_error():
// the endpoint, the registers, and the meaning (timeout, exception code and its name, CRC, the
// status bits). Reads and writes are planned once at create(): values of the same table whose
// registers touch are merged into one transaction (at most 125 registers per read, 123 per write);
// values at separate addresses (`address = [a0, a1, …]`) take more. Not thread-safe: one thread
// drives a ModbusArm.

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

/// How one value lies in its registers.
struct Layout {
  arm::FieldType type = arm::FieldType::kU16;
  bool high_word_first = true;  ///< 32-bit values: the register holding the high half comes first
  bool swap_bytes = false;      ///< each register's two bytes are swapped (byte_order = "little")
};
/// The layout of a map entry.
[[nodiscard]] Layout layout_of(const arm::RegisterField& f) noexcept;

/// Registers one value of the type takes: 1 for u16/i16, 2 for u32/i32/f32 (0 for 8-bit types,
/// which Modbus maps do not use).
[[nodiscard]] int register_count(arm::FieldType type) noexcept;

/// The raw value in regs[0, register_count): integers exactly (signed ones sign-extended), f32 as
/// its float. Precondition: regs is long enough (asserted).
[[nodiscard]] double decode_value(const Layout& layout, std::span<const std::uint16_t> regs) noexcept;
/// The raw bits as a word (u16/u32: the value; other types: their bit pattern, low 32 bits).
[[nodiscard]] std::uint32_t decode_word(const Layout& layout, std::span<const std::uint16_t> regs) noexcept;
/// Writes raw into regs: integer types rounded to the nearest integer and clamped to the type's
/// range (NaN: 0), f32 as the nearest float. Returns the value stored; `clamped` (optional) says
/// whether it had to clamp. Precondition: regs is long enough (asserted).
double encode_value(const Layout& layout, double raw, std::span<std::uint16_t> regs, bool* clamped = nullptr) noexcept;
/// Writes a word (u16: its low 16 bits) into regs.
void encode_word(const Layout& layout, std::uint32_t word, std::span<std::uint16_t> regs) noexcept;

/// What a libmodbus errno means for the device: ETIMEDOUT → kTimeout, EMBBADCRC → kCrcError,
/// ECONNRESET / EPIPE / ECONNREFUSED / EBADF / ENOTCONN / EIO (and other link errors) →
/// kDisconnected, EMBBADDATA / EMBBADEXC / EMBMDATA / EMBBADSLAVE / Modbus exception codes
/// (EMBX*) and anything else → kProtocolError. 0 maps to kOk.
[[nodiscard]] IoStatus io_status_from_errno(int err) noexcept;

/// The name of a Modbus exception code (0x02 → "illegal data address"); "unknown exception" else.
[[nodiscard]] const char* exception_name(int code) noexcept;

/// One transaction: `count` registers of one table from `address`, kept at
/// buffer[offset, offset + count) in the caller's register buffer.
struct RegisterBlock {
  arm::RegisterTable table = arm::RegisterTable::kInput;
  std::uint16_t address = 0;
  std::uint16_t count = 0;
  std::uint16_t offset = 0;
};

/// A register range of one value of the map (address, registers).
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
  /// Transactions one read() / write() makes (after merging registers that touch).
  [[nodiscard]] int read_transactions() const noexcept { return static_cast<int>(read_blocks_.size()); }
  [[nodiscard]] int write_transactions() const noexcept { return static_cast<int>(write_blocks_.size()); }
  /// errno of the last failed transaction (0 when none failed yet; a Modbus exception is
  /// MODBUS_ENOBASE + its code, as libmodbus numbers them).
  [[nodiscard]] int last_errno() const noexcept { return last_errno_; }
  /// Setpoints clamped at ± the actuator's peak current, or to the register type's range.
  [[nodiscard]] std::uint64_t current_clamps() const noexcept { return current_clamps_; }
  /// The last motor current sent per joint (A), after the clamps and the register's quantisation
  /// (for a torque setpoint: the torque sent / the torque constant).
  [[nodiscard]] double commanded_current(int j) const noexcept { return sent_current_[static_cast<std::size_t>(j)]; }
  /// The response timeout (s): the config's response_timeout_ms until set_response_timeout().
  [[nodiscard]] double response_timeout() const noexcept { return static_cast<double>(timeout_ns_) * 1e-9; }
  /// Bounds every transaction from the next one on by `seconds` (> 0 and finite, else ignored; at
  /// least 1 µs). For tools and tests (a short timeout while a reply is withheld on purpose, a
  /// generous one otherwise); not to be called while another thread drives the arm.
  void set_response_timeout(double seconds) noexcept;
  /// What stamps each reading for the velocity estimate: CLOCK_MONOTONIC (ns) by default; nullptr
  /// restores it. Tests drive their own clock to get exact finite differences.
  using Clock = std::int64_t (*)() noexcept;
  void set_clock(Clock clock) noexcept;
  /// How many timed-out requests whose replies may still come are remembered (oldest first).
  /// Beyond that the oldest is forgotten: over TCP its reply is still known by its id if no
  /// request was answered since (else it is a protocol error); over RTU it could be taken for a
  /// later request's if it came after kMaxLateRequests later requests timed out too (the default
  /// fault policy trips long before; rearm() starts afresh).
  static constexpr std::size_t kMaxLateRequests = 16;

 protected:
  Result<void> on_configure() override;
  Result<void> on_activate() override;
  Result<void> on_deactivate() override;
  Result<void> on_rearm() override;
  Result<void> on_reconnect() override;
  IoStatus on_read(JointState& out) noexcept override;
  IoStatus on_write(const JointCommand& cmd) noexcept override;

 private:
  struct ContextDeleter {
    void operator()(::_modbus* ctx) const noexcept;
  };
  /// Where one value lives in the read or write buffer.
  struct Slot {
    bool present = false;
    modbus::Layout layout;
    std::uint16_t offset = 0;  // into rbuf_ / wbuf_
  };
  /// What identifies a request's reply: its transaction id (TCP), or on a line without ids (RTU)
  /// its function, address and count.
  struct Signature {
    bool valid = false;
    std::uint8_t function = 0;
    std::uint16_t address = 0, count = 0;
    std::uint16_t tid = 0;
  };

  ModbusArm(const arm::ArmConfig& config, FaultPolicy policy);

  [[nodiscard]] bool tcp() const noexcept { return bus_.transport == arm::ModbusTransport::kTcp; }

  // Configure-time steps (may allocate); failures name the endpoint and what failed.
  Result<void> open_link(const std::string& what);
  Result<void> reopen_link(const std::string& what);
  Result<void> fail(const std::string& what) const;
  Result<void> check(IoStatus s, const std::string& what) const;
  Result<void> write_word(const arm::RegisterField& f, std::uint32_t word, const std::string& what);
  Result<void> write_enable(std::uint32_t word, const std::string& what);
  Result<void> write_zero_setpoints(const std::string& what);
  Result<void> enable_drives(const std::string& step, bool always_reset);
  Result<void> read_status(const std::string& what, std::uint32_t& word);
  void reset_stream() noexcept;

  // Real-time path.
  IoStatus transact(std::uint8_t function, std::uint16_t address, std::uint16_t count, const std::uint16_t* src,
                    std::uint16_t* dst, arm::RegisterTable table) noexcept;
  IoStatus tcp_transact(std::size_t pdu_len, std::int64_t deadline_ns) noexcept;
  IoStatus tcp_receive(int fd, std::int64_t deadline_ns) noexcept;
  IoStatus rtu_transact(std::size_t pdu_len, std::int64_t deadline_ns) noexcept;
  IoStatus check_reply(const std::uint8_t* pdu, std::size_t len) noexcept;
  bool reply_matches(const Signature& s, const std::uint8_t* pdu, std::size_t len) const noexcept;
  void push_late(const Signature& s) noexcept;
  void pop_late(std::size_t k) noexcept;
  void erase_late(std::size_t i) noexcept;
  [[nodiscard]] const Signature& late_at(std::size_t i) const noexcept { return late_[(late_first_ + i) % kMaxLateRequests]; }
  void flush_input() noexcept;
  IoStatus link_error(int err, const char* what) noexcept;
  IoStatus error(IoStatus s, std::uint32_t code, const char* fmt, ...) noexcept __attribute__((format(printf, 4, 5)));
  IoStatus read_blocks() noexcept;
  IoStatus write_blocks() noexcept;
  void encode_setpoints(const JointCommand& cmd) noexcept;
  void put_enable_word() noexcept;

  arm::ArmConfig config_;
  arm::ModbusBusConfig bus_;
  std::string endpoint_;
  int n_ = 0;
  std::int64_t timeout_ns_ = 5'000'000;
  std::unique_ptr<::_modbus, ContextDeleter> ctx_;

  std::vector<modbus::RegisterBlock> read_blocks_, write_blocks_;
  std::vector<std::uint16_t> rbuf_, wbuf_;                // sized at create(), never resized
  std::array<Slot, kMaxJoints> encoders_{}, setpoints_{};  // in rbuf_ / wbuf_, one per joint
  Slot status_, buttons_;                                 // in rbuf_
  Slot heartbeat_, enable_;                               // in wbuf_ (enable_: only when it merges with the others)
  std::array<double, kMaxJoints> q_per_count_{};          // rad (m) per count, for fractional counts

  // The transaction in progress (real-time path: fixed buffers).
  std::uint8_t function_ = 0;
  std::uint16_t address_ = 0, count_ = 0;
  arm::RegisterTable table_ = arm::RegisterTable::kInput;
  std::uint16_t* dst_ = nullptr;
  std::array<std::uint8_t, 264> tx_{};  // TCP: MBAP header + PDU; RTU: unit + PDU (libmodbus adds the CRC)
  std::array<std::uint8_t, 264> rx_{};  // TCP: one frame, possibly cut by a timeout; RTU: one ADU
  std::size_t rx_len_ = 0;              // TCP: bytes of the current frame received so far
  std::uint16_t tid_ = 0;               // TCP: transaction id of the last request sent
  std::uint16_t tid_done_ = 0;          // TCP: the last id whose reply came; ids after it are late
  std::array<Signature, kMaxLateRequests> late_{};  // requests owed a reply (a ring, oldest at late_first_)
  std::size_t late_first_ = 0, late_count_ = 0;
  Clock clock_ = nullptr;               // stamps readings for the velocity estimate (nullptr: monotonic_ns)

  std::uint32_t enable_word_ = 0;
  std::uint32_t heartbeat_count_ = 0;
  bool drives_on_ = false;   // the driver enabled the drives: ready / enabled bits are required
  bool need_flush_ = false;  // garbled input: drop what is buffered before the next request
  bool link_broken_ = false; // the last error was a disconnect (or an unframeable TCP stream): reopen
  int last_errno_ = 0;
  std::uint64_t current_clamps_ = 0;
  std::array<double, kMaxJoints> sent_current_{};

  VelocityEstimator velocity_{100.0};  ///< a light low-pass (100 Hz) on the finite difference
};

}  // namespace lancet::device
