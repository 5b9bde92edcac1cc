#pragma once
// CiA 402 (IEC 61800-7) drive profile: the power drive state machine as the statusword (0x6041)
// reports it and the controlword (0x6040) drives it, from both ends: the master's decode and next
// command toward operation enabled, and a drive's transitions and statusword. Also the modes of
// operation (0x6060 / 0x6061), the interpolation time period (0x60C2) and the abort connection
// option (0x6007). Real-time safe.

#include <cstdint>
#include <optional>

namespace lancet::device::canopen {

/// CiA 402 power drive states, from the statusword.
enum class Cia402State : std::uint8_t {
  kNotReadyToSwitchOn,
  kSwitchOnDisabled,
  kReadyToSwitchOn,
  kSwitchedOn,
  kOperationEnabled,
  kQuickStopActive,
  kFaultReactionActive,
  kFault,
  kUnknown,
};

// Statusword bits.
inline constexpr std::uint16_t kSwReadyToSwitchOn = 1u << 0;
inline constexpr std::uint16_t kSwSwitchedOn = 1u << 1;
inline constexpr std::uint16_t kSwOperationEnabled = 1u << 2;
inline constexpr std::uint16_t kSwFault = 1u << 3;
inline constexpr std::uint16_t kSwVoltageEnabled = 1u << 4;
inline constexpr std::uint16_t kSwQuickStop = 1u << 5;
inline constexpr std::uint16_t kSwSwitchOnDisabled = 1u << 6;
inline constexpr std::uint16_t kSwWarning = 1u << 7;
inline constexpr std::uint16_t kSwRemote = 1u << 9;  ///< the controlword is in effect (remote control)
// Controlword commands (CiA 402 device control).
inline constexpr std::uint16_t kCwDisableVoltage = 0x0000;
inline constexpr std::uint16_t kCwShutdown = 0x0006;
inline constexpr std::uint16_t kCwSwitchOn = 0x0007;
inline constexpr std::uint16_t kCwEnableOperation = 0x000F;
inline constexpr std::uint16_t kCwFaultReset = 0x0080;  ///< acts on the rising edge of bit 7

/// The drive state a statusword encodes.
[[nodiscard]] Cia402State cia402_state(std::uint16_t statusword) noexcept;
[[nodiscard]] const char* to_string(Cia402State s) noexcept;

/// The next controlword on the way to operation enabled, given the drive's statusword and the
/// controlword sent last (for the fault reset's rising edge: a drive in fault gets 0x0000, then
/// 0x0080). Holds 0x000F once enabled; waits (0x0000) through the transient states.
[[nodiscard]] std::uint16_t controlword_toward_enabled(std::uint16_t statusword, std::uint16_t previous) noexcept;

/// A drive's side: the state after controlword `cw` in state `s` (`previous`: the controlword
/// before, for the fault reset's rising edge). Ready to switch on with enable operation goes to
/// operation enabled at once (transitions 3 and 4); a drive not ready to switch on ignores the
/// controlword. kFaultReactionActive and kUnknown stay as they are.
[[nodiscard]] Cia402State drive_transition(Cia402State s, std::uint16_t cw, std::uint16_t previous) noexcept;

/// The statusword a drive in state `s` reports, voltage enabled (bit 4) and quick stop off
/// (bit 5 = 1) where the state leaves them open, remote (bit 9) not included: switch on disabled
/// 0x0050, ready to switch on 0x0031, switched on 0x0033, operation enabled 0x0037, quick stop
/// active 0x0017, fault reaction active 0x001F, fault 0x0018; 0x0000 otherwise.
[[nodiscard]] std::uint16_t statusword_of(Cia402State s) noexcept;

/// CiA 402 modes of operation (0x6060).
inline constexpr std::int8_t kModeNone = 0;
inline constexpr std::int8_t kModeProfileTorque = 4;
inline constexpr std::int8_t kModeCyclicSyncTorque = 10;
/// The CiA 402 name of a mode of operation ("cyclic synchronous torque", "no mode" for 0…);
/// "another mode" for codes not listed (manufacturer-specific, reserved).
[[nodiscard]] const char* mode_name(std::int8_t mode) noexcept;
/// 0x6502 supported drive modes: the bit of mode `mode` (1..32: bit mode − 1).
[[nodiscard]] constexpr std::uint32_t supported_mode_bit(std::int8_t mode) noexcept { return 1u << (mode - 1); }

/// Abort connection option codes (0x6007): what a drive does when it loses the master (its
/// heartbeat consumer times out) while operation is enabled.
inline constexpr std::int16_t kAbortConnectionNoAction = 0;
inline constexpr std::int16_t kAbortConnectionFault = 1;  ///< the CiA 402 default
/// The one the driver writes: the drive's power stage goes off at once (see canopen_arm.hpp).
inline constexpr std::int16_t kAbortConnectionDisableVoltage = 2;
inline constexpr std::int16_t kAbortConnectionQuickStop = 3;

/// 0x60C2, the interpolation time period: value · 10^index s.
struct InterpolationPeriod {
  std::uint8_t value = 0;  ///< 0x60C2:1, 1..255
  std::int8_t index = 0;   ///< 0x60C2:2, the power of ten, −6..0
};
/// The period of `period_us` µs as 0x60C2 writes it, with the largest index that is exact
/// (1000 → {1, −3}, 2500 → {25, −4}); nullopt when no value ≤ 255 is exact (333) or period_us ≤ 0.
[[nodiscard]] std::optional<InterpolationPeriod> interpolation_period(std::int64_t period_us) noexcept;

}  // namespace lancet::device::canopen
