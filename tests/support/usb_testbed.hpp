#pragma once
// UsbTestbed: a umockdev testbed (sysfs and /dev) built from a .umockdev file, with one device of
// the file served by a UsbdevfsDevice (usbdevfs_emulator.hpp) that can be plugged at a bus
// address, unplugged, and plugged again at another. Unmodified libusb code in the same process
// then enumerates it and transfers to it.
//
//   MyDevice dev;                                    // a UsbdevfsDevice
//   UsbTestbed bed(dev, source_path("tests/.../my.umockdev"), "/sys/devices/.../usb1/1-1");
//   ASSERT_TRUE(bed.plug(2));                        // the file's other devices (the hub) come too
//   ... libusb finds it at bus 1 address 2 ...
//   bed.unplug();                                    // transfers in flight: ENODEV; gone from sysfs
//   ASSERT_TRUE(bed.plug(3));                        // re-enumerated at address 3
//
// The process must run with umockdev's preload library: in_umockdev() says whether it does, and
// reexec_under_umockdev_if_needed() at the top of main() re-executes the test under
// umockdev-wrapper (Debian package umockdev) when it does not.
//
// Test-only code: failures are reported to GoogleTest (ADD_FAILURE) and returned as false.

#include <string>
#include <vector>

#include "usbdevfs_emulator.hpp"

struct _UMockdevTestbed;
struct _UMockdevIoctlBase;

namespace lancet::test {

/// True when umockdev's preload library is loaded (umockdev_in_mock_environment() is not
/// reliable for this: it said false under the preload).
[[nodiscard]] bool in_umockdev();

/// Why the tests that need umockdev skip, for GTEST_SKIP().
[[nodiscard]] const char* not_in_umockdev_reason();

/// At the top of main(): re-executes this binary under umockdev-wrapper unless the preload library
/// is already loaded (once: never loops), adding verify_asan_link_order=0 to ASAN_OPTIONS in
/// AddressSanitizer builds. Returns only when it does not re-execute (already there, or no
/// wrapper: then it says so on stderr and the umockdev tests skip).
void reexec_under_umockdev_if_needed(char** argv);

/// `umockdev_text` (a .umockdev file's text) with the device at `sys_path` and its children (its
/// interfaces) enumerated at bus address `address`: their node names (N:, DEVNAME), DEVNUM,
/// devnum, MINOR and dev lines say the new address, the rest is untouched. Only the device's
/// paragraphs are kept, or all of them with `with_others`. `sys_path` is the P: path, with or
/// without "/sys" in front.
[[nodiscard]] std::string umockdev_at_address(const std::string& umockdev_text, const std::string& sys_path, int address,
                                              bool with_others);

class UsbTestbed {
 public:
  /// Reads `umockdev_file`; `sys_path` names the device `device` serves. Nothing is plugged yet.
  /// `device` must outlive the testbed.
  UsbTestbed(UsbdevfsDevice& device, const std::string& umockdev_file, std::string sys_path);
  ~UsbTestbed();
  UsbTestbed(const UsbTestbed&) = delete;
  UsbTestbed& operator=(const UsbTestbed&) = delete;

  /// Enumerates the device on its bus at `address` (1..127) and points its node's ioctls at the
  /// device (an old node keeps answering ENODEV). The first plug adds the file's other devices too
  /// (the root hub). False (with a test failure) when umockdev refuses.
  bool plug(int address);
  /// Pulls the cable: the device fails what is in flight (ENODEV), then the testbed forgets it.
  void unplug();
  /// Only the testbed's half of unplug(): sysfs and /dev forget the device (for a device that
  /// already vanished by itself, UsbdevfsDevice::vanish_on_next_in()).
  void remove_from_testbed();

  /// The device's node at its current address, e.g. "/dev/bus/usb/001/002".
  [[nodiscard]] std::string devnode() const;
  [[nodiscard]] int bus() const { return bus_; }
  [[nodiscard]] int address() const { return address_; }

 private:
  UsbdevfsDevice& device_;
  std::string text_, sys_path_;         // the file; the device's P: path (no "/sys")
  std::vector<std::string> children_;   // the P: paths under the device's (its interfaces)
  int bus_ = 0, address_ = 0;
  bool others_added_ = false;
  std::vector<std::string> attached_;   // nodes whose ioctls reach the device
  _UMockdevTestbed* tb_ = nullptr;
  _UMockdevIoctlBase* handler_ = nullptr;
};

}  // namespace lancet::test
