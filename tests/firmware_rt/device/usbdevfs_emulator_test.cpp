// The test support for emulated USB devices (tests/support/usbdevfs_emulator.hpp, usb_testbed.hpp)
// with the Novint Falcon's device file (data/novint_falcon.umockdev: a root hub and the Falcon's
// FTDI FT232BM-class chip, 0403:cb48, one vendor-class interface bound to ftdi_sio, bulk endpoints
// 0x81 IN and 0x02 OUT of 64 bytes) and a stub emulator that records what it is sent.
//
// Plain libusb, as a Falcon driver would use it: enumeration (ids, endpoints), the kernel driver
// detached and the interface claimed, vendor control requests OUT and IN and a stall, bulk OUT,
// bulk IN that pends until the emulator has data (from the test's thread or from inside its OUT
// hook, in submission order), a pending IN failed on purpose, unplug (LIBUSB_ERROR_NO_DEVICE) and
// re-plug at another address. And the .umockdev rewriting for an address, without umockdev.
//
// No test depends on the machine's speed: a transfer that must time out has no reply coming at
// all; every other wait is for an event, with a deadline that only catches hangs.

#include <errno.h>
#include <libusb.h>
#include <time.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdint>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "usb_testbed.hpp"
#include "usbdevfs_emulator.hpp"
#include "wait.hpp"

#ifndef LANCET_SOURCE_DIR
#define LANCET_SOURCE_DIR "."
#endif

namespace lancet::test {
namespace {

constexpr const char* kFalconFile = LANCET_SOURCE_DIR "/tests/firmware_rt/device/data/novint_falcon.umockdev";
constexpr const char* kFalconSysPath = "/sys/devices/pci0000:00/0000:00:14.0/usb1/1-1";
constexpr std::uint16_t kVid = 0x0403, kPid = 0xcb48;
constexpr std::uint8_t kIn = 0x81, kOut = 0x02;
// A transfer that is answered: generous (umockdev's handler thread may be held back on a loaded
// machine). One that must time out has no reply coming, so any value gives the same outcome.
constexpr unsigned kTimeoutMs = 5000, kShortTimeoutMs = 20;

std::string read_text(const std::string& path) {
  std::ifstream f(path);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

using Bytes = std::vector<std::uint8_t>;

// The Falcon's USB side as the test needs it: control requests and OUT bytes recorded; IN answers
// with the bytes queued so far (provide_in), or pends while there are none; in echo mode each OUT
// queues its own bytes for IN and completes what pends, from inside the OUT hook. Vendor request
// 0x90 IN (FTDI's "read EEPROM word") answers 0x1234; every other IN request stalls.
class FalconStub : public UsbdevfsDevice {
 public:
  FalconStub()
      : UsbdevfsDevice({0, "ftdi_sio", {{kIn, UsbEndpoint::Type::kBulk}, {kOut, UsbEndpoint::Type::kBulk}}}) {}

  void provide_in(const Bytes& b) {
    auto lk = lock();
    in_.insert(in_.end(), b.begin(), b.end());
  }
  void echo(bool on) {
    auto lk = lock();
    echo_ = on;
  }
  std::vector<ControlSetup> controls() {
    auto lk = lock();
    return controls_;
  }
  std::vector<Bytes> control_data() {
    auto lk = lock();
    return control_data_;
  }
  Bytes received() {
    auto lk = lock();
    return received_;
  }

 private:
  UrbReply on_control(const ControlSetup& s, std::span<std::uint8_t> data) override {
    controls_.push_back(s);
    if (!s.is_in()) {
      control_data_.emplace_back(data.begin(), data.end());
      return UrbReply::done(0);
    }
    if (s.request_type != 0xC0 || s.request != 0x90 || data.size() < 2) return UrbReply::stall();
    data[0] = 0x34;
    data[1] = 0x12;
    return UrbReply::done(2);
  }
  UrbReply on_out(std::uint8_t, std::span<const std::uint8_t> data) override {
    received_.insert(received_.end(), data.begin(), data.end());
    if (echo_) {
      in_.insert(in_.end(), data.begin(), data.end());
      complete_pending_in();  // re-entrant: this hook already holds the device's mutex
    }
    return UrbReply::done(data.size());
  }
  UrbReply on_in(std::uint8_t, std::span<std::uint8_t> buffer) override {
    if (in_.empty()) return UrbReply::nothing_yet();
    const std::size_t n = std::min(buffer.size(), in_.size());
    std::copy_n(in_.begin(), n, buffer.begin());
    in_.erase(in_.begin(), in_.begin() + static_cast<std::ptrdiff_t>(n));
    return UrbReply::done(n);
  }

  Bytes in_, received_;
  bool echo_ = false;
  std::vector<ControlSetup> controls_;
  std::vector<Bytes> control_data_;
};

// One asynchronous bulk IN of 64 bytes, without a timeout (it pends as long as the device does).
struct AsyncIn {
  explicit AsyncIn(libusb_device_handle* h) : t(libusb_alloc_transfer(0)) {
    libusb_fill_bulk_transfer(
        t, h, kIn, buf.data(), static_cast<int>(buf.size()), [](libusb_transfer* x) { *static_cast<int*>(x->user_data) = 1; },
        &done, 0);
  }
  ~AsyncIn() { libusb_free_transfer(t); }
  AsyncIn(const AsyncIn&) = delete;
  AsyncIn& operator=(const AsyncIn&) = delete;

  /// Handles libusb's events until the transfer is back (true) or a hang (false).
  bool wait(libusb_context* ctx) {
    const auto deadline = std::chrono::steady_clock::now() + kHangTimeout;
    while (done == 0 && std::chrono::steady_clock::now() < deadline) {
      timeval tv{0, 100'000};
      (void)libusb_handle_events_timeout_completed(ctx, &tv, &done);
    }
    return done != 0;
  }
  [[nodiscard]] Bytes data() const { return Bytes(buf.begin(), buf.begin() + t->actual_length); }

  libusb_transfer* t;
  std::array<std::uint8_t, 64> buf{};
  int done = 0;
};

// ---------------------------------------------------------------------------------------------
// The device file at another address (no umockdev needed)

TEST(UsbTestbedFile, TheDevicesAddressLinesFollowItsAddressAndNothingElseChanges) {
  const std::string text = read_text(kFalconFile);
  ASSERT_FALSE(text.empty()) << kFalconFile;
  const std::string at3 = umockdev_at_address(text, kFalconSysPath, 3, false);
  for (const char* line : {"\nN: bus/usb/001/003=1201000200000008", "\nE: DEVNAME=/dev/bus/usb/001/003\n", "\nE: DEVNUM=003\n",
                           "\nE: MINOR=2\n", "\nA: devnum=3\\n\n", "\nA: dev=189:2\\n\n", "\nE: DRIVER=ftdi_sio\n"})
    EXPECT_NE(at3.find(line), std::string::npos) << line;
  EXPECT_EQ(at3.find("/001/002"), std::string::npos);
  EXPECT_EQ(at3.find("P: /devices/pci0000:00/0000:00:14.0/usb1\n"), std::string::npos) << "the hub only with_others";
  EXPECT_EQ(at3.rfind("P: /devices/pci0000:00/0000:00:14.0/usb1/1-1\n", 0), 0u);

  // At its own address, with the others: the file as it is.
  const std::string same = umockdev_at_address(text, kFalconSysPath, 2, true);
  EXPECT_EQ(same.substr(0, text.size()), text);
}

// ---------------------------------------------------------------------------------------------
// The Falcon under umockdev, through plain libusb

class UsbdevfsFalconTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!in_umockdev()) GTEST_SKIP() << not_in_umockdev_reason();
    bed_ = std::make_unique<UsbTestbed>(stub_, kFalconFile, kFalconSysPath);
    ASSERT_TRUE(bed_->plug(2));
    ASSERT_EQ(libusb_init(&ctx_), 0);
  }
  void TearDown() override {
    if (h_ != nullptr) libusb_close(h_);
    if (ctx_ != nullptr) libusb_exit(ctx_);
    bed_.reset();  // before the stub it routes to
  }

  // The Falcon in a fresh scan of the bus (nullptr: not there); `*address` gets its address.
  libusb_device* find_falcon(int* address = nullptr) {
    libusb_device** list = nullptr;
    const ssize_t n = libusb_get_device_list(ctx_, &list);
    libusb_device* found = nullptr;
    for (ssize_t i = 0; i < n && found == nullptr; ++i) {
      libusb_device_descriptor d{};
      if (libusb_get_device_descriptor(list[i], &d) == 0 && d.idVendor == kVid && d.idProduct == kPid) found = libusb_ref_device(list[i]);
    }
    if (list != nullptr) libusb_free_device_list(list, 1);
    if (found != nullptr && address != nullptr) *address = libusb_get_device_address(found);
    return found;
  }
  // Opens the Falcon and claims its interface, detaching ftdi_sio.
  ::testing::AssertionResult open_and_claim() {
    libusb_device* dev = find_falcon();
    if (dev == nullptr) return ::testing::AssertionFailure() << "no 0403:cb48 on the bus";
    const int r = libusb_open(dev, &h_);
    libusb_unref_device(dev);
    if (r != 0) return ::testing::AssertionFailure() << "libusb_open: " << libusb_error_name(r);
    if (libusb_kernel_driver_active(h_, 0) != 1) return ::testing::AssertionFailure() << "ftdi_sio is not bound";
    if (const int e = libusb_detach_kernel_driver(h_, 0); e != 0) return ::testing::AssertionFailure() << "detach: " << libusb_error_name(e);
    if (const int e = libusb_claim_interface(h_, 0); e != 0) return ::testing::AssertionFailure() << "claim: " << libusb_error_name(e);
    return ::testing::AssertionSuccess();
  }
  int bulk_out(const Bytes& b) {
    int sent = -1;
    Bytes copy = b;
    const int r = libusb_bulk_transfer(h_, kOut, copy.data(), static_cast<int>(copy.size()), &sent, kTimeoutMs);
    return r == 0 ? sent : r;
  }

  FalconStub stub_;
  std::unique_ptr<UsbTestbed> bed_;
  libusb_context* ctx_ = nullptr;
  libusb_device_handle* h_ = nullptr;
};

TEST_F(UsbdevfsFalconTest, EnumeratesWithItsIdsAndTwoBulkEndpointsOf64Bytes) {
  int address = 0;
  libusb_device* dev = find_falcon(&address);
  ASSERT_NE(dev, nullptr);
  EXPECT_EQ(libusb_get_bus_number(dev), 1);
  EXPECT_EQ(address, 2);
  libusb_device_descriptor d{};
  ASSERT_EQ(libusb_get_device_descriptor(dev, &d), 0);
  EXPECT_EQ(d.bcdDevice, 0x0400);
  EXPECT_EQ(d.bDeviceClass, 0);
  EXPECT_EQ(d.bNumConfigurations, 1);
  EXPECT_NE(d.iManufacturer, 0);
  EXPECT_NE(d.iProduct, 0);
  EXPECT_NE(d.iSerialNumber, 0);
  EXPECT_EQ(libusb_get_device_speed(dev), LIBUSB_SPEED_FULL);

  libusb_config_descriptor* c = nullptr;
  ASSERT_EQ(libusb_get_active_config_descriptor(dev, &c), 0);
  ASSERT_EQ(c->bNumInterfaces, 1);
  const libusb_interface_descriptor& itf = c->interface[0].altsetting[0];
  EXPECT_EQ(itf.bInterfaceClass, 0xff);
  EXPECT_EQ(itf.bInterfaceSubClass, 0xff);
  EXPECT_EQ(itf.bInterfaceProtocol, 0xff);
  ASSERT_EQ(itf.bNumEndpoints, 2);
  for (int i = 0; i < 2; ++i) {
    const libusb_endpoint_descriptor& e = itf.endpoint[i];
    EXPECT_EQ(e.bmAttributes & 0x03, LIBUSB_TRANSFER_TYPE_BULK) << "endpoint " << i;
    EXPECT_EQ(e.wMaxPacketSize, 64) << "endpoint " << i;
  }
  EXPECT_EQ(itf.endpoint[0].bEndpointAddress, kIn);
  EXPECT_EQ(itf.endpoint[1].bEndpointAddress, kOut);
  libusb_free_config_descriptor(c);
  EXPECT_EQ(libusb_get_max_packet_size(dev, kIn), 64);
  EXPECT_EQ(libusb_get_max_packet_size(dev, kOut), 64);
  libusb_unref_device(dev);
}

TEST_F(UsbdevfsFalconTest, TheInterfaceIsClaimedAfterFtdiSioIsDetached) {
  libusb_device* dev = find_falcon();
  ASSERT_NE(dev, nullptr);
  ASSERT_EQ(libusb_open(dev, &h_), 0);
  libusb_unref_device(dev);
  EXPECT_EQ(libusb_kernel_driver_active(h_, 0), 1);
  EXPECT_EQ(libusb_claim_interface(h_, 0), LIBUSB_ERROR_BUSY) << "ftdi_sio holds it";
  ASSERT_EQ(libusb_detach_kernel_driver(h_, 0), 0);
  EXPECT_EQ(libusb_kernel_driver_active(h_, 0), 0);
  ASSERT_EQ(libusb_claim_interface(h_, 0), 0);
  const UsbdevfsState s = stub_.state();
  EXPECT_TRUE(s.claimed);
  EXPECT_FALSE(s.driver_bound);
  EXPECT_EQ(s.driver_detaches, 1);
  EXPECT_EQ(libusb_claim_interface(h_, 1), LIBUSB_ERROR_NOT_FOUND) << "there is one interface";
}

TEST_F(UsbdevfsFalconTest, VendorControlRequestsReachTheEmulatorAndOthersStall) {
  ASSERT_TRUE(open_and_claim());
  // FTDI's reset (0x40, 0) and set-baud-rate (0x40, 3): OUT, no data stage.
  EXPECT_EQ(libusb_control_transfer(h_, 0x40, 0x00, 0x0000, 0x0001, nullptr, 0, kTimeoutMs), 0);
  EXPECT_EQ(libusb_control_transfer(h_, 0x40, 0x03, 0x4138, 0x0000, nullptr, 0, kTimeoutMs), 0);
  // An OUT with a data stage.
  std::array<std::uint8_t, 3> out{0xA5, 0x5A, 0x01};
  EXPECT_EQ(libusb_control_transfer(h_, 0x40, 0x7E, 0x0102, 0x0304, out.data(), out.size(), kTimeoutMs), 3);
  // IN: the emulator's answer arrives.
  std::array<std::uint8_t, 2> word{};
  EXPECT_EQ(libusb_control_transfer(h_, 0xC0, 0x90, 0x0000, 0x0005, word.data(), word.size(), kTimeoutMs), 2);
  EXPECT_EQ(word[0], 0x34);
  EXPECT_EQ(word[1], 0x12);
  // A request the emulator does not answer (GET_STATUS here) stalls.
  EXPECT_EQ(libusb_control_transfer(h_, 0x80, 0x00, 0, 0, word.data(), word.size(), kTimeoutMs), LIBUSB_ERROR_PIPE);

  const std::vector<ControlSetup> c = stub_.controls();
  ASSERT_EQ(c.size(), 5u);
  EXPECT_EQ(c[0].request_type, 0x40);
  EXPECT_EQ(c[0].request, 0x00);
  EXPECT_EQ(c[0].index, 0x0001);
  EXPECT_EQ(c[1].request, 0x03);
  EXPECT_EQ(c[1].value, 0x4138);
  EXPECT_EQ(c[1].length, 0);
  EXPECT_EQ(c[2].value, 0x0102);
  EXPECT_EQ(c[2].index, 0x0304);
  EXPECT_EQ(c[2].length, 3);
  EXPECT_TRUE(c[3].is_in());
  EXPECT_EQ(c[3].index, 0x0005);
  EXPECT_EQ(c[3].length, 2);
  const std::vector<Bytes> d = stub_.control_data();
  ASSERT_EQ(d.size(), 3u);
  EXPECT_TRUE(d[0].empty());
  EXPECT_EQ(d[2], (Bytes{0xA5, 0x5A, 0x01}));
}

TEST_F(UsbdevfsFalconTest, BulkOutArrivesAndBulkInPendsUntilTheEmulatorHasData) {
  ASSERT_TRUE(open_and_claim());
  EXPECT_EQ(bulk_out({'h', 'e', 'l', 'l', 'o'}), 5);
  EXPECT_EQ(stub_.received(), (Bytes{'h', 'e', 'l', 'l', 'o'}));

  // Nothing to read: the IN pends, and a transfer with a timeout times out (and is discarded).
  std::array<std::uint8_t, 64> buf{};
  int got = -1;
  EXPECT_EQ(libusb_bulk_transfer(h_, kIn, buf.data(), 64, &got, kShortTimeoutMs), LIBUSB_ERROR_TIMEOUT);
  EXPECT_EQ(got, 0);
  EXPECT_EQ(stub_.state().discards, 1u);
  EXPECT_EQ(stub_.state().pending_in, 0u);

  // Without a timeout: it pends until the test gives the emulator data and completes it.
  AsyncIn in(h_);
  ASSERT_EQ(libusb_submit_transfer(in.t), 0);
  EXPECT_EQ(stub_.state().pending_in, 1u) << "SUBMITURB is answered at once: the URB waits in the emulator";
  stub_.provide_in({1, 2, 3});
  EXPECT_EQ(stub_.state().pending_in, 1u) << "data alone completes nothing";
  stub_.complete_pending_in();
  ASSERT_TRUE(in.wait(ctx_));
  EXPECT_EQ(in.t->status, LIBUSB_TRANSFER_COMPLETED);
  EXPECT_EQ(in.data(), (Bytes{1, 2, 3}));

  // Data there already: answered at submission.
  stub_.provide_in({9});
  EXPECT_EQ(libusb_bulk_transfer(h_, kIn, buf.data(), 64, &got, kTimeoutMs), 0);
  EXPECT_EQ(got, 1);
  EXPECT_EQ(buf[0], 9);
}

TEST_F(UsbdevfsFalconTest, AnOutHookCompletesPendingInsInSubmissionOrder) {
  ASSERT_TRUE(open_and_claim());
  stub_.echo(true);
  AsyncIn first(h_), second(h_);
  ASSERT_EQ(libusb_submit_transfer(first.t), 0);
  ASSERT_EQ(libusb_submit_transfer(second.t), 0);
  EXPECT_EQ(stub_.state().pending_in, 2u);

  // The echo of one OUT fills the first IN; the second waits for the next OUT.
  EXPECT_EQ(bulk_out({10, 11, 12, 13}), 4);
  ASSERT_TRUE(first.wait(ctx_));
  EXPECT_EQ(first.t->status, LIBUSB_TRANSFER_COMPLETED);
  EXPECT_EQ(first.data(), (Bytes{10, 11, 12, 13}));
  EXPECT_EQ(second.done, 0);
  EXPECT_EQ(stub_.state().pending_in, 1u);
  EXPECT_EQ(bulk_out({14}), 1);
  ASSERT_TRUE(second.wait(ctx_));
  EXPECT_EQ(second.data(), (Bytes{14}));
}

TEST_F(UsbdevfsFalconTest, APendingInFailsWithTheStatusTheTestChooses) {
  ASSERT_TRUE(open_and_claim());
  EXPECT_FALSE(stub_.fail_pending_in(-EPROTO)) << "nothing pends";
  AsyncIn a(h_);
  ASSERT_EQ(libusb_submit_transfer(a.t), 0);
  ASSERT_TRUE(stub_.fail_pending_in(-EPROTO));
  ASSERT_TRUE(a.wait(ctx_));
  EXPECT_EQ(a.t->status, LIBUSB_TRANSFER_ERROR);

  AsyncIn b(h_);
  ASSERT_EQ(libusb_submit_transfer(b.t), 0);
  ASSERT_TRUE(stub_.fail_pending_in(-EOVERFLOW));
  ASSERT_TRUE(b.wait(ctx_));
  EXPECT_EQ(b.t->status, LIBUSB_TRANSFER_OVERFLOW);
  EXPECT_EQ(stub_.state().pending_in, 0u);
}

TEST_F(UsbdevfsFalconTest, UnplugIsNoDeviceAndThePlugAgainAtAddress3IsFound) {
  ASSERT_TRUE(open_and_claim());
  AsyncIn in(h_);
  ASSERT_EQ(libusb_submit_transfer(in.t), 0);
  bed_->unplug();
  ASSERT_TRUE(in.wait(ctx_));
  EXPECT_EQ(in.t->status, LIBUSB_TRANSFER_NO_DEVICE) << "the IN in flight";
  EXPECT_EQ(bulk_out({1}), LIBUSB_ERROR_NO_DEVICE);
  EXPECT_EQ(libusb_control_transfer(h_, 0x40, 0x00, 0, 1, nullptr, 0, kTimeoutMs), LIBUSB_ERROR_NO_DEVICE);
  libusb_close(h_);
  h_ = nullptr;
  // A fresh context's scan, as a driver's reconnect makes it (hotplug events are not relied on).
  libusb_exit(ctx_);
  ASSERT_EQ(libusb_init(&ctx_), 0);
  EXPECT_EQ(find_falcon(), nullptr) << "gone from the bus";

  ASSERT_TRUE(bed_->plug(3));
  EXPECT_EQ(bed_->devnode(), "/dev/bus/usb/001/003");
  libusb_exit(ctx_);
  ASSERT_EQ(libusb_init(&ctx_), 0);
  int address = 0;
  libusb_device* dev = find_falcon(&address);
  ASSERT_NE(dev, nullptr);
  EXPECT_EQ(address, 3);
  libusb_unref_device(dev);
  ASSERT_TRUE(open_and_claim()) << "ftdi_sio bound the re-enumerated Falcon again";
  EXPECT_EQ(stub_.state().driver_detaches, 2);
  EXPECT_EQ(bulk_out({7, 7}), 2);
  EXPECT_EQ(stub_.received().back(), 7);
}

}  // namespace
}  // namespace lancet::test
