// host-check: the kernel's and the servo CPU's checks, and the process's limits. The severity
// policy is in host_check.hpp.

#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <sstream>

#include "rt/rt_setup.hpp"
#include "text/text.hpp"
#include "tools/host_check_detail.hpp"

namespace lancet::tools::host_check {

namespace {

constexpr int kCapIpcLock = 14;
constexpr int kCapSysNice = 23;
const char* const kGrub = " (GRUB_CMDLINE_LINUX in /etc/default/grub, then update-grub and reboot)";

bool has_cap(const ProcessLimits& l, int cap) { return ((l.cap_effective >> cap) & 1u) != 0; }

std::string cpu_path(int cpu, const char* rest) { return "/sys/devices/system/cpu/cpu" + std::to_string(cpu) + rest; }

std::vector<int> online_cpus(const HostFs& fs) { return rt::parse_cpu_list(fs.line("/sys/devices/system/cpu/online").value_or("")); }

std::string mib(std::uint64_t bytes) { return text::format("%.0f MiB", static_cast<double>(bytes) / (1 << 20)); }

// The CPUs isolated from the scheduler: the kernel's own view when it has one, else the boot line.
std::optional<std::vector<int>> isolated_cpus(const HostFs& fs) {
  if (auto iso = fs.line("/sys/devices/system/cpu/isolated")) return rt::parse_cpu_list(*iso);
  const auto cmdline = fs.line("/proc/cmdline");
  if (!cmdline) return std::nullopt;
  return boot_cpu_list(boot_param(*cmdline, "isolcpus").value_or(""), online_cpus(fs));
}

}  // namespace

CheckResult check_servo_cpu(const HostFs& fs, int cpu) {
  const auto online = fs.line("/sys/devices/system/cpu/online");
  if (!online) return unknown("servo_cpu", "/sys/devices/system/cpu/online", "mount sysfs: mount -t sysfs sysfs /sys");
  if (contains(rt::parse_cpu_list(*online), cpu)) return {CheckStatus::kPass, "servo_cpu", "CPU " + std::to_string(cpu) + " (online: " + *online + ")", ""};
  return {CheckStatus::kFail, "servo_cpu", "CPU " + std::to_string(cpu) + " is not online (online: " + *online + ")",
          "give lancet-rt and host-check --cpu N with an online CPU"};
}

CheckResult check_preempt_rt(const HostFs& fs, const std::string& uname_version) {
  const std::string realtime = fs.line("/sys/kernel/realtime").value_or("");
  const std::string release = fs.line("/proc/sys/kernel/osrelease").value_or("?");
  const std::string kernel = release + " (uname -v: " + uname_version + ")";
  if (rt::kernel_is_preempt_rt(realtime, uname_version)) return {CheckStatus::kPass, "preempt_rt", "PREEMPT_RT kernel " + kernel, ""};
  return {CheckStatus::kFail, "preempt_rt", "not a PREEMPT_RT kernel: " + kernel,
          "install a PREEMPT_RT kernel and boot it: apt install linux-image-rt-amd64 (Debian; Ubuntu: pro enable realtime-kernel)"};
}

CheckResult check_isolation(const HostFs& fs, int cpu, std::string_view param) {
  const std::string name(param);
  const std::string fix = "boot with " + name + "=" + std::to_string(cpu) + kGrub;
  const auto cmdline = fs.line("/proc/cmdline");
  if (!cmdline) return unknown(name, "/proc/cmdline", fix);
  const auto value = boot_param(*cmdline, param);
  std::vector<int> cpus = boot_cpu_list(value.value_or(""), online_cpus(fs));
  // The kernel's effective lists, where it publishes them (it drops CPUs it cannot isolate).
  std::string effective;
  if (param == "isolcpus") effective = fs.line("/sys/devices/system/cpu/isolated").value_or("");
  if (param == "nohz_full") effective = fs.line("/sys/devices/system/cpu/nohz_full").value_or("");
  if (!effective.empty() && effective != "(null)") cpus = rt::parse_cpu_list(effective);
  if (contains(cpus, cpu)) return {CheckStatus::kPass, name, "CPU " + std::to_string(cpu) + " in " + name + "=" + value.value_or(effective), ""};
  const std::string what = value ? name + "=" + *value + " leaves CPU " + std::to_string(cpu) + " out" : name + " not on the boot line";
  return {CheckStatus::kWarn, name, what, fix};
}

CheckResult check_smt_sibling(const HostFs& fs, int cpu) {
  const auto list = fs.line(cpu_path(cpu, "/topology/thread_siblings_list"));
  if (!list) return unknown("smt_sibling", cpu_path(cpu, "/topology/thread_siblings_list"), "");
  const auto iso = isolated_cpus(fs).value_or(std::vector<int>{});
  std::string busy, idle;
  for (int s : rt::parse_cpu_list(*list)) {
    if (s == cpu) continue;
    const bool offline = fs.line(cpu_path(s, "/online")).value_or("1") == "0";
    std::string& into = offline || contains(iso, s) ? idle : busy;
    into += (into.empty() ? "" : ",") + std::to_string(s);
  }
  if (busy.empty() && idle.empty()) return {CheckStatus::kPass, "smt_sibling", "CPU " + std::to_string(cpu) + " has no SMT sibling", ""};
  if (busy.empty()) return {CheckStatus::kPass, "smt_sibling", "sibling CPU " + idle + " isolated or offline", ""};
  return {CheckStatus::kWarn, "smt_sibling",
          "sibling CPU " + busy + " shares CPU " + std::to_string(cpu) + "'s core and runs other tasks",
          "isolate it with the servo CPU (isolcpus=" + std::to_string(cpu) + "," + busy + ") or take it offline: echo 0 > " +
              cpu_path(std::atoi(busy.c_str()), "/online") + " (or boot with nosmt)"};
}

CheckResult check_governor(const HostFs& fs, int cpu) {
  const std::string file = cpu_path(cpu, "/cpufreq/scaling_governor");
  if (!fs.exists(cpu_path(cpu, "/cpufreq"))) {
    return {CheckStatus::kSkip, "cpufreq_governor", "no cpufreq driver for CPU " + std::to_string(cpu) + " (fixed frequency; in a VM the host decides)", ""};
  }
  const std::string fix = "cpupower -c " + std::to_string(cpu) + " frequency-set -g performance (or echo performance > " + file + ")";
  const auto gov = fs.line(file);
  if (!gov) return unknown("cpufreq_governor", file, fix);
  if (*gov == "performance") return {CheckStatus::kPass, "cpufreq_governor", "performance", ""};
  return {CheckStatus::kWarn, "cpufreq_governor", *gov + ": the clock ramps up only after the servo's tick began", fix};
}

namespace {

// The cpuidle states of a CPU as "POLL 0us, C1 2us, ..." and the deepest enabled state's exit
// latency (us).
std::string idle_states(const HostFs& fs, int cpu, long& deepest_us) {
  std::string states;
  deepest_us = 0;
  for (const auto& s : fs.list(cpu_path(cpu, "/cpuidle"))) {
    if (s.rfind("state", 0) != 0) continue;
    const std::string dir = cpu_path(cpu, "/cpuidle/") + s;
    const long latency = std::atol(fs.line(dir + "/latency").value_or("0").c_str());
    const bool disabled = fs.line(dir + "/disable").value_or("0") == "1";
    states += (states.empty() ? "" : ", ") + fs.line(dir + "/name").value_or(s) + " " + std::to_string(latency) + " us" + (disabled ? " (disabled)" : "");
    if (!disabled) deepest_us = std::max(deepest_us, latency);
  }
  return states;
}

// Whether a process with these limits can open `path` for writing (root, or the mode bits).
bool writable_by(const HostFs& fs, const std::string& path, const ProcessLimits& l) {
  struct stat st {};
  if (::stat(fs.path(path).c_str(), &st) != 0) return false;
  if (l.euid == 0) return true;
  if (st.st_uid == l.euid) return (st.st_mode & S_IWUSR) != 0;
  if (st.st_gid == ::getegid() && (st.st_mode & S_IWGRP) != 0) return true;
  return (st.st_mode & S_IWOTH) != 0;
}

}  // namespace

CheckResult check_cstates(const HostFs& fs, int cpu, const ProcessLimits& limits) {
  long deepest_us = 0;
  const std::string states = idle_states(fs, cpu, deepest_us);
  const std::string cmdline = fs.line("/proc/cmdline").value_or("");
  std::string boot;
  for (const char* p : {"intel_idle.max_cstate", "processor.max_cstate", "idle"}) {
    if (auto v = boot_param(cmdline, p)) boot += std::string(boot.empty() ? "" : " ") + p + "=" + *v;
  }
  const std::string seen = (states.empty() ? "no cpuidle states" : "states " + states) + (boot.empty() ? "" : "; boot: " + boot);
  if (deepest_us <= 1) return {CheckStatus::kPass, "cstates", "no deep C-state to leave (" + seen + ")", ""};
  if (writable_by(fs, "/dev/cpu_dma_latency", limits)) {
    return {CheckStatus::kPass, "cstates", "lancet-rt holds /dev/cpu_dma_latency at 0 while it runs (" + seen + ")", ""};
  }
  return {CheckStatus::kWarn, "cstates",
          "lancet-rt cannot hold /dev/cpu_dma_latency at 0 (missing or not writable for uid " + std::to_string(limits.euid) +
              "): waking from the deepest state takes " + std::to_string(deepest_us) + " us (" + seen + ")",
          "run lancet-rt as root, or boot with intel_idle.max_cstate=0 processor.max_cstate=1 (or idle=poll)"};
}

CheckResult check_rt_throttling(const HostFs& fs) {
  const char* const file = "/proc/sys/kernel/sched_rt_runtime_us";
  const std::string fix = "sysctl -w kernel.sched_rt_runtime_us=-1 (or 950000, the default)";
  const auto runtime = fs.line(file);
  if (!runtime) return unknown("rt_throttling", file, fix);
  const long run = std::atol(runtime->c_str());
  const long period = std::atol(fs.line("/proc/sys/kernel/sched_rt_period_us").value_or("1000000").c_str());
  if (run < 0) return {CheckStatus::kPass, "rt_throttling", "off (sched_rt_runtime_us -1)", ""};
  const std::string found = "RT tasks may run " + std::to_string(run) + " us of every " + std::to_string(period) + " us";
  // The spin strategy keeps the servo busy for its margin (200 us of 1000 by default) plus its tick.
  if (period <= 0 || run * 4 < period) return {CheckStatus::kFail, "rt_throttling", found + ": the servo gets throttled", fix};
  if (run * 100 < period * 95) return {CheckStatus::kWarn, "rt_throttling", found + " (below the kernel's 95 %)", fix};
  return {CheckStatus::kPass, "rt_throttling", found + " (throttles only a runaway RT task)", ""};
}

CheckResult check_timer_migration(const HostFs& fs) {
  const char* const file = "/proc/sys/kernel/timer_migration";
  const std::string fix = "sysctl -w kernel.timer_migration=0";
  const auto v = fs.line(file);
  if (!v) return unknown("timer_migration", file, fix);
  if (*v == "0") return {CheckStatus::kPass, "timer_migration", "0: timers stay on the CPU that armed them", ""};
  return {CheckStatus::kWarn, "timer_migration", *v + ": other CPUs' timers may be moved onto the servo CPU", fix};
}

CheckResult check_thp(const HostFs& fs) {
  const char* const file = "/sys/kernel/mm/transparent_hugepage/enabled";
  if (!fs.exists("/sys/kernel/mm/transparent_hugepage")) return {CheckStatus::kSkip, "transparent_hugepage", "not in this kernel", ""};
  const std::string fix = "echo madvise > /sys/kernel/mm/transparent_hugepage/enabled (or boot with transparent_hugepage=madvise)";
  const auto v = fs.line(file);
  if (!v) return unknown("transparent_hugepage", file, fix);
  if (v->find("[always]") != std::string::npos) {
    return {CheckStatus::kWarn, "transparent_hugepage", *v + ": khugepaged compaction can stall memory accesses", fix};
  }
  return {CheckStatus::kPass, "transparent_hugepage", *v, ""};
}

CheckResult check_swap(const HostFs& fs) {
  const auto swaps = fs.text("/proc/swaps");
  if (!swaps) return unknown("swap", "/proc/swaps", "swapoff -a");
  std::istringstream in(*swaps);
  std::string line, on;
  std::getline(in, line);  // the header
  while (std::getline(in, line)) {
    std::istringstream fields(line);
    std::string file, type, size_kib;
    if (fields >> file >> type >> size_kib) on += (on.empty() ? "" : ", ") + file + " (" + mib(std::strtoull(size_kib.c_str(), nullptr, 10) << 10) + ")";
  }
  if (on.empty()) return {CheckStatus::kPass, "swap", "off", ""};
  return {CheckStatus::kWarn, "swap", "on: " + on + ": lancet-rt's locked memory stays, but swapping stalls the rest of the system",
          "swapoff -a (and remove the swap lines from /etc/fstab)"};
}

CheckResult check_memlock(const ProcessLimits& l) {
  const std::string fix = "ulimit -l unlimited, or '<user> - memlock unlimited' in /etc/security/limits.conf "
                          "(LimitMEMLOCK=infinity in a systemd unit), or run lancet-rt as root";
  if (has_cap(l, kCapIpcLock)) return {CheckStatus::kPass, "rlimit_memlock", "CAP_IPC_LOCK: mlockall has no limit", ""};
  if (l.memlock == ProcessLimits::kUnlimited) return {CheckStatus::kPass, "rlimit_memlock", "unlimited", ""};
  const std::string found = mib(l.memlock) + " (lancet-rt locks all its memory: its shared segment alone is about 18 MiB)";
  if (l.memlock < kMemlockNeededBytes) return {CheckStatus::kFail, "rlimit_memlock", found + ", no CAP_IPC_LOCK: mlockall fails", fix};
  return {CheckStatus::kPass, "rlimit_memlock", found, ""};
}

CheckResult check_rtprio(const ProcessLimits& l, int priority) {
  const std::string fix = "'<user> - rtprio 98' in /etc/security/limits.conf (LimitRTPRIO=98 in a systemd unit), or run lancet-rt as root";
  if (has_cap(l, kCapSysNice)) return {CheckStatus::kPass, "rlimit_rtprio", "CAP_SYS_NICE: any SCHED_FIFO priority", ""};
  if (l.rtprio == ProcessLimits::kUnlimited || l.rtprio >= static_cast<std::uint64_t>(priority)) {
    return {CheckStatus::kPass, "rlimit_rtprio", l.rtprio == ProcessLimits::kUnlimited ? "unlimited" : std::to_string(l.rtprio), ""};
  }
  if (l.rtprio == 0) return {CheckStatus::kFail, "rlimit_rtprio", "0, no CAP_SYS_NICE: lancet-rt cannot run SCHED_FIFO", fix};
  return {CheckStatus::kWarn, "rlimit_rtprio",
          std::to_string(l.rtprio) + ", below the servo's priority " + std::to_string(priority),
          "run lancet-rt with --priority " + std::to_string(l.rtprio) + ", or raise it: " + fix};
}

CheckResult check_clocksource(const HostFs& fs) {
  const char* const file = "/sys/devices/system/clocksource/clocksource0/current_clocksource";
  const auto cur = fs.line(file);
  const std::string available = fs.line("/sys/devices/system/clocksource/clocksource0/available_clocksource").value_or("");
  const std::string fix = available.find("tsc") != std::string::npos
                              ? "boot with clocksource=tsc tsc=reliable (if the TSC is stable: dmesg | grep -i tsc)"
                              : "no tsc clocksource here (dmesg | grep -i tsc says why; an unstable TSC is a hardware or BIOS matter)";
  if (!cur) return unknown("clocksource", file, fix);
  if (*cur == "tsc") return {CheckStatus::kPass, "clocksource", "tsc", ""};
  return {CheckStatus::kWarn, "clocksource", *cur + " (available: " + available + "): reading the clock costs more", fix};
}

CheckResult check_irqbalance(const HostFs& fs, int cpu) {
  const auto procs = processes(fs);
  if (procs.empty()) return unknown("irqbalance", "/proc/*/comm", "mount procfs: mount -t proc proc /proc");
  std::string pids;
  for (const Process& p : procs) {
    if (p.comm == "irqbalance") pids += (pids.empty() ? "" : ",") + std::to_string(p.pid);
  }
  if (pids.empty()) return {CheckStatus::kPass, "irqbalance", "not running", ""};
  return {CheckStatus::kWarn, "irqbalance", "running (pid " + pids + "): it moves IRQs, the arm's bus's too",
          "systemctl disable --now irqbalance, or IRQBALANCE_BANNED_CPULIST=" + std::to_string(cpu) + " in /etc/default/irqbalance"};
}

}  // namespace lancet::tools::host_check
