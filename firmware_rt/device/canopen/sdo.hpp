#pragma once
// CiA 301 SDO, expedited transfers only (values of 1..4 bytes in one 8-byte frame each way):
// the requests a client (the master) sends to 0x600 + node id, the answers a server (the drive)
// sends from 0x580 + node id, and the abort codes. A segmented transfer is recognised, never
// carried out. Real-time safe.

#include <cstdint>
#include <optional>

#include "device/canopen/frame.hpp"

namespace lancet::device::canopen {

// Command bytes (byte 0): the command specifier in bits 5..7; for an expedited transfer bit 1
// (e) is set, bit 0 (s) says that bits 2..3 (n) hold 4 − the data size.
inline constexpr std::uint8_t kSdoUploadRequest = 0x40;       ///< client: initiate upload
inline constexpr std::uint8_t kSdoDownloadExpedited = 0x23;   ///< client: initiate download, e = s = 1
inline constexpr std::uint8_t kSdoUploadExpedited = 0x43;     ///< server: upload response, e = s = 1
inline constexpr std::uint8_t kSdoDownloadResponse = 0x60;    ///< server: download done
inline constexpr std::uint8_t kSdoAbort = 0x80;               ///< either side: abort transfer

// Abort codes (CiA 301, 7.2.4.3.17) that the driver or the emulated drives use by name.
inline constexpr std::uint32_t kAbortCommand = 0x05040001;       ///< command specifier not valid or unknown
inline constexpr std::uint32_t kAbortUnsupported = 0x06010000;   ///< unsupported access to an object
inline constexpr std::uint32_t kAbortReadOnly = 0x06010002;      ///< attempt to write a read-only object
inline constexpr std::uint32_t kAbortNoObject = 0x06020000;      ///< object does not exist
inline constexpr std::uint32_t kAbortNotMappable = 0x06040041;   ///< object cannot be mapped to the PDO
inline constexpr std::uint32_t kAbortPdoLength = 0x06040042;     ///< mapping would exceed the PDO length
inline constexpr std::uint32_t kAbortLength = 0x06070010;        ///< length of service parameter does not match
inline constexpr std::uint32_t kAbortNoSubindex = 0x06090011;    ///< sub-index does not exist
inline constexpr std::uint32_t kAbortValue = 0x06090030;         ///< invalid value for parameter
inline constexpr std::uint32_t kAbortDeviceState = 0x08000022;   ///< not in the present device state

/// A few words on an SDO abort code; "unknown abort code" otherwise.
[[nodiscard]] const char* sdo_abort_text(std::uint32_t code) noexcept;

/// The data size of an expedited transfer's command byte: 4 − n where s is set, else 4.
[[nodiscard]] constexpr int expedited_size(std::uint8_t command) noexcept {
  return (command & 0x01) != 0 ? 4 - ((command >> 2) & 0x03) : 4;
}

// ---- client (master) side ----

/// Initiate upload of index:sub from node `node_id`.
[[nodiscard]] Frame sdo_upload_request(int node_id, std::uint16_t index, std::uint8_t sub) noexcept;
/// Expedited download of the low `bytes` bytes (1..4) of `value` to index:sub of node `node_id`.
[[nodiscard]] Frame sdo_download_request(int node_id, std::uint16_t index, std::uint8_t sub, std::uint32_t value, int bytes) noexcept;

/// What an SDO server frame says about one request.
struct SdoResponse {
  enum class Kind : std::uint8_t {
    kOk,         ///< done: `value` holds the uploaded value (0 for a download)
    kAbort,      ///< `value` holds the abort code
    kSegmented,  ///< an upload answered with a segmented transfer (not supported)
    kNotThis,    ///< not the answer to this request (other object, other service, not 8 bytes)
  } kind = Kind::kNotThis;
  std::uint32_t value = 0;
};
/// Reads `f` (from 0x580 + node id) as the answer to an upload (`upload`) or download of
/// index:sub. The COB-ID is the caller's to check.
[[nodiscard]] SdoResponse decode_sdo_response(const Frame& f, std::uint16_t index, std::uint8_t sub, bool upload) noexcept;

// ---- server (drive) side ----

/// A client's request as a server reads it.
struct SdoRequest {
  enum class Kind : std::uint8_t {
    kUpload,              ///< initiate upload of index:sub
    kDownload,            ///< expedited download: `value`, `bytes` (1..4)
    kSegmentedDownload,   ///< initiate download without the expedited bit (not supported)
    kOther,               ///< any other command specifier
  } kind = Kind::kOther;
  std::uint16_t index = 0;
  std::uint8_t sub = 0;
  std::uint32_t value = 0;
  int bytes = 0;
};
/// The request in `f` (to 0x600 + node id); nullopt unless the frame has 8 bytes.
[[nodiscard]] std::optional<SdoRequest> decode_sdo_request(const Frame& f) noexcept;

/// Node `node_id`'s answers to a request for index:sub: the uploaded value (`bytes` 1..4), a
/// download done, or an abort with `code`.
[[nodiscard]] Frame sdo_upload_response(int node_id, std::uint16_t index, std::uint8_t sub, std::uint32_t value, int bytes) noexcept;
[[nodiscard]] Frame sdo_download_response(int node_id, std::uint16_t index, std::uint8_t sub) noexcept;
[[nodiscard]] Frame sdo_abort_response(int node_id, std::uint16_t index, std::uint8_t sub, std::uint32_t code) noexcept;

}  // namespace lancet::device::canopen
