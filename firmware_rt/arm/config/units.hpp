#pragma once
// The arm files' units in one place. A config writes lengths in mm, angles in degrees, periods in
// ms or µs (config/units.hpp has the factors into SI); a joint's position keys take the unit of
// its kind: offset_deg, min_deg, max_deg, max_speed_deg_s for a revolute joint, offset_mm, ...,
// lead_mm for a prismatic one, in the config and in its calibration file alike. The conversions
// between motor and joint space (declared in arm/arm_config.hpp) are in units.cpp.

#include <string>

#include "arm/kinematics.hpp"
#include "config/units.hpp"

namespace lancet::arm::detail {

using config::kDeg;
using config::kMm;
using config::kMs;
using config::kUs;

/// How a joint's positions are written in the files.
struct JointFileUnit {
  const char* suffix;  ///< "deg" or "mm": the keys are offset_<suffix>, min_<suffix>, ...
  double to_si;        ///< file unit → rad or m
  /// `<what>_<suffix>`, e.g. key("offset") is "offset_deg".
  [[nodiscard]] std::string key(const char* what) const { return std::string(what) + "_" + suffix; }
};

[[nodiscard]] inline JointFileUnit joint_file_unit(JointType type) {
  return type == JointType::kRevolute ? JointFileUnit{"deg", kDeg} : JointFileUnit{"mm", kMm};
}

}  // namespace lancet::arm::detail
