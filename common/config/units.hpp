#pragma once
// The units config files write, as factors into SI: a value `x` under a key ending in `_mm` is
// `x * kMm` metres. Keys name their unit (length_mm, offset_deg, watchdog_period_ms); the loaders
// multiply once, at the key, and everything past the loader is SI.

#include <numbers>

namespace lancet::config {

inline constexpr double kMm = 1e-3;                     ///< mm → m
inline constexpr double kDeg = std::numbers::pi / 180;  ///< deg → rad
inline constexpr double kMs = 1e-3;                     ///< ms → s
inline constexpr double kUs = 1e-6;                     ///< µs → s

}  // namespace lancet::config
