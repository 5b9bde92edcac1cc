#pragma once
// UsbdevfsDevice: the usbdevfs side of an emulated USB device under umockdev, for tests that run
// unmodified libusb code against a device that answers with computed state.
//
// umockdev's testbed (UsbTestbed, usb_testbed.hpp) routes every ioctl on the device's node to
// handle_ioctl(), which answers the usbdevfs requests libusb makes (SUBMITURB, REAPURB[NDELAY],
// DISCARDURB, GET_CAPABILITIES, GETDRIVER, USBDEVFS_IOCTL disconnect / connect of the kernel
// driver, CLAIM / RELEASEINTERFACE, CLEAR_HALT, RESETEP, RESET, SETINTERFACE, SETCONFIGURATION)
// and keeps the URBs: pending (an IN waiting for data) and done (ready to reap). A derived class
// gives the device's own behaviour through three hooks:
//
//   on_control(setup, data)  a control transfer (default: a stall, as a device that emulates none)
//   on_out(endpoint, bytes)  a bulk or interrupt OUT: consume the bytes
//   on_in(endpoint, buffer)  a bulk or interrupt IN: fill the buffer now, or say nothing_yet() and
//                            the URB pends until complete_pending_in() (the device calls it when
//                            data is there: from its OUT hook, or the test from its thread)
//
// Threads: handle_ioctl() runs on umockdev's handler thread; the test's thread calls the public
// methods. One recursive mutex guards everything: every public method takes it, every hook runs
// with it held, and a derived class takes it (lock()) in its own public methods, so its state is
// safe to share with its hooks. complete_pending_in() may be called from inside a hook.
//
// Test-only code: it allocates freely (on umockdev's thread, not the test's).

#include <cerrno>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <mutex>
#include <span>
#include <string>
#include <vector>

// umockdev's types (umockdev.h), declared here so that users need not include it.
struct _UMockdevIoctlClient;
struct _UMockdevIoctlData;

namespace lancet::test {

/// What a transfer hook answers.
struct UrbReply {
  enum class Kind { kDone, kNothingYet, kFailed };
  Kind kind = Kind::kDone;
  std::size_t length = 0;  ///< kDone: bytes transferred (≤ the buffer's size)
  int status = 0;          ///< kFailed: the URB's status, a negative errno

  /// `n` bytes transferred (IN: written to the buffer; OUT: consumed; control OUT: 0).
  static UrbReply done(std::size_t n) { return {Kind::kDone, n, 0}; }
  /// IN only: no data yet; the URB pends until complete_pending_in() or fail_pending_in().
  static UrbReply nothing_yet() { return {Kind::kNothingYet, 0, 0}; }
  /// The endpoint stalls (-EPIPE: libusb's LIBUSB_TRANSFER_STALL / LIBUSB_ERROR_PIPE).
  static UrbReply stall() { return {Kind::kFailed, 0, -EPIPE}; }
  /// Completes the URB with `negative_errno` (-EPROTO: a transfer error, -EOVERFLOW: babble...).
  static UrbReply failed(int negative_errno) { return {Kind::kFailed, 0, negative_errno}; }
};

/// The 8-byte setup packet of a control transfer, decoded (little-endian on the wire).
struct ControlSetup {
  std::uint8_t request_type = 0;  ///< bmRequestType: bit 7 set = IN (device to host)
  std::uint8_t request = 0;       ///< bRequest
  std::uint16_t value = 0;        ///< wValue
  std::uint16_t index = 0;        ///< wIndex
  std::uint16_t length = 0;       ///< wLength
  [[nodiscard]] bool is_in() const { return (request_type & 0x80) != 0; }
};

/// One endpoint of the emulated interface (bit 7 of the address set: IN).
struct UsbEndpoint {
  enum class Type { kInterrupt, kBulk };
  std::uint8_t address = 0;
  Type type = Type::kBulk;
};

/// The device's interface as usbdevfs shows it.
struct UsbdevfsInterface {
  int number = 0;                     ///< bInterfaceNumber (the one interface that can be claimed)
  std::string kernel_driver;          ///< bound at every plug ("usbhid", "ftdi_sio"); empty: none
  std::vector<UsbEndpoint> endpoints; ///< the only endpoints bulk / interrupt URBs may name
};

/// What the host did to the interface, for the test to check.
struct UsbdevfsState {
  bool claimed = false;            ///< claimed by the host now
  bool driver_bound = false;       ///< the kernel driver is bound now
  int driver_detaches = 0;         ///< times the host detached the kernel driver (all plugs)
  std::uint64_t discards = 0;      ///< URBs the host discarded while they pended (all plugs)
  std::size_t pending_in = 0;      ///< IN URBs waiting for data now
};

class UsbdevfsDevice {
 public:
  explicit UsbdevfsDevice(UsbdevfsInterface interface);
  virtual ~UsbdevfsDevice();
  UsbdevfsDevice(const UsbdevfsDevice&) = delete;
  UsbdevfsDevice& operator=(const UsbdevfsDevice&) = delete;

  /// The node the device is enumerated at now (UsbTestbed calls it); ioctls on any other node (an
  /// fd opened before a re-plug) get ENODEV. Resets the claim and binds the kernel driver.
  void plugged_at(const std::string& devnode);
  /// Gone from the bus: URBs in flight complete with -ENODEV, every later ioctl but reaping fails
  /// with ENODEV.
  void unplug();
  /// The next IN URB is the last: the device vanishes with it in flight (-ESHUTDOWN), then
  /// behaves as unplugged.
  void vanish_on_next_in();
  /// While on, IN URBs pend without asking on_in() (a device that never answers) and
  /// complete_pending_in() leaves them; switching it off completes nothing by itself.
  void withhold_in(bool on);
  /// Runs on_in() for the pending IN URBs in submission order and completes each it fills; on
  /// each endpoint it stops at the first that gets nothing_yet(). Any thread, hooks included.
  void complete_pending_in();
  /// Completes the oldest pending IN URB with `negative_errno` (-EPROTO, -EOVERFLOW...). Returns
  /// false when none pends.
  bool fail_pending_in(int negative_errno);
  [[nodiscard]] UsbdevfsState state() const;

  /// Answers one ioctl on umockdev's handler thread (UsbTestbed connects it). Returns true: every
  /// request on the node is answered here, unknown ones with ENOTTY.
  bool handle_ioctl(_UMockdevIoctlClient* client);

 protected:
  /// A control transfer, claimed or not. `data` is the data stage (wLength bytes, fewer only if
  /// the client's buffer is shorter): IN fills it and returns done(n ≤ data.size()); OUT reads it
  /// and returns done(0) to accept it (the whole data stage counts as transferred). Or stall(),
  /// or failed(). Default: stall() (a device that emulates no control request).
  virtual UrbReply on_control(const ControlSetup& setup, std::span<std::uint8_t> data);
  /// A bulk / interrupt OUT on `endpoint`: returns done(bytes consumed) or failed().
  virtual UrbReply on_out(std::uint8_t endpoint, std::span<const std::uint8_t> data) = 0;
  /// A bulk / interrupt IN on `endpoint`: fills `buffer` and returns done(n), or nothing_yet(),
  /// or failed().
  virtual UrbReply on_in(std::uint8_t endpoint, std::span<std::uint8_t> buffer) = 0;

  /// The device's mutex, for a derived class's public methods (hooks already hold it).
  [[nodiscard]] std::unique_lock<std::recursive_mutex> lock() const { return std::unique_lock(m_); }

 private:
  struct Urb {
    _UMockdevIoctlData* data;      // the submitted usbdevfs_urb (a reference we hold)
    _UMockdevIoctlClient* client;  // the fd it came from
    std::uint8_t* buffer;          // its buffer, resolved into `data` (lives as long as it)
    std::size_t length;            // the buffer's size
  };

  bool reap(_UMockdevIoctlClient* client, _UMockdevIoctlData* arg, bool live);
  bool discard(_UMockdevIoctlClient* client, _UMockdevIoctlData* arg, bool live);
  void answer_driver_ioctl(_UMockdevIoctlClient* client, unsigned long request, _UMockdevIoctlData* arg);
  void submit(_UMockdevIoctlClient* client, _UMockdevIoctlData* arg);
  void submit_control(const Urb& urb);
  void submit_in(const Urb& urb, std::uint8_t endpoint);
  const UsbEndpoint* endpoint(std::uint8_t address, unsigned urb_type) const;
  void finish(const Urb& urb, const UrbReply& reply);
  bool in_waits(std::uint8_t endpoint) const;

  const UsbdevfsInterface interface_;
  mutable std::recursive_mutex m_;
  std::string live_;
  bool unplugged_ = false, withhold_ = false, vanish_next_in_ = false, completing_ = false;
  UsbdevfsState state_;
  std::deque<Urb> pending_, done_;  // IN URBs waiting for data; URBs ready to reap
};

}  // namespace lancet::test
