#pragma once
// CANopen COB-IDs of the CiA 301 predefined connection set: an 11-bit identifier is a function
// code (bits 7..10) plus a node id (bits 0..6, 1..127). NMT (0x000) and SYNC (0x080) carry no
// node id. Header only, constexpr, real-time safe.

#include <cstdint>

namespace lancet::device::canopen {

inline constexpr std::uint32_t kCobIdMask = 0x7FF;     ///< the 11 identifier bits
inline constexpr std::uint32_t kNodeIdMask = 0x07F;    ///< the node id in a COB-ID
inline constexpr std::uint32_t kFunctionMask = 0x780;  ///< the function code in a COB-ID
inline constexpr int kMaxNodeId = 127;

inline constexpr std::uint32_t kCobNmt = 0x000;
inline constexpr std::uint32_t kCobSync = 0x080;
inline constexpr std::uint32_t kCobEmcy = 0x080;       ///< + node id
inline constexpr std::uint32_t kCobSdoTx = 0x580;      ///< server → client, + node id
inline constexpr std::uint32_t kCobSdoRx = 0x600;      ///< client → server, + node id
inline constexpr std::uint32_t kCobHeartbeat = 0x700;  ///< + node id (also the boot-up message)

/// Whether `id` is a node id a device may have (1..127).
[[nodiscard]] constexpr bool valid_node_id(int id) noexcept { return id >= 1 && id <= kMaxNodeId; }

[[nodiscard]] constexpr std::uint32_t emcy_cob_id(int node_id) noexcept { return kCobEmcy + static_cast<std::uint32_t>(node_id); }
/// SDO server → client (the drive's answers).
[[nodiscard]] constexpr std::uint32_t sdo_tx_cob_id(int node_id) noexcept { return kCobSdoTx + static_cast<std::uint32_t>(node_id); }
/// SDO client → server (the master's requests).
[[nodiscard]] constexpr std::uint32_t sdo_rx_cob_id(int node_id) noexcept { return kCobSdoRx + static_cast<std::uint32_t>(node_id); }
[[nodiscard]] constexpr std::uint32_t heartbeat_cob_id(int node_id) noexcept {
  return kCobHeartbeat + static_cast<std::uint32_t>(node_id);
}
/// TPDOn (node → host) and RPDOn (host → node) COB-IDs of the predefined connection set, n = 1..4.
[[nodiscard]] constexpr std::uint32_t tpdo_cob_id(int number, int node_id) noexcept {
  return static_cast<std::uint32_t>(0x080 + 0x100 * number + node_id);
}
[[nodiscard]] constexpr std::uint32_t rpdo_cob_id(int number, int node_id) noexcept {
  return static_cast<std::uint32_t>(0x100 + 0x100 * number + node_id);
}

/// What a COB-ID of the predefined connection set is for.
enum class Function : std::uint8_t { kNmt, kSync, kEmcy, kTpdo, kRpdo, kSdoTx, kSdoRx, kHeartbeat, kOther };

/// A COB-ID taken apart. node_id is the low 7 bits as they stand: 0 is no node (for anything
/// but NMT and SYNC a caller looking the node up finds none).
struct CobId {
  Function function = Function::kOther;
  int node_id = 0;
  int pdo_number = 0;  ///< 1..4 for kTpdo and kRpdo, else 0
};

/// The function and node of an 11-bit COB-ID (bits above 0x7FF are ignored). kOther for the
/// identifiers the predefined set leaves to others (TIME 0x100, LSS, 0x000 + a node id…).
[[nodiscard]] constexpr CobId decode_cob_id(std::uint32_t cob) noexcept {
  cob &= kCobIdMask;
  if (cob == kCobNmt) return {Function::kNmt, 0, 0};
  if (cob == kCobSync) return {Function::kSync, 0, 0};
  const int node = static_cast<int>(cob & kNodeIdMask);
  const std::uint32_t fn = cob & kFunctionMask;
  switch (fn) {
    case 0x080: return {Function::kEmcy, node, 0};
    case 0x180:
    case 0x280:
    case 0x380:
    case 0x480: return {Function::kTpdo, node, static_cast<int>((fn - 0x080) / 0x100)};
    case 0x200:
    case 0x300:
    case 0x400:
    case 0x500: return {Function::kRpdo, node, static_cast<int>((fn - 0x100) / 0x100)};
    case kCobSdoTx: return {Function::kSdoTx, node, 0};
    case kCobSdoRx: return {Function::kSdoRx, node, 0};
    case kCobHeartbeat: return {Function::kHeartbeat, node, 0};
    default: return {Function::kOther, node, 0};
  }
}

}  // namespace lancet::device::canopen
