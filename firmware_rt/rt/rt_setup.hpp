#pragma once
// Best-effort real-time setup for the servo thread: lock memory, SCHED_FIFO at a configurable
// priority. Each step that is not permitted is reported in one line with what to do about it, and
// the process carries on in a degraded mode. (The real-time issue extends this: CPU affinity,
// /dev/cpu_dma_latency, PREEMPT_RT detection.)

#include <string>
#include <vector>

namespace lancet::rt {

struct RtSetupOptions {
  bool enable = true;   ///< false: skip everything (tests, --no-rt)
  int priority = 80;    ///< SCHED_FIFO priority, 1..98 (99 is left to the kernel's watchdogs)
};

struct RtSetupReport {
  bool memory_locked = false;
  bool fifo = false;
  std::vector<std::string> degraded;  ///< one line per step that did not take effect
};

/// Applies the setup to the calling thread and process. Not real-time safe (configure time).
RtSetupReport apply_rt_setup(const RtSetupOptions& options);

}  // namespace lancet::rt
