#include "device/canopen/nmt.hpp"

namespace lancet::device::canopen {

const char* to_string(NmtState s) noexcept {
  switch (s) {
    case NmtState::kBootUp: return "boot-up";
    case NmtState::kStopped: return "stopped";
    case NmtState::kOperational: return "operational";
    case NmtState::kPreOperational: return "pre-operational";
    case NmtState::kUnknown: return "unknown";
  }
  return "?";
}

}  // namespace lancet::device::canopen
