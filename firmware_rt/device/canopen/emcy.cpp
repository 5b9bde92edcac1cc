#include "device/canopen/emcy.hpp"

#include <cstdio>

namespace lancet::device::canopen {

Frame emcy_frame(int node_id, std::uint16_t error_code, std::uint8_t error_register) noexcept {
  Frame f{};
  f.cob_id = emcy_cob_id(node_id);
  f.len = 8;
  put_le(f.data.data(), error_code, 2);
  f.data[2] = error_register;
  return f;
}

std::optional<Emcy> decode_emcy(const Frame& f) noexcept {
  const CobId c = decode_cob_id(f.cob_id);
  if (c.function != Function::kEmcy || f.len < 3) return std::nullopt;
  Emcy e{};
  e.node_id = c.node_id;
  e.error_code = static_cast<std::uint16_t>(get_le(f.data.data(), 2));
  e.error_register = f.data[2];
  for (std::size_t b = 0; b < e.vendor.size(); ++b) e.vendor[b] = b + 3 < f.len ? f.data[b + 3] : 0;
  return e;
}

namespace {

struct EmcyEntry {
  std::uint16_t code;
  const char* text;
};

// The common codes of CiA 301 (communication) and CiA 402 / IEC 61800-7 (drives).
constexpr EmcyEntry kEmcyCodes[] = {
    {0x0000, "error reset or no error"},
    {0x1000, "generic error"},
    {0x2110, "short circuit / earth leakage (input side)"},
    {0x2120, "earth leakage (input side)"},
    {0x2130, "short circuit (input side)"},
    {0x2230, "short circuit / earth leakage (inside the device)"},
    {0x2300, "current, device output side"},
    {0x2310, "continuous over-current (output side)"},
    {0x2311, "continuous over-current no. 1 (output side)"},
    {0x2312, "continuous over-current no. 2 (output side)"},
    {0x2320, "short circuit / earth leakage (motor side)"},
    {0x2330, "earth leakage (motor side)"},
    {0x2340, "short circuit (motor side)"},
    {0x3110, "mains over-voltage"},
    {0x3120, "mains under-voltage"},
    {0x3130, "mains phase failure"},
    {0x3210, "DC link over-voltage"},
    {0x3220, "DC link under-voltage"},
    {0x3230, "DC link load error"},
    {0x3310, "output over-voltage"},
    {0x4110, "excess ambient temperature"},
    {0x4120, "too low ambient temperature"},
    {0x4210, "excess device temperature"},
    {0x4220, "too low device temperature"},
    {0x4300, "drive temperature"},
    {0x4310, "drive over-temperature"},
    {0x4320, "too low drive temperature"},
    {0x4410, "excess supply temperature"},
    {0x5111, "control supply ±15 V"},
    {0x5112, "control supply +24 V"},
    {0x5113, "control supply +5 V"},
    {0x5210, "measurement circuit"},
    {0x5220, "computing circuit"},
    {0x5400, "power section"},
    {0x5410, "output stages"},
    {0x5420, "chopper"},
    {0x5430, "input stages"},
    {0x5440, "contactors"},
    {0x5441, "contactor 1 (manufacturer-specific)"},
    {0x5450, "fuses"},
    {0x5530, "flash memory"},
    {0x6010, "software reset (watchdog)"},
    {0x6100, "internal software"},
    {0x6200, "user software"},
    {0x6300, "data set"},
    {0x6320, "parameter error"},
    {0x7110, "brake chopper"},
    {0x7111, "brake chopper failure"},
    {0x7112, "brake chopper over-current"},
    {0x7120, "motor"},
    {0x7121, "motor blocked"},
    {0x7122, "motor error or commutation malfunction"},
    {0x7123, "motor tilted"},
    {0x7300, "sensor"},
    {0x7303, "resolver 1 fault"},
    {0x7304, "resolver 2 fault"},
    {0x7305, "incremental encoder 1 fault"},
    {0x7306, "incremental encoder 2 fault"},
    {0x7310, "speed sensor"},
    {0x7320, "position sensor"},
    {0x8100, "communication"},
    {0x8110, "CAN overrun (objects lost)"},
    {0x8120, "CAN in error passive mode"},
    {0x8130, "heartbeat / life guard error"},
    {0x8140, "recovered from bus off"},
    {0x8150, "CAN-ID collision"},
    {0x8200, "protocol error"},
    {0x8210, "PDO not processed: length error"},
    {0x8220, "PDO length exceeded"},
    {0x8240, "unexpected SYNC data length"},
    {0x8250, "RPDO timeout"},
    {0x8300, "torque control"},
    {0x8311, "excess torque"},
    {0x8312, "difficult start-up"},
    {0x8313, "standstill torque"},
    {0x8321, "insufficient torque"},
    {0x8331, "torque fault"},
    {0x8400, "velocity / speed controller"},
    {0x8500, "position controller"},
    {0x8600, "positioning controller"},
    {0x8611, "following error"},
    {0x8612, "reference limit"},
    {0x8700, "sync controller"},
    {0x8800, "winding controller"},
    {0x9000, "external error"},
    {0xF000, "additional functions"},
    {0xFF00, "device-specific"},
};

// Classes by the high byte, then by the high nibble.
constexpr EmcyEntry kEmcyByteClasses[] = {
    {0x00, "error reset or no error"},  {0x10, "generic error"},
    {0x20, "current"},                  {0x21, "current, device input side"},
    {0x22, "current inside the device"}, {0x23, "current, device output side"},
    {0x30, "voltage"},                  {0x31, "mains voltage"},
    {0x32, "voltage inside the device"}, {0x33, "output voltage"},
    {0x40, "temperature"},              {0x41, "ambient temperature"},
    {0x42, "device temperature"},       {0x43, "drive temperature"},
    {0x44, "supply temperature"},       {0x50, "device hardware"},
    {0x51, "supply"},                   {0x52, "control"},
    {0x53, "operating unit"},           {0x54, "power section"},
    {0x55, "data storage"},             {0x60, "device software"},
    {0x61, "internal software"},        {0x62, "user software"},
    {0x63, "data set"},                 {0x70, "additional modules"},
    {0x71, "power"},                    {0x72, "measurement circuit"},
    {0x73, "sensor"},                   {0x74, "computation circuit"},
    {0x75, "communication"},            {0x76, "data storage"},
    {0x80, "monitoring"},               {0x81, "monitoring: communication"},
    {0x82, "monitoring: protocol error"}, {0x83, "torque control"},
    {0x84, "velocity / speed controller"}, {0x85, "position controller"},
    {0x86, "positioning controller"},   {0x87, "sync controller"},
    {0x88, "winding controller"},       {0x90, "external error"},
    {0xF0, "additional functions"},     {0xFF, "device-specific"},
};
constexpr const char* kEmcyNibbleClasses[16] = {
    "error reset or no error", "generic error", "current", "voltage", "temperature", "device hardware",
    "device software", "additional modules", "monitoring", "external error", "reserved class", "reserved class",
    "reserved class", "reserved class", "reserved class", "additional functions",
};

}  // namespace

EmcyMeaning emcy_meaning(std::uint16_t code) noexcept {
  for (const EmcyEntry& e : kEmcyCodes)
    if (e.code == code) return {e.text, true};
  for (const EmcyEntry& e : kEmcyByteClasses)
    if (e.code == (code >> 8)) return {e.text, false};
  return {kEmcyNibbleClasses[code >> 12], false};
}

const char* format_emcy(char* buf, std::size_t size, const Emcy& e) noexcept {
  if (buf == nullptr || size == 0) return buf;
  const EmcyMeaning m = emcy_meaning(e.error_code);
  bool by_byte = false;
  for (const EmcyEntry& c : kEmcyByteClasses) by_byte = by_byte || c.code == (e.error_code >> 8);
  if (m.specific) {
    std::snprintf(buf, size, "node %d: EMCY 0x%04X %s, error register 0x%02X", e.node_id, e.error_code, m.text, e.error_register);
  } else if (by_byte) {
    std::snprintf(buf, size, "node %d: EMCY 0x%04X (0x%02Xxx %s), error register 0x%02X", e.node_id, e.error_code,
                  e.error_code >> 8, m.text, e.error_register);
  } else {
    std::snprintf(buf, size, "node %d: EMCY 0x%04X (0x%Xxxx %s), error register 0x%02X", e.node_id, e.error_code,
                  e.error_code >> 12, m.text, e.error_register);
  }
  return buf;
}

}  // namespace lancet::device::canopen
