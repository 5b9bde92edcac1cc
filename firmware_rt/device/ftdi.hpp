#pragma once
// An FTDI USB-serial chip (FT232BM/R class) driven directly over libusb-1.0: the vendor control
// requests, bulk transfers with the chip's two modem-status bytes stripped, and asynchronous
// transfers kept in flight so that a 1 kHz packet exchange fits in a tick. libftdi's synchronous
// reads top out near 300 exchanges per second on Linux; this does not go through it.
//
// The chip's protocol, as every open driver uses it (libftdi, Linux's ftdi_sio, libnifalcon):
//   control OUT, bmRequestType 0x40 (vendor, device), wIndex 0 (one-port chips, as the Falcon's;
//   multi-port chips, which take the port in wIndex, are not handled here)
//     0x00 reset           wValue 0 reset the port, 1 purge the receive buffer, 2 purge transmit
//     0x01 modem control   wValue = (mask << 8) | levels: DTR is bit 0, RTS bit 1
//     0x02 flow control    wIndex high byte: 0 none, 1 RTS/CTS, 2 DTR/DSR, 4 XON/XOFF
//     0x03 baud rate       wValue and wIndex carry the divisor of a 3 MHz clock (baud_setting)
//     0x04 data format     wValue = bits | parity << 8 | stop bits << 11
//     0x09 latency timer   wValue = ms (1..255) the chip holds a partly filled IN packet
//     0x0B bit mode        wValue = (mode << 8) | pin mask; mode 0 is the plain UART
//   bulk IN: every packet of up to wMaxPacketSize (64 at full speed) begins with two modem-status
//     bytes; a packet with only those two is "no data yet". The chip sends one per latency period.
//   bulk OUT: the data as it is.
//
// Setup (open, the control requests, write_all, read_exact) blocks and allocates: configure time
// only. The exchange (start_streaming, submit_write, wait_for, take) is real-time: it allocates
// nothing in this class, throws nothing, and waits at most until the deadline it is given. libusb
// 1.0.26's Linux backend callocs one URB descriptor per submitted transfer (one per write and one
// per IN packet resubmitted), which this class cannot avoid without bypassing libusb.
//
// Not thread-safe: one thread opens, configures and exchanges; libusb's events are handled inside
// wait_for() and submit_write(), where the IN transfer's callback resubmits it at once.

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>

#include "lancet/shared_model/device_codes.hpp"
#include "lancet/shared_model/result.hpp"

struct libusb_context;
struct libusb_device_handle;
struct libusb_transfer;

namespace lancet::device::ftdi {

/// The vendor requests (bRequest).
enum Request : std::uint8_t {
  kReset = 0x00,
  kModemControl = 0x01,
  kFlowControl = 0x02,
  kBaudRate = 0x03,
  kDataFormat = 0x04,
  kLatencyTimer = 0x09,
  kBitMode = 0x0B,
};
inline constexpr std::uint8_t kVendorOut = 0x40;  ///< bmRequestType of every request above
inline constexpr std::uint16_t kResetPort = 0, kPurgeRx = 1, kPurgeTx = 2;
inline constexpr std::uint16_t kDtrHigh = 0x0101, kDtrLow = 0x0100, kRtsHigh = 0x0202, kRtsLow = 0x0200;
inline constexpr std::uint16_t k8N1 = 8;  ///< 8 data bits, no parity, one stop bit
inline constexpr int kModemStatusBytes = 2;

/// What the baud-rate request carries for a rate, and the rate the chip then really runs at.
struct BaudSetting {
  std::uint16_t value = 0;
  std::uint16_t index = 0;  ///< bit 0: the divisor's third fraction bit
  double actual = 0;        ///< baud
};
/// The FT232BM/R divisor closest to `baud`: 3 MHz / (n + k/8), n ≥ 2 a 14-bit integer, k/8 one of
/// the chip's eight fractions (and the two special divisors 0 → 3 Mbaud, 1 → 2 Mbaud). nullopt
/// for a rate the chip cannot get within 3 % of (below 183 baud, above 3 Mbaud, not finite).
[[nodiscard]] std::optional<BaudSetting> baud_setting(double baud) noexcept;
/// The rate a baud-rate request's wValue and wIndex (its low byte) set. The inverse of baud_setting.
[[nodiscard]] double baud_of(std::uint16_t value, std::uint16_t index) noexcept;

/// Copies the data bytes of `in` (bulk IN, packets of `packet_size` bytes each, the last one
/// possibly short) to `out`, dropping the two status bytes that begin every packet. Returns the
/// number of bytes written (at most out.size(); the rest is dropped). Real-time safe.
std::size_t strip_modem_status(std::span<const std::uint8_t> in, std::size_t packet_size, std::span<std::uint8_t> out) noexcept;

/// Which chip to open: the `index`-th device (in libusb's enumeration order) with this VID:PID.
struct PortId {
  std::uint16_t vid = 0x0403, pid = 0x6001;
  int index = 0;
  int interface_number = 0;
  std::uint8_t endpoint_in = 0x81, endpoint_out = 0x02;
  std::string what = "FTDI device";  ///< the device's name in messages, e.g. "Novint Falcon"
};

class Port {
 public:
  /// Finds the device, checks both bulk endpoints, detaches a kernel driver (ftdi_sio) if one is
  /// bound, claims the interface. Errors name what was looked for and what was found instead: no
  /// USB device with the VID:PID (listing the devices of the same vendor, with their product ids),
  /// fewer such devices than index + 1, missing or wrong-typed endpoints, or a claim refused.
  [[nodiscard]] static Result<std::unique_ptr<Port>> open(const PortId& id);
  ~Port();
  Port(const Port&) = delete;
  Port& operator=(const Port&) = delete;

  /// "bus 001 address 002".
  [[nodiscard]] const std::string& location() const noexcept { return location_; }

  // ---- setup (blocking, not real-time); each failure names the request ----
  Result<void> control(std::uint8_t request, std::uint16_t value, const char* what);
  /// As control(), with a wIndex (the baud rate's third fraction bit).
  Result<void> control_indexed(std::uint8_t request, std::uint16_t value, std::uint16_t index, const char* what);
  Result<void> reset() { return control(kReset, kResetPort, "reset"); }
  Result<void> purge();  ///< both buffers
  Result<void> set_baud(double baud);
  Result<void> set_latency_ms(int ms);
  Result<void> set_8n1_no_flow_control();
  Result<void> set_dtr(bool high) { return control(kModemControl, high ? kDtrHigh : kDtrLow, high ? "DTR high" : "DTR low"); }
  Result<void> set_rts(bool high) { return control(kModemControl, high ? kRtsHigh : kRtsLow, high ? "RTS high" : "RTS low"); }
  Result<void> set_uart_mode() { return control(kBitMode, 0x0000, "bit mode UART"); }
  /// Writes all of `data` (bulk OUT, synchronous).
  Result<void> write_all(std::span<const std::uint8_t> data, double timeout_s, const char* what);
  /// Reads exactly out.size() data bytes from the stream (start_streaming() first), or fails once
  /// `timeout_s` passes with fewer: the error says how many came. Bytes already buffered come first.
  Result<void> read_exact(std::span<std::uint8_t> out, double timeout_s, const char* what);

  // ---- the exchange (real-time) ----
  /// Keeps one IN transfer of one packet in flight from now on; each completion appends its data
  /// bytes to the receive buffer (kRxCapacity; overflow drops the oldest and is counted) and
  /// resubmits. Not real-time (first call); idempotent.
  Result<void> start_streaming();
  /// Stops the IN transfer (cancels it and waits up to 100 ms for it to come back). Not real-time.
  void stop_streaming() noexcept;
  /// Starts an asynchronous bulk OUT of `data` (≤ kMaxWrite bytes, copied). If the previous write
  /// is still in flight, waits for it until `deadline_ns` (CLOCK_MONOTONIC); kTimeout when it
  /// does not come back, kDisconnected when the device is gone.
  IoStatus submit_write(std::span<const std::uint8_t> data, std::int64_t deadline_ns) noexcept;
  /// Handles libusb events until at least `bytes` data bytes are buffered, the device is gone, or
  /// `deadline_ns` passes. Returns kOk, kTimeout or kDisconnected.
  IoStatus wait_for(std::size_t bytes, std::int64_t deadline_ns) noexcept;
  /// The buffered data bytes (oldest first); take() consumes from the front.
  [[nodiscard]] std::span<const std::uint8_t> rx() const noexcept { return {rx_.data(), rx_size_}; }
  void take(std::size_t n) noexcept;
  void clear_rx() noexcept { rx_size_ = 0; }
  /// The device is gone (a transfer ended with NO_DEVICE or the IN stream failed): only a new
  /// open() helps.
  [[nodiscard]] bool lost() const noexcept { return lost_; }
  /// Why the stream stopped or the last exchange failed, in words (a static string).
  [[nodiscard]] const char* detail() const noexcept { return detail_; }

  struct Stats {
    std::uint64_t in_packets = 0, in_bytes = 0, writes = 0, rx_overflow_bytes = 0, in_errors = 0;
  };
  [[nodiscard]] const Stats& stats() const noexcept { return stats_; }

  static constexpr std::size_t kRxCapacity = 4096;
  static constexpr std::size_t kMaxWrite = 512;

 private:
  Port() = default;
  void on_in_done() noexcept;
  void on_out_done() noexcept;
  friend void in_done_trampoline(libusb_transfer* t);
  friend void out_done_trampoline(libusb_transfer* t);
  /// Handles libusb's events until done() or the deadline; false when handling them failed.
  template <class Done>
  bool pump(std::int64_t deadline_ns, Done done) noexcept;

  libusb_context* ctx_ = nullptr;
  libusb_device_handle* handle_ = nullptr;
  PortId id_;
  std::string location_;
  std::size_t packet_size_ = 64;
  bool claimed_ = false, detached_driver_ = false;

  libusb_transfer* in_ = nullptr;
  libusb_transfer* out_ = nullptr;
  std::array<std::uint8_t, 512> in_buf_{};
  std::array<std::uint8_t, kMaxWrite> out_buf_{};
  bool streaming_ = false, in_flight_ = false, out_in_flight_ = false;
  bool lost_ = false;
  const char* detail_ = "";
  std::array<std::uint8_t, kRxCapacity> rx_{};
  std::size_t rx_size_ = 0;
  Stats stats_{};
};

}  // namespace lancet::device::ftdi
