#pragma once
// CiA 301 emergency messages (COB-ID 0x080 + node id): the error code (CiA 301 and the CiA 402
// drive codes), the error register (0x1001) and five manufacturer-specific bytes; what a code
// means, in words. Real-time safe.

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>

#include "device/canopen/cob_id.hpp"
#include "device/canopen/frame.hpp"

namespace lancet::device::canopen {

inline constexpr std::uint16_t kEmcyErrorReset = 0x0000;  ///< "error reset or no error"
/// The EMCY error code of a heartbeat consumer timeout (CiA 301: life guard or heartbeat error).
inline constexpr std::uint16_t kEmcyHeartbeat = 0x8130;
// Error register (0x1001) bits.
inline constexpr std::uint8_t kErrorRegisterGeneric = 0x01;
inline constexpr std::uint8_t kErrorRegisterCommunication = 0x10;

/// An emergency message. Code 0x0000 is "error reset / no error".
struct Emcy {
  int node_id = 0;
  std::uint16_t error_code = 0;
  std::uint8_t error_register = 0;
  std::array<std::uint8_t, 5> vendor{};
  std::int64_t t_ns = 0;  ///< CLOCK_MONOTONIC when received (set by the receiver)
};

/// Node `node_id`'s EMCY with `error_code` and `error_register`, 8 bytes, the vendor bytes 0.
[[nodiscard]] Frame emcy_frame(int node_id, std::uint16_t error_code, std::uint8_t error_register) noexcept;
/// The EMCY in `f`: vendor bytes the frame lacks read 0, t_ns is left 0. nullopt when the COB-ID
/// is no EMCY or the frame is under 3 bytes.
[[nodiscard]] std::optional<Emcy> decode_emcy(const Frame& f) noexcept;

/// What an EMCY error code means: `text` names the code itself when it is a common one
/// (`specific`), else its class ("current, device output side" for 0x23xx, "monitoring:
/// communication" for 0x81xx…). 0x0000 is "error reset or no error".
struct EmcyMeaning {
  const char* text = "";
  bool specific = false;
};
[[nodiscard]] EmcyMeaning emcy_meaning(std::uint16_t code) noexcept;

/// One line for an EMCY: "node 1: EMCY 0x2310 continuous over-current (output side), error register
/// 0x03"; a code known by its class only: "node 1: EMCY 0x2399 (0x23xx current, device output
/// side), error register 0x03". Truncated to `size` − 1 characters; returns `buf`.
const char* format_emcy(char* buf, std::size_t size, const Emcy& e) noexcept;

}  // namespace lancet::device::canopen
