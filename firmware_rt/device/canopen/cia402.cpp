#include "device/canopen/cia402.hpp"

namespace lancet::device::canopen {

Cia402State cia402_state(std::uint16_t sw) noexcept {
  if ((sw & 0x4F) == 0x00) return Cia402State::kNotReadyToSwitchOn;
  if ((sw & 0x4F) == 0x40) return Cia402State::kSwitchOnDisabled;
  if ((sw & 0x6F) == 0x21) return Cia402State::kReadyToSwitchOn;
  if ((sw & 0x6F) == 0x23) return Cia402State::kSwitchedOn;
  if ((sw & 0x6F) == 0x27) return Cia402State::kOperationEnabled;
  if ((sw & 0x6F) == 0x07) return Cia402State::kQuickStopActive;
  if ((sw & 0x4F) == 0x0F) return Cia402State::kFaultReactionActive;
  if ((sw & 0x4F) == 0x08) return Cia402State::kFault;
  return Cia402State::kUnknown;
}

const char* to_string(Cia402State s) noexcept {
  switch (s) {
    case Cia402State::kNotReadyToSwitchOn: return "not ready to switch on";
    case Cia402State::kSwitchOnDisabled: return "switch on disabled";
    case Cia402State::kReadyToSwitchOn: return "ready to switch on";
    case Cia402State::kSwitchedOn: return "switched on";
    case Cia402State::kOperationEnabled: return "operation enabled";
    case Cia402State::kQuickStopActive: return "quick stop active";
    case Cia402State::kFaultReactionActive: return "fault reaction active";
    case Cia402State::kFault: return "fault";
    case Cia402State::kUnknown: return "unknown";
  }
  return "?";
}

std::uint16_t controlword_toward_enabled(std::uint16_t statusword, std::uint16_t previous) noexcept {
  switch (cia402_state(statusword)) {
    case Cia402State::kFault:
      // Fault reset acts on the rising edge of bit 7: drop it first if it is still set.
      return (previous & kCwFaultReset) != 0 ? kCwDisableVoltage : kCwFaultReset;
    case Cia402State::kSwitchOnDisabled: return kCwShutdown;
    case Cia402State::kReadyToSwitchOn: return kCwSwitchOn;
    case Cia402State::kSwitchedOn:
    case Cia402State::kOperationEnabled: return kCwEnableOperation;
    case Cia402State::kQuickStopActive:  // back through switch on disabled
    case Cia402State::kNotReadyToSwitchOn:
    case Cia402State::kFaultReactionActive:
    case Cia402State::kUnknown: return kCwDisableVoltage;
  }
  return kCwDisableVoltage;
}

Cia402State drive_transition(Cia402State s, std::uint16_t cw, std::uint16_t previous) noexcept {
  using S = Cia402State;
  if (s == S::kFault) {
    const bool reset_edge = (cw & kCwFaultReset) != 0 && (previous & kCwFaultReset) == 0;
    return reset_edge ? S::kSwitchOnDisabled : S::kFault;  // transition 15
  }
  // The device control commands by their bits (CiA 402, table "command coding").
  const bool voltage_off = (cw & 0x02) == 0;
  const bool quick_stop = (cw & 0x06) == 0x02;
  const bool shutdown = (cw & 0x07) == 0x06;
  const bool switch_on = (cw & 0x0F) == 0x07;
  const bool enable = (cw & 0x0F) == 0x0F;
  switch (s) {
    case S::kSwitchOnDisabled: return shutdown ? S::kReadyToSwitchOn : s;
    case S::kReadyToSwitchOn:
      if (voltage_off || quick_stop) return S::kSwitchOnDisabled;
      if (switch_on) return S::kSwitchedOn;
      if (enable) return S::kOperationEnabled;
      return s;
    case S::kSwitchedOn:
      if (voltage_off || quick_stop) return S::kSwitchOnDisabled;
      if (shutdown) return S::kReadyToSwitchOn;
      if (enable) return S::kOperationEnabled;
      return s;
    case S::kOperationEnabled:
      if (voltage_off) return S::kSwitchOnDisabled;
      if (quick_stop) return S::kQuickStopActive;
      if (shutdown) return S::kReadyToSwitchOn;
      if (switch_on) return S::kSwitchedOn;
      return s;
    case S::kQuickStopActive: return voltage_off ? S::kSwitchOnDisabled : s;
    case S::kNotReadyToSwitchOn:
    case S::kFaultReactionActive:
    case S::kFault:
    case S::kUnknown: return s;
  }
  return s;
}

std::uint16_t statusword_of(Cia402State s) noexcept {
  switch (s) {
    case Cia402State::kNotReadyToSwitchOn: return 0x0000;
    case Cia402State::kSwitchOnDisabled: return 0x0050;
    case Cia402State::kReadyToSwitchOn: return 0x0031;
    case Cia402State::kSwitchedOn: return 0x0033;
    case Cia402State::kOperationEnabled: return 0x0037;
    case Cia402State::kQuickStopActive: return 0x0017;
    case Cia402State::kFaultReactionActive: return 0x001F;
    case Cia402State::kFault: return 0x0018;
    case Cia402State::kUnknown: return 0x0000;
  }
  return 0x0000;
}

const char* mode_name(std::int8_t mode) noexcept {
  switch (mode) {
    case kModeNone: return "no mode";
    case kModeProfileTorque: return "profile torque";
    case kModeCyclicSyncTorque: return "cyclic synchronous torque";
    case 1: return "profile position";
    case 3: return "profile velocity";
    case 6: return "homing";
    case 8: return "cyclic synchronous position";
    case 9: return "cyclic synchronous velocity";
    default: return "another mode";
  }
}

std::optional<InterpolationPeriod> interpolation_period(std::int64_t period_us) noexcept {
  if (period_us <= 0) return std::nullopt;
  std::int64_t value = period_us;
  int index = -6;
  while (value % 10 == 0 && index < 0) {
    value /= 10;
    ++index;
  }
  if (value > 255) return std::nullopt;
  return InterpolationPeriod{static_cast<std::uint8_t>(value), static_cast<std::int8_t>(index)};
}

}  // namespace lancet::device::canopen
