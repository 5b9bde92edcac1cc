// lancet-rt on the kernel it is meant for: these tests run inside a QEMU guest booted by
// tests/qemu/run_in_guest.sh, once on Debian's PREEMPT_RT kernel and once on its stock kernel, both
// with the same boot line (isolcpus, nohz_full and rcu_nocbs for CPU 1, threadirqs), so that the
// kernel is the only difference. LANCET_RTK_EXPECT says which kernel the guest booted ("rt" or
// "stock"); LANCET_TOOLS_DIR holds lancet-rt and lancetctl. Outside such a guest they skip.
//
// On the RT kernel lancet-rt must come up with nothing degraded (PREEMPT_RT, SCHED_FIFO, memory
// locked, CPU 1 isolated, /dev/cpu_dma_latency held), say so in its stats JSON, run 10 s with the
// simulated arms and their scripted hands and exit clean; on the stock kernel it must run just as
// well and say that the kernel is not PREEMPT_RT, and nothing else. `lancetctl host-check` must pass
// the RT guest and fail the stock one on PREEMPT_RT, naming the package that fixes it.
#include <gtest/gtest.h>
#include <sys/utsname.h>
#include <sys/wait.h>

#include <chrono>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "process.hpp"

namespace {

using lancet::test::Child;
using lancet::test::json_number;
using lancet::test::read_file;

std::string env(const char* name) {
  const char* v = std::getenv(name);
  return v == nullptr ? std::string() : std::string(v);
}

// "rt" or "stock" inside a guest; empty elsewhere.
std::string expected_kernel() { return env("LANCET_RTK_EXPECT"); }
std::string tool(const char* name) { return env("LANCET_TOOLS_DIR") + "/" + name; }

#define SKIP_OUTSIDE_A_GUEST()                                                                                         \
  do {                                                                                                                 \
    if (expected_kernel().empty() || env("LANCET_TOOLS_DIR").empty())                                                  \
      GTEST_SKIP() << "not in a guest of tests/qemu/run_in_guest.sh (LANCET_RTK_EXPECT and LANCET_TOOLS_DIR unset)"; \
  } while (false)

bool rt_expected() { return expected_kernel() == "rt"; }

std::string first_line(const std::string& path) {
  std::ifstream in(path);
  std::string line;
  std::getline(in, line);
  return line;
}

std::vector<std::string> lines_with(const std::string& text, const std::string& needle) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);)
    if (line.find(needle) != std::string::npos) out.push_back(line);
  return out;
}

TEST(RtKernelGuest, TheGuestRunsTheKernelItWasMeantTo) {
  SKIP_OUTSIDE_A_GUEST();
  std::printf("guest: %s\n", env("LANCET_GUEST").c_str());
  utsname u{};
  ASSERT_EQ(uname(&u), 0);
  std::printf("uname -r -v: %s %s\ncmdline: %s\n", u.release, u.version, first_line("/proc/cmdline").c_str());
  const bool realtime = first_line("/sys/kernel/realtime") == "1";
  const bool says_rt = std::string(u.version).find("PREEMPT_RT") != std::string::npos;
  EXPECT_EQ(realtime, rt_expected()) << "/sys/kernel/realtime";
  EXPECT_EQ(says_rt, rt_expected()) << "uname -v: " << u.version;
  // The boot line both guests share: CPU 1 is the servo's, isolated.
  EXPECT_EQ(first_line("/sys/devices/system/cpu/isolated"), "1");
  EXPECT_EQ(first_line("/sys/devices/system/cpu/online"), "0-1");
}

TEST(RtKernelGuest, LancetRtRunsTenSecondsWithTheScriptedHandsAndSaysHowItsSetupWent) {
  SKIP_OUTSIDE_A_GUEST();
  const std::string log = "/tmp/lancet-rt.log", stats_path = "/tmp/lancet-rt.json";
  Child rt({tool("lancet-rt"), "--shm", "/lancet-rtk", "--duration", "10", "-q", "--stats", stats_path}, log);
  ASSERT_TRUE(rt.started());
  // Ten seconds of servo, however slowly the emulator runs the rest; then it ends by itself.
  const auto st = rt.wait_exit(std::chrono::minutes(5));
  const std::string out = read_file(log);
  std::printf("%s", out.c_str());
  ASSERT_TRUE(st.has_value()) << "lancet-rt --duration 10 still running after 5 minutes";
  ASSERT_TRUE(WIFEXITED(*st)) << out;
  EXPECT_EQ(WEXITSTATUS(*st), 0) << out;
  const std::string stats = read_file(stats_path);
  std::printf("%s", stats.c_str());
  EXPECT_NE(stats.find("\"ended_by\": \"duration\""), std::string::npos) << stats;
  EXPECT_NE(stats.find("\"clean_exit\": true"), std::string::npos) << stats;
  EXPECT_GT(json_number(stats, "ticks").value_or(0), 1000) << stats;
  EXPECT_EQ(json_number(stats, "nan_guards").value_or(-1), 0) << stats;
  // What took effect, in both kernels (root in the guest, CPU 1 isolated by the boot line).
  for (const char* applied : {"\"fifo\": true", "\"affinity\": true", "\"cpu_isolated\": true", "\"memory_locked\": true",
                              "\"dma_latency_held\": true"})
    EXPECT_NE(stats.find(applied), std::string::npos) << applied << "\n" << stats;
  const std::vector<std::string> degraded = lines_with(out, "lancet-rt: degraded:");
  if (rt_expected()) {
    EXPECT_TRUE(degraded.empty()) << "on PREEMPT_RT with the servo CPU isolated nothing is degraded:\n" << out;
    EXPECT_NE(stats.find("\"preempt_rt\": true"), std::string::npos) << stats;
    EXPECT_NE(stats.find("\"degraded\": []"), std::string::npos) << stats;
    EXPECT_NE(out.find("lancet-rt: kernel is PREEMPT_RT"), std::string::npos) << out;
  } else {
    ASSERT_EQ(degraded.size(), 1u) << "the stock kernel, and nothing else:\n" << out;
    EXPECT_NE(degraded[0].find("kernel is not PREEMPT_RT"), std::string::npos) << degraded[0];
    EXPECT_NE(stats.find("\"preempt_rt\": false"), std::string::npos) << stats;
    EXPECT_NE(stats.find("\"degraded\": [\"kernel is not PREEMPT_RT"), std::string::npos) << stats;
  }
}

// The host audit in the guest: the RT kernel with the boot line passes (warnings allowed: the
// guest has no cpufreq, timer migration on); the stock kernel fails on PREEMPT_RT alone and names
// the package that fixes it. Run as a newcomer would, text first, then --json.
TEST(RtKernelGuest, HostCheckPassesTheRtGuestAndFailsTheStockOneOnPreemptRt) {
  SKIP_OUTSIDE_A_GUEST();
  {
    Child text({tool("lancetctl"), "host-check"}, "/tmp/host-check.txt");
    const auto st = text.wait_exit(std::chrono::minutes(2));
    ASSERT_TRUE(st.has_value() && WIFEXITED(*st));
    std::printf("%s", read_file("/tmp/host-check.txt").c_str());
    EXPECT_EQ(WEXITSTATUS(*st), rt_expected() ? 0 : 1) << read_file("/tmp/host-check.txt");
  }
  Child json({tool("lancetctl"), "host-check", "--json"}, "/tmp/host-check.json");
  const auto st = json.wait_exit(std::chrono::minutes(2));
  ASSERT_TRUE(st.has_value() && WIFEXITED(*st));
  const std::string report = read_file("/tmp/host-check.json");
  EXPECT_EQ(WEXITSTATUS(*st), rt_expected() ? 0 : 1) << report;
  const auto line_of = [&](const std::string& name) {
    const auto at = report.find("\"name\": \"" + name + "\"");
    if (at == std::string::npos) return std::string();
    const auto begin = report.rfind('{', at), end = report.find('}', at);
    return report.substr(begin, end - begin + 1);
  };
  for (const char* isolated : {"isolcpus", "nohz_full", "rcu_nocbs"})
    EXPECT_NE(line_of(isolated).find("\"status\": \"pass\""), std::string::npos) << line_of(isolated);
  const std::string preempt = line_of("preempt_rt");
  if (rt_expected()) {
    EXPECT_NE(preempt.find("\"status\": \"pass\""), std::string::npos) << preempt;
    EXPECT_NE(report.find("\"fail\": 0"), std::string::npos) << report;
  } else {
    EXPECT_NE(preempt.find("\"status\": \"fail\""), std::string::npos) << preempt;
    EXPECT_NE(preempt.find("linux-image-rt-amd64"), std::string::npos) << "the fix names the package: " << preempt;
    EXPECT_NE(report.find("\"fail\": 1"), std::string::npos) << "PREEMPT_RT, and nothing else, fails: " << report;
  }
}

}  // namespace
