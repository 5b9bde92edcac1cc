#pragma once
// CiA 301 process data objects: where a PDO's parameters sit in the object dictionary
// (communication 0x1400/0x1800, mapping 0x1600/0x1A00, PDO n at + n − 1), the COB-ID entry's
// valid bit, the transmission types, and the mapping entries (index << 16 | sub << 8 | bits).
// Header only, constexpr, real-time safe.

#include <cstdint>
#include <optional>

namespace lancet::device::canopen {

inline constexpr int kMaxPdos = 4;  ///< per direction, in the predefined connection set
inline constexpr int kMaxMappedObjects = 8;
/// Bit 31 of a PDO's COB-ID entry (sub 1 of its communication parameter): the PDO does not exist.
inline constexpr std::uint32_t kPdoInvalid = 0x8000'0000u;
/// Transmission types 1..240: synchronous, sent (TPDO) every nth SYNC. 241..251 are reserved.
inline constexpr std::uint8_t kMaxSyncTransmissionType = 240;

[[nodiscard]] constexpr std::uint16_t rpdo_communication_index(int number) noexcept { return static_cast<std::uint16_t>(0x1400 + number - 1); }
[[nodiscard]] constexpr std::uint16_t rpdo_mapping_index(int number) noexcept { return static_cast<std::uint16_t>(0x1600 + number - 1); }
[[nodiscard]] constexpr std::uint16_t tpdo_communication_index(int number) noexcept { return static_cast<std::uint16_t>(0x1800 + number - 1); }
[[nodiscard]] constexpr std::uint16_t tpdo_mapping_index(int number) noexcept { return static_cast<std::uint16_t>(0x1A00 + number - 1); }

/// A PDO parameter object taken apart: which PDO, and whether mapping or communication.
struct PdoParameter {
  bool tpdo = false;     ///< false: RPDO
  bool mapping = false;  ///< false: communication parameter
  int number = 0;        ///< 1..4
};
/// The PDO parameter at `index`; nullopt for any other object.
[[nodiscard]] constexpr std::optional<PdoParameter> pdo_parameter(std::uint16_t index) noexcept {
  const int base = index & 0xFFFC;
  const int number = (index & 0x3) + 1;
  switch (base) {
    case 0x1400: return PdoParameter{false, false, number};
    case 0x1600: return PdoParameter{false, true, number};
    case 0x1800: return PdoParameter{true, false, number};
    case 0x1A00: return PdoParameter{true, true, number};
    default: return std::nullopt;
  }
}

/// One mapped object: index, sub-index and length in bits.
struct MappingEntry {
  std::uint16_t index = 0;
  std::uint8_t sub = 0;
  std::uint8_t bits = 0;
};
[[nodiscard]] constexpr std::uint32_t encode_mapping(MappingEntry e) noexcept {
  return static_cast<std::uint32_t>(e.index) << 16 | static_cast<std::uint32_t>(e.sub) << 8 | e.bits;
}
[[nodiscard]] constexpr MappingEntry decode_mapping(std::uint32_t v) noexcept {
  return {static_cast<std::uint16_t>(v >> 16), static_cast<std::uint8_t>(v >> 8), static_cast<std::uint8_t>(v)};
}
/// The whole bytes an entry takes in the PDO's data.
[[nodiscard]] constexpr int mapped_bytes(std::uint32_t entry) noexcept { return static_cast<int>(entry & 0xFF) / 8; }
/// The bits the first `count` entries of `map` take together.
[[nodiscard]] constexpr int mapped_bits(const std::uint32_t* map, int count) noexcept {
  int bits = 0;
  for (int k = 0; k < count; ++k) bits += static_cast<int>(map[k] & 0xFF);
  return bits;
}

}  // namespace lancet::device::canopen
