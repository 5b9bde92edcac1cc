#pragma once
// Helpers private to the CanopenArm sources (canopen_arm*.cpp): numbers in the words of the
// driver's messages, and the clock arithmetic its waits share. Not part of the device API.

#include <errno.h>
#include <time.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <string>

namespace lancet::device::canopen_detail {

/// "0x%0*X": v in hexadecimal with `digits` digits at least (allocates).
inline std::string hex(std::uint32_t v, int digits) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "0x%0*X", digits, v);
  return buf;
}

/// "0x6041:00" (allocates).
inline std::string object_name(std::uint16_t index, std::uint8_t sub) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "0x%04X:%02X", index, sub);
  return buf;
}

/// "No such device (errno 19)" (allocates).
inline std::string errno_text(int err) { return std::string(std::strerror(err)) + " (errno " + std::to_string(err) + ")"; }

/// Seconds as "12 ms" (allocates).
inline std::string ms_text(double s) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.0f ms", s * 1e3);
  return buf;
}

/// Seconds to whole nanoseconds, rounded. Real-time safe.
inline std::int64_t ns_of(double seconds) noexcept { return static_cast<std::int64_t>(std::llround(seconds * 1e9)); }

/// A CLOCK_MONOTONIC time or interval in ns as a timespec (negative: 0). Real-time safe.
inline timespec to_timespec(std::int64_t ns) noexcept {
  if (ns < 0) ns = 0;
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(ns / 1'000'000'000);
  ts.tv_nsec = static_cast<long>(ns % 1'000'000'000);
  return ts;
}

/// Sleeps until CLOCK_MONOTONIC reaches t_ns (through signals).
inline void sleep_until(std::int64_t t_ns) noexcept {
  const timespec ts = to_timespec(t_ns);
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
}

}  // namespace lancet::device::canopen_detail
