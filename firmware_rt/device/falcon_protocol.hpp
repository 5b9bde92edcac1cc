#pragma once
// The Novint Falcon's wire protocol, as its open drivers speak it (libnifalcon's
// FalconCommLibUSB, FalconFirmware and FalconFirmwareNovintSDK, BSD; CHAI3D and H3D drive the
// Falcon through the same firmware). Pure encoding and decoding: no I/O, no allocation.
//
// The Falcon is an FTDI FT232 USB-serial chip (0403:cb48) in front of a microcontroller that boots
// into a loader. Bringing it up (falcon_arm.cpp does this over device/ftdi.hpp):
//   1. the loader handshake at 9600 baud 8N1, no flow control, latency timer 16 ms: RTS low, DTR
//      low then high; send 0x0A 'C' 0x0D, the loader answers 0x0A 'D' ',' 0x0D (some hosts see a
//      0x00 before it); DTR low, 140 000 baud; send 'A', the loader answers 'A'.
//   2. the firmware upload: the file (supplied by the user; we ship none) in 62-byte chunks, each
//      echoed back byte for byte by the loader before the next goes.
//   3. normal mode: latency timer 1 ms, 1.5 Mbaud, both buffers purged. From here every 16-byte
//      command packet is answered by one 16-byte reply packet.
//
// Normal-mode packets: '<', 14 bytes each carrying one nibble as 0x41 + nibble ('A'..'P'), '>'.
//   command (host → Falcon):
//     bytes 1..12   three motor commands, signed 16-bit, four nibbles each, least significant first
//     byte 13       LEDs and homing: bit 0 homing mode, bit 1 green, bit 2 blue, bit 3 red
//     byte 14       0
//   reply (Falcon → host):
//     bytes 1..12   three encoder counts, signed 16-bit, as above
//     byte 13       0x41 + (homed << 4 | grip): grip buttons in the low nibble, bit 4+i set once
//                   motor i passed its home switch (this byte is the one that goes past 'P')
//     byte 14       0x41 (unused)

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>

namespace lancet::device::falcon {

inline constexpr std::uint16_t kVendorId = 0x0403;
inline constexpr std::uint16_t kProductId = 0xCB48;
inline constexpr std::size_t kPacketSize = 16;
inline constexpr std::size_t kUploadChunk = 62;  ///< firmware bytes per write, each echoed before the next

// The loader handshake.
inline constexpr double kLoaderBaud = 9600;
inline constexpr double kUploadBaud = 140'000;
inline constexpr double kNormalBaud = 1'500'000;
inline constexpr int kLoaderLatencyMs = 16;
inline constexpr int kNormalLatencyMs = 1;
inline constexpr std::array<std::uint8_t, 3> kLoaderHello = {0x0A, 0x43, 0x0D};
inline constexpr std::array<std::uint8_t, 4> kLoaderHelloReply = {0x0A, 0x44, 0x2C, 0x0D};
inline constexpr std::uint8_t kUploadReady = 0x41;

/// LED and homing bits of the command's byte 13 (before the 0x41 offset).
enum : std::uint8_t { kHomingMode = 0x1, kLedGreen = 0x2, kLedBlue = 0x4, kLedRed = 0x8 };
/// All three motors homed (Reply::homed).
inline constexpr std::uint8_t kAllHomed = 0x7;

struct Command {
  std::array<std::int16_t, 3> motor{};
  std::uint8_t leds = 0;  ///< kLedGreen | kLedBlue | kLedRed
  bool homing = false;
};

struct Reply {
  std::array<std::int16_t, 3> encoder{};
  std::uint8_t grip = 0;   ///< the grip's buttons, bits 0..3
  std::uint8_t homed = 0;  ///< bit i: motor i has passed its home switch
};

/// The 16 bytes of a command packet. Real-time safe.
[[nodiscard]] std::array<std::uint8_t, kPacketSize> encode(const Command& c) noexcept;

/// Why a 16-byte window is not a reply.
enum class Malformed : std::uint8_t { kNone, kFraming, kNibble };

/// Decodes a reply packet: nullopt when the framing ('<' … '>') or a nibble byte is wrong (the
/// reason in `why` when given). Real-time safe.
[[nodiscard]] std::optional<Reply> decode_reply(std::span<const std::uint8_t, kPacketSize> p, Malformed* why = nullptr) noexcept;

/// What the receive buffer holds, scanned from the front.
struct Scan {
  std::optional<Reply> newest;  ///< the last well-formed reply in the buffer
  std::size_t replies = 0;      ///< well-formed replies found (more than one: the older were late)
  std::size_t malformed = 0;    ///< '<'…'>' windows that failed to decode, and runs of bytes outside any packet
  std::size_t consumed = 0;     ///< bytes to drop from the front (an incomplete packet at the end stays)
};
/// Finds the replies in `rx` (data bytes as they came), resynchronising on '<' after junk.
/// Real-time safe.
[[nodiscard]] Scan scan_replies(std::span<const std::uint8_t> rx) noexcept;

/// Whether `got` is the loader's answer to kLoaderHello (with or without the leading 0x00).
[[nodiscard]] bool is_loader_hello_reply(std::span<const std::uint8_t> got) noexcept;

}  // namespace lancet::device::falcon
