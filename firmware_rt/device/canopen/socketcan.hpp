#pragma once
// canopen::Frame ↔ SocketCAN's struct can_frame, for the code that owns a CAN_RAW socket.
// Real-time safe.

#include <linux/can.h>

#include <algorithm>
#include <cstring>

#include "device/canopen/frame.hpp"

namespace lancet::device::canopen {

/// A standard-identifier data frame; len above 8 is sent as 8.
[[nodiscard]] inline ::can_frame to_can_frame(const Frame& f) noexcept {
  ::can_frame c{};
  c.can_id = f.cob_id & CAN_SFF_MASK;
  c.len = std::min<std::uint8_t>(f.len, 8);
  std::memcpy(c.data, f.data.data(), c.len);
  return c;
}

/// The COB-ID and data of a received frame. The caller first drops error, RTR and extended frames.
[[nodiscard]] inline Frame from_can_frame(const ::can_frame& c) noexcept {
  Frame f{};
  f.cob_id = c.can_id & CAN_SFF_MASK;
  f.len = c.len;
  std::memcpy(f.data.data(), c.data, std::min<std::size_t>(c.len, 8));
  return f;
}

}  // namespace lancet::device::canopen
