#pragma once
// SI units used everywhere inside Lancet: metres, newtons, seconds, kilograms, radians.
// Time on the wire is CLOCK_MONOTONIC in integer nanoseconds (int64), which every process on one
// host shares. These helpers are the only place conversions are written.

#include <cstdint>
#include <ctime>

namespace lancet {

inline constexpr std::int64_t kNsPerSecond = 1'000'000'000;
inline constexpr std::int64_t kNsPerMs = 1'000'000;
inline constexpr std::int64_t kNsPerUs = 1'000;

constexpr double ns_to_seconds(std::int64_t ns) { return static_cast<double>(ns) * 1e-9; }
constexpr std::int64_t seconds_to_ns(double s) { return static_cast<std::int64_t>(s * 1e9); }
constexpr double millimetres(double mm) { return mm * 1e-3; }

/// CLOCK_MONOTONIC now, in ns. Real-time safe (vDSO, no syscall on x86-64 Linux).
inline std::int64_t monotonic_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * kNsPerSecond + ts.tv_nsec;
}

}  // namespace lancet
