// libFuzzer target: arm configs (hw_configs TOML) through the validator, the loader and the
// kinematics factory. Any input must give a report or a config, never a crash, a hang or an
// escaping exception; a config that loads must give kinematics or a clear error.
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "arm/arm_config.hpp"
#include "arm/kinematics.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  const auto report = lancet::arm::validate_arm_config_text(text, "fuzz.toml");
  (void)lancet::arm::format_report(report);
  auto cfg = lancet::arm::load_arm_config_text(text, "fuzz.toml");
  if (cfg.ok()) {
    auto kin = lancet::arm::make_kinematics(cfg.value());
    if (kin.ok()) {
      const double q[lancet::arm::kMaxJoints] = {};
      (void)kin.value().position(std::span<const double>(q, static_cast<std::size_t>(kin.value().joint_count())));
    }
  }
  return 0;
}
