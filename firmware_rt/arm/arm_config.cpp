// The arm config loader: reads the root table and hands each schema section to its parser
// (arm/config/sections.hpp says which file reads which), then reports every error found, in file
// order. The schema reader itself (Sink, Section, value describers) is common/config/schema.hpp.

#include "arm/arm_config.hpp"

#include <optional>
#include <utility>

#include "arm/config/sections.hpp"
#include "config/text_file.hpp"

namespace lancet::arm {

namespace {

using namespace detail;

ArmConfig parse_root(const toml::table& root, Sink& sink) {
  ArmConfig cfg;
  cfg.source = sink.file;
  Section top(sink, root, "");
  cfg.schema_version = static_cast<int>(top.integer("schema_version", kReq, 1, 1).value_or(1));
  cfg.name = top.text("name", kReq, 64).value_or("");
  cfg.description = top.text("description", kOpt, 1024).value_or("");
  Context ctx;
  ctx.backend = top.choice<Backend>("backend", kReq,
                                    {{"sim", Backend::kSim}, {"usb", Backend::kUsb}, {"modbus", Backend::kModbus},
                                     {"canopen", Backend::kCanopen}, {"falcon", Backend::kFalcon}});
  if (ctx.backend) {
    cfg.backend = *ctx.backend;
    ctx.backend_name = std::string(backend_key(*ctx.backend));
  }

  if (const toml::table* kt = top.table("kinematics", kReq)) {
    Section k(sink, *kt, "kinematics");
    parse_kinematics(k, cfg.kinematics, ctx);
    k.finish();
  }
  parse_joints(top, cfg.joints, ctx);
  parse_actuators(top, cfg.actuators, ctx);

  // Without a usable model, size the per-joint bus fields by the joints table.
  Context bus_ctx = ctx;
  if (!bus_ctx.n && !cfg.joints.empty()) bus_ctx.n = static_cast<int>(cfg.joints.size());

  const toml::node* bn = root.get("buttons");
  const bool has_buttons = bn != nullptr && bn->as_array() != nullptr && !bn->as_array()->empty();
  std::optional<int> button_bits;
  bool button_source_known = false;
  parse_bus(top, cfg, bus_ctx, has_buttons, button_bits, button_source_known);
  parse_safety(top, cfg.safety, bus_ctx);
  parse_buttons(top, cfg.buttons, ctx, button_bits, button_source_known);
  top.finish();
  return cfg;
}

struct Parsed {
  ConfigReport report;
  std::optional<ArmConfig> config;
};

Parsed parse_text(std::string_view text, const std::string& source_name) {
  Parsed out;
  out.report.file = source_name;
  Sink sink{source_name, {}};
  if (const auto root = config::parse_toml(text, sink)) {
    ArmConfig cfg = parse_root(*root, sink);
    if (sink.errors.empty()) out.config = std::move(cfg);
  }
  config::sort_errors(sink.errors);
  out.report.errors = std::move(sink.errors);
  return out;
}

ConfigReport unreadable(const std::string& path, std::string why) {
  ConfigReport r;
  r.file = path;
  r.readable = false;
  ConfigError e;
  e.file = path;
  e.expected = "a readable file";
  e.found = why;
  e.message = std::move(why);
  r.errors.push_back(std::move(e));
  return r;
}

}  // namespace

int field_size(FieldType t) noexcept {
  switch (t) {
    case FieldType::kU8:
    case FieldType::kI8: return 1;
    case FieldType::kU16:
    case FieldType::kI16: return 2;
    case FieldType::kU32:
    case FieldType::kI32:
    case FieldType::kF32: return 4;
  }
  return 1;
}

ConfigReport validate_arm_config_text(std::string_view text, const std::string& source_name) {
  return parse_text(text, source_name).report;
}

ConfigReport validate_arm_config_file(const std::string& path) {
  auto text = config::read_text_file(path, kMaxFileBytes, "an arm config");
  if (!text.ok()) return unreadable(path, text.error().message);
  return validate_arm_config_text(text.value(), path);
}

Result<ArmConfig> load_arm_config_text(std::string_view text, const std::string& source_name) {
  Parsed p = parse_text(text, source_name);
  if (!p.config) return Error{ErrorCode::kInvalid, format_report(p.report)};
  return std::move(*p.config);
}

Result<ArmConfig> load_arm_config(const std::string& path) {
  auto text = config::read_text_file(path, kMaxFileBytes, "an arm config");
  if (!text.ok()) return Error{text.error().code, path + ": " + text.error().message};
  return load_arm_config_text(text.value(), path);
}

std::string format_report(const ConfigReport& report) { return config::format_errors(report.errors); }

}  // namespace lancet::arm
