#pragma once
// Keys the arm config schema has replaced. Each is reported at the key with the way to write it
// now (the number carried over where there is one), and counts as known, so it is not also an
// unknown key. Internal to lancet::arm.

#include <string>
#include <string_view>

#include "arm/config/sections.hpp"

namespace lancet::arm::detail {

/// `key`, when present: "\"key\" was replaced: <now>".
void replaced_key(Section& s, std::string_view key, const std::string& now);

/// `control` of a USB out_report or a Modbus register map (bit 0 enable, bit 1 fault reset):
/// written out as the `enable` and `fault_reset` entries at the old entry's place.
void replaced_control(Section& r, bool modbus);

/// The scale keys of a quantity field: `lsb_ma` (mA per count; now `scale`, A per count) and, in
/// a Modbus entry, `offset` (now `bias`).
void replaced_scale_keys(Section& f, bool modbus);

}  // namespace lancet::arm::detail
