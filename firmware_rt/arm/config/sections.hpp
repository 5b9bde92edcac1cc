#pragma once
// The arm config's schema sections, each read by its own parse_* function into the plain
// ArmConfig (arm/arm_config.hpp). arm_config.cpp reads the root and calls them in file order:
// kinematics, joints, actuators (arm_sections.cpp), the bus (bus_section.cpp, which hands the
// backend's table to sim_section.cpp, usb_section.cpp, modbus_section.cpp or
// canopen_section.cpp), safety and buttons (arm_sections.cpp). Every check records an error in
// the Sink and carries on. Internal to lancet::arm.

#include <cstddef>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "arm/arm_config.hpp"
#include "config/schema.hpp"

namespace lancet::arm::detail {

using config::Choice;
using config::describe;
using config::indexed;
using config::kAny;
using config::kOpt;
using config::kPositive;
using config::kReq;
using config::num;
using config::positive_up_to;
using config::read_integer;
using config::read_integer_in;
using config::read_number;
using config::Range;
using config::Section;
using config::Sink;

/// The largest arm config (or calibration file) read: one is a few kB; refuse anything absurd.
inline constexpr std::size_t kMaxFileBytes = 4u << 20;

/// What the sections read so far say about the rest.
struct Context {
  std::optional<int> n;          ///< joints of the kinematic model, when it is known
  std::vector<JointType> types;  ///< per joint, when the model is known
  std::optional<Backend> backend;
  std::string backend_name;
};

/// The backend's name in the file and its bus section's key: "sim", "usb", "modbus", "canopen", "falcon".
[[nodiscard]] std::string_view backend_key(Backend b);

// arm_sections.cpp
/// [kinematics]: sets ctx.n and ctx.types when the model reads.
void parse_kinematics(Section& k, KinematicsConfig& out, Context& ctx);
/// [[joints]], one per joint of the model, in its unit family (deg or mm).
void parse_joints(Section& top, std::vector<JointConfig>& out, const Context& ctx);
/// [[actuators]], one per joint.
void parse_actuators(Section& top, std::vector<ActuatorConfig>& out, const Context& ctx);
/// [safety].
void parse_safety(Section& top, SafetyConfig& out, const Context& ctx);
/// [[buttons]]: bits within the bus's button word (`button_bits` wide; unknown: 32), when the
/// backend's section has been read (`button_source_known`).
void parse_buttons(Section& top, std::vector<ButtonConfig>& out, const Context& ctx, std::optional<int> button_bits,
                   bool button_source_known);

// bus_section.cpp
/// [bus]: only the backend's own section, read by the parser of that bus. Sets `button_bits`
/// to the width of the bus's button word (nullopt: the bus has none).
void parse_bus(Section& top, ArmConfig& cfg, const Context& ctx, bool has_buttons, std::optional<int>& button_bits,
               bool& button_source_known);

// One file each; `button_bits` as for parse_bus.
SimBusConfig parse_sim(Section& s);
UsbBusConfig parse_usb(Section& s, const Context& ctx, std::optional<int>& button_bits);
ModbusBusConfig parse_modbus(Section& s, const Context& ctx, std::optional<int>& button_bits);
CanopenBusConfig parse_canopen(Section& s, const Context& ctx, bool has_buttons, std::optional<int>& button_bits);
FalconBusConfig parse_falcon(Section& s, const Context& ctx, std::optional<int>& button_bits);

}  // namespace lancet::arm::detail
