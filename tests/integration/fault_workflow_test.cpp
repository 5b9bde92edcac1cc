// The fault workflow an integrator sees, end to end with the real programs: lancet-armsim serves
// the Modbus TCP arm, lancet-rt drives it, lancetctl re-arms it.
//   - encoder glitches are counted and announced; a rare glitch is survived, repeated ones fault
//     the arm, with the joint named;
//   - the bus going away is announced at once with its cause, lancet-rt reconnects on its own when
//     the arm comes back, the arm stays at zero force until `lancetctl rearm --rt SHM --yes`, and
//     every step is in lancet-rt's stderr and --stats.
// Nothing here depends on the machine's speed: the bus timeout and the drive watchdog are far
// longer than anything a loaded VM does to lancet-rt's ticks, a glitch is far larger than any
// joint could move between two readings however late the second one is, and every wait is for an
// event (a line in the log, a value in lancet-rt's status), with a deadline that only catches hangs.

#include <gtest/gtest.h>
#include <sys/mman.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <string>
#include <thread>

#include "lancet/shared_model/shared_state.hpp"
#include "lancet/shared_model/validate.hpp"
#include "process_test.hpp"
#include "wait.hpp"

namespace lancet {
namespace {

using namespace std::chrono_literals;
using test::Child;
using test::eventually;
using test::json_number;
using test::read_file;

const std::string kBin = std::string(LANCET_BINARY_DIR);
const std::string kSrc = std::string(LANCET_SOURCE_DIR);

class FaultWorkflow : public test::ProcessTest {
 protected:
  FaultWorkflow() : ProcessTest("faults") {}

  /// lancet-armsim on `port` (0: any; the port it took is returned through port_out, empty if it
  /// never said).
  std::unique_ptr<Child> start_armsim(const std::string& port, std::vector<std::string> extra, const std::string& log,
                                      std::string& port_out) {
    std::vector<std::string> argv{kBin + "/firmware_rt/lancet-armsim", kSrc + "/hw_configs/modbus_tcp_arm.toml", "--port", port,
                                  "--hand", "hold", "--duration", "600"};
    argv.insert(argv.end(), extra.begin(), extra.end());
    auto sim = std::make_unique<Child>(argv, path(log));
    port_out.clear();
    (void)eventually([&] {
      std::smatch m;
      const std::string text = read_file(path(log));
      if (std::regex_search(text, m, std::regex("127\\.0\\.0\\.1:([0-9]+)"))) port_out = m[1].str();
      return !port_out.empty() || !sim->running();
    });
    return sim;
  }
  /// The shipped config pointed at `port`, with a bus timeout and a drive watchdog (at least four
  /// bus timeouts, as the loader demands) that no tick held back by a loaded machine reaches.
  std::string write_config(const std::string& port) {
    std::string cfg = read_file(kSrc + "/hw_configs/modbus_tcp_arm.toml");
    cfg = std::regex_replace(cfg, std::regex("\nport = [0-9]+"), "\nport = " + port);
    cfg = std::regex_replace(cfg, std::regex("\nresponse_timeout_ms = [0-9.]+"), "\nresponse_timeout_ms = 250");
    cfg = std::regex_replace(cfg, std::regex("\ndrive_watchdog_ms = [0-9]+"), "\ndrive_watchdog_ms = 2000");
    cfg = std::regex_replace(cfg, std::regex("\nwatchdog_period_ms = [0-9.]+"), "\nwatchdog_period_ms = 500");
    std::ofstream(path("arm.toml")) << cfg;
    return path("arm.toml");
  }
  /// lancet-rt driving the arm until told to stop (SIGTERM), once its segment is there.
  std::unique_ptr<Child> start_rt(const std::string& config) {
    auto rt = std::make_unique<Child>(std::vector<std::string>{kBin + "/firmware_rt/lancet-rt", "--config", config, "--shm", shm_,
                                                               "--duration", "600", "--no-rt", "-q", "--stats", path("rt.json")},
                                      path("rt.log"));
    (void)eventually([&] { return static_cast<bool>(SharedChannel::open(shm_)) || !rt->running(); });
    return rt;
  }
  /// Stops lancet-rt (SIGTERM) and waits for it; its exit status, if it exited.
  std::optional<int> stop_rt(Child& rt) {
    rt.signal(SIGTERM);
    return rt.wait_exit(test::kHangTimeout);
  }
  /// Waits until lancet-rt's stderr says `text`.
  bool wait_log(const std::string& text) {
    return eventually([&] { return read_file(path("rt.log")).find(text) != std::string::npos; });
  }
  /// lancet-rt's status (checked), polled until pred holds.
  template <class Pred>
  bool wait_status(Pred pred, RtStatus& st) {
    auto ch = SharedChannel::open(shm_);
    if (!ch) return false;
    return eventually([&] { return ch.value().state().rt_status.try_read(st) == ReadStatus::kOk && wire::check(st) == nullptr && pred(st); });
  }
};

constexpr DeviceLifecycle kActive = DeviceLifecycle::kActive, kFault = DeviceLifecycle::kFault;

TEST_F(FaultWorkflow, EncoderGlitchesAreCountedAndAnnouncedAndRepeatedOnesFaultTheArm) {
  // A glitch of a hundred million counts (thousands of radians): no reading that late could make
  // it plausible, so each one is a glitch however the machine schedules lancet-rt.
  const std::vector<std::string> big = {"--glitch-counts", "100000000"};
  std::string port;
  // One reply in five hundred carries a glitch: counted and announced, never a fault.
  std::vector<std::string> extra = big;
  extra.insert(extra.end(), {"--encoder-glitch", "0.002", "--seed", "3"});
  auto rare = start_armsim("0", extra, "armsim1.log", port);
  ASSERT_FALSE(port.empty()) << read_file(path("armsim1.log"));
  auto rt = start_rt(write_config(port));
  RtStatus st{};
  ASSERT_TRUE(wait_status([](const RtStatus& s) { return s.hand[0].bus.glitches >= 1 || s.hand[0].bus.faults > 0; }, st)) << read_file(path("rt.log"));
  // And lancet-rt goes on: a few hundred good readings after it, still active.
  const std::uint64_t reads_at_glitch = st.hand[0].bus.reads;
  ASSERT_TRUE(wait_status([&](const RtStatus& s) { return s.hand[0].bus.reads >= reads_at_glitch + 300 || s.hand[0].bus.faults > 0; }, st))
      << read_file(path("rt.log"));
  EXPECT_EQ(st.hand[0].device_state, kActive) << read_file(path("rt.log"));
  EXPECT_TRUE(wait_log("encoder glitches (last: joint")) << read_file(path("rt.log"));
  ASSERT_TRUE(stop_rt(*rt).has_value()) << read_file(path("rt.log"));
  std::string log = read_file(path("rt.log")), stats = read_file(path("rt.json"));
  EXPECT_GT(json_number(stats, "glitches").value_or(0), 0) << stats;
  EXPECT_EQ(log.find("FAULT"), std::string::npos) << "a rare glitch is not a fault\n" << log;
  EXPECT_NE(stats.find("\"state\": \"active\""), std::string::npos) << stats;
  rare->signal(SIGTERM);
  (void)rare->wait_exit(test::kHangTimeout);

  // One in ten: the bucket fills and the arm faults at once, the cause and the joint said.
  extra = big;
  extra.insert(extra.end(), {"--encoder-glitch", "0.1", "--seed", "4"});
  auto often = start_armsim("0", extra, "armsim2.log", port);
  ASSERT_FALSE(port.empty()) << read_file(path("armsim2.log"));
  rt = start_rt(write_config(port));
  ASSERT_TRUE(wait_status([](const RtStatus& s) { return s.hand[0].device_state == kFault; }, st)) << read_file(path("rt.log"));
  EXPECT_TRUE(wait_log("lancetctl rearm --rt " + shm_)) << read_file(path("rt.log"));
  ASSERT_TRUE(stop_rt(*rt).has_value()) << read_file(path("rt.log"));
  log = read_file(path("rt.log"));
  stats = read_file(path("rt.json"));
  EXPECT_NE(log.find("FAULT on modbus arm"), std::string::npos) << log;
  EXPECT_NE(log.find("fault (encoder glitch): joint"), std::string::npos) << log;
  EXPECT_NE(stats.find("\"state\": \"fault\""), std::string::npos) << stats;
  EXPECT_NE(stats.find("\"fault_cause\": \"encoder glitch\""), std::string::npos) << stats;
  EXPECT_GE(json_number(stats, "glitches").value_or(0), 3) << stats;
  often->signal(SIGTERM);
  (void)often->wait_exit(test::kHangTimeout);
}

TEST_F(FaultWorkflow, ALostBusIsReconnectedAndTheArmWaitsForAnExplicitRearmFromLancetctl) {
  std::string port;
  auto sim = start_armsim("0", {}, "armsim1.log", port);
  ASSERT_FALSE(port.empty()) << read_file(path("armsim1.log"));
  auto rt = start_rt(write_config(port));
  RtStatus st{};
  ASSERT_TRUE(wait_status([](const RtStatus& s) { return s.hand[0].device_state == kActive && s.tick > 200; }, st)) << read_file(path("rt.log"));

  // The arm's box dies.
  kill(sim->pid(), SIGKILL);
  (void)sim->wait_exit(test::kHangTimeout);
  ASSERT_TRUE(wait_log("FAULT on modbus arm")) << read_file(path("rt.log"));
  EXPECT_TRUE(wait_log("bus link lost; reconnecting")) << read_file(path("rt.log"));
  ASSERT_TRUE(wait_status([](const RtStatus& s) { return s.hand[0].device_state == kFault && s.hand[0].link_lost == 1; }, st));
  EXPECT_EQ(st.hand[0].force.x, 0.0);
  EXPECT_EQ(st.hand[0].force.y, 0.0);
  EXPECT_EQ(st.hand[0].force.z, 0.0);
  EXPECT_GE(st.hand[0].bus.disconnects + st.hand[0].bus.timeouts, 1u);

  // It comes back on the same port: lancet-rt reconnects by itself, but does not re-arm.
  std::string port2;
  auto sim2 = start_armsim(port, {}, "armsim2.log", port2);
  ASSERT_EQ(port2, port) << read_file(path("armsim2.log"));
  ASSERT_TRUE(wait_log("bus link back after")) << read_file(path("rt.log"));
  ASSERT_TRUE(wait_status([](const RtStatus& s) { return s.hand[0].link_lost == 0; }, st));
  // Some hundreds of ticks on the link that is back: still faulted.
  const std::uint64_t tick_back = st.tick;
  ASSERT_TRUE(wait_status([&](const RtStatus& s) { return s.tick >= tick_back + 500 || s.hand[0].device_state != kFault; }, st));
  EXPECT_EQ(st.hand[0].device_state, kFault) << "a reconnect never re-arms";
  EXPECT_GE(st.hand[0].bus.reconnects, 1u);

  // The operator re-arms from the command line.
  Child ctl({kBin + "/firmware_rt/lancetctl", "rearm", "--rt", shm_, "--yes", "--timeout", "30"}, path("rearm.log"));
  const auto ctl_code = ctl.wait_exit(2 * test::kHangTimeout);
  const std::string ctl_out = read_file(path("rearm.log"));
  ASSERT_TRUE(ctl_code.has_value() && WIFEXITED(*ctl_code)) << ctl_out;
  EXPECT_EQ(WEXITSTATUS(*ctl_code), 0) << ctl_out;
  EXPECT_NE(ctl_out.find("arm: fault ("), std::string::npos) << "the fault is shown first\n" << ctl_out;
  EXPECT_NE(ctl_out.find("rearm: re-armed: right arm active"), std::string::npos) << ctl_out;
  ASSERT_TRUE(wait_status([](const RtStatus& s) { return s.hand[0].device_state == kActive; }, st));
  EXPECT_TRUE(wait_log("re-arm requested by an operator"));
  EXPECT_TRUE(wait_log("re-armed: active")) << read_file(path("rt.log"));

  ASSERT_TRUE(stop_rt(*rt).has_value());
  const std::string stats = read_file(path("rt.json"));
  EXPECT_GE(json_number(stats, "reconnects").value_or(0), 1) << stats;
  EXPECT_GE(json_number(stats, "rearms").value_or(0), 1) << stats;
  EXPECT_GE(json_number(stats, "operator_requests").value_or(0), 1) << stats;
  EXPECT_NE(stats.find("\"state\": \"active\""), std::string::npos) << stats;
  sim2->signal(SIGTERM);
  (void)sim2->wait_exit(test::kHangTimeout);
}

}  // namespace
}  // namespace lancet
