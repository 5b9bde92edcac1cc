#pragma once
// `lancetctl host-check`: audits this host for 1 kHz servo work, one line per check with what was
// found and the fix (a command or a boot parameter). Reads nothing but /proc and /sys (and
// getrlimit and the process's capabilities), so it runs in a bare busybox guest too; every path
// goes through a root folder so tests can hand it a fake /proc and /sys.
//
// Severity policy:
//   fail  the 1 kHz promise cannot hold: the kernel is not PREEMPT_RT; RT throttling leaves the
//         servo too little of its CPU (sched_rt_runtime_us 0 or under a quarter of the period);
//         lancet-rt cannot lock its memory (RLIMIT_MEMLOCK under kMemlockNeededBytes without
//         CAP_IPC_LOCK) or cannot run SCHED_FIFO (RLIMIT_RTPRIO 0 without CAP_SYS_NICE); the
//         servo CPU does not exist.
//   warn  the loop runs but its latency tail degrades: the servo CPU not isolated (isolcpus,
//         nohz_full, rcu_nocbs); its SMT sibling not isolated; cpufreq governor not performance;
//         deep C-states that lancet-rt cannot hold off; transparent huge pages "always"; swap on;
//         timer_migration 1; a clocksource other than tsc; irqbalance running; the arm's bus IRQ
//         not on the servo CPU or its thread not above the servo's priority; RLIMIT_RTPRIO under
//         the servo's priority; anything that could not be read ("unknown").
//   skip  not applicable here (no cpufreq driver, no arm config, a simulated or loopback bus).
//   pass  as a 1 kHz host wants it.
// Run it as the user that runs lancet-rt: the limits are this process's.
// Configure-time tool: nothing here is real-time safe.

#include <sys/types.h>

#include <cstdint>
#include <cstdio>
#include <optional>
#include <string>
#include <vector>

namespace lancet::tools {

enum class CheckStatus : std::uint8_t { kPass, kWarn, kFail, kSkip };
[[nodiscard]] const char* to_string(CheckStatus s) noexcept;

/// One line of the report.
struct CheckResult {
  CheckStatus status = CheckStatus::kPass;
  std::string name;   ///< short, stable (scripts match on it), e.g. "preempt_rt"
  std::string found;  ///< what this host has
  std::string fix;    ///< a command or boot parameter; "" when nothing is to be done
};

/// The limits of the process that will run lancet-rt (this one's, or a test's).
struct ProcessLimits {
  uid_t euid = 0;
  std::uint64_t cap_effective = 0;  ///< CapEff of /proc/self/status (bit n: capability n)
  std::uint64_t memlock = 0;        ///< RLIMIT_MEMLOCK soft limit, bytes; kUnlimited: none
  std::uint64_t rtprio = 0;         ///< RLIMIT_RTPRIO soft limit; kUnlimited: none
  static constexpr std::uint64_t kUnlimited = ~std::uint64_t{0};
  /// This process's limits (getrlimit, geteuid, /proc/self/status).
  static ProcessLimits of_this_process();
};

/// The arm's bus, as the host sees it (from hw_configs/*.toml).
struct ArmBus {
  enum class Kind : std::uint8_t { kSim, kCan, kUsb, kModbusTcp, kModbusRtu };
  Kind kind = Kind::kSim;
  std::string arm{};                 ///< the config's name
  std::string can_interface{};       ///< kCan: e.g. can0
  int can_bitrate = 1'000'000;     ///< kCan: bit/s
  std::uint16_t vid = 0, pid = 0;  ///< kUsb
  std::string host{};                ///< kModbusTcp: address or name of the drive box
  std::string serial_device{};       ///< kModbusRtu: e.g. /dev/ttyUSB0
};

struct HostCheckInput {
  std::string root = "/";          ///< where /proc and /sys are found (tests: a fake tree)
  int cpu = 0;                     ///< the servo CPU
  int priority = 80;               ///< the servo's SCHED_FIFO priority (lancet-rt's default)
  std::string uname_version;       ///< uname -v
  ProcessLimits limits;
  std::optional<ArmBus> bus;       ///< empty: the bus checks are skipped, with `no_bus_reason`
  std::string no_bus_reason = "no --config given";
};

struct HostCheckReport {
  std::vector<CheckResult> checks;
  [[nodiscard]] int count(CheckStatus s) const noexcept;
  [[nodiscard]] bool ok() const noexcept { return count(CheckStatus::kFail) == 0; }
};

/// The memory lancet-rt locks with mlockall (its shared segment is about 18 MiB; heap, stacks and
/// code come on top), with headroom: a finite RLIMIT_MEMLOCK below this fails.
inline constexpr std::uint64_t kMemlockNeededBytes = 256ull << 20;

/// Every check, in report order. Never throws for what the host lacks (that is "unknown").
[[nodiscard]] HostCheckReport run_host_check(const HostCheckInput& input);
/// One line per check: `STATUS  name: found` and, when there is one, `        fix: ...`; then
/// a summary line.
[[nodiscard]] std::string format_host_check_text(const HostCheckReport& report);
/// {"cpu": N, "checks": [{"status", "name", "found", "fix"}...], "summary": {"pass", "warn",
/// "fail", "skip", "ok"}}
[[nodiscard]] std::string format_host_check_json(const HostCheckInput& input, const HostCheckReport& report);

struct HostCheckOptions {
  std::string config_path;  ///< the arm config; "" for none
  int cpu = -2;             ///< -2: lancet-rt's default (the last online CPU)
  int priority = 80;
  bool json = false;
  std::string root = "/";
};
/// The subcommand: 0 when no check fails, 1 when one does, 2 on a bad config (printed to `err`
/// with file, line and field).
int run_host_check_command(const HostCheckOptions& options, std::FILE* out, std::FILE* err);

}  // namespace lancet::tools
