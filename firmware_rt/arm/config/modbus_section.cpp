// [bus.modbus]: the connection (TCP or RTU), the unit, and the register map.

#include <array>
#include <iterator>
#include <utility>

#include "arm/config/bus_fields.hpp"
#include "arm/config/migration.hpp"
#include "arm/config/units.hpp"

namespace lancet::arm::detail {

namespace {

const std::initializer_list<Choice<FieldType>> kRegNumberTypes = {
    {"u16", FieldType::kU16}, {"i16", FieldType::kI16}, {"u32", FieldType::kU32}, {"i32", FieldType::kI32}, {"f32", FieldType::kF32}};
const std::initializer_list<Choice<FieldType>> kRegSetpointTypes = {{"i16", FieldType::kI16}, {"i32", FieldType::kI32}, {"f32", FieldType::kF32}};
const std::initializer_list<Choice<FieldType>> kRegWordTypes = {{"u16", FieldType::kU16}, {"u32", FieldType::kU32}};
const std::initializer_list<Choice<bool>> kWordOrders = {{"high_first", true}, {"low_first", false}};

struct ModbusEntry {
  RegisterField field;
  FieldMeaning meaning;
  std::vector<Extent> extents;
};

/// Where an entry's values are: `address = N` (values back to back from N) or, per joint,
/// `address = [a0, a1, …]` (one address per joint, in any order, not overlapping).
std::vector<std::uint16_t> parse_addresses(Section& f, const FieldSpec& spec, int count, std::optional<FieldType> type,
                                           std::vector<Extent>& extents) {
  std::vector<std::uint16_t> out;
  const std::int64_t w = type ? field_size(*type) / 2 : 1;
  const std::string expected = spec.per_joint ? "an address 0..65535, or an array of " + std::to_string(count) +
                                                    " addresses (one per joint)"
                                              : "an address 0..65535";
  const toml::node* n = f.get("address");
  if (n == nullptr) {
    f.missing("address", expected);
    return out;
  }
  const std::string key(spec.key);
  if (const auto* a = n->as_array(); a != nullptr && spec.per_joint) {
    if (a->size() != static_cast<std::size_t>(count)) {
      f.sink().add(a->source(), f.field("address"), expected, describe(*a));
      return {};
    }
    bool ok = true;
    for (std::size_t j = 0; j < a->size(); ++j) {
      const std::string fj = indexed(f.field("address"), j);
      const auto v = read_integer(f.sink(), *a->get(j), fj, 0, 65535);
      if (!v) {
        ok = false;
        continue;
      }
      if (*v + w > 65536) {
        f.sink().add(a->get(j)->source(), fj, "registers within 0..65535 (one value takes " + num(w) + ")",
                     "registers " + num(*v) + ".." + num(*v + w - 1));
        ok = false;
        continue;
      }
      out.push_back(static_cast<std::uint16_t>(*v));
      extents.push_back({fj, *v, *v + w, a->get(j)->source()});
    }
    if (!ok) out.clear();
    return out;
  }
  const auto v = read_integer(f.sink(), *n, f.field("address"), 0, 65535);
  if (!v) return out;
  const int values = spec.per_joint ? count : 1;
  const std::int64_t regs = w * values;
  if (*v + regs > 65536) {
    f.sink().add(n->source(), f.field("address"), "registers within 0..65535 (" + key + " takes " + num(regs) + ")",
                 "registers " + num(*v) + ".." + num(*v + regs - 1));
    return out;
  }
  for (int j = 0; j < values; ++j) out.push_back(static_cast<std::uint16_t>(*v + j * w));
  extents.push_back({f.field("address"), *v, *v + regs, n->source()});
  return out;
}

// The connection keys of one transport; the other transport's keys are reported.
void parse_connection(Section& s, ModbusBusConfig& c) {
  const auto transport =
      s.choice<ModbusTransport>("transport", kReq, {{"tcp", ModbusTransport::kTcp}, {"rtu", ModbusTransport::kRtu}});
  if (transport) c.transport = *transport;
  if (!transport) {
    s.skip({"host", "port", "device", "baud", "parity", "data_bits", "stop_bits"});
  } else if (*transport == ModbusTransport::kTcp) {
    c.host = s.text("host", kReq, 253).value_or("");
    c.port = static_cast<int>(s.integer("port", kOpt, 1, 65535).value_or(502));
    for (const char* k : {"device", "baud", "parity", "data_bits", "stop_bits"}) s.forbid(k, "transport = \"rtu\"");
  } else {
    c.device = s.text("device", kReq, 255).value_or("");
    c.baud = static_cast<int>(s.integer("baud", kReq, 300, 4'000'000).value_or(115200));
    c.parity = s.choice<Parity>("parity", kReq, {{"none", Parity::kNone}, {"even", Parity::kEven}, {"odd", Parity::kOdd}})
                   .value_or(Parity::kNone);
    const std::int64_t data_bits[] = {7, 8};
    const std::int64_t stop_bits[] = {1, 2};
    c.data_bits = static_cast<int>(s.integer_in("data_bits", kOpt, data_bits).value_or(8));
    c.stop_bits = static_cast<int>(s.integer_in("stop_bits", kOpt, stop_bits).value_or(1));
    for (const char* k : {"host", "port"}) s.forbid(k, "transport = \"tcp\"");
  }
}

const FieldSpec kSpecs[] = {
    {"encoder_counts", true, true, false, Extra::kScale, kRegNumberTypes},
    {"current_command", false, true, true, Extra::kScale, kRegSetpointTypes},
    {"torque_command", false, true, true, Extra::kScale, kRegSetpointTypes},
    {"status", false, false, false, Extra::kBits, kRegWordTypes},
    {"buttons", false, false, false, Extra::kNone, kRegWordTypes},
    {"enable", false, false, true, Extra::kEnable, kRegWordTypes},
    {"fault_reset", false, false, true, Extra::kFaultReset, kRegWordTypes},
    {"heartbeat", false, false, true, Extra::kNone, kRegWordTypes},
    {"watchdog_timeout", false, false, true, Extra::kScale, kRegWordTypes},
};
enum : std::size_t { kEncoders, kCurrent, kTorque, kStatus, kButtons, kEnable, kFaultReset, kHeartbeat, kWatchdogTimeout };
using Entries = std::array<std::optional<ModbusEntry>, std::size(kSpecs)>;

// One entry of the register map; nullopt when its place or type did not read.
std::optional<ModbusEntry> parse_entry(Section& f, const FieldSpec& spec, int count, bool high_word_first,
                                       ByteOrder byte_order) {
  ModbusEntry e;
  const auto table = spec.written
                         ? f.choice<RegisterTable>("table", kReq, {{"holding", RegisterTable::kHolding}})
                         : f.choice<RegisterTable>("table", kReq, {{"input", RegisterTable::kInput}, {"holding", RegisterTable::kHolding}});
  const auto type = f.choice<FieldType>("type", kReq, spec.types);
  e.field.address = parse_addresses(f, spec, count, type, e.extents);
  e.field.high_word_first = f.choice<bool>("word_order", kOpt, kWordOrders).value_or(high_word_first);
  e.field.byte_order = f.choice<ByteOrder>("byte_order", kOpt, kByteOrders).value_or(byte_order);
  e.meaning = parse_meaning(f, spec, type);
  e.field.scale = e.meaning.scale;
  e.field.bias = e.meaning.bias;
  if (spec.extra == Extra::kScale) replaced_scale_keys(f, true);
  f.finish();
  if (!table || !type || e.field.address.empty()) return std::nullopt;
  e.field.table = *table;
  e.field.type = *type;
  return e;
}

// Overlaps per table; a fault reset written to the enable register itself is meant.
void check_register_overlaps(Sink& sink, const Entries& fields) {
  const auto& en = fields[kEnable];
  const auto& fr = fields[kFaultReset];
  const bool shared = en && fr && en->field.table == fr->field.table && en->field.address == fr->field.address &&
                      en->field.type == fr->field.type;
  std::vector<Extent> input, holding;
  for (std::size_t i = 0; i < fields.size(); ++i) {
    if (!fields[i] || (shared && i == kFaultReset)) continue;
    auto& dst = fields[i]->field.table == RegisterTable::kInput ? input : holding;
    dst.insert(dst.end(), fields[i]->extents.begin(), fields[i]->extents.end());
  }
  check_overlaps(sink, std::move(input), "input registers");
  check_overlaps(sink, std::move(holding), "holding registers");
}

void fill_register_map(const Entries& fields, ModbusRegisterMap& m) {
  if (fields[kEncoders]) m.encoder_counts = fields[kEncoders]->field;
  if (fields[kCurrent]) m.setpoint = fields[kCurrent]->field;
  if (fields[kTorque]) {
    m.setpoint = fields[kTorque]->field;
    m.setpoint_kind = SetpointKind::kTorque;
  }
  if (fields[kStatus]) {
    m.status = fields[kStatus]->field;
    m.status_bits = fields[kStatus]->meaning.bits;
  }
  if (fields[kButtons]) m.buttons = fields[kButtons]->field;
  if (const auto& en = fields[kEnable]) {
    m.enable = en->field;
    m.enable_on = en->meaning.on;
    m.enable_off = en->meaning.off;
  }
  if (const auto& fr = fields[kFaultReset]) {
    m.fault_reset = fr->field;
    m.fault_reset_value = fr->meaning.value;
  }
  if (fields[kHeartbeat]) m.heartbeat = fields[kHeartbeat]->field;
  if (fields[kWatchdogTimeout]) m.watchdog_timeout = fields[kWatchdogTimeout]->field;
}

// [bus.modbus.registers]: the defaults of word and byte order, then each entry.
void parse_registers(Section& r, const Context& ctx, ModbusRegisterMap& m, std::optional<int>& button_bits) {
  const bool hwf = r.choice<bool>("word_order", kOpt, kWordOrders).value_or(true);
  const ByteOrder bo = r.choice<ByteOrder>("byte_order", kOpt, kByteOrders).value_or(ByteOrder::kBig);
  Entries fields{};
  const int count = ctx.n.value_or(1);
  for (std::size_t i = 0; i < std::size(kSpecs); ++i) {
    const FieldSpec& spec = kSpecs[i];
    const toml::table* ft = r.table(spec.key, spec.required ? kReq : kOpt);
    if (ft == nullptr) continue;
    Section f(r.sink(), *ft, r.field(spec.key));
    fields[i] = parse_entry(f, spec, count, hwf, bo);
  }
  replaced_control(r, true);
  require_one_setpoint(r, "current_command = { table = \"holding\", address, type, scale } (A per count) or "
                          "torque_command = { ... } (N·m per count), one value per joint");
  r.finish();
  check_register_overlaps(r.sink(), fields);
  fill_register_map(fields, m);
  if (m.buttons) {
    button_bits = 8 * field_size(m.buttons->type);
  } else if (r.has("buttons")) {
    button_bits = 32;  // a broken entry: its own error says what is wrong, the buttons need not
  }
}

}  // namespace

ModbusBusConfig parse_modbus(Section& s, const Context& ctx, std::optional<int>& button_bits) {
  ModbusBusConfig c;
  parse_connection(s, c);
  c.unit_id = static_cast<int>(s.integer("unit_id", kReq, 1, 247).value_or(1));
  c.response_timeout = s.number("response_timeout_ms", kOpt, positive_up_to(10'000)).value_or(5) * kMs;
  bool has_heartbeat = false;
  if (const toml::table* rt = s.table("registers", kReq)) {
    Section r(s.sink(), *rt, s.field("registers"));
    parse_registers(r, ctx, c.registers, button_bits);
    has_heartbeat = rt->contains("heartbeat");
  }
  c.drive_watchdog = parse_drive_watchdog(s, has_heartbeat, "bus.modbus.registers.heartbeat", c.response_timeout);
  s.finish();
  return c;
}

}  // namespace lancet::arm::detail
