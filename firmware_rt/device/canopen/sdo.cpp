#include "device/canopen/sdo.hpp"

#include <cassert>

#include "device/canopen/cob_id.hpp"

namespace lancet::device::canopen {

namespace {

Frame sdo_frame(std::uint32_t cob, std::uint8_t command, std::uint16_t index, std::uint8_t sub) noexcept {
  Frame f{};
  f.cob_id = cob;
  f.len = 8;
  f.data[0] = command;
  put_le(f.data.data() + 1, index, 2);
  f.data[3] = sub;
  return f;
}

// n (bits 2..3): the bytes of the 4-byte data field that hold no data.
std::uint8_t unused_bytes(int bytes) noexcept { return static_cast<std::uint8_t>((4 - bytes) << 2); }

}  // namespace

const char* sdo_abort_text(std::uint32_t code) noexcept {
  switch (code) {
    case 0x05030000: return "toggle bit not alternated";
    case 0x05040000: return "SDO protocol timed out";
    case 0x05040001: return "client/server command specifier not valid or unknown";
    case 0x05040005: return "out of memory";
    case 0x06010000: return "unsupported access to an object";
    case 0x06010001: return "attempt to read a write-only object";
    case 0x06010002: return "attempt to write a read-only object";
    case 0x06020000: return "object does not exist in the object dictionary";
    case 0x06040041: return "object cannot be mapped to the PDO";
    case 0x06040042: return "the number and length of the objects to be mapped would exceed the PDO length";
    case 0x06040043: return "general parameter incompatibility";
    case 0x06040047: return "general internal incompatibility in the device";
    case 0x06060000: return "access failed due to a hardware error";
    case 0x06070010: return "data type does not match, length of service parameter does not match";
    case 0x06070012: return "data type does not match, length of service parameter too high";
    case 0x06070013: return "data type does not match, length of service parameter too low";
    case 0x06090011: return "sub-index does not exist";
    case 0x06090030: return "invalid value for parameter";
    case 0x06090031: return "value of parameter written too high";
    case 0x06090032: return "value of parameter written too low";
    case 0x08000000: return "general error";
    case 0x08000020: return "data cannot be transferred or stored to the application";
    case 0x08000021: return "data cannot be transferred because of local control";
    case 0x08000022: return "data cannot be transferred because of the present device state";
    default: return "unknown abort code";
  }
}

Frame sdo_upload_request(int node_id, std::uint16_t index, std::uint8_t sub) noexcept {
  return sdo_frame(sdo_rx_cob_id(node_id), kSdoUploadRequest, index, sub);
}

Frame sdo_download_request(int node_id, std::uint16_t index, std::uint8_t sub, std::uint32_t value, int bytes) noexcept {
  assert(bytes >= 1 && bytes <= 4 && "sdo_download_request: an expedited value has 1..4 bytes");
  Frame f = sdo_frame(sdo_rx_cob_id(node_id), static_cast<std::uint8_t>(kSdoDownloadExpedited | unused_bytes(bytes)), index, sub);
  put_le(f.data.data() + 4, value, bytes);
  return f;
}

SdoResponse decode_sdo_response(const Frame& f, std::uint16_t index, std::uint8_t sub, bool upload) noexcept {
  using K = SdoResponse::Kind;
  if (f.len != 8) return {K::kNotThis, 0};
  const std::uint8_t* d = f.data.data();
  if (get_le(d + 1, 2) != index || d[3] != sub) return {K::kNotThis, 0};
  if (d[0] == kSdoAbort) return {K::kAbort, get_le(d + 4, 4)};
  if (!upload && d[0] == kSdoDownloadResponse) return {K::kOk, 0};
  if (upload && (d[0] & 0xE0) == kSdoUploadRequest) {
    if ((d[0] & 0x02) == 0) return {K::kSegmented, 0};
    return {K::kOk, get_le(d + 4, expedited_size(d[0]))};
  }
  return {K::kNotThis, 0};
}

std::optional<SdoRequest> decode_sdo_request(const Frame& f) noexcept {
  using K = SdoRequest::Kind;
  if (f.len != 8) return std::nullopt;
  const std::uint8_t* d = f.data.data();
  SdoRequest r{};
  r.index = static_cast<std::uint16_t>(get_le(d + 1, 2));
  r.sub = d[3];
  switch (d[0] >> 5) {
    case 1:  // initiate download
      if ((d[0] & 0x02) == 0) {
        r.kind = K::kSegmentedDownload;
      } else {
        r.kind = K::kDownload;
        r.bytes = expedited_size(d[0]);
        r.value = get_le(d + 4, r.bytes);
      }
      break;
    case 2: r.kind = K::kUpload; break;  // initiate upload
    default: r.kind = K::kOther; break;
  }
  return r;
}

Frame sdo_upload_response(int node_id, std::uint16_t index, std::uint8_t sub, std::uint32_t value, int bytes) noexcept {
  assert(bytes >= 1 && bytes <= 4 && "sdo_upload_response: an expedited value has 1..4 bytes");
  Frame f = sdo_frame(sdo_tx_cob_id(node_id), static_cast<std::uint8_t>(kSdoUploadExpedited | unused_bytes(bytes)), index, sub);
  put_le(f.data.data() + 4, value, bytes);
  return f;
}

Frame sdo_download_response(int node_id, std::uint16_t index, std::uint8_t sub) noexcept {
  return sdo_frame(sdo_tx_cob_id(node_id), kSdoDownloadResponse, index, sub);
}

Frame sdo_abort_response(int node_id, std::uint16_t index, std::uint8_t sub, std::uint32_t code) noexcept {
  Frame f = sdo_frame(sdo_tx_cob_id(node_id), kSdoAbort, index, sub);
  put_le(f.data.data() + 4, code, 4);
  return f;
}

}  // namespace lancet::device::canopen
