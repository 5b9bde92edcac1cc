#pragma once
// Checks of what a peer wrote into the shared segment. Whatever crosses the process boundary is
// input: a crashed, buggy or hostile peer (or anything else with write access to the segment) may
// leave any bytes there. Every message is checked here before it is used or printed: numbers
// finite and within physical bounds, enums known, counts within capacity, texts terminated,
// timestamps not from the future.
//
// Each check returns nullptr when the message is valid, else a static string naming the first bad
// field ("patch.triangles[].v: not finite"), for counting and for a rate-limited log line. All are
// real-time safe: no allocation, no system call, O(size of the message).

#include <cstdint>

#include "lancet/shared_model/messages.hpp"

namespace lancet::wire {

/// m: nothing in a tissue scene or a haptic workspace is this far from the origin.
inline constexpr double kMaxCoordinate = 10.0;
/// N: any force on the wire above this is garbage (every clamp is far below it).
inline constexpr double kMaxForce = 1000.0;
/// Highest material id a message may name (haptics::kMaxMaterials - 1).
inline constexpr std::uint32_t kMaxMaterialId = 15;
/// ns: how far ahead of the reader's clock a timestamp may be (both processes read
/// CLOCK_MONOTONIC; a writer stamps a reading it took earlier, so only garbage gets further).
inline constexpr std::int64_t kFutureSlackNs = 5'000'000;

/// The check word of a command: a hash of its other fields (and a constant), so random bytes in
/// the ring pass for a command with probability 2^-32.
[[nodiscard]] std::uint32_t command_check(const Command& c) noexcept;
/// Sets c.check; senders call it last.
inline void seal(Command& c) noexcept { c.check = command_check(c); }
/// The check word of an operator request.
[[nodiscard]] std::uint64_t operator_request_check(const OperatorRequest& r) noexcept;
inline void seal(OperatorRequest& r) noexcept { r.check = operator_request_check(r); }

/// lancet-rt, on every command it pops.
[[nodiscard]] const char* check(const Command& c) noexcept;
/// lancet-rt, on every stylus target it reads; now_ns: its clock.
[[nodiscard]] const char* check(const StylusTarget& t, std::int64_t now_ns) noexcept;
/// lancet-rt, on every patch it reads; now_ns: its clock.
[[nodiscard]] const char* check(const TissuePatch& p, std::int64_t now_ns) noexcept;
/// lancet-rt, on an operator request; now_ns: its clock.
[[nodiscard]] const char* check(const OperatorRequest& r, std::int64_t now_ns) noexcept;
/// lancet-viz, on every ToolSample it pops.
[[nodiscard]] const char* check(const ToolSample& s) noexcept;
/// lancet-viz and lancetctl, on every RtStatus they read (before anything of it is printed).
[[nodiscard]] const char* check(const RtStatus& s) noexcept;

}  // namespace lancet::wire
