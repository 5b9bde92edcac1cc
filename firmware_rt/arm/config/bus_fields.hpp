#pragma once
// What USB report fields and Modbus register entries have in common: a type from a list, the keys
// that say what the value means (scale and bias, status bits, enable on / off, the fault-reset
// value), the drive-side watchdog, and overlap checks between fields of one byte or register
// space. usb_section.cpp and modbus_section.cpp add where a field is (a byte offset; a register
// table and address). Internal to lancet::arm.

#include <cstdint>
#include <initializer_list>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "arm/config/sections.hpp"

namespace lancet::arm::detail {

/// "little" or "big".
extern const std::initializer_list<Choice<ByteOrder>> kByteOrders;

/// What else a field takes besides its place and type.
enum class Extra : std::uint8_t {
  kNone,        // a raw word (buttons, heartbeat)
  kScale,       // a quantity: scale and bias
  kBits,        // the status word: bits = { ready, fault, enabled, estop, comm_lost }
  kEnable,      // on and off values
  kFaultReset,  // the value that resets a fault
};

/// One field a bus section may have.
struct FieldSpec {
  std::string_view key;
  bool required;
  bool per_joint;
  bool written;  // Modbus: must be a holding register
  Extra extra;
  std::initializer_list<Choice<FieldType>> types;
};

/// The keys of one field that say what its value means, by spec: scale and bias, status bits,
/// enable on / off, the fault-reset value.
struct FieldMeaning {
  double scale = 1, bias = 0;
  StatusBits bits;
  std::uint32_t on = 1, off = 0, value = 0;
};

/// Reads the meaning keys of `spec.extra`; `type` is the field's type, when it read (it bounds
/// the words and the status bits).
FieldMeaning parse_meaning(Section& f, const FieldSpec& spec, std::optional<FieldType> type);

/// A setpoint entry of a bus's output: exactly one of current_command and torque_command
/// (`expected` describes them when both are missing).
void require_one_setpoint(Section& r, const std::string& expected);

/// `drive_watchdog_ms` of a bus section: meaningful only with a heartbeat; 0 is off; otherwise
/// at least 10 ms and four times the bus's own timeout (a few late replies never trip it).
/// Returns the watchdog in s.
double parse_drive_watchdog(Section& s, bool has_heartbeat, const std::string& heartbeat_field, double timeout_s);

/// A byte / register extent for overlap checks.
struct Extent {
  std::string field;
  std::int64_t begin = 0, end = 0;  // [begin, end)
  toml::source_region where;
};

/// Reports each extent that overlaps an earlier one (in file order) of the same space (`unit`:
/// "bytes", "input registers", ...).
void check_overlaps(Sink& s, std::vector<Extent> extents, const std::string& unit);

}  // namespace lancet::arm::detail
