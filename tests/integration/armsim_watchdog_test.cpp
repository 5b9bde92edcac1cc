// The drive-side watchdog and late replies with the real programs over Modbus TCP: lancet-armsim
// serves the arm of hw_configs/modbus_tcp_arm.toml, lancet-rt drives it every tick.
//   - lancet-rt stopped (SIGSTOP) or killed (SIGKILL): the heartbeat register stops counting and
//     lancet-armsim's drives go torque-free within the configured watchdog time, with a latched
//     fault and the comm_lost status bit, seen both in lancet-armsim's stderr and in its status
//     register (read here with plain libmodbus); a resumed lancet-rt announces the fault in the
//     config's words;
//   - replies that come late now and then are thrown away and counted by lancet-rt, never a fault.
// Times are asserted with wide margins: this runs on loaded two-core VMs.

#include <gtest/gtest.h>
#include <modbus.h>
#include <sys/mman.h>

#include <cerrno>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <regex>
#include <string>
#include <thread>

#include "lancet/shared_model/shared_state.hpp"
#include "process_test.hpp"

namespace lancet {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using test::Child;
using test::read_file;

const std::string kBin = std::string(LANCET_BINARY_DIR);
const std::string kSrc = std::string(LANCET_SOURCE_DIR);

// The shipped map (hw_configs/modbus_tcp_arm.toml): status input register 6, heartbeat holding 4.
constexpr int kStatusRegister = 6, kHeartbeatRegister = 4;
constexpr std::uint16_t kFaultBit = 1u << 0, kEnabledBit = 1u << 1, kCommLostBit = 1u << 2;
constexpr double kWatchdogMs = 100;  // robust on a loaded VM: lancet-rt writes every millisecond

class ArmsimWatchdog : public test::ProcessTest {
 protected:
  ArmsimWatchdog() : ProcessTest("wd") {}
  void TearDown() override {
    if (peek_ != nullptr) {
      modbus_close(peek_);
      modbus_free(peek_);
    }
    ProcessTest::TearDown();
  }

  /// The shipped config with this test's port, timeouts and drive watchdog.
  std::string write_config(const std::string& port, double response_timeout_ms, double watchdog_ms) {
    std::string cfg = read_file(kSrc + "/hw_configs/modbus_tcp_arm.toml");
    cfg = std::regex_replace(cfg, std::regex("\nport = [0-9]+"), "\nport = " + port);
    cfg = std::regex_replace(cfg, std::regex("\nresponse_timeout_ms = [0-9.]+"), "\nresponse_timeout_ms = " + std::to_string(response_timeout_ms));
    cfg = std::regex_replace(cfg, std::regex("\ndrive_watchdog_ms = [0-9]+"), "\ndrive_watchdog_ms = " + std::to_string(static_cast<int>(watchdog_ms)));
    cfg = std::regex_replace(cfg, std::regex("\nwatchdog_period_ms = [0-9.]+"), "\nwatchdog_period_ms = 500");
    std::ofstream(path("arm.toml")) << cfg;
    return path("arm.toml");
  }
  /// lancet-armsim on an ephemeral port, serving `config` (its drive watchdog included).
  std::unique_ptr<Child> start_armsim(const std::string& config, std::vector<std::string> extra, std::string& port) {
    std::vector<std::string> argv{kBin + "/firmware_rt/lancet-armsim", config, "--port", "0", "--hand", "hold", "--duration", "60"};
    argv.insert(argv.end(), extra.begin(), extra.end());
    auto sim = std::make_unique<Child>(argv, path("armsim.log"));
    port.clear();
    for (int i = 0; i < 500 && port.empty(); ++i) {
      std::smatch m;
      const std::string text = read_file(path("armsim.log"));
      if (std::regex_search(text, m, std::regex("127\\.0\\.0\\.1:([0-9]+)"))) port = m[1].str();
      std::this_thread::sleep_for(10ms);
    }
    return sim;
  }
  std::unique_ptr<Child> start_rt(const std::string& config, double duration) {
    auto rt = std::make_unique<Child>(std::vector<std::string>{kBin + "/firmware_rt/lancet-rt", "--config", config, "--shm", shm_, "--duration",
                                                               std::to_string(duration), "--no-rt", "-q", "--stats", path("rt.json")},
                                      path("rt.log"));
    return rt;
  }
  /// A plain libmodbus client of the simulated drives, beside lancet-rt's connection.
  bool connect_peek(const std::string& port) {
    peek_ = modbus_new_tcp("127.0.0.1", std::stoi(port));
    if (peek_ == nullptr) return false;
    modbus_set_response_timeout(peek_, 1, 0);
    return modbus_connect(peek_) == 0;
  }
  std::optional<std::uint16_t> status() {
    std::uint16_t v = 0;
    if (modbus_read_input_registers(peek_, kStatusRegister, 1, &v) != 1) return std::nullopt;
    return v;
  }
  std::optional<std::uint16_t> heartbeat() {
    std::uint16_t v = 0;
    if (modbus_read_registers(peek_, kHeartbeatRegister, 1, &v) != 1) return std::nullopt;
    return v;
  }
  /// Waits until lancet-rt drives the arm: the drives enabled and the heartbeat counting.
  bool wait_driven(std::chrono::milliseconds timeout) {
    const auto end = Clock::now() + timeout;
    while (Clock::now() < end) {
      const auto s = status();
      const auto h0 = heartbeat();
      std::this_thread::sleep_for(30ms);
      const auto h1 = heartbeat();
      if (s && h0 && h1 && (*s & kEnabledBit) != 0 && *h0 != *h1) return true;
    }
    return false;
  }
  /// Waits for lancet-armsim's watchdog line; returns the silence it reports (ms).
  std::optional<double> wait_trip(std::chrono::milliseconds timeout) {
    const auto end = Clock::now() + timeout;
    const std::regex line("watchdog: heartbeat lost after ([0-9.]+) ms");
    while (Clock::now() < end) {
      std::smatch m;
      const std::string text = read_file(path("armsim.log"));
      if (std::regex_search(text, m, line)) return std::stod(m[1].str());
      std::this_thread::sleep_for(5ms);
    }
    return std::nullopt;
  }
  bool wait_log(const std::string& file, const std::string& text, std::chrono::milliseconds timeout) {
    const auto end = Clock::now() + timeout;
    while (Clock::now() < end) {
      if (read_file(path(file)).find(text) != std::string::npos) return true;
      std::this_thread::sleep_for(20ms);
    }
    return false;
  }
  /// The drives are torque-free: not enabled, the fault latched with the comm_lost bit.
  void expect_torque_free() {
    const auto s = status();
    ASSERT_TRUE(s) << modbus_strerror(errno);
    EXPECT_EQ(*s & kEnabledBit, 0) << "status 0x" << std::hex << *s;
    EXPECT_EQ(*s & (kFaultBit | kCommLostBit), kFaultBit | kCommLostBit) << "status 0x" << std::hex << *s;
  }

  modbus_t* peek_ = nullptr;
};

TEST_F(ArmsimWatchdog, AStoppedLancetRtLeavesTheDrivesTorqueFreeWithinTheWatchdogTime) {
  std::string port;
  auto sim = start_armsim(write_config("1502", 20, kWatchdogMs), {}, port);
  ASSERT_FALSE(port.empty()) << read_file(path("armsim.log"));
  auto rt = start_rt(write_config(port, 20, kWatchdogMs), 30);
  ASSERT_TRUE(connect_peek(port));
  ASSERT_TRUE(wait_driven(10s)) << read_file(path("rt.log")) << read_file(path("armsim.log"));
  EXPECT_EQ(read_file(path("armsim.log")).find("watchdog:"), std::string::npos) << "no trip while lancet-rt runs\n"
                                                                                   << read_file(path("armsim.log"));

  // lancet-rt stops dead (a debugger, a hung machine): no more heartbeats.
  const auto stopped = Clock::now();
  rt->signal(SIGSTOP);
  const auto silence = wait_trip(5s);
  const double seen_ms = std::chrono::duration<double, std::milli>(Clock::now() - stopped).count();
  ASSERT_TRUE(silence) << read_file(path("armsim.log"));
  std::printf("[ info     ] drive watchdog %.0f ms: lancet-armsim tripped after %.1f ms of silence; the test saw it %.0f ms after SIGSTOP\n",
              kWatchdogMs, *silence, seen_ms);
  EXPECT_GE(*silence, kWatchdogMs);
  EXPECT_LT(*silence, kWatchdogMs + 500) << "torque-free within the watchdog time (and a wide margin for a loaded VM)";
  EXPECT_LT(seen_ms, 3000);
  expect_torque_free();
  EXPECT_NE(read_file(path("armsim.log")).find("drives torque-free"), std::string::npos);

  // Resumed, lancet-rt finds the drives faulted and says why, in the config's words; the fault
  // stays until someone re-arms.
  rt->signal(SIGCONT);
  EXPECT_TRUE(wait_log("rt.log", "communication lost (bit 2)", 5s)) << read_file(path("rt.log"));
  EXPECT_NE(read_file(path("rt.log")).find("FAULT on modbus arm"), std::string::npos) << read_file(path("rt.log"));
  std::this_thread::sleep_for(200ms);
  expect_torque_free();
  rt->signal(SIGTERM);
  EXPECT_TRUE(rt->wait_exit(10s).has_value());
  sim->signal(SIGTERM);
  (void)sim->wait_exit(5s);
}

TEST_F(ArmsimWatchdog, AKilledLancetRtLeavesTheDrivesTorqueFreeWithinTheWatchdogTime) {
  std::string port;
  auto sim = start_armsim(write_config("1502", 20, kWatchdogMs), {}, port);
  ASSERT_FALSE(port.empty()) << read_file(path("armsim.log"));
  auto rt = start_rt(write_config(port, 20, kWatchdogMs), 30);
  ASSERT_TRUE(connect_peek(port));
  ASSERT_TRUE(wait_driven(10s)) << read_file(path("rt.log")) << read_file(path("armsim.log"));

  const auto killed = Clock::now();
  rt->signal(SIGKILL);
  ASSERT_TRUE(rt->wait_exit(5s).has_value());
  const auto silence = wait_trip(5s);
  const double seen_ms = std::chrono::duration<double, std::milli>(Clock::now() - killed).count();
  ASSERT_TRUE(silence) << read_file(path("armsim.log"));
  std::printf("[ info     ] drive watchdog %.0f ms: lancet-armsim tripped after %.1f ms of silence; the test saw it %.0f ms after SIGKILL\n",
              kWatchdogMs, *silence, seen_ms);
  EXPECT_GE(*silence, kWatchdogMs);
  EXPECT_LT(*silence, kWatchdogMs + 500);
  EXPECT_LT(seen_ms, 3000);
  expect_torque_free();
  // It stays so: nobody reset it.
  std::this_thread::sleep_for(300ms);
  expect_torque_free();
  sim->signal(SIGTERM);
  ASSERT_TRUE(sim->wait_exit(5s).has_value());
  EXPECT_NE(read_file(path("armsim.log")).find("1 watchdog trips"), std::string::npos) << read_file(path("armsim.log"));
}

TEST_F(ArmsimWatchdog, LancetRtRidesOutOccasionalLateRepliesWithoutAFault) {
  std::string port;
  // One reply in two hundred comes 30 ms late: past the 20 ms timeout, inside two of them.
  auto sim = start_armsim(write_config("1502", 20, kWatchdogMs), {"--delay-us", "30000", "--delay-probability", "0.005", "--seed", "7"}, port);
  ASSERT_FALSE(port.empty()) << read_file(path("armsim.log"));
  auto rt = start_rt(write_config(port, 20, kWatchdogMs), 3);
  const auto code = rt->wait_exit(30s);
  const std::string log = read_file(path("rt.log"));
  ASSERT_TRUE(code.has_value() && WIFEXITED(*code)) << log;
  EXPECT_EQ(WEXITSTATUS(*code), 0) << log;
  EXPECT_EQ(log.find("FAULT"), std::string::npos) << "late replies are no fault\n" << log;
  const std::string stats = read_file(path("rt.json"));
  const auto stale = test::json_number(stats, "stale_replies");
  const auto timeouts = test::json_number(stats, "timeouts");
  ASSERT_TRUE(stale && timeouts) << stats;
  std::printf("[ info     ] lancet-rt, 3 s with 0.5%% of the replies 30 ms late: %.0f timeouts, %.0f stale replies discarded\n", *timeouts,
              *stale);
  EXPECT_GT(*timeouts, 0) << stats;
  EXPECT_GT(*stale, 0) << stats;
  EXPECT_NE(stats.find("\"state\": \"active\""), std::string::npos) << stats;
  sim->signal(SIGTERM);
  (void)sim->wait_exit(5s);
  EXPECT_EQ(read_file(path("armsim.log")).find("watchdog:"), std::string::npos) << read_file(path("armsim.log"));
}

}  // namespace
}  // namespace lancet
