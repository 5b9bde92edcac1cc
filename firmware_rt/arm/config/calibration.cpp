// The calibration file: each joint's encoder offset as `lancetctl calibrate` measured it, kept
// next to the config (foo.toml → foo.calibration.toml) and read after it with the config's own
// schema reader, in the config's units (offset_deg, or offset_mm for a prismatic joint).

#include <cstdio>
#include <vector>

#include "arm/arm_config.hpp"
#include "arm/config/sections.hpp"
#include "arm/config/units.hpp"
#include "config/text_file.hpp"

namespace lancet::arm {

namespace {

using config::quote;
using detail::JointFileUnit;
using detail::joint_file_unit;
using detail::kOpt;
using detail::kReq;
using detail::Section;
using detail::Sink;

// The file's arm name: it must be the config's. False when the rest is not worth reading.
bool read_arm_name(Section& top, const ArmConfig& config) {
  const toml::node* arm = top.get("arm");
  const std::string expected = "the name of the arm this calibration is for";
  if (arm == nullptr) {
    top.missing("arm", expected);
    return true;
  }
  const auto* name = arm->as_string();
  if (name == nullptr) {
    top.sink().add(arm->source(), "arm", expected + " (a string)", config::describe(*arm));
    return true;
  }
  if (name->get() == config.name) return true;
  top.sink().add(arm->source(), "arm", "'" + config.name + "'", "'" + name->get() + "'",
                 "this calibration is for '" + name->get() + "', the config is '" + config.name + "'");
  return false;
}

// One [[joints]] entry: the config's joint name and its offset (rad or m), nullopt on an error.
std::optional<double> read_joint(Section& s, const JointConfig& jc) {
  const toml::node* name = s.get("name");
  const auto* text = name != nullptr ? name->as_string() : nullptr;
  if (text == nullptr || text->get() != jc.name) {
    const std::string expected = "'" + jc.name + "'";
    if (name == nullptr) {
      s.sink().add(s.where(), s.field("name"), expected, "nothing", "expected " + expected + ", missing");
    } else {
      s.sink().add(name->source(), s.field("name"), expected, text != nullptr ? "'" + text->get() + "'" : config::describe(*name));
    }
  }
  const JointFileUnit unit = joint_file_unit(jc.type);
  const auto offset = s.number(unit.key("offset"), kReq, config::kAny);
  s.finish();
  if (!offset) return std::nullopt;
  return *offset * unit.to_si;
}

// The offsets of every joint (rad or m, config order); empty when any error was found.
std::vector<double> read_offsets(const toml::table& root, const ArmConfig& config, Sink& sink) {
  Section top(sink, root, "");
  if (!read_arm_name(top, config)) return {};
  const toml::node* jn = top.get("joints");
  const toml::array* joints = jn != nullptr ? jn->as_array() : nullptr;
  const std::string expected = std::to_string(config.joints.size()) + " [[joints]] tables, one per joint of the config";
  top.finish();
  if (jn == nullptr) {
    top.missing("joints", expected);
    return {};
  }
  if (joints == nullptr || !joints->is_array_of_tables() || joints->size() != config.joints.size()) {
    sink.add(jn->source(), "joints", expected, config::describe(*jn));
    return {};
  }
  std::vector<double> offsets(config.joints.size());
  for (std::size_t j = 0; j < config.joints.size(); ++j) {
    Section s(sink, *joints->get(j)->as_table(), config::indexed("joints", j));
    offsets[j] = read_joint(s, config.joints[j]).value_or(0);
  }
  if (!sink.errors.empty()) return {};
  return offsets;
}

}  // namespace

std::string calibration_path(const std::string& config_path) {
  const std::string ext = ".toml";
  const bool has_ext = config_path.size() >= ext.size() && config_path.compare(config_path.size() - ext.size(), ext.size(), ext) == 0;
  return (has_ext ? config_path.substr(0, config_path.size() - ext.size()) : config_path) + ".calibration.toml";
}

std::string calibration_text(const ArmConfig& config, std::span<const double> offsets, const std::string& note) {
  std::string out = "# Encoder offsets for arm '" + config.name + "' (" + config.source + "), written by lancetctl calibrate.\n";
  out += "# " + note + "\n";
  out += "# Loaded after the config by lancet-rt and lancetctl; delete this file to use the config's offsets.\n";
  out += "arm = " + quote(config.name) + "\n";
  for (std::size_t j = 0; j < config.joints.size(); ++j) {
    const JointConfig& jc = config.joints[j];
    const JointFileUnit unit = joint_file_unit(jc.type);
    const double v = j < offsets.size() ? offsets[j] : jc.offset;
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.9g", v / unit.to_si);
    out += "\n[[joints]]\nname = " + quote(jc.name) + "\n" + unit.key("offset") + " = " + buf + "\n";
  }
  return out;
}

Result<bool> apply_calibration_file(ArmConfig& config, const std::string& path) {
  auto text = config::read_text_file(path, detail::kMaxFileBytes, "an arm config");
  if (!text.ok()) {
    if (text.error().code == ErrorCode::kNotFound) return false;
    return Error{text.error().code, path + ": " + text.error().message};
  }
  Sink sink{path, {}};
  std::vector<double> offsets;
  if (const auto root = config::parse_toml(text.value(), sink)) offsets = read_offsets(*root, config, sink);
  if (!sink.errors.empty()) {
    config::sort_errors(sink.errors);
    std::string report = config::format_errors(sink.errors);
    report.pop_back();  // the callers end the message's line
    return Error{ErrorCode::kInvalid, std::move(report)};
  }
  for (std::size_t j = 0; j < offsets.size(); ++j) config.joints[j].offset = offsets[j];
  return true;
}

}  // namespace lancet::arm
