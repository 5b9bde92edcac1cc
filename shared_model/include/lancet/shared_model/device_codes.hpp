#pragma once
// The codes lancet-rt's device and watchdog states cross the segment as (RtStatus, ToolSample):
// one definition, used by the driver side (device::Device, rt::Watchdog) and by every reader
// (lancet-viz, lancetctl), so that no reader compares against a bare number.

#include <cstdint>

namespace lancet {

/// An arm's lifecycle, after ros2_control's hardware-interface states.
enum class DeviceLifecycle : std::uint32_t { kUnconfigured = 0, kInactive = 1, kActive = 2, kFault = 3 };
inline constexpr DeviceLifecycle kLastDeviceLifecycle = DeviceLifecycle::kFault;

/// What a device read or write came back with.
enum class IoStatus : std::uint8_t {
  kOk = 0,
  kTimeout,        ///< no reply within the backend's timeout
  kCrcError,       ///< a reply arrived corrupted
  kProtocolError,  ///< a reply arrived but made no sense (exception code, wrong length, bad EMCY…)
  kDisconnected,   ///< the bus or the device went away
  kDeviceFault,    ///< the device reports a fault of its own (drive fault bit, EMCY)
  kNotActive,      ///< read/write outside the active state
  kFault,          ///< the device is in kFault: zero torque until rearm()
  kImplausible,    ///< an encoder jumped further than the joint's maximum speed allows (a glitch)
};
inline constexpr IoStatus kLastIoStatus = IoStatus::kImplausible;

/// Why the servo's watchdog tripped.
enum class WatchdogReason : std::uint32_t { kNone = 0, kConsecutiveMisses = 1, kTickOverBudget = 2 };
inline constexpr WatchdogReason kLastWatchdogReason = WatchdogReason::kTickOverBudget;

[[nodiscard]] const char* to_string(DeviceLifecycle s) noexcept;
[[nodiscard]] const char* to_string(IoStatus s) noexcept;
[[nodiscard]] const char* to_string(WatchdogReason r) noexcept;

/// Whether a value read from the segment names a code of this build (a peer's garbage does not).
template <class E>
constexpr bool known_code(E value, E last) noexcept {
  return static_cast<std::uint64_t>(value) <= static_cast<std::uint64_t>(last);
}

}  // namespace lancet
