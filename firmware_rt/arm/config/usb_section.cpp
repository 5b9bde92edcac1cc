// [bus.usb]: the device's IDs and endpoints, and the layout of its IN and OUT reports.

#include <array>
#include <span>
#include <utility>

#include "arm/config/bus_fields.hpp"
#include "arm/config/migration.hpp"
#include "arm/config/units.hpp"

namespace lancet::arm::detail {

namespace {

const std::initializer_list<Choice<FieldType>> kUsbNumberTypes = {
    {"u8", FieldType::kU8},   {"i8", FieldType::kI8},   {"u16", FieldType::kU16}, {"i16", FieldType::kI16},
    {"u32", FieldType::kU32}, {"i32", FieldType::kI32}, {"f32", FieldType::kF32}};
const std::initializer_list<Choice<FieldType>> kUsbSetpointTypes = {
    {"i8", FieldType::kI8}, {"i16", FieldType::kI16}, {"i32", FieldType::kI32}, {"f32", FieldType::kF32}};
const std::initializer_list<Choice<FieldType>> kUsbWordTypes = {{"u8", FieldType::kU8}, {"u16", FieldType::kU16}, {"u32", FieldType::kU32}};

struct UsbField {
  ReportField field;
  FieldMeaning meaning;
  std::vector<Extent> extents;
};

// One report (in or out) of the USB section: size, optional report ID, its fields; a fault reset
// at exactly the enable's bytes (fields[reset_at], fields[enable_at]) shares them on purpose.
void parse_usb_report(Section& usb, std::string_view key, std::span<const FieldSpec> specs, ByteOrder default_order,
                      std::uint32_t& size, std::optional<std::uint8_t>& report_id, std::span<std::optional<UsbField>> fields,
                      const Context& ctx, std::optional<std::size_t> enable_at = {}, std::optional<std::size_t> reset_at = {}) {
  const toml::table* t = usb.table(key, kReq);
  if (t == nullptr) return;
  Section r(usb.sink(), *t, usb.field(key));
  const auto sz = r.integer("size", kReq, 1, 1024);
  size = static_cast<std::uint32_t>(sz.value_or(0));
  if (auto id = r.integer("report_id", kOpt, 1, 255)) report_id = static_cast<std::uint8_t>(*id);
  const int count = ctx.n.value_or(1);
  for (std::size_t i = 0; i < specs.size(); ++i) {
    const FieldSpec& spec = specs[i];
    const toml::table* ft = r.table(spec.key, spec.required ? kReq : kOpt);
    if (ft == nullptr) continue;
    Section f(usb.sink(), *ft, r.field(spec.key));
    UsbField uf;
    const auto off = f.integer("offset", kReq, 0, 1023);
    const auto type = f.choice<FieldType>("type", kReq, spec.types);
    uf.field.byte_order = f.choice<ByteOrder>("byte_order", kOpt, kByteOrders).value_or(default_order);
    uf.meaning = parse_meaning(f, spec, type);
    if (spec.extra == Extra::kScale) {
      uf.field.scale = uf.meaning.scale;
      uf.field.bias = uf.meaning.bias;
      replaced_scale_keys(f, false);
    }
    f.finish();
    if (!off || !type) continue;
    uf.field.offset = static_cast<std::uint32_t>(*off);
    uf.field.type = *type;
    const std::int64_t bytes = field_size(*type) * (spec.per_joint ? count : 1);
    if (sz && *off + bytes > *sz) {
      usb.sink().add(f.where("offset"), f.field("offset"),
                     "a field that fits in size = " + num(*sz) + " bytes (" + std::string(spec.key) + " takes " +
                         num(bytes) + " bytes" + (spec.per_joint ? ", one value per joint" : "") + ")",
                     "bytes " + num(*off) + ".." + num(*off + bytes - 1));
    }
    uf.extents.push_back({f.field("offset"), *off, *off + bytes, f.where("offset")});
    fields[i] = std::move(uf);
  }
  if (key == "out_report") {
    replaced_control(r, false);
    require_one_setpoint(r, "current_command = { offset, type, scale } (A per count) or torque_command = { ... } "
                            "(N·m per count), one value per joint");
  }
  r.finish();
  std::vector<Extent> extents;
  if (report_id) extents.push_back({r.field("report_id"), 0, 1, r.where("report_id")});
  const bool shared = enable_at && reset_at && fields[*enable_at] && fields[*reset_at] &&
                      fields[*enable_at]->field.offset == fields[*reset_at]->field.offset &&
                      fields[*enable_at]->field.type == fields[*reset_at]->field.type;
  for (std::size_t i = 0; i < fields.size(); ++i) {
    if (!fields[i] || (shared && i == *reset_at)) continue;
    extents.insert(extents.end(), fields[i]->extents.begin(), fields[i]->extents.end());
  }
  check_overlaps(usb.sink(), std::move(extents), "bytes");
}

}  // namespace

UsbBusConfig parse_usb(Section& s, const Context& ctx, std::optional<int>& button_bits) {
  UsbBusConfig c;
  c.vid = static_cast<std::uint16_t>(s.integer("vid", kReq, 0, 0xFFFF, true).value_or(0));
  c.pid = static_cast<std::uint16_t>(s.integer("pid", kReq, 0, 0xFFFF, true).value_or(0));
  c.interface_number = static_cast<int>(s.integer("interface", kReq, 0, 255).value_or(0));
  c.endpoint_in = static_cast<std::uint8_t>(s.integer("endpoint_in", kReq, 0x81, 0x8F, true).value_or(0x81));
  c.endpoint_out = static_cast<std::uint8_t>(s.integer("endpoint_out", kReq, 0x01, 0x0F, true).value_or(0x01));
  c.byte_order = s.choice<ByteOrder>("byte_order", kOpt, kByteOrders).value_or(ByteOrder::kLittle);
  c.timeout = s.number("timeout_ms", kOpt, positive_up_to(1000)).value_or(2) * kMs;

  const FieldSpec in_specs[] = {
      {"encoder_counts", true, true, false, Extra::kScale, kUsbNumberTypes},
      {"buttons", false, false, false, Extra::kNone, kUsbWordTypes},
      {"status", false, false, false, Extra::kBits, kUsbWordTypes},
  };
  std::array<std::optional<UsbField>, 3> in{};
  parse_usb_report(s, "in_report", in_specs, c.byte_order, c.in_size, c.in_report_id, in, ctx);
  if (in[0]) c.encoder_counts = in[0]->field;
  if (in[1]) c.buttons = in[1]->field;
  if (in[2]) {
    c.status = in[2]->field;
    c.status_bits = in[2]->meaning.bits;
  }
  if (c.buttons) button_bits = 8 * field_size(c.buttons->type);
  const toml::node* in_node = s.has("in_report") ? s.get("in_report") : nullptr;
  if (!c.buttons && in_node != nullptr && in_node->is_table() && in_node->as_table()->contains("buttons"))
    button_bits = 32;  // a broken entry: its own error says what is wrong, the buttons need not

  const FieldSpec out_specs[] = {
      {"current_command", false, true, false, Extra::kScale, kUsbSetpointTypes},
      {"torque_command", false, true, false, Extra::kScale, kUsbSetpointTypes},
      {"enable", false, false, false, Extra::kEnable, kUsbWordTypes},
      {"fault_reset", false, false, false, Extra::kFaultReset, kUsbWordTypes},
      {"heartbeat", false, false, false, Extra::kNone, kUsbWordTypes},
  };
  std::array<std::optional<UsbField>, 5> out{};
  parse_usb_report(s, "out_report", out_specs, c.byte_order, c.out_size, c.out_report_id, out, ctx, 2, 3);
  if (out[0]) c.setpoint = out[0]->field;
  if (out[1]) {
    c.setpoint = out[1]->field;
    c.setpoint_kind = SetpointKind::kTorque;
  }
  if (out[2]) {
    c.enable = out[2]->field;
    c.enable_on = out[2]->meaning.on;
    c.enable_off = out[2]->meaning.off;
  }
  if (out[3]) {
    c.fault_reset = out[3]->field;
    c.fault_reset_value = out[3]->meaning.value;
  }
  if (out[4]) c.heartbeat = out[4]->field;
  c.drive_watchdog = parse_drive_watchdog(s, c.heartbeat.has_value(), "bus.usb.out_report.heartbeat", c.timeout);
  s.finish();
  return c;
}

}  // namespace lancet::arm::detail
