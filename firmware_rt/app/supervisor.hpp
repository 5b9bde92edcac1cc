#pragma once
// RtSupervisor: lancet-rt's non-real-time watcher of its own servo. Polled every few ms from an
// ordinary thread, it
//   - runs each hand's device handover (RtServo::supervise): re-arms asked for, reconnects of a
//     lost bus;
//   - says on stderr, the moment it sees it, what changed: an arm fault with its cause (node,
//     code, words) and how to re-arm, a lost and a reopened bus link, a re-arm and its outcome
//     (each such line starts with the hand's name: "right arm: FAULT on ..."),
//     a watchdog trip, the viz coming and going, what the segment's peers wrote that was rejected
//     (at most once a second), encoder glitches (at most once a second);
//   - notices a servo tick that stops advancing (stalled(): the process must end).
// It reads only the servo's private status copy (RtServo::read_status), never the segment.

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "app/rt_servo.hpp"

namespace lancet::app {

struct SupervisorParams {
  std::string shm_name = kDefaultShmName;    ///< for the re-arm hint
  std::array<std::string, kHandCount> arm_name;  ///< by Hand, for the messages ("" with the built-in stylus)
  std::int64_t stall_timeout_ns = 1'000'000'000;  ///< no new tick for this long: stalled
  std::int64_t first_tick_grace_ns = 2'000'000'000;  ///< the first tick may take this much longer
  std::int64_t summary_interval_ns = 1'000'000'000;   ///< rate limit of the rejected / glitch lines
};

class RtSupervisor {
 public:
  RtSupervisor(RtServo& servo, SupervisorParams params, std::int64_t start_ns);

  /// One look at the servo at now_ns; returns the lines to print (each a full sentence, no
  /// trailing newline). May block for the duration of a re-arm or reconnect.
  std::vector<std::string> poll(std::int64_t now_ns);

  /// True once the servo's tick has not advanced for stall_timeout_ns (sticky).
  [[nodiscard]] bool stalled() const noexcept { return stalled_; }
  /// The newest status seen (zero before the first tick).
  [[nodiscard]] const RtStatus& last() const noexcept { return last_; }
  [[nodiscard]] bool has_status() const noexcept { return have_; }

 private:
  void compare(const RtStatus& before, const RtStatus& now, std::int64_t now_ns, std::vector<std::string>& out);

  RtServo& servo_;
  SupervisorParams params_;
  std::int64_t start_ns_;
  RtStatus last_{};
  bool have_ = false;
  std::uint64_t tick_seen_ = 0;
  std::int64_t tick_seen_at_ns_ = 0;
  bool stalled_ = false;
  std::int64_t next_summary_ns_ = 0;
  SegmentHealth health_reported_{};
  std::array<std::uint64_t, kHandCount> glitches_reported_{};
  std::array<std::int64_t, kHandCount> link_lost_at_ns_{};
};

/// The arm state, fault cause and words of a hand's status, as one line: "fault (timeout): node 1: ...".
[[nodiscard]] std::string describe_arm(const HandStatus& st);
/// Per-kind bus counters as one line.
[[nodiscard]] std::string describe_bus(const BusCounters& b);

}  // namespace lancet::app
