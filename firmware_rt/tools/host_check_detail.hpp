#pragma once
// host-check's parts (tools/host_check*.cpp): the reader of a root folder's /proc and /sys and one
// function per check. Internal to lancetctl and its tests.

#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "tools/host_check.hpp"

namespace lancet::tools::host_check {

/// Reads files under a root folder: path("/proc/cmdline") is <root>/proc/cmdline.
class HostFs {
 public:
  explicit HostFs(std::string root);
  [[nodiscard]] std::string path(std::string_view absolute) const;
  /// The first line (no '\n'); empty when the file cannot be read.
  [[nodiscard]] std::optional<std::string> line(std::string_view absolute) const;
  /// The whole file; empty when it cannot be read.
  [[nodiscard]] std::optional<std::string> text(std::string_view absolute) const;
  [[nodiscard]] bool exists(std::string_view absolute) const;
  /// Names in a folder, sorted; none when it cannot be read.
  [[nodiscard]] std::vector<std::string> list(std::string_view absolute) const;
  /// The folder's real path below the root (symbolic links followed), as an absolute path without
  /// the root; empty when it does not resolve inside the root.
  [[nodiscard]] std::string resolve(std::string_view absolute) const;

 private:
  std::string root_;  ///< without a trailing '/' ("" for "/")
};

/// A running process: pid and comm.
struct Process {
  int pid = 0;
  std::string comm;
};
/// Every process in <root>/proc.
[[nodiscard]] std::vector<Process> processes(const HostFs& fs);

/// The value of `name` on a kernel command line: "" for a bare `name`, none when absent (the last
/// one wins, as for the kernel; init's arguments after " -- " are not looked at).
[[nodiscard]] std::optional<std::string> boot_param(const std::string& cmdline, std::string_view name);
/// The CPUs of an isolcpus / nohz_full / rcu_nocbs value ("domain,managed_irq,2-3" → 2, 3; flags
/// dropped); "all" gives every CPU in `online`.
[[nodiscard]] std::vector<int> boot_cpu_list(const std::string& value, const std::vector<int>& online);
[[nodiscard]] bool contains(const std::vector<int>& cpus, int cpu);
/// "found unreadable" result: status warn, found "unknown (cannot read <what>)".
[[nodiscard]] CheckResult unknown(std::string name, const std::string& what, std::string fix);

// ---- kernel and CPU (host_check_kernel.cpp) ----
[[nodiscard]] CheckResult check_servo_cpu(const HostFs& fs, int cpu);
[[nodiscard]] CheckResult check_preempt_rt(const HostFs& fs, const std::string& uname_version);
/// param: isolcpus, nohz_full or rcu_nocbs.
[[nodiscard]] CheckResult check_isolation(const HostFs& fs, int cpu, std::string_view param);
[[nodiscard]] CheckResult check_smt_sibling(const HostFs& fs, int cpu);
[[nodiscard]] CheckResult check_governor(const HostFs& fs, int cpu);
[[nodiscard]] CheckResult check_cstates(const HostFs& fs, int cpu, const ProcessLimits& limits);
[[nodiscard]] CheckResult check_rt_throttling(const HostFs& fs);
[[nodiscard]] CheckResult check_timer_migration(const HostFs& fs);
[[nodiscard]] CheckResult check_thp(const HostFs& fs);
[[nodiscard]] CheckResult check_swap(const HostFs& fs);
[[nodiscard]] CheckResult check_memlock(const ProcessLimits& limits);
[[nodiscard]] CheckResult check_rtprio(const ProcessLimits& limits, int priority);
[[nodiscard]] CheckResult check_clocksource(const HostFs& fs);
[[nodiscard]] CheckResult check_irqbalance(const HostFs& fs, int cpu);

// ---- the arm's bus (host_check_bus.cpp) ----
/// bus_device, bus_irq_affinity and bus_irq_thread.
[[nodiscard]] std::vector<CheckResult> check_bus(const HostFs& fs, const ArmBus& bus, int cpu, int priority);

}  // namespace lancet::tools::host_check
