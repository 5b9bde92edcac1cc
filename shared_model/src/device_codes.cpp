#include "lancet/shared_model/device_codes.hpp"

namespace lancet {

const char* to_string(DeviceLifecycle s) noexcept {
  switch (s) {
    case DeviceLifecycle::kUnconfigured: return "unconfigured";
    case DeviceLifecycle::kInactive: return "inactive";
    case DeviceLifecycle::kActive: return "active";
    case DeviceLifecycle::kFault: return "fault";
  }
  return "?";
}

const char* to_string(IoStatus s) noexcept {
  switch (s) {
    case IoStatus::kOk: return "ok";
    case IoStatus::kTimeout: return "timeout";
    case IoStatus::kCrcError: return "crc error";
    case IoStatus::kProtocolError: return "protocol error";
    case IoStatus::kDisconnected: return "disconnected";
    case IoStatus::kDeviceFault: return "device fault";
    case IoStatus::kNotActive: return "not active";
    case IoStatus::kFault: return "fault";
    case IoStatus::kImplausible: return "encoder glitch";
  }
  return "?";
}

const char* to_string(WatchdogReason r) noexcept {
  switch (r) {
    case WatchdogReason::kNone: return "none";
    case WatchdogReason::kConsecutiveMisses: return "consecutive missed deadlines";
    case WatchdogReason::kTickOverBudget: return "tick over budget";
  }
  return "?";
}

}  // namespace lancet
