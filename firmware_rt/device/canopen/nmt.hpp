#pragma once
// CiA 301 network management: the NMT commands a master sends (COB-ID 0x000), the NMT states a
// node reports in its heartbeat and boot-up message (0x700 + node id), and the heartbeat
// consumer entry (0x1016:n) by which a node watches another's heartbeat. Real-time safe.

#include <cstdint>
#include <optional>

#include "device/canopen/cob_id.hpp"
#include "device/canopen/frame.hpp"

namespace lancet::device::canopen {

/// NMT command specifiers (byte 0 of an NMT frame; byte 1 is the node id, 0 for all).
enum class NmtCommand : std::uint8_t {
  kStart = 0x01,
  kStop = 0x02,
  kEnterPreOperational = 0x80,
  kResetNode = 0x81,
  kResetCommunication = 0x82,
};

/// NMT states as a heartbeat reports them (byte 0; boot-up is the one-off 0x00).
enum class NmtState : std::uint8_t {
  kBootUp = 0x00,
  kStopped = 0x04,
  kOperational = 0x05,
  kPreOperational = 0x7F,
  kUnknown = 0xFF,  ///< nothing heard yet, or a byte that names no state
};

[[nodiscard]] const char* to_string(NmtState s) noexcept;

/// The state in a heartbeat's byte 0 (bit 7, the node guarding toggle, ignored); kUnknown for a
/// value that is no state.
[[nodiscard]] constexpr NmtState nmt_state_from_byte(std::uint8_t b) noexcept {
  switch (b & 0x7F) {
    case 0x00: return NmtState::kBootUp;
    case 0x04: return NmtState::kStopped;
    case 0x05: return NmtState::kOperational;
    case 0x7F: return NmtState::kPreOperational;
    default: return NmtState::kUnknown;
  }
}

/// The NMT frame for `cmd` to node `node_id` (0: every node).
[[nodiscard]] constexpr Frame nmt_frame(NmtCommand cmd, int node_id) noexcept {
  Frame f{};
  f.cob_id = kCobNmt;
  f.len = 2;
  f.data[0] = static_cast<std::uint8_t>(cmd);
  f.data[1] = static_cast<std::uint8_t>(node_id);
  return f;
}

/// An NMT command as received. `command` is the byte as sent: it may name no NmtCommand.
struct NmtRequest {
  NmtCommand command{};
  int node_id = 0;  ///< 0: every node
};
/// The command in an NMT frame; nullopt when the COB-ID is not 0x000 or the frame is under 2 bytes.
[[nodiscard]] constexpr std::optional<NmtRequest> decode_nmt(const Frame& f) noexcept {
  if ((f.cob_id & kCobIdMask) != kCobNmt || f.len < 2) return std::nullopt;
  return NmtRequest{static_cast<NmtCommand>(f.data[0]), f.data[1]};
}

/// A heartbeat of node `node_id` in `state` (kBootUp: the boot-up message).
[[nodiscard]] constexpr Frame heartbeat_frame(int node_id, NmtState state) noexcept {
  Frame f{};
  f.cob_id = heartbeat_cob_id(node_id);
  f.len = 1;
  f.data[0] = static_cast<std::uint8_t>(state);
  return f;
}

/// The state in a heartbeat or boot-up message; nullopt when the frame is empty or is no heartbeat.
[[nodiscard]] constexpr std::optional<NmtState> decode_heartbeat(const Frame& f) noexcept {
  if (decode_cob_id(f.cob_id).function != Function::kHeartbeat || f.len < 1) return std::nullopt;
  return nmt_state_from_byte(f.data[0]);
}

/// A heartbeat consumer entry (0x1016:n): watch node `producer_id`, time out after `time_ms` ms
/// without its heartbeat. Node id 0 or time 0: the entry is off.
[[nodiscard]] constexpr std::uint32_t heartbeat_consumer_entry(int producer_id, std::uint32_t time_ms) noexcept {
  return static_cast<std::uint32_t>(producer_id) << 16 | (time_ms & 0xFFFF);
}
/// The producer node id (bits 16..22) and the consumer time in ms (bits 0..15) of an entry.
[[nodiscard]] constexpr int consumer_producer_id(std::uint32_t entry) noexcept { return static_cast<int>((entry >> 16) & kNodeIdMask); }
[[nodiscard]] constexpr std::uint32_t consumer_time_ms(std::uint32_t entry) noexcept { return entry & 0xFFFF; }

}  // namespace lancet::device::canopen
