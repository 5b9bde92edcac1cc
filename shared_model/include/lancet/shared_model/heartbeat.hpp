#pragma once
// Heartbeat: one process says "I am alive" by stamping CLOCK_MONOTONIC; the other side judges
// freshness against a timeout. Lives in shared memory; one writer, any readers.

#include <atomic>
#include <cstdint>

namespace lancet {

class Heartbeat {
 public:
  /// Writer only. Stamps now_ns (CLOCK_MONOTONIC). Real-time safe.
  void beat(std::int64_t now_ns, std::int32_t pid) noexcept {
    pid_.store(pid, std::memory_order_relaxed);
    count_.store(count_.load(std::memory_order_relaxed) + 1, std::memory_order_relaxed);
    t_ns_.store(now_ns, std::memory_order_release);
  }
  /// Writer only. Marks a clean departure: readers see the peer as gone at once.
  void stop() noexcept { t_ns_.store(0, std::memory_order_release); }

  /// Last beat (ns); 0 when never beaten or stopped.
  [[nodiscard]] std::int64_t last_ns() const noexcept { return t_ns_.load(std::memory_order_acquire); }
  [[nodiscard]] std::uint64_t count() const noexcept { return count_.load(std::memory_order_relaxed); }
  [[nodiscard]] std::int32_t pid() const noexcept { return pid_.load(std::memory_order_relaxed); }
  /// True when a beat is no older than timeout_ns at now_ns. A beat from the future (more than
  /// kFutureSlackNs ahead of now_ns: the writer stamps its own earlier clock reading, so only a
  /// corrupted segment gets there) is not fresh. Real-time safe.
  [[nodiscard]] bool fresh(std::int64_t now_ns, std::int64_t timeout_ns) const noexcept {
    const std::int64_t t = last_ns();
    return t != 0 && t - now_ns <= kFutureSlackNs && now_ns - t <= timeout_ns;
  }
  static constexpr std::int64_t kFutureSlackNs = 5'000'000;

 private:
  std::atomic<std::int64_t> t_ns_{0};
  std::atomic<std::uint64_t> count_{0};
  std::atomic<std::int32_t> pid_{0};
};

}  // namespace lancet
