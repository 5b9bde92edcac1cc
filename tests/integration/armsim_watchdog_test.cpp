// The drive-side watchdog and late replies with the real programs over Modbus TCP: lancet-armsim
// serves the arm of hw_configs/modbus_tcp_arm.toml, lancet-rt drives it every tick.
//   - lancet-rt stopped (SIGSTOP) or killed (SIGKILL): the heartbeat register stops counting and
//     lancet-armsim's drives go torque-free once it has been silent for longer than the configured
//     watchdog time, with a latched fault and the comm_lost status bit, seen both in
//     lancet-armsim's stderr and in its status register (read here with plain libmodbus); a
//     resumed lancet-rt announces the fault in the config's words, and its heartbeat does not
//     clear it;
//   - replies that come late now and then are thrown away and counted by lancet-rt, never a fault.
// Nothing here depends on the machine's speed: the bus timeout and the drive watchdog are far
// longer than anything a loaded VM does to lancet-rt's ticks (this is about what happens, not how
// fast); every wait is for an event, with a deadline that only catches hangs; how long after the
// stop the drives tripped is lancet-armsim's business (it reports the silence it measured itself,
// which is never shorter than the watchdog time: that is checked).

#include <gtest/gtest.h>
#include <modbus.h>
#include <sys/mman.h>

#include <cerrno>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <random>
#include <regex>
#include <string>
#include <thread>
#include <vector>

#include "lancet/shared_model/shared_state.hpp"
#include "lancet/shared_model/validate.hpp"
#include "process_test.hpp"
#include "wait.hpp"

namespace lancet {
namespace {

using namespace std::chrono_literals;
using test::Child;
using test::eventually;
using test::read_file;

const std::string kBin = std::string(LANCET_BINARY_DIR);
const std::string kSrc = std::string(LANCET_SOURCE_DIR);

// The shipped map (hw_configs/modbus_tcp_arm.toml): status input register 6, heartbeat holding 4.
constexpr int kStatusRegister = 6, kHeartbeatRegister = 4;
constexpr std::uint16_t kFaultBit = 1u << 0, kEnabledBit = 1u << 1, kCommLostBit = 1u << 2;
// lancet-rt's bus timeout and the drives' watchdog (at least four bus timeouts, as the config
// loader demands): a reply or a tick held back by a loaded machine stays well inside both.
constexpr double kTimeoutMs = 250, kWatchdogMs = 2000;
constexpr DeviceLifecycle kActive = DeviceLifecycle::kActive;

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
  std::string write_config(const std::string& port) {
    std::string cfg = read_file(kSrc + "/hw_configs/modbus_tcp_arm.toml");
    cfg = std::regex_replace(cfg, std::regex("\nport = [0-9]+"), "\nport = " + port);
    cfg = std::regex_replace(cfg, std::regex("\nresponse_timeout_ms = [0-9.]+"), "\nresponse_timeout_ms = " + std::to_string(kTimeoutMs));
    cfg = std::regex_replace(cfg, std::regex("\ndrive_watchdog_ms = [0-9]+"), "\ndrive_watchdog_ms = " + std::to_string(static_cast<int>(kWatchdogMs)));
    cfg = std::regex_replace(cfg, std::regex("\nwatchdog_period_ms = [0-9.]+"), "\nwatchdog_period_ms = 500");
    std::ofstream(path("arm.toml")) << cfg;
    return path("arm.toml");
  }
  /// lancet-armsim on an ephemeral port, serving `config` (its drive watchdog included); the port
  /// it took, or empty if it never said.
  std::unique_ptr<Child> start_armsim(const std::string& config, std::vector<std::string> extra, std::string& port) {
    std::vector<std::string> argv{kBin + "/firmware_rt/lancet-armsim", config, "--port", "0", "--hand", "hold", "--duration", "600"};
    argv.insert(argv.end(), extra.begin(), extra.end());
    auto sim = std::make_unique<Child>(argv, path("armsim.log"));
    port.clear();
    (void)eventually([&] {
      std::smatch m;
      const std::string text = read_file(path("armsim.log"));
      if (std::regex_search(text, m, std::regex("127\\.0\\.0\\.1:([0-9]+)"))) port = m[1].str();
      return !port.empty() || !sim->running();
    });
    return sim;
  }
  /// lancet-rt driving the arm until told to stop (SIGTERM).
  std::unique_ptr<Child> start_rt(const std::string& config) {
    return std::make_unique<Child>(std::vector<std::string>{kBin + "/firmware_rt/lancet-rt", "--config", config, "--shm", shm_, "--duration",
                                                            "600", "--no-rt", "-q", "--stats", path("rt.json")},
                                   path("rt.log"));
  }
  /// lancet-rt's status (checked), polled until pred holds (false: a hang, or lancet-rt gone).
  template <class Pred>
  bool wait_status(Pred pred, RtStatus& st) {
    std::optional<SharedChannel> ch;
    return eventually([&] {
      if (!ch) {
        auto opened = SharedChannel::open(shm_);
        if (!opened) return false;
        ch.emplace(std::move(opened).value());
      }
      return ch->state().rt_status.try_read(st) == ReadStatus::kOk && wire::check(st) == nullptr && pred(st);
    });
  }
  /// A plain libmodbus client of the simulated drives, beside lancet-rt's connection.
  bool connect_peek(const std::string& port) {
    peek_ = modbus_new_tcp("127.0.0.1", std::stoi(port));
    if (peek_ == nullptr) return false;
    modbus_set_response_timeout(peek_, 5, 0);
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
  /// Waits until the heartbeat register differs from `from` (lancet-rt wrote since).
  bool wait_heartbeat_moves(std::optional<std::uint16_t> from) {
    return eventually([&] {
      const auto h = heartbeat();
      return h && h != from;
    });
  }
  /// Waits until lancet-rt drives the arm: the drives enabled and the heartbeat counting.
  bool wait_driven() {
    if (!eventually([&] {
          const auto s = status();
          return s && (*s & kEnabledBit) != 0;
        }))
      return false;
    return wait_heartbeat_moves(heartbeat());
  }
  /// Waits for lancet-armsim's watchdog line; returns the silence it reports (ms).
  std::optional<double> wait_trip() {
    const std::regex line("watchdog: heartbeat lost after ([0-9.]+) ms");
    std::optional<double> silence;
    (void)eventually([&] {
      std::smatch m;
      const std::string text = read_file(path("armsim.log"));
      if (std::regex_search(text, m, line)) silence = std::stod(m[1].str());
      return silence.has_value();
    });
    return silence;
  }
  bool wait_log(const std::string& file, const std::string& text) {
    return eventually([&] { return read_file(path(file)).find(text) != std::string::npos; });
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

TEST_F(ArmsimWatchdog, AStoppedLancetRtLeavesTheDrivesTorqueFreeAfterTheWatchdogTime) {
  std::string port;
  auto sim = start_armsim(write_config("1502"), {}, port);
  ASSERT_FALSE(port.empty()) << read_file(path("armsim.log"));
  auto rt = start_rt(write_config(port));
  ASSERT_TRUE(connect_peek(port));
  ASSERT_TRUE(wait_driven()) << read_file(path("rt.log")) << read_file(path("armsim.log"));
  EXPECT_EQ(read_file(path("armsim.log")).find("watchdog:"), std::string::npos) << "no trip while lancet-rt runs\n"
                                                                                   << read_file(path("armsim.log"));

  // lancet-rt stops dead (a debugger, a hung machine): no more heartbeats.
  rt->signal(SIGSTOP);
  const auto silence = wait_trip();
  ASSERT_TRUE(silence) << read_file(path("armsim.log"));
  std::printf("[ info     ] drive watchdog %.0f ms: lancet-armsim tripped after %.1f ms of silence\n", kWatchdogMs, *silence);
  EXPECT_GE(*silence, kWatchdogMs) << "not before the watchdog time (the line rounds to 0.1 ms)";
  expect_torque_free();
  EXPECT_NE(read_file(path("armsim.log")).find("drives torque-free"), std::string::npos);

  // Resumed, lancet-rt finds the drives faulted and says why, in the config's words; its
  // heartbeat comes back, and the fault stays until someone re-arms.
  const auto at_trip = heartbeat();
  rt->signal(SIGCONT);
  EXPECT_TRUE(wait_log("rt.log", "communication lost (bit 2)")) << read_file(path("rt.log"));
  EXPECT_NE(read_file(path("rt.log")).find("FAULT on modbus arm"), std::string::npos) << read_file(path("rt.log"));
  ASSERT_TRUE(wait_heartbeat_moves(at_trip)) << "lancet-rt writes its heartbeat again\n" << read_file(path("rt.log"));
  expect_torque_free();
  rt->signal(SIGTERM);
  EXPECT_TRUE(rt->wait_exit(test::kHangTimeout).has_value());
  sim->signal(SIGTERM);
  ASSERT_TRUE(sim->wait_exit(test::kHangTimeout).has_value());
  EXPECT_NE(read_file(path("armsim.log")).find("1 watchdog trips"), std::string::npos) << read_file(path("armsim.log"));
}

TEST_F(ArmsimWatchdog, AKilledLancetRtLeavesTheDrivesTorqueFreeAfterTheWatchdogTime) {
  std::string port;
  auto sim = start_armsim(write_config("1502"), {}, port);
  ASSERT_FALSE(port.empty()) << read_file(path("armsim.log"));
  auto rt = start_rt(write_config(port));
  ASSERT_TRUE(connect_peek(port));
  ASSERT_TRUE(wait_driven()) << read_file(path("rt.log")) << read_file(path("armsim.log"));

  rt->signal(SIGKILL);
  ASSERT_TRUE(rt->wait_exit(test::kHangTimeout).has_value());
  const auto silence = wait_trip();
  ASSERT_TRUE(silence) << read_file(path("armsim.log"));
  std::printf("[ info     ] drive watchdog %.0f ms: lancet-armsim tripped after %.1f ms of silence\n", kWatchdogMs, *silence);
  EXPECT_GE(*silence, kWatchdogMs) << "not before the watchdog time (the line rounds to 0.1 ms)";
  expect_torque_free();
  // Nobody resets it: it is still latched when lancet-armsim stops, after one trip.
  sim->signal(SIGTERM);
  ASSERT_TRUE(sim->wait_exit(test::kHangTimeout).has_value());
  EXPECT_NE(read_file(path("armsim.log")).find("1 watchdog trips"), std::string::npos) << read_file(path("armsim.log"));
}

TEST_F(ArmsimWatchdog, LancetRtRidesOutOccasionalLateRepliesWithoutAFault) {
  // One reply in five hundred goes out 1 s late (four bus timeouts): lancet-rt times out on it,
  // and takes it for what it is when it comes (over TCP later replies overtake it). The seeded
  // draws pick the same requests on every run; the test checks (with the same generator) that no
  // two late ones are close enough to make two errors in a row, and that a few come early on.
  constexpr std::uint64_t kSeed = 5;
  constexpr double kProbability = 0.002;
  {
    std::mt19937_64 rng(kSeed);
    std::vector<int> picks;
    for (int i = 0; i < 20000; ++i)
      if (std::uniform_real_distribution<double>(0.0, 1.0)(rng) < kProbability) picks.push_back(i);
    ASSERT_GE(picks.size(), 3u);
    ASSERT_GE(picks.front(), 100) << "a late reply during lancet-rt's start-up: choose another seed";
    ASSERT_LT(picks[2], 4000) << "choose another seed";
    for (std::size_t k = 1; k < picks.size(); ++k)
      ASSERT_GE(picks[k] - picks[k - 1], 8) << "two late replies too close (requests " << picks[k - 1] << ", " << picks[k] << "): choose another seed";
  }
  std::string port;
  auto sim = start_armsim(write_config("1502"),
                          {"--delay-us", std::to_string(static_cast<int>(4 * kTimeoutMs * 1000)), "--delay-probability",
                           std::to_string(kProbability), "--seed", std::to_string(kSeed)},
                          port);
  ASSERT_FALSE(port.empty()) << read_file(path("armsim.log"));
  auto rt = start_rt(write_config(port));
  RtStatus st{};
  ASSERT_TRUE(wait_status([](const RtStatus& s) { return s.hand[0].bus.stale_replies >= 3 || s.hand[0].bus.faults > 0; }, st)) << read_file(path("rt.log"));
  EXPECT_EQ(st.hand[0].device_state, kActive) << read_file(path("rt.log"));
  EXPECT_EQ(st.hand[0].bus.faults, 0u) << read_file(path("rt.log"));
  rt->signal(SIGTERM);
  const auto code = rt->wait_exit(test::kHangTimeout);
  const std::string log = read_file(path("rt.log"));
  ASSERT_TRUE(code.has_value() && WIFEXITED(*code)) << log;
  EXPECT_EQ(WEXITSTATUS(*code), 0) << log;
  EXPECT_EQ(log.find("FAULT"), std::string::npos) << "late replies are no fault\n" << log;
  const std::string stats = read_file(path("rt.json"));
  const auto stale = test::json_number(stats, "stale_replies");
  const auto timeouts = test::json_number(stats, "timeouts");
  const auto protocol = test::json_number(stats, "protocol_errors");
  const auto faults = test::json_number(stats, "faults");
  ASSERT_TRUE(stale && timeouts && protocol && faults) << stats;
  std::printf("[ info     ] lancet-rt, 0.2%% of the replies 1 s late (timeout 250 ms): %.0f timeouts, %.0f stale replies discarded\n", *timeouts,
              *stale);
  EXPECT_GE(*stale, 3) << stats;
  EXPECT_GE(*timeouts, *stale) << "each late reply was one timed-out request's" << stats;
  EXPECT_EQ(*protocol, 0) << "a late reply is never taken for a wrong one" << stats;
  EXPECT_EQ(*faults, 0) << stats;
  EXPECT_NE(stats.find("\"state\": \"active\""), std::string::npos) << stats;
  sim->signal(SIGTERM);
  ASSERT_TRUE(sim->wait_exit(test::kHangTimeout).has_value());
  EXPECT_EQ(read_file(path("armsim.log")).find("watchdog:"), std::string::npos) << read_file(path("armsim.log"));
}

}  // namespace
}  // namespace lancet
