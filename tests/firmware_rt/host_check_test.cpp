// lancetctl host-check against fake /proc and /sys trees built in a temporary folder: a well-tuned
// PREEMPT_RT host passes every check, a stock kernel fails PREEMPT_RT with the package to install,
// each degradation gives its own warn or fail, missing files say "unknown", the JSON parses (Python's
// json module) and says what the text says. Then the real host and the real binary, whose statuses
// are this machine's business: only the report's shape is checked there.

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <ostream>
#include <string>
#include <vector>

#include "process.hpp"
#include "temp_files.hpp"
#include "tools/host_check.hpp"

namespace lancet::tools {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

constexpr int kCpu = 3;
const std::string kRtUname = "#1 SMP PREEMPT_RT Debian 6.1.112-1 (2024-09-30)";
const std::string kStockUname = "#1 SMP PREEMPT_DYNAMIC Debian 6.1.112-1 (2024-09-30)";
const std::string kController = "/sys/devices/pci0000:00/0000:00:14.0";  // the USB host controller
const std::string kUsbDevice = kController + "/usb1/1-2";

// A fake root: files, folders and links under a temporary folder, as /proc and /sys show them.
struct FakeTree {
  std::string root;
  void put(const std::string& path, const std::string& text, mode_t mode = 0644) const {
    const fs::path p = root + path;
    fs::create_directories(p.parent_path());
    std::ofstream(p) << text << (text.empty() || text.back() == '\n' ? "" : "\n");
    ::chmod(p.c_str(), mode);
  }
  void link(const std::string& path, const std::string& target) const {
    fs::create_directories(fs::path(root + path).parent_path());
    fs::create_directory_symlink(target, root + path);
  }
  void remove(const std::string& path) const { fs::remove_all(root + path); }
  void idle_state(int n, const std::string& name, int latency_us) const {
    const std::string d = cpu("/cpuidle/state" + std::to_string(n));
    put(d + "/name", name);
    put(d + "/latency", std::to_string(latency_us));
    put(d + "/disable", "0");
  }
  // A process with this scheduling policy (1: SCHED_FIFO) and RT priority in its stat line.
  void process(int pid, const std::string& comm, int policy, int rt_priority) const {
    const std::string d = "/proc/" + std::to_string(pid);
    put(d + "/comm", comm);
    std::string stat = std::to_string(pid) + " (" + comm + ") S";
    for (int field = 4; field <= 39; ++field) stat += " 0";
    stat += " " + std::to_string(rt_priority) + " " + std::to_string(policy) + " 0 0 0";
    put(d + "/stat", stat);
  }
  static std::string cpu(const std::string& rest) { return "/sys/devices/system/cpu/cpu" + std::to_string(kCpu) + rest; }
};

// A host tuned as the severity policy wants it: 4 CPUs, CPU 3 isolated, RT kernel, the arm's USB
// controller's interrupt (124) on CPU 3 with its thread at FIFO 90; lancet-rt's user has every
// limit it needs and no capability.
class HostCheck : public test::TempDirTest {
 protected:
  void SetUp() override {
    TempDirTest::SetUp();
    tree_.root = dir_.string();
    const FakeTree& t = tree_;
    t.put("/proc/cmdline", "BOOT_IMAGE=/vmlinuz-6.1.0-26-rt-amd64 root=/dev/sda1 isolcpus=domain,managed_irq,3 nohz_full=3 rcu_nocbs=3 -- quiet");
    t.put("/sys/kernel/realtime", "1");
    t.put("/proc/sys/kernel/osrelease", "6.1.0-26-rt-amd64");
    t.put("/sys/devices/system/cpu/online", "0-3");
    t.put("/sys/devices/system/cpu/isolated", "3");
    t.put("/sys/devices/system/cpu/nohz_full", "3");
    t.put(FakeTree::cpu("/topology/thread_siblings_list"), "3");
    t.put(FakeTree::cpu("/cpufreq/scaling_governor"), "performance");
    t.idle_state(0, "POLL", 0);
    t.idle_state(1, "C1", 2);
    t.idle_state(2, "C6", 133);
    t.put("/dev/cpu_dma_latency", "", 0600);
    t.put("/proc/sys/kernel/sched_rt_runtime_us", "950000");
    t.put("/proc/sys/kernel/sched_rt_period_us", "1000000");
    t.put("/proc/sys/kernel/timer_migration", "0");
    t.put("/sys/kernel/mm/transparent_hugepage/enabled", "always madvise [never]");
    t.put("/proc/swaps", "Filename\t\t\t\tType\t\tSize\t\tUsed\t\tPriority\n");
    t.put("/sys/devices/system/clocksource/clocksource0/current_clocksource", "tsc");
    t.put("/sys/devices/system/clocksource/clocksource0/available_clocksource", "tsc hpet acpi_pm");
    t.process(1, "systemd", 0, 0);
    // The arm: a USB device 1209:0001 on the controller at 0000:00:14.0 (MSI vector 124).
    t.put(kController + "/irq", "16");
    t.put(kController + "/msi_irqs/124", "msi");
    t.put(kUsbDevice + "/idVendor", "1209");
    t.put(kUsbDevice + "/idProduct", "0001");
    t.link("/sys/bus/usb/devices/1-2", "../../../devices/pci0000:00/0000:00:14.0/usb1/1-2");
    t.put("/proc/interrupts", "           CPU0       CPU1       CPU2       CPU3\n"
                              "  16:          0          0          0          0  IR-IO-APIC   16-fasteoi   i801_smbus\n"
                              " 124:        100        200        300     123456  IR-PCI-MSI 327680-edge      xhci_hcd\n"
                              " 130:          1          0          0          0  IR-PCI-MSI 520192-edge      eth1-rx-0\n");
    t.put("/proc/irq/124/smp_affinity_list", "3");
    t.process(200, "irq/124-xhci_hc", 1, 90);
    input_.root = tree_.root;
    input_.cpu = kCpu;
    input_.priority = 80;
    input_.uname_version = kRtUname;
    input_.limits.euid = ::geteuid();  // the owner of the fake files; no capability
    input_.limits.memlock = ProcessLimits::kUnlimited;
    input_.limits.rtprio = 98;
    input_.bus = ArmBus{.kind = ArmBus::Kind::kUsb, .arm = "usb-touch-3dof", .vid = 0x1209, .pid = 0x0001};
  }

  [[nodiscard]] HostCheckReport run() const { return run_host_check(input_); }
  [[nodiscard]] static const CheckResult& check(const HostCheckReport& r, const std::string& name) {
    for (const CheckResult& c : r.checks) {
      if (c.name == name) return c;
    }
    static const CheckResult kMissing{CheckStatus::kSkip, "<missing>", "", ""};
    ADD_FAILURE() << "no check named " << name;
    return kMissing;
  }

  FakeTree tree_;
  HostCheckInput input_;
};

::testing::AssertionResult all_pass(const HostCheckReport& r) {
  for (const CheckResult& c : r.checks) {
    if (c.status != CheckStatus::kPass) return ::testing::AssertionFailure() << format_host_check_text(r);
  }
  return ::testing::AssertionSuccess();
}

TEST_F(HostCheck, WellTunedRtHostPassesEveryCheck) {
  const HostCheckReport r = run();
  EXPECT_TRUE(all_pass(r));
  EXPECT_TRUE(r.ok());
  EXPECT_EQ(r.checks.size(), 19u) << format_host_check_text(r);
  EXPECT_NE(check(r, "bus_device").found.find("124 (xhci_hcd)"), std::string::npos) << check(r, "bus_device").found;
  EXPECT_NE(check(r, "cstates").found.find("lancet-rt holds /dev/cpu_dma_latency"), std::string::npos);
  EXPECT_NE(format_host_check_text(r).find("19 pass, 0 warn, 0 fail, 0 skip: no check fails"), std::string::npos);
}

// The command reads the same tree with this process's own limits and uname (the tree's
// /sys/kernel/realtime says PREEMPT_RT): its exit status follows the report.
TEST_F(HostCheck, CommandExitStatusFollowsTheReport) {
  HostCheckOptions o;
  o.root = tree_.root;
  o.cpu = kCpu;
  input_.limits = ProcessLimits::of_this_process();
  input_.bus.reset();
  std::FILE* out = std::tmpfile();
  EXPECT_EQ(run_host_check_command(o, out, out), run().ok() ? 0 : 1);
  std::fclose(out);
  tree_.put("/proc/sys/kernel/sched_rt_runtime_us", "0");
  out = std::tmpfile();
  EXPECT_EQ(run_host_check_command(o, out, out), 1);
  std::fclose(out);
}

TEST_F(HostCheck, ServoCpuOfflineFails) {
  input_.cpu = 7;
  const HostCheckReport r = run();
  EXPECT_EQ(check(r, "servo_cpu").status, CheckStatus::kFail);
  EXPECT_NE(check(r, "servo_cpu").found.find("online: 0-3"), std::string::npos);
  EXPECT_NE(check(r, "servo_cpu").fix.find("--cpu"), std::string::npos);
  EXPECT_EQ(check(r, "isolcpus").status, CheckStatus::kWarn);
  EXPECT_FALSE(r.ok());
}

TEST_F(HostCheck, StockKernelFailsPreemptRtNamingThePackage) {
  tree_.remove("/sys/kernel/realtime");
  input_.uname_version = kStockUname;
  const HostCheckReport r = run();
  const CheckResult& c = check(r, "preempt_rt");
  EXPECT_EQ(c.status, CheckStatus::kFail);
  EXPECT_NE(c.found.find(kStockUname), std::string::npos) << c.found;
  EXPECT_NE(c.fix.find("linux-image-rt-amd64"), std::string::npos) << c.fix;
  EXPECT_FALSE(r.ok());
  EXPECT_EQ(r.count(CheckStatus::kFail), 1) << format_host_check_text(r);
  EXPECT_NE(format_host_check_text(r).find("FAIL  preempt_rt"), std::string::npos);
  // Either spelling in uname -v is enough without /sys/kernel/realtime.
  for (const char* v : {"#1 SMP PREEMPT_RT Thu", "#1 SMP PREEMPT RT Thu"}) {
    input_.uname_version = v;
    EXPECT_EQ(check(run(), "preempt_rt").status, CheckStatus::kPass) << v;
  }
}

// One change to the well-tuned host, and the one check it must turn.
struct Degradation {
  const char* what;
  std::function<void(const FakeTree&, HostCheckInput&)> change;
  const char* check;
  CheckStatus status;
  const char* fix_has;  ///< the fix names this ("" when the status is pass)
  friend void PrintTo(const Degradation& d, std::ostream* os) { *os << d.what; }  // ctest's names
};

class HostCheckDegraded : public HostCheck, public ::testing::WithParamInterface<Degradation> {};

const char* const kBoot = "root=/dev/sda1 ";

const std::vector<Degradation> kDegradations = {
    {"no isolcpus", [](const FakeTree& t, HostCheckInput&) {
       t.put("/proc/cmdline", std::string(kBoot) + "nohz_full=3 rcu_nocbs=3");
       t.put("/sys/devices/system/cpu/isolated", "");
     }, "isolcpus", CheckStatus::kWarn, "isolcpus=3"},
    {"isolcpus elsewhere", [](const FakeTree& t, HostCheckInput&) {
       t.put("/proc/cmdline", std::string(kBoot) + "isolcpus=2 nohz_full=3 rcu_nocbs=3");
       t.remove("/sys/devices/system/cpu/isolated");
     }, "isolcpus", CheckStatus::kWarn, "isolcpus=3"},
    {"no nohz_full", [](const FakeTree& t, HostCheckInput&) {
       t.put("/proc/cmdline", std::string(kBoot) + "isolcpus=3 rcu_nocbs=3");
       t.put("/sys/devices/system/cpu/nohz_full", "(null)");
     }, "nohz_full", CheckStatus::kWarn, "nohz_full=3"},
    {"no rcu_nocbs", [](const FakeTree& t, HostCheckInput&) {
       t.put("/proc/cmdline", std::string(kBoot) + "isolcpus=3 nohz_full=3");
     }, "rcu_nocbs", CheckStatus::kWarn, "rcu_nocbs=3"},
    {"SMT sibling busy", [](const FakeTree& t, HostCheckInput&) {
       t.put(FakeTree::cpu("/topology/thread_siblings_list"), "1,3");
     }, "smt_sibling", CheckStatus::kWarn, "cpu1/online"},
    {"SMT sibling offline", [](const FakeTree& t, HostCheckInput&) {
       t.put(FakeTree::cpu("/topology/thread_siblings_list"), "1,3");
       t.put("/sys/devices/system/cpu/cpu1/online", "0");
     }, "smt_sibling", CheckStatus::kPass, ""},
    {"governor powersave", [](const FakeTree& t, HostCheckInput&) {
       t.put(FakeTree::cpu("/cpufreq/scaling_governor"), "powersave");
     }, "cpufreq_governor", CheckStatus::kWarn, "performance"},
    {"no cpufreq driver", [](const FakeTree& t, HostCheckInput&) {
       t.remove(FakeTree::cpu("/cpufreq"));
     }, "cpufreq_governor", CheckStatus::kSkip, ""},
    {"C-states, dma latency not writable", [](const FakeTree&, HostCheckInput& in) {
       in.limits.euid = 4242;  // not the file's owner, and 0600
     }, "cstates", CheckStatus::kWarn, "max_cstate"},
    {"C-states, no dma latency device", [](const FakeTree& t, HostCheckInput&) {
       t.remove("/dev/cpu_dma_latency");
     }, "cstates", CheckStatus::kWarn, "idle=poll"},
    {"RT throttling leaves nothing", [](const FakeTree& t, HostCheckInput&) {
       t.put("/proc/sys/kernel/sched_rt_runtime_us", "0");
     }, "rt_throttling", CheckStatus::kFail, "sched_rt_runtime_us=-1"},
    {"RT throttling at a fifth", [](const FakeTree& t, HostCheckInput&) {
       t.put("/proc/sys/kernel/sched_rt_runtime_us", "200000");
     }, "rt_throttling", CheckStatus::kFail, "sched_rt_runtime_us=-1"},
    {"RT throttling below the default", [](const FakeTree& t, HostCheckInput&) {
       t.put("/proc/sys/kernel/sched_rt_runtime_us", "800000");
     }, "rt_throttling", CheckStatus::kWarn, "sched_rt_runtime_us"},
    {"RT throttling off", [](const FakeTree& t, HostCheckInput&) {
       t.put("/proc/sys/kernel/sched_rt_runtime_us", "-1");
     }, "rt_throttling", CheckStatus::kPass, ""},
    {"timer migration on", [](const FakeTree& t, HostCheckInput&) {
       t.put("/proc/sys/kernel/timer_migration", "1");
     }, "timer_migration", CheckStatus::kWarn, "timer_migration=0"},
    {"THP always", [](const FakeTree& t, HostCheckInput&) {
       t.put("/sys/kernel/mm/transparent_hugepage/enabled", "[always] madvise never");
     }, "transparent_hugepage", CheckStatus::kWarn, "madvise"},
    {"swap on", [](const FakeTree& t, HostCheckInput&) {
       t.put("/proc/swaps", "Filename\tType\tSize\tUsed\tPriority\n/dev/sda2 partition 8388604 0 -2\n");
     }, "swap", CheckStatus::kWarn, "swapoff -a"},
    {"memlock 8 MiB", [](const FakeTree&, HostCheckInput& in) { in.limits.memlock = 8u << 20; }, "rlimit_memlock", CheckStatus::kFail,
     "memlock unlimited"},
    {"memlock 8 MiB with CAP_IPC_LOCK", [](const FakeTree&, HostCheckInput& in) {
       in.limits.memlock = 8u << 20;
       in.limits.cap_effective = 1u << 14;
     }, "rlimit_memlock", CheckStatus::kPass, ""},
    {"memlock 1 GiB", [](const FakeTree&, HostCheckInput& in) { in.limits.memlock = 1ull << 30; }, "rlimit_memlock", CheckStatus::kPass, ""},
    {"rtprio 0", [](const FakeTree&, HostCheckInput& in) { in.limits.rtprio = 0; }, "rlimit_rtprio", CheckStatus::kFail, "rtprio 98"},
    {"rtprio 0 with CAP_SYS_NICE", [](const FakeTree&, HostCheckInput& in) {
       in.limits.rtprio = 0;
       in.limits.cap_effective = 1u << 23;
     }, "rlimit_rtprio", CheckStatus::kPass, ""},
    {"rtprio under the servo's", [](const FakeTree&, HostCheckInput& in) { in.limits.rtprio = 50; }, "rlimit_rtprio", CheckStatus::kWarn,
     "--priority 50"},
    {"clocksource hpet", [](const FakeTree& t, HostCheckInput&) {
       t.put("/sys/devices/system/clocksource/clocksource0/current_clocksource", "hpet");
     }, "clocksource", CheckStatus::kWarn, "clocksource=tsc"},
    {"irqbalance running", [](const FakeTree& t, HostCheckInput&) {
       t.process(812, "irqbalance", 0, 0);
     }, "irqbalance", CheckStatus::kWarn, "irqbalance"},
    {"bus IRQ on every CPU", [](const FakeTree& t, HostCheckInput&) {
       t.put("/proc/irq/124/smp_affinity_list", "0-3");
     }, "bus_irq_affinity", CheckStatus::kWarn, "echo 3 > /proc/irq/124/smp_affinity_list"},
    {"bus IRQ thread below the servo", [](const FakeTree& t, HostCheckInput&) {
       t.process(200, "irq/124-xhci_hc", 1, 50);
     }, "bus_irq_thread", CheckStatus::kWarn, "chrt -f -p 85 200"},
    {"bus IRQ not threaded", [](const FakeTree& t, HostCheckInput&) {
       t.remove("/proc/200");
     }, "bus_irq_thread", CheckStatus::kWarn, "PREEMPT_RT"},
    {"USB arm unplugged", [](const FakeTree&, HostCheckInput& in) { in.bus->pid = 0x0002; }, "bus_device", CheckStatus::kWarn, "plug the arm in"},
    {"USB device whose IRQ cannot be found", [](const FakeTree& t, HostCheckInput&) {
       t.remove(kController + "/irq");
       t.remove(kController + "/msi_irqs");
     }, "bus_device", CheckStatus::kWarn, "/proc/interrupts"},
    {"CAN interface on a USB adapter", [](const FakeTree& t, HostCheckInput& in) {
       t.put(kUsbDevice + "/1-2:1.0/net/can0/type", "280");
       t.link("/sys/class/net/can0/device", "../../../devices/pci0000:00/0000:00:14.0/usb1/1-2/1-2:1.0");
       in.bus = ArmBus{.kind = ArmBus::Kind::kCan, .arm = "canopen-lap-4dof", .can_interface = "can0"};
     }, "bus_irq_thread", CheckStatus::kPass, ""},
    {"CAN interface missing", [](const FakeTree&, HostCheckInput& in) {
       in.bus = ArmBus{.kind = ArmBus::Kind::kCan, .arm = "canopen-lap-4dof", .can_interface = "can1"};
     }, "bus_device", CheckStatus::kWarn, "ip link set can1 up type can bitrate 1000000"},
    {"virtual CAN", [](const FakeTree& t, HostCheckInput& in) {
       t.put("/sys/class/net/vcan0/type", "280");
       in.bus = ArmBus{.kind = ArmBus::Kind::kCan, .arm = "canopen-lap-4dof", .can_interface = "vcan0"};
     }, "bus_device", CheckStatus::kSkip, ""},
    {"Modbus TCP through a NIC with its IRQ elsewhere", [](const FakeTree& t, HostCheckInput& in) {
       t.put("/proc/net/route", "Iface\tDestination\tGateway\tFlags\tRefCnt\tUse\tMetric\tMask\tMTU\tWindow\tIRTT\n"
                                   "eth0\t00000000\t0101A8C0\t0003\t0\t0\t100\t00000000\t0\t0\t0\n"
                                   "eth1\t0001A8C0\t00000000\t0001\t0\t0\t100\t00FFFFFF\t0\t0\t0\n");
       t.put("/sys/devices/pci0000:00/0000:00:1f.6/msi_irqs/130", "msi");
       t.put("/proc/irq/130/smp_affinity_list", "0");
       t.link("/sys/class/net/eth1/device", "../../../devices/pci0000:00/0000:00:1f.6");
       in.bus = ArmBus{.kind = ArmBus::Kind::kModbusTcp, .arm = "modbus-bench-3dof", .host = "192.168.1.20"};
     }, "bus_irq_affinity", CheckStatus::kWarn, "echo 3 > /proc/irq/130/smp_affinity_list"},
    {"Modbus TCP on loopback", [](const FakeTree&, HostCheckInput& in) {
       in.bus = ArmBus{.kind = ArmBus::Kind::kModbusTcp, .arm = "modbus-bench-3dof", .host = "127.0.0.1"};
     }, "bus_device", CheckStatus::kSkip, ""},
    {"Modbus RTU on a USB serial adapter", [](const FakeTree& t, HostCheckInput& in) {
       t.put(kUsbDevice + "/1-2:1.0/ttyUSB0/port_number", "0");
       t.link("/sys/class/tty/ttyUSB0/device", "../../../devices/pci0000:00/0000:00:14.0/usb1/1-2/1-2:1.0/ttyUSB0");
       in.bus = ArmBus{.kind = ArmBus::Kind::kModbusRtu, .arm = "modbus-rtu", .serial_device = "/dev/ttyUSB0"};
     }, "bus_irq_affinity", CheckStatus::kPass, ""},
    {"simulated arm", [](const FakeTree&, HostCheckInput& in) { in.bus = ArmBus{}; }, "bus_device", CheckStatus::kSkip, ""},
    {"no config", [](const FakeTree&, HostCheckInput& in) { in.bus.reset(); }, "bus_device", CheckStatus::kSkip, "--config"},
};

TEST_P(HostCheckDegraded, TurnsItsCheckOnly) {
  const Degradation& d = GetParam();
  d.change(tree_, input_);
  const HostCheckReport r = run();
  const CheckResult& c = check(r, d.check);
  EXPECT_EQ(c.status, d.status) << d.what << "\n" << format_host_check_text(r);
  EXPECT_NE(c.fix.find(d.fix_has), std::string::npos) << d.what << ": " << c.fix;
  EXPECT_FALSE(c.found.empty());
  // Every other check stays as it was (a bus that changed may drop its IRQ lines).
  for (const CheckResult& other : r.checks) {
    if (other.name == d.check || other.name.rfind("bus_", 0) == 0) continue;
    EXPECT_EQ(other.status, CheckStatus::kPass) << d.what << ": " << other.name << ": " << other.found;
  }
  EXPECT_EQ(r.ok(), d.status != CheckStatus::kFail);
}

INSTANTIATE_TEST_SUITE_P(Each, HostCheckDegraded, ::testing::ValuesIn(kDegradations),
                         [](const ::testing::TestParamInfo<Degradation>& i) {
                           std::string n = i.param.what;
                           for (char& ch : n) ch = std::isalnum(static_cast<unsigned char>(ch)) != 0 ? ch : '_';
                           return n;
                         });

TEST_F(HostCheck, EmptyRootSaysUnknownAndDoesNotCrash) {
  input_.root = (dir_ / "empty").string();
  fs::create_directories(input_.root);
  input_.uname_version = kStockUname;
  const HostCheckReport r = run();
  ASSERT_EQ(r.checks.size(), 17u) << format_host_check_text(r);
  for (const char* name : {"servo_cpu", "isolcpus", "rt_throttling", "timer_migration", "swap", "clocksource", "irqbalance"}) {
    EXPECT_EQ(check(r, name).status, CheckStatus::kWarn) << name;
    EXPECT_NE(check(r, name).found.find("unknown"), std::string::npos) << name << ": " << check(r, name).found;
  }
  EXPECT_EQ(check(r, "bus_device").status, CheckStatus::kWarn);  // the USB device is nowhere
}

// The checks as Python's json module reads them: one "status\tname\tfound\tfix" line each, then
// the summary; empty when python3 fails (its error in `why`).
std::string parse_json_with_python(const std::string& json, const std::string& dir, std::string& why) {
  const std::string file = dir + "/report.json", log = dir + "/python.txt";
  std::ofstream(file) << json;
  test::Child py({"/usr/bin/python3", "-c",
                  "import json,sys\n"
                  "d = json.load(open(sys.argv[1]))\n"
                  "for c in d['checks']: print('\\t'.join([c['status'], c['name'], c['found'], c['fix']]))\n"
                  "s = d['summary']\n"
                  "print(s['pass'], s['warn'], s['fail'], s['skip'], s['ok'], d['cpu'])\n",
                  file},
                 log);
  const auto st = py.wait_exit(30s);
  why = test::read_file(log);
  return st && WIFEXITED(*st) && WEXITSTATUS(*st) == 0 ? why : std::string();
}

// The text report's checks as "status\tname\tfound\tfix" lines, for comparison with the JSON's:
// "STATUS  name   found" and, on the next line when there is one, "   fix: ...".
std::string text_as_lines(const std::string& text) {
  std::istringstream in(text);
  std::vector<std::array<std::string, 4>> checks;
  for (std::string l; std::getline(in, l) && l.rfind("host-check:", 0) != 0;) {
    if (l.rfind("      ", 0) == 0) {
      checks.back()[3] = l.substr(l.find("fix: ") + 5);
      continue;
    }
    std::string status = l.substr(0, l.find(' '));
    for (char& ch : status) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
    const auto name = l.find_first_not_of(' ', status.size());
    const auto found = l.find_first_not_of(' ', l.find(' ', name));
    checks.push_back({status, l.substr(name, l.find(' ', name) - name), l.substr(found), ""});
  }
  std::string out;
  for (const auto& c : checks) out += c[0] + "\t" + c[1] + "\t" + c[2] + "\t" + c[3] + "\n";
  return out;
}

TEST_F(HostCheck, JsonParsesAndAgreesWithTheText) {
  tree_.remove("/sys/kernel/realtime");
  input_.uname_version = "#1 SMP \"quoted\" \\ PREEMPT_DYNAMIC";  // escapes must survive
  tree_.put("/proc/sys/kernel/timer_migration", "1");
  const HostCheckReport r = run();
  std::string why;
  const std::string parsed = parse_json_with_python(format_host_check_json(input_, r), dir_.string(), why);
  ASSERT_FALSE(parsed.empty()) << why;
  const auto last = parsed.rfind('\n', parsed.size() - 2);
  EXPECT_EQ(parsed.substr(0, last + 1), text_as_lines(format_host_check_text(r)));
  EXPECT_EQ(parsed.substr(last + 1), "17 1 1 0 False 3\n");
}

// The real host: whatever it is, the report has every check, each with a status and a finding.
TEST(HostCheckRealHost, RunsAndGivesAWellFormedReport) {
  HostCheckOptions o;
  o.json = true;
  std::FILE* out = std::tmpfile();
  const int code = run_host_check_command(o, out, stderr);
  EXPECT_TRUE(code == 0 || code == 1) << code;
  std::rewind(out);
  std::string json;
  for (int ch; (ch = std::fgetc(out)) != EOF;) json += static_cast<char>(ch);
  std::fclose(out);
  std::string why;
  const std::string parsed = parse_json_with_python(json, ::testing::TempDir(), why);
  ASSERT_FALSE(parsed.empty()) << why << json;
  std::istringstream lines(parsed);
  int checks = 0;
  for (std::string l; std::getline(lines, l) && l.find('\t') != std::string::npos; ++checks) {
    EXPECT_TRUE(l.rfind("pass\t", 0) == 0 || l.rfind("warn\t", 0) == 0 || l.rfind("fail\t", 0) == 0 || l.rfind("skip\t", 0) == 0) << l;
  }
  EXPECT_EQ(checks, 17) << parsed;
  EXPECT_NE(parsed.find(code == 0 ? " True " : " False "), std::string::npos) << parsed;
}

// As a newcomer runs it: the binary, --json, with an arm config, and a broken config.
TEST(HostCheckBinary, JsonWithAConfigAndABadConfig) {
  const std::string ctl = std::string(LANCET_BINARY_DIR) + "/firmware_rt/lancetctl";
  const std::string dir = ::testing::TempDir() + "host_check_binary_" + std::to_string(::getpid());
  fs::create_directories(dir);
  test::Child run({ctl, "host-check", "--json", "--config", std::string(LANCET_SOURCE_DIR) + "/hw_configs/canopen_arm.toml"}, dir + "/out.json");
  const auto st = run.wait_exit(60s);
  ASSERT_TRUE(st && WIFEXITED(*st)) << test::read_file(dir + "/out.json");
  EXPECT_TRUE(WEXITSTATUS(*st) == 0 || WEXITSTATUS(*st) == 1);
  std::string why;
  const std::string parsed = parse_json_with_python(test::read_file(dir + "/out.json"), dir, why);
  ASSERT_FALSE(parsed.empty()) << why;
  EXPECT_NE(parsed.find("canopen-lap-4dof"), std::string::npos) << parsed;
  std::ofstream(dir + "/bad.toml") << "schema_version = 1\nname = 3\n";
  test::Child bad({ctl, "host-check", "--config", dir + "/bad.toml"}, dir + "/bad.txt");
  const auto bst = bad.wait_exit(60s);
  ASSERT_TRUE(bst && WIFEXITED(*bst));
  EXPECT_EQ(WEXITSTATUS(*bst), 2);
  EXPECT_NE(test::read_file(dir + "/bad.txt").find("bad.toml:2:8: name:"), std::string::npos) << test::read_file(dir + "/bad.txt");
  fs::remove_all(dir);
}

}  // namespace
}  // namespace lancet::tools
