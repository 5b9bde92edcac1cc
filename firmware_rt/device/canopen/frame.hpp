#pragma once
// A CAN frame as the CANopen codec reads and writes it: an 11-bit COB-ID and up to 8 data bytes,
// with the little-endian packing CiA 301 uses for every value. Kept free of <linux/can.h>: the
// SocketCAN users convert at their socket (socketcan.hpp). Header only; everything here is
// real-time safe (no allocation, no exceptions).

#include <array>
#include <cstdint>

namespace lancet::device::canopen {

/// One classic CAN data frame (no RTR, no extended identifier).
struct Frame {
  std::uint32_t cob_id = 0;            ///< 11-bit identifier, 0x000..0x7FF
  std::uint8_t len = 0;                ///< data bytes, 0..8
  std::array<std::uint8_t, 8> data{};  ///< bytes beyond len are 0
};

/// Writes the low `bytes` bytes of v at p, least significant first (CiA 301 byte order).
/// Precondition: 0 <= bytes <= 4 and p has room for them.
constexpr void put_le(std::uint8_t* p, std::uint32_t v, int bytes) noexcept {
  for (int b = 0; b < bytes; ++b) p[b] = static_cast<std::uint8_t>(v >> (8 * b));
}

/// The value of `bytes` bytes at p, least significant first. Precondition: 0 <= bytes <= 4.
[[nodiscard]] constexpr std::uint32_t get_le(const std::uint8_t* p, int bytes) noexcept {
  std::uint32_t v = 0;
  for (int b = 0; b < bytes; ++b) v |= static_cast<std::uint32_t>(p[b]) << (8 * b);
  return v;
}

}  // namespace lancet::device::canopen
