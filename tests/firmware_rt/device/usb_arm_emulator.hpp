#pragma once
// ArmEmulator: the USB arm of usb_arm_test.cpp (data/usb_arm.umockdev: HID-class 1209:0001,
// interrupt endpoints from the config) as a UsbdevfsDevice: OUT reports drive an ArmPhysics
// (setpoints → joint torques → 1 ms of physics), IN reports carry its encoder counts, the
// buttons and the status the test sets, at once; every control request stalls (none is
// emulated). Its firmware has a keep-alive watchdog on a clock the test advances. Its field
// codecs are written apart from UsbArm's on purpose.
//
// Threads: as UsbdevfsDevice (the hooks run on umockdev's thread; every method here takes the
// device's mutex).

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>

#include "arm/arm_config.hpp"
#include "device/arm_physics.hpp"
#include "usbdevfs_emulator.hpp"

namespace lancet::device {

/// A fault the next IN report carries: half its bytes, or the wrong report id.
enum class Corruption { kNone, kShort, kWrongId };

struct EmulatorSnapshot {
  std::array<std::int64_t, kMaxJoints> current_counts{};  ///< last OUT report's setpoints, raw (rounded)
  std::array<double, kMaxJoints> setpoint{};              ///< the same in A or N·m (scale · raw + bias)
  bool enabled = false;
  std::uint32_t enable_raw = 0, heartbeat = 0;            ///< last OUT report's fields
  bool tripped = false;                                   ///< the keep-alive watchdog made the arm torque-free (latched)
  std::uint64_t trips = 0, resets = 0;                    ///< watchdog trips; fault-reset reports
  std::uint64_t out_reports = 0, in_reports = 0, bad_out_reports = 0, discards = 0;
  bool claimed = false, driver_bound = true;
  int driver_detaches = 0;
};

class ArmEmulator : public lancet::test::UsbdevfsDevice {
 public:
  /// `cfg` must have a [bus.usb] section. A physics that cannot be made is a test failure.
  explicit ArmEmulator(const arm::ArmConfig& cfg);

  void corrupt_next_in(Corruption c) {
    auto lk = lock();
    corrupt_ = c;
  }
  void set_status(std::uint32_t s) {
    auto lk = lock();
    status_ = s;
  }
  void set_buttons(std::uint32_t b) {
    auto lk = lock();
    buttons_ = b;
  }
  void with_physics(const std::function<void(ArmPhysics&)>& f) {
    auto lk = lock();
    f(*physics_);
  }
  /// What the firmware saw and did, with the host's usbdevfs state (claim, kernel driver).
  EmulatorSnapshot snapshot();
  /// The firmware's keep-alive watchdog time (s; 0: off). Default: the config's drive_watchdog.
  void set_watchdog(double s) {
    auto lk = lock();
    watchdog_s_ = s;
  }
  /// The firmware's clock (ns): it moves only when the test advances it.
  void advance_clock(std::int64_t ns) {
    auto lk = lock();
    clock_ns_ += ns;
    poll_watchdog();
  }
  [[nodiscard]] std::int64_t clock_ns() {
    auto lk = lock();
    return clock_ns_;
  }

 private:
  lancet::test::UrbReply on_out(std::uint8_t endpoint, std::span<const std::uint8_t> data) override;
  lancet::test::UrbReply on_in(std::uint8_t endpoint, std::span<std::uint8_t> buffer) override;
  void poll_watchdog();
  void consume_out(const std::uint8_t* b, std::size_t len);
  std::size_t fill_in(std::uint8_t* b, std::size_t len);

  const arm::ArmConfig cfg_;
  const arm::UsbBusConfig usb_;
  std::unique_ptr<ArmPhysics> physics_;
  Corruption corrupt_ = Corruption::kNone;
  std::uint32_t status_ = 0, buttons_ = 0;
  double watchdog_s_ = usb_.drive_watchdog;
  bool armed_ = false;
  std::int64_t clock_ns_ = 0, heartbeat_at_ns_ = 0;
  EmulatorSnapshot snap_{};
};

}  // namespace lancet::device
