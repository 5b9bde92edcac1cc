// [bus.falcon]: which Novint Falcon, its firmware file and how the exchange runs. Every key but
// `firmware` has a default.

#include "arm/config/sections.hpp"
#include "arm/config/units.hpp"

#include <cmath>

namespace lancet::arm::detail {

FalconBusConfig parse_falcon(Section& s, const Context& ctx, std::optional<int>& button_bits) {
  FalconBusConfig c;
  c.vid = static_cast<std::uint16_t>(s.integer("vid", kOpt, 0, 0xFFFF, true).value_or(c.vid));
  c.pid = static_cast<std::uint16_t>(s.integer("pid", kOpt, 0, 0xFFFF, true).value_or(c.pid));
  c.index = static_cast<int>(s.integer("index", kOpt, 0, 127).value_or(0));
  c.firmware = s.text("firmware", kReq, 4096).value_or("");
  if (s.has("firmware") && c.firmware.empty())
    s.sink().add(s.where("firmware"), s.field("firmware"), "the path of the Falcon's firmware file (we ship none)", "\"\"");
  c.upload = s.choice<FirmwareUpload>("upload", kOpt, {{"when_needed", FirmwareUpload::kWhenNeeded}, {"always", FirmwareUpload::kAlways}})
                 .value_or(c.upload);
  c.timeout = s.number("timeout_ms", kOpt, positive_up_to(1000)).value_or(2) * kMs;
  if (auto k = s.number("motor_command_per_nm", kOpt, Range{-1e6, 1e6})) {
    if (*k == 0) s.sink().add(s.where("motor_command_per_nm"), s.field("motor_command_per_nm"), "a non-zero number", "0");
    else c.motor_command_per_nm = *k;
  }
  c.homing_timeout = s.number("homing_timeout_s", kOpt, positive_up_to(3600)).value_or(c.homing_timeout);
  if (ctx.n && *ctx.n != 3)
    s.sink().add(s.where("firmware"), s.field(""), "a three-joint kinematic model (the Falcon has three motors)",
                 std::to_string(*ctx.n) + " joints");
  button_bits = 4;  // the grip's four buttons
  s.finish();
  return c;
}

}  // namespace lancet::arm::detail
