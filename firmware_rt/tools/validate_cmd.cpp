#include "tools/validate_cmd.hpp"

#include <string_view>

#include "arm/arm_config.hpp"

namespace lancet::tools {

namespace {

std::string_view backend_name(arm::Backend b) {
  switch (b) {
    case arm::Backend::kSim: return "sim";
    case arm::Backend::kUsb: return "usb";
    case arm::Backend::kModbus: return "modbus";
    case arm::Backend::kCanopen: return "canopen";
    case arm::Backend::kFalcon: return "falcon";
  }
  return "?";
}

}  // namespace

int run_validate(const std::string& path, std::FILE* out) {
  const arm::ConfigReport report = arm::validate_arm_config_file(path);
  if (!report.readable) {
    std::fputs(arm::format_report(report).c_str(), out);
    return 2;
  }
  if (!report.ok()) {
    std::fputs(arm::format_report(report).c_str(), out);
    std::fprintf(out, "%s: %zu error%s\n", path.c_str(), report.errors.size(), report.errors.size() == 1 ? "" : "s");
    return 1;
  }
  // Valid: load it for the summary (the file may have changed in between; report that honestly).
  Result<arm::ArmConfig> config = arm::load_arm_config(path);
  if (!config.ok()) {
    std::fputs(config.error().message.c_str(), out);
    return config.error().code == ErrorCode::kInvalid ? 1 : 2;
  }
  const arm::ArmConfig& c = config.value();
  const std::string_view model = arm::model_name(c.kinematics.model);
  std::fprintf(out, "%s: ok: \"%s\", backend %.*s, %.*s model, %d joints, %zu buttons\n", path.c_str(), c.name.c_str(),
               static_cast<int>(backend_name(c.backend).size()), backend_name(c.backend).data(),
               static_cast<int>(model.size()), model.data(), c.joint_count(),
               c.buttons.size());
  return 0;
}

}  // namespace lancet::tools
