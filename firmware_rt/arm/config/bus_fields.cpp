#include "arm/config/bus_fields.hpp"

#include <algorithm>
#include <cmath>
#include <utility>

#include "arm/config/migration.hpp"
#include "arm/config/units.hpp"

namespace lancet::arm::detail {

const std::initializer_list<Choice<ByteOrder>> kByteOrders = {{"little", ByteOrder::kLittle}, {"big", ByteOrder::kBig}};

namespace {

/// The largest raw word of an unsigned field type.
std::int64_t word_max(FieldType t) {
  return t == FieldType::kU8 ? 0xFF : t == FieldType::kU16 ? 0xFFFF : std::int64_t{0xFFFF'FFFF};
}

/// scale (> 0) and bias (finite) of a quantity field: physical = scale · raw + bias.
void parse_scale(Section& f, double& scale, double& bias) {
  scale = f.number("scale", kOpt, kPositive).value_or(1);
  bias = f.number("bias", kOpt, kAny).value_or(0);
}

/// `bits = { name = BIT, name = { bit = BIT, active_low = true }, … }` of a status word `width` bits wide.
StatusBits parse_status_bits(Section& f, int width) {
  StatusBits out;
  if (!f.has("bits")) {
    f.missing("bits", "bits = { ... }: which bits of the word mean what (ready, fault, enabled, estop, comm_lost; "
                      "e.g. bits = { fault = 0, enabled = 1 }, the fixed meaning before this key)");
    (void)f.get("bits");
    return out;
  }
  const toml::table* t = f.table("bits", kReq);
  if (t == nullptr) return out;
  Section bs(f.sink(), *t, f.field("bits"));
  const std::pair<std::string_view, StatusBit StatusBits::*> names[] = {
      {"ready", &StatusBits::ready}, {"fault", &StatusBits::fault}, {"enabled", &StatusBits::enabled},
      {"estop", &StatusBits::estop}, {"comm_lost", &StatusBits::comm_lost}};
  const std::string expected = "a bit number 0.." + std::to_string(width - 1) + ", or { bit = N, active_low = true }";
  struct Named {
    std::string_view name;
    int bit;
    toml::source_region where;
  };
  std::vector<Named> used;
  for (const auto& [name, member] : names) {
    const toml::node* n = bs.get(name);
    if (n == nullptr) continue;
    StatusBit b;
    if (n->is_integer()) {
      if (auto v = read_integer(f.sink(), *n, bs.field(name), 0, width - 1)) b.bit = static_cast<int>(*v);
    } else if (const auto* bt = n->as_table()) {
      Section e(f.sink(), *bt, bs.field(name));
      if (auto v = e.integer("bit", kReq, 0, width - 1)) b.bit = static_cast<int>(*v);
      b.active_low = e.boolean("active_low", kOpt).value_or(false);
      e.finish();
    } else {
      f.sink().add(n->source(), bs.field(name), expected, describe(*n));
    }
    if (!b.mapped()) continue;
    used.push_back({name, b.bit, n->source()});
    out.*member = b;
  }
  // Two names on one bit: reported at the later one in the file.
  std::stable_sort(used.begin(), used.end(), [](const Named& a, const Named& b) {
    return std::pair(a.where.begin.line, a.where.begin.column) < std::pair(b.where.begin.line, b.where.begin.column);
  });
  for (std::size_t i = 0; i < used.size(); ++i) {
    for (std::size_t k = 0; k < i; ++k) {
      if (used[k].bit == used[i].bit) {
        f.sink().add(used[i].where, bs.field(used[i].name), "a bit not used by " + bs.field(used[k].name), "bit " + std::to_string(used[i].bit));
        break;
      }
    }
  }
  bs.finish();
  return out;
}

/// An enable / fault-reset word: an integer that fits the field's unsigned type.
std::optional<std::uint32_t> word_value(Section& f, std::string_view key, std::optional<FieldType> type) {
  const std::int64_t hi = type ? word_max(*type) : std::int64_t{0xFFFF'FFFF};
  const auto v = f.integer(key, kReq, 0, hi, true);
  return v ? std::optional<std::uint32_t>(static_cast<std::uint32_t>(*v)) : std::nullopt;
}

}  // namespace

FieldMeaning parse_meaning(Section& f, const FieldSpec& spec, std::optional<FieldType> type) {
  FieldMeaning m;
  switch (spec.extra) {
    case Extra::kNone: break;
    case Extra::kScale: parse_scale(f, m.scale, m.bias); break;
    case Extra::kBits: m.bits = parse_status_bits(f, type ? 8 * field_size(*type) : 32); break;
    case Extra::kEnable: {
      const auto on = word_value(f, "on", type);
      const auto off = word_value(f, "off", type);
      if (on && off && *on == *off)
        f.sink().add(f.where("off"), f.field("off"), "a value other than on (" + num(std::int64_t{*on}, true) + ")", "the same value");
      m.on = on.value_or(1);
      m.off = off.value_or(0);
      break;
    }
    case Extra::kFaultReset: m.value = word_value(f, "value", type).value_or(0); break;
  }
  return m;
}

void require_one_setpoint(Section& r, const std::string& expected) {
  if (!r.has("current_command") && !r.has("torque_command")) {
    r.missing("current_command", expected);
  } else if (r.has("current_command") && r.has("torque_command")) {
    r.sink().add(r.where("torque_command"), r.field("torque_command"), "only one of current_command and torque_command", "both");
  }
}

double parse_drive_watchdog(Section& s, bool has_heartbeat, const std::string& heartbeat_field, double timeout_s) {
  const auto ms = s.integer("drive_watchdog_ms", kOpt, 0, 65'535);
  if (!has_heartbeat) {
    if (ms && *ms > 0)
      s.sink().add(s.where("drive_watchdog_ms"), s.field("drive_watchdog_ms"), "a " + heartbeat_field + " for the drive to watch",
                   "no heartbeat in the map", "drive_watchdog_ms needs " + heartbeat_field + " (the value the drive watches)");
    return 0;
  }
  const std::int64_t v = ms.value_or(100);
  const double floor_ms = std::max(10.0, 4.0 * timeout_s * 1e3);
  if (ms && v > 0 && static_cast<double>(v) < floor_ms) {
    s.sink().add(s.where("drive_watchdog_ms"), s.field("drive_watchdog_ms"),
                 "0 (off) or at least " + num(static_cast<std::int64_t>(std::ceil(floor_ms))) +
                     " ms (10 ms and 4 bus timeouts: a few late replies must not trip the drive)",
                 "integer " + num(v));
  }
  return static_cast<double>(v) * kMs;
}

// Reports each extent that overlaps an earlier one (in file order) of the same space.
void check_overlaps(Sink& s, std::vector<Extent> extents, const std::string& unit) {
  std::stable_sort(extents.begin(), extents.end(), [](const Extent& a, const Extent& b) {
    return std::pair(a.where.begin.line, a.where.begin.column) < std::pair(b.where.begin.line, b.where.begin.column);
  });
  for (std::size_t i = 0; i < extents.size(); ++i) {
    for (std::size_t j = 0; j < i; ++j) {
      const Extent& a = extents[j];
      const Extent& b = extents[i];
      if (b.begin < a.end && a.begin < b.end) {
        s.add(b.where, b.field,
              unit + " not used by " + a.field + " (" + num(a.begin) + ".." + num(a.end - 1) + ")",
              unit + " " + num(b.begin) + ".." + num(b.end - 1));
        break;
      }
    }
  }
}

}  // namespace lancet::arm::detail
