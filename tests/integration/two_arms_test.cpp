// Two arms in one loop, with the real programs: two lancet-armsim processes serve a Modbus TCP arm
// each (two ports), one lancet-rt drives both (`--hands 2 --config right.toml --left-config
// left.toml`), lancetctl re-arms one hand. What is checked:
//   - both arms reach active and both hands' bus counters advance, every tick reading and writing
//     each arm;
//   - a drive fault injected into one armsim (its --control FIFO) faults that hand's arm alone: its
//     force is zero, the other hand's arm stays active and its bus keeps working, and lancet-rt
//     names the hand;
//   - `lancetctl rearm --hand <that hand>` re-arms it, and only it; then the same the other way
//     round.
// In that test no viz runs (the subject is the bus: two devices, their lifecycles and counters), so
// every force is zero; the second test runs lancet-viz too: a fault on the left hand's arm leaves
// the right hand pressing into the tissue at full force (as two SimArms do in-process,
// RtServoTwoArms in rt_servo_arm_test).
// Nothing here depends on the machine's speed: the bus timeout and the drive watchdog are far
// longer than anything a loaded VM does to lancet-rt's ticks, and every wait is for an event (a
// line in a log, a value in lancet-rt's status), with a deadline that only catches hangs.

#include <fcntl.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <array>
#include <cstdlib>
#include <fstream>
#include <memory>
#include <optional>
#include <regex>
#include <string>

#include "lancet/shared_model/shared_state.hpp"
#include "lancet/shared_model/validate.hpp"
#include "process_test.hpp"
#include "wait.hpp"

namespace lancet {
namespace {

using test::Child;
using test::eventually;
using test::read_file;

const std::string kBin = std::string(LANCET_BINARY_DIR);
const std::string kSrc = std::string(LANCET_SOURCE_DIR);

constexpr DeviceLifecycle kActive = DeviceLifecycle::kActive, kFault = DeviceLifecycle::kFault;
constexpr std::array<const char*, 2> kHandNames = {"right", "left"};  // by Hand: the right hand is 0

class TwoArms : public test::ProcessTest {
 protected:
  TwoArms() : ProcessTest("twoarms") {}

  /// One hand's arm: lancet-armsim on a port of its own, taking faults from a FIFO.
  struct Arm {
    std::unique_ptr<Child> sim;
    std::string port;     ///< the port it serves on ("" if it never said)
    std::string log;      ///< its stdout and stderr
    std::string control;  ///< its --control FIFO
  };

  /// lancet-armsim for hand `h` (holding its arm still: no tissue here to press into).
  Arm start_armsim(std::size_t h) {
    Arm a;
    const std::string name = kHandNames[h];
    a.log = path("armsim-" + name + ".log");
    a.control = path("armsim-" + name + ".control");
    a.sim = std::make_unique<Child>(std::vector<std::string>{kBin + "/firmware_rt/lancet-armsim", kSrc + "/hw_configs/modbus_tcp_arm.toml",
                                                             "--port", "0", "--hand", "hold", "--duration", "600", "--control", a.control},
                                    a.log);
    (void)eventually([&] {
      std::smatch m;
      const std::string text = read_file(a.log);
      if (std::regex_search(text, m, std::regex("127\\.0\\.0\\.1:([0-9]+)"))) a.port = m[1].str();
      return !a.port.empty() || !a.sim->running();
    });
    return a;
  }
  /// The shipped config pointed at `port` (as `<hand>.toml`), with a bus timeout and a drive
  /// watchdog (at least four bus timeouts, as the loader demands) that no tick held back by a
  /// loaded machine reaches.
  std::string write_config(std::size_t h, const std::string& port) {
    std::string cfg = read_file(kSrc + "/hw_configs/modbus_tcp_arm.toml");
    cfg = std::regex_replace(cfg, std::regex("\nport = [0-9]+"), "\nport = " + port);
    cfg = std::regex_replace(cfg, std::regex("\nresponse_timeout_ms = [0-9.]+"), "\nresponse_timeout_ms = 250");
    cfg = std::regex_replace(cfg, std::regex("\ndrive_watchdog_ms = [0-9]+"), "\ndrive_watchdog_ms = 2000");
    cfg = std::regex_replace(cfg, std::regex("\nwatchdog_period_ms = [0-9.]+"), "\nwatchdog_period_ms = 500");
    const std::string file = path(std::string(kHandNames[h]) + ".toml");
    std::ofstream(file) << cfg;
    return file;
  }
  /// Sends one command to an armsim's FIFO and waits until it says it took effect.
  bool control(const Arm& a, const std::string& command) {
    const auto acks = [&] {
      const std::string text = read_file(a.log);
      std::size_t n = 0;
      for (std::size_t at = text.find("armsim: control: "); at != std::string::npos; at = text.find("armsim: control: ", at + 1)) ++n;
      return n;
    };
    const std::size_t before = acks();
    // lancet-armsim holds a writer of its own open, so this open never blocks and never fails
    // for want of a reader.
    const int fd = ::open(a.control.c_str(), O_WRONLY | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0) return false;
    const std::string line = command + "\n";
    const bool written = ::write(fd, line.data(), line.size()) == static_cast<ssize_t>(line.size());
    ::close(fd);
    return written && eventually([&] { return acks() > before; }) && read_file(a.log).find("armsim: control: error") == std::string::npos;
  }
  /// lancet-rt driving both arms until told to stop (SIGTERM), once its segment is there.
  std::unique_ptr<Child> start_rt(const std::string& right, const std::string& left) {
    auto rt = std::make_unique<Child>(std::vector<std::string>{kBin + "/firmware_rt/lancet-rt", "--hands", "2", "--config", right,
                                                               "--left-config", left, "--shm", shm_, "--duration", "600", "--no-rt", "-q",
                                                               "--stats", path("rt.json")},
                                      path("rt.log"));
    (void)eventually([&] { return static_cast<bool>(SharedChannel::open(shm_)) || !rt->running(); });
    return rt;
  }
  /// lancet-rt's status (checked), polled until pred holds; false on a hang or a missing segment.
  template <class Pred>
  bool wait_status(Pred pred, RtStatus& st) {
    auto ch = SharedChannel::open(shm_);
    if (!ch) return false;
    return eventually([&] { return ch.value().state().rt_status.try_read(st) == ReadStatus::kOk && wire::check(st) == nullptr && pred(st); });
  }
  /// Waits until hand h's bus has read and written at least `more` more times than in `from`.
  bool wait_bus_advances(std::size_t h, const RtStatus& from, std::uint64_t more, RtStatus& st) {
    const std::uint64_t reads = from.hand[h].bus.reads, writes = from.hand[h].bus.writes;
    return wait_status([&](const RtStatus& s) { return s.hand[h].bus.reads >= reads + more && s.hand[h].bus.writes >= writes + more; }, st);
  }
  /// `lancetctl rearm --hand <name> --yes`: its exit status (nullopt: a hang) and its output.
  std::optional<int> rearm(const std::string& hand, std::string& out) {
    const std::string log = path("rearm-" + hand + ".log");
    Child ctl({kBin + "/firmware_rt/lancetctl", "rearm", "--rt", shm_, "--hand", hand, "--yes", "--timeout", "30"}, log);
    const auto code = ctl.wait_exit(2 * test::kHangTimeout);
    out = read_file(log);
    if (!code || !WIFEXITED(*code)) return std::nullopt;
    return WEXITSTATUS(*code);
  }
  std::string rt_log() const { return read_file(path("rt.log")); }

  /// Faults hand `h`'s arm through its armsim, checks the other hand is untouched, re-arms it with
  /// lancetctl and checks both are active again.
  void fault_one_and_rearm_it(std::size_t h, std::array<Arm, 2>& arms) {
    SCOPED_TRACE(std::string("fault on the ") + kHandNames[h] + " arm");
    const std::size_t other = 1 - h;
    const std::string name = kHandNames[h], other_name = kHandNames[other];
    RtStatus st{};
    const std::size_t log_from = rt_log().size();  // what lancet-rt says from here on
    const auto said = [&](const std::string& text) { return rt_log().find(text, log_from) != std::string::npos; };
    ASSERT_TRUE(control(arms[h], "fault")) << read_file(arms[h].log);
    ASSERT_TRUE(wait_status([&](const RtStatus& s) { return s.hand[h].device_state == kFault; }, st)) << rt_log();
    EXPECT_EQ(st.hand[h].force.x, 0.0);
    EXPECT_EQ(st.hand[h].force.y, 0.0);
    EXPECT_EQ(st.hand[h].force.z, 0.0);
    EXPECT_EQ(st.hand[h].device_fault_cause, IoStatus::kDeviceFault) << st.hand[h].fault_text;
    EXPECT_GE(st.hand[h].bus.device_faults, 1u);
    EXPECT_EQ(st.hand[other].device_state, kActive) << st.hand[other].fault_text << "\n" << rt_log();

    // The other arm goes on: hundreds more reads and writes, still active, no fault of its own;
    // the faulted one stays faulted all that time (nothing re-arms it but a request).
    const RtStatus at_fault = st;
    ASSERT_TRUE(wait_bus_advances(other, at_fault, 300, st)) << rt_log();
    EXPECT_EQ(st.hand[other].device_state, kActive) << st.hand[other].fault_text;
    EXPECT_EQ(st.hand[other].bus.faults, at_fault.hand[other].bus.faults);
    EXPECT_EQ(st.hand[other].bus.timeouts, at_fault.hand[other].bus.timeouts);
    EXPECT_EQ(st.hand[h].device_state, kFault) << "a fault never re-arms itself";
    EXPECT_TRUE(eventually([&] { return said(name + " arm: FAULT on modbus arm"); })) << rt_log();
    EXPECT_TRUE(said("lancetctl rearm --rt " + shm_ + " --hand " + name)) << rt_log();
    EXPECT_FALSE(said(other_name + " arm: FAULT")) << rt_log();

    // The operator re-arms that hand: lancetctl shows its fault and re-arms it alone.
    std::string out;
    const auto code = rearm(name, out);
    ASSERT_TRUE(code.has_value()) << out;
    EXPECT_EQ(*code, 0) << out;
    EXPECT_NE(out.find(name + " arm: fault ("), std::string::npos) << "the fault is shown first\n" << out;
    EXPECT_EQ(out.find(other_name + " arm:"), std::string::npos) << "--hand " << name << " shows that hand only\n" << out;
    EXPECT_NE(out.find("rearm: re-armed: " + name + " arm active"), std::string::npos) << out;
    ASSERT_TRUE(wait_status([&](const RtStatus& s) { return s.hand[h].device_state == kActive && s.hand[h].rearm_pending == 0; }, st))
        << rt_log();
    EXPECT_EQ(st.hand[other].device_state, kActive);
    EXPECT_TRUE(eventually([&] { return said(name + " arm: modbus arm 'modbus-bench-3dof' re-armed: active"); })) << rt_log();
    // And the re-armed arm's bus works again with the other's, without a new fault.
    const RtStatus rearmed = st;
    ASSERT_TRUE(wait_bus_advances(h, rearmed, 300, st)) << rt_log();
    ASSERT_TRUE(wait_bus_advances(other, rearmed, 300, st)) << rt_log();
    EXPECT_EQ(st.hand[h].device_state, kActive) << st.hand[h].fault_text;
    EXPECT_EQ(st.hand[other].device_state, kActive) << st.hand[other].fault_text;
    EXPECT_EQ(st.hand[h].bus.faults, rearmed.hand[h].bus.faults);
  }
};

TEST_F(TwoArms, TwoModbusArmsInOneLoopFaultAndRearmEachHandAlone) {
  std::array<Arm, 2> arms{start_armsim(0), start_armsim(1)};
  for (const Arm& a : arms) ASSERT_FALSE(a.port.empty()) << read_file(a.log);
  ASSERT_NE(arms[0].port, arms[1].port);
  auto rt = start_rt(write_config(0, arms[0].port), write_config(1, arms[1].port));

  // Both arms active, both buses read and written tick after tick.
  RtStatus st{};
  ASSERT_TRUE(wait_status([](const RtStatus& s) { return s.hands == 2 && s.hand[0].device_state == kActive && s.hand[1].device_state == kActive; },
                          st))
      << rt_log();
  EXPECT_EQ(st.hand[0].has_arm, 1u);
  EXPECT_EQ(st.hand[1].has_arm, 1u);
  const RtStatus started = st;
  ASSERT_TRUE(wait_bus_advances(0, started, 300, st)) << rt_log();
  ASSERT_TRUE(wait_bus_advances(1, started, 300, st)) << rt_log();
  for (std::size_t h = 0; h < 2; ++h) {
    EXPECT_EQ(st.hand[h].device_state, kActive) << kHandNames[h] << ": " << st.hand[h].fault_text;
    EXPECT_EQ(st.hand[h].bus.faults, 0u) << kHandNames[h];
  }
  EXPECT_NE(rt_log().find("right hand: arm 'modbus-bench-3dof' (modbus arm"), std::string::npos) << rt_log();
  EXPECT_NE(rt_log().find("left hand: arm 'modbus-bench-3dof' (modbus arm"), std::string::npos) << rt_log();

  fault_one_and_rearm_it(1, arms);
  if (HasFatalFailure()) return;
  fault_one_and_rearm_it(0, arms);
  if (HasFatalFailure()) return;

  rt->signal(SIGTERM);
  const auto rt_code = rt->wait_exit(test::kHangTimeout);
  ASSERT_TRUE(rt_code.has_value() && WIFEXITED(*rt_code)) << rt_log();
  EXPECT_EQ(WEXITSTATUS(*rt_code), 0) << rt_log();
  // Each armsim served its own client all along: one connection each, no lost link.
  for (Arm& a : arms) {
    a.sim->signal(SIGTERM);
    const auto code = a.sim->wait_exit(test::kHangTimeout);
    EXPECT_TRUE(code.has_value() && WIFEXITED(*code) && WEXITSTATUS(*code) == 0) << read_file(a.log);
    EXPECT_NE(read_file(a.log).find(" 1 connections, 0 forced disconnects"), std::string::npos) << read_file(a.log);
  }
}

// With a viz publishing tissue: the right hand (the built-in stylus, pressing into the block by its
// script) feels the tissue; the left hand's arm (a Modbus arm, lancet-armsim) faults; the right
// hand's force goes on, at full scale, for as long as the left arm stays faulted.
TEST_F(TwoArms, AFaultOnTheLeftArmLeavesTheRightHandsForce) {
  Arm left = start_armsim(1);
  ASSERT_FALSE(left.port.empty()) << read_file(left.log);
  const std::string left_config = write_config(1, left.port);
  auto rt = std::make_unique<Child>(std::vector<std::string>{kBin + "/firmware_rt/lancet-rt", "--hands", "2", "--left-config", left_config,
                                                             "--shm", shm_, "--duration", "600", "--no-rt", "-q", "--viz-timeout-ms", "2000",
                                                             "--stale-patch-ms", "2000"},
                                    path("rt.log"));
  ASSERT_TRUE(eventually([&] { return static_cast<bool>(SharedChannel::open(shm_)) || !rt->running(); })) << rt_log();
  // Headless through EGL; leak checking off for Mesa (as the two-process tests do).
  unsetenv("DISPLAY");
  Child viz({kBin + "/host_viz/lancet-viz", "--headless", "--shm", shm_, "--width", "320", "--height", "200", "--duration", "600"},
            path("viz.log"), std::vector<std::string>{"LSAN_OPTIONS=detect_leaks=0"});
  const auto pressing = [](const RtStatus& s) {
    return s.viz_alive != 0 && s.hand[0].contact != 0 && s.hand[0].force_scale == 1.0 && norm(s.hand[0].force) > 0.2;
  };
  RtStatus st{};
  ASSERT_TRUE(wait_status([&](const RtStatus& s) { return s.hand[1].device_state == kActive && pressing(s); }, st))
      << rt_log() << read_file(path("viz.log"));
  EXPECT_EQ(st.hand[0].has_arm, 0u) << "the right hand is the built-in stylus";

  ASSERT_TRUE(control(left, "fault")) << read_file(left.log);
  ASSERT_TRUE(wait_status([](const RtStatus& s) { return s.hand[1].device_state == kFault; }, st)) << rt_log();
  EXPECT_EQ(st.hand[1].force.x, 0.0);
  EXPECT_EQ(st.hand[1].force.y, 0.0);
  EXPECT_EQ(st.hand[1].force.z, 0.0);
  EXPECT_EQ(st.watchdog_tripped, 0u) << "an arm's fault is that hand's, not the loop's";
  // A thousand ticks on, the left arm still faulted: the right hand presses on, at full scale.
  const std::uint64_t at_fault = st.tick;
  ASSERT_TRUE(wait_status([&](const RtStatus& s) { return s.tick > at_fault + 1000 && pressing(s); }, st))
      << "the right hand's force stopped with the left arm's fault\n" << rt_log();
  EXPECT_EQ(st.hand[1].device_state, kFault) << "a fault never re-arms itself";
  EXPECT_EQ(st.hand[0].device_errors, 0u);

  viz.signal(SIGINT);
  (void)viz.wait_exit(test::kHangTimeout);
  rt->signal(SIGTERM);
  (void)rt->wait_exit(test::kHangTimeout);
  left.sim->signal(SIGTERM);
  (void)left.sim->wait_exit(test::kHangTimeout);
}

}  // namespace
}  // namespace lancet
