#pragma once
// Real-time setup that says what took effect.
//
// RtEnvironment (process-wide, construct once in main before any thread starts):
//   mlockall(MCL_CURRENT|MCL_FUTURE); malloc trimming and mmap allocation off (so freed memory
//   stays mapped and locked); /dev/cpu_dma_latency held at 0 while the object lives; detection of
//   PREEMPT_RT and of isolated CPUs.
// start_rt_thread (per thread): SCHED_FIFO at a configurable priority set through
//   PTHREAD_EXPLICIT_SCHED at creation, CPU affinity, stack prefault.
// Every step that is not permitted (not root, RLIMIT_MEMLOCK, no CAP_SYS_NICE) is reported in one
// line with what to do about it, and the program carries on in a clearly reported degraded mode.
// Nothing here is real-time safe: it is the configure step.

#include <pthread.h>

#include <cstddef>
#include <functional>
#include <string>
#include <vector>

namespace lancet::rt {

struct RtSetupOptions {
  bool enable = true;                 ///< false: skip every step (tests, --no-rt); reported as degraded
  int priority = 80;                  ///< SCHED_FIFO priority, 1..98 (99 is left to the kernel's own threads)
  int cpu = -1;                       ///< pin the RT thread to this CPU; -1: no affinity
  bool hold_dma_latency = true;       ///< write 0 to /dev/cpu_dma_latency and keep it open
  std::size_t stack_prefault = 256 * 1024;  ///< bytes of the RT thread's stack touched up front
};

struct RtSetupReport {
  bool memory_locked = false;
  bool malloc_tuned = false;
  bool dma_latency_held = false;
  bool fifo = false;
  bool affinity = false;
  bool preempt_rt = false;
  bool cpu_isolated = false;
  std::string kernel;                 ///< uname -r and -v
  std::string isolated_cpus;          ///< /sys/devices/system/cpu/isolated ("" if none)
  std::vector<std::string> applied;   ///< one line per step that took effect
  std::vector<std::string> degraded;  ///< one line per step that did not, with the remedy
};

/// Process-wide real-time environment; holds /dev/cpu_dma_latency open while alive.
class RtEnvironment {
 public:
  RtEnvironment(const RtSetupOptions& options, RtSetupReport& report);
  ~RtEnvironment();
  RtEnvironment(const RtEnvironment&) = delete;
  RtEnvironment& operator=(const RtEnvironment&) = delete;

 private:
  int dma_fd_ = -1;
};

/// A started real-time thread; join() waits for it.
class RtThread {
 public:
  RtThread() = default;
  RtThread(RtThread&& o) noexcept;
  RtThread& operator=(RtThread&& o) noexcept;
  RtThread(const RtThread&) = delete;
  RtThread& operator=(const RtThread&) = delete;
  ~RtThread();  ///< joins if still joinable
  void join();
  [[nodiscard]] bool joinable() const noexcept { return started_; }

 private:
  friend RtThread start_rt_thread(const RtSetupOptions&, RtSetupReport&, std::function<void()>);
  pthread_t thread_{};
  bool started_ = false;
};

/// Starts body on a new thread with SCHED_FIFO (explicit scheduling attributes), the CPU affinity
/// and a prefaulted stack. When the kernel refuses FIFO or the CPU, the thread starts without
/// them and report.degraded says so. Throws std::runtime_error only when no thread can start.
RtThread start_rt_thread(const RtSetupOptions& options, RtSetupReport& report, std::function<void()> body);

/// True when the calling thread runs SCHED_FIFO.
bool current_thread_is_fifo();
/// True when the running kernel is PREEMPT_RT (/sys/kernel/realtime or uname -v).
bool kernel_is_preempt_rt();
/// The same decision from what those say: `sys_kernel_realtime` is the first line of
/// /sys/kernel/realtime ("" when there is none), `uname_version` uname's version (uname -v), which
/// names PREEMPT_RT (or "PREEMPT RT" on older kernels) on a real-time build.
bool kernel_is_preempt_rt(const std::string& sys_kernel_realtime, const std::string& uname_version);
/// The CPU the servo loop is pinned to when none is given (lancet-rt, lancetctl jitter and
/// host-check): the last online one.
int default_rt_cpu();
/// Keeps the calling thread (and the threads it starts from now on, which inherit its mask) off
/// `cpu`, the servo's: its allowed CPUs less that one. False, and nothing changed, when cpu < 0,
/// when the thread may not run there anyway, or when no other CPU would be left. A thread that
/// sets its own affinity (the servo's) is not bound by it.
bool keep_off_cpu(int cpu);
/// The calling thread's allowed CPUs less `cpu`, into `set`: what keep_off_cpu applies, for a
/// thread to be created with it (pthread_attr_setaffinity_np). False under the same conditions.
bool allowed_cpus_without(int cpu, cpu_set_t& set);
/// CPUs in a list such as "1,3-5" (the /sys cpulist format); empty on a parse error.
std::vector<int> parse_cpu_list(const std::string& list);

}  // namespace lancet::rt
