// The real lancet-rt against what can go wrong around it: every ending signal ends it promptly with
// its stats written and its segment removed; a servo thread that stops ticking ends the process
// within a bounded time; eight bytes written into a ring index of the live segment (the attack that
// once froze the servo for good) are counted and survived, and --duration is honoured.

#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/mman.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <utility>
#include <vector>

#include "lancet/shared_model/shared_state.hpp"
#include "lancet/shared_model/validate.hpp"
#include "rt/rt_setup.hpp"
#include "process_test.hpp"  // tests/support
#include "wait.hpp"          // tests/support

namespace lancet {
namespace {

using namespace std::chrono_literals;
using test::Child;
using test::json_number;
using test::read_file;

const std::string kRt = std::string(LANCET_BINARY_DIR) + "/firmware_rt/lancet-rt";

class RtRobustness : public test::ProcessTest {
 protected:
  RtRobustness() : ProcessTest("rob") {}
  bool segment_exists() const {
    const int fd = shm_open(shm_.c_str(), O_RDONLY, 0);
    if (fd < 0) return errno != ENOENT;
    close(fd);
    return true;
  }
  std::unique_ptr<Child> start_rt(std::vector<std::string> extra) {
    std::vector<std::string> argv{kRt, "--shm", shm_, "-q", "--no-rt", "--stats", path("rt.json")};
    argv.insert(argv.end(), extra.begin(), extra.end());
    auto rt = std::make_unique<Child>(argv, path("rt.log"));
    EXPECT_TRUE(test::eventually([&] { return SharedChannel::open(shm_).ok(); })) << read_file(path("rt.log"));
    return rt;
  }
  /// The newest status that passes the checks (lancet-rt's tick counter), or 0.
  static std::uint64_t tick_of(const SharedState& s) {
    RtStatus st{};
    if (s.rt_status.try_read(st) != ReadStatus::kOk || wire::check(st) != nullptr) return 0;
    return st.tick;
  }
};

TEST_F(RtRobustness, SigintSigtermAndSighupEachEndItPromptlyWithStatsAndTheSegmentRemoved) {
  for (const auto& [sig, name] : {std::pair{SIGINT, "SIGINT"}, std::pair{SIGTERM, "SIGTERM"}, std::pair{SIGHUP, "SIGHUP"}}) {
    SCOPED_TRACE(name);
    std::filesystem::remove(path("rt.json"));
    auto rt = start_rt({});
    ASSERT_TRUE(segment_exists());
    auto ch = SharedChannel::open(shm_);
    ASSERT_TRUE(ch.ok()) << ch.error().message;
    ASSERT_TRUE(test::eventually([&] { return tick_of(ch.value().state()) > 0; })) << "lancet-rt never ticked";
    rt->signal(sig);
    const auto st = rt->wait_exit(60s);
    ASSERT_TRUE(st.has_value()) << "still running a minute after " << name << "\n" << read_file(path("rt.log"));
    // Promptly: the servo thread stopped at its next tick, within the shutdown grace (had it not,
    // lancet-rt would have left without it: exit 4, clean_exit false).
    EXPECT_TRUE(WIFEXITED(*st) && WEXITSTATUS(*st) == 0) << read_file(path("rt.log"));
    EXPECT_EQ(read_file(path("rt.log")).find("did not stop within"), std::string::npos) << read_file(path("rt.log"));
    const std::string stats = read_file(path("rt.json"));
    EXPECT_NE(stats.find(std::string("\"ended_by\": \"") + name + "\""), std::string::npos) << stats;
    EXPECT_NE(stats.find("\"clean_exit\": true"), std::string::npos) << stats;
    // The real-time setup as it went (--no-rt here): nothing applied, and the degradation's line.
    EXPECT_NE(stats.find("\"realtime\": {\"preempt_rt\": "), std::string::npos) << stats;
    EXPECT_NE(stats.find("\"fifo\": false"), std::string::npos) << stats;
    EXPECT_NE(stats.find("\"memory_locked\": false"), std::string::npos) << stats;
    EXPECT_NE(stats.find("\"degraded\": [\"real-time setup skipped (--no-rt)"), std::string::npos) << stats;
    EXPECT_FALSE(segment_exists()) << "the segment must be removed";
  }
}

// With the real-time setup on, the servo's CPU (the last online one by default) is the servo
// thread's alone among lancet-rt's threads: the supervisor, the patch intakes and any thread a
// device starts keep off it, so the servo wakes to a CPU none of its own process holds.
TEST_F(RtRobustness, OnlyTheServoThreadMayRunOnTheServoCpu) {
  const int servo_cpu = static_cast<int>(sysconf(_SC_NPROCESSORS_ONLN)) - 1;
  if (servo_cpu < 1) GTEST_SKIP() << "one CPU: nothing to keep off it";
  Child rt({kRt, "--shm", shm_, "-q", "--duration", "600", "--stats", path("rt.json")}, path("rt.log"));
  ASSERT_TRUE(test::eventually([&] { return SharedChannel::open(shm_).ok(); })) << read_file(path("rt.log"));
  auto ch = SharedChannel::open(shm_);
  ASSERT_TRUE(ch.ok()) << ch.error().message;
  ASSERT_TRUE(test::eventually([&] { return tick_of(ch.value().state()) > 0; })) << "lancet-rt never ticked";
  // Each thread's allowed CPUs, from /proc/PID/task/TID/status.
  std::vector<std::string> on_servo_cpu, threads;
  for (const auto& task : std::filesystem::directory_iterator("/proc/" + std::to_string(rt.pid()) + "/task")) {
    std::ifstream in(task.path() / "status");
    std::string line, allowed, name;
    while (std::getline(in, line)) {
      if (line.rfind("Name:", 0) == 0) name = line.substr(5);
      if (line.rfind("Cpus_allowed_list:", 0) == 0) allowed = line.substr(18);
    }
    const std::string what = task.path().filename().string() + name + " allowed" + allowed;
    threads.push_back(what);
    std::vector<int> cpus = rt::parse_cpu_list(allowed.substr(allowed.find_first_not_of(" \t")));
    if (std::find(cpus.begin(), cpus.end(), servo_cpu) != cpus.end()) on_servo_cpu.push_back(what);
  }
  std::string all;
  for (const auto& t : threads) all += "\n  " + t;
  EXPECT_GE(threads.size(), 3u) << "the supervisor, the servo and the patch intakes" << all;
  ASSERT_EQ(on_servo_cpu.size(), 1u) << "threads allowed on CPU " << servo_cpu << ":" << all << "\n" << read_file(path("rt.log"));
  EXPECT_NE(on_servo_cpu[0].find("allowed\t" + std::to_string(servo_cpu)), std::string::npos)
      << "the one thread there is pinned to it alone (the servo): " << on_servo_cpu[0];
  rt.signal(SIGTERM);
  ASSERT_TRUE(rt.wait_exit(60s).has_value()) << read_file(path("rt.log"));
}

TEST_F(RtRobustness, AServoThreadThatStopsTickingEndsTheProcessWithinABoundedTime) {
  // Bounded by construction: the supervisor declares the stall after 300 ms without a tick, and
  // leaves without the stuck thread after a 300 ms grace; the log and the exit status show that
  // this path, and no other, ended it.
  auto rt = start_rt({"--inject-stall-s", "0.5", "--stall-timeout-ms", "300", "--shutdown-grace-ms", "300"});
  const auto st = rt->wait_exit(60s);
  ASSERT_TRUE(st.has_value()) << "a stalled servo must not keep lancet-rt alive\n" << read_file(path("rt.log"));
  ASSERT_TRUE(WIFEXITED(*st)) << read_file(path("rt.log"));
  EXPECT_EQ(WEXITSTATUS(*st), 4) << "left without the stuck thread\n" << read_file(path("rt.log"));
  const std::string log = read_file(path("rt.log"));
  EXPECT_NE(log.find("SERVO STALLED: no tick for"), std::string::npos) << log;
  EXPECT_NE(log.find("leaving without it"), std::string::npos) << log;
  const std::string stats = read_file(path("rt.json"));
  EXPECT_NE(stats.find("\"ended_by\": \"stall\""), std::string::npos) << stats;
  EXPECT_NE(stats.find("\"clean_exit\": false"), std::string::npos) << stats;
  EXPECT_GT(json_number(stats, "ticks").value_or(0), 0) << "it ticked until the stall\n" << stats;
  EXPECT_FALSE(segment_exists()) << "the segment must be removed even then";
}

TEST_F(RtRobustness, EightBytesIntoARingIndexAreCountedAndTheServoTicksOnToItsDuration) {
  auto rt = start_rt({"--duration", "5"});
  auto ch = SharedChannel::open(shm_);
  ASSERT_TRUE(ch.ok()) << ch.error().message;
  SharedState& s = ch.value().state();
  ASSERT_TRUE(test::eventually([&] { return tick_of(s) > 0; })) << "lancet-rt never ticked";
  // The attack from the report: eight bytes into the producer index of the command ring.
  auto* ring = reinterpret_cast<unsigned char*>(&s.commands);
  const std::uint64_t garbage = 0x4141414141414141ull;
  std::memcpy(ring + s.commands.head_offset(), &garbage, sizeof garbage);
  const std::uint64_t before = tick_of(s);
  EXPECT_TRUE(test::eventually([&] { return tick_of(s) > before + 100; }))
      << "the servo keeps ticking (it used to spin in the command drain for good)";
  // And again, the other way round: the consumer's index far ahead.
  std::memcpy(ring + s.commands.tail_offset(), &garbage, sizeof garbage);
  std::memcpy(ring + s.commands.head_offset(), &before, sizeof before);
  const auto st = rt->wait_exit(60s);
  ASSERT_TRUE(st.has_value()) << "--duration 5 must be honoured\n" << read_file(path("rt.log"));
  EXPECT_TRUE(WIFEXITED(*st) && WEXITSTATUS(*st) == 0) << read_file(path("rt.log"));
  const std::string stats = read_file(path("rt.json"));
  EXPECT_GE(json_number(stats, "ring_resets").value_or(0), 1) << stats;
  EXPECT_NE(stats.find("\"ended_by\": \"duration\""), std::string::npos) << stats;
  EXPECT_NE(read_file(path("rt.log")).find("shared segment: rejected"), std::string::npos) << "announced on stderr";
}

TEST_F(RtRobustness, AServoPeriodThatDisagreesWithTheCanopenSyncPeriodIsRefusedBeforeTheBusIsTouched) {
  // The drives are told the cycle (0x1006) from the config; lancet-rt on another period would
  // send SYNC at a rate they do not expect. No CAN interface is needed to be refused.
  Child rt({kRt, "--shm", shm_, "-q", "--no-rt", "--period-us", "500", "--config",
            std::string(LANCET_SOURCE_DIR) + "/hw_configs/canopen_arm.toml"},
           path("rt.log"));
  const auto st = rt.wait_exit(10s);
  ASSERT_TRUE(st.has_value());
  ASSERT_TRUE(WIFEXITED(*st));
  EXPECT_EQ(WEXITSTATUS(*st), 2);
  const std::string log = read_file(path("rt.log"));
  EXPECT_NE(log.find("--period-us 500 differs from sync_period_us 1000 in [bus.canopen]"), std::string::npos) << log;
  EXPECT_FALSE(segment_exists());
}

// Two CANopen arms on one interface are one network. lancet-rt refuses, before it opens the bus
// (no CAN interface is needed here), a pair that does not have exactly one SYNC producer, the
// right hand's; that shares a node id (drives or masters); or that has two SYNC periods. Each
// problem names both files and the fields.
class TwoCanopenArms : public RtRobustness {
 protected:
  /// hw_configs/canopen_arm.toml with these lines of [bus.canopen] replaced (or added below its
  /// header when the file has none), as `<name>.toml`.
  std::string config(const std::string& name, const std::vector<std::pair<std::string, std::string>>& keys) {
    std::string text = read_file(std::string(LANCET_SOURCE_DIR) + "/hw_configs/canopen_arm.toml");
    for (const auto& [key, value] : keys) {
      const std::size_t at = text.find("\n" + key + " ");
      if (at == std::string::npos) {
        const std::size_t header = text.find("[bus.canopen]\n");
        text.insert(header + 14, key + " = " + value + "\n");
      } else {
        const std::size_t eol = text.find('\n', at + 1);
        text.replace(at + 1, eol - at - 1, key + " = " + value);
      }
    }
    const std::string file = path(name + ".toml");
    std::ofstream(file) << text;
    return file;
  }
  /// lancet-rt on both files: its exit status (2 expected) and its log.
  std::string refused(const std::string& right, const std::string& left) {
    Child rt({kRt, "--shm", shm_, "-q", "--no-rt", "--hands", "2", "--config", right, "--left-config", left}, path("rt.log"));
    const auto st = rt.wait_exit(10s);
    EXPECT_TRUE(st.has_value() && WIFEXITED(*st) && WEXITSTATUS(*st) == 2) << read_file(path("rt.log"));
    EXPECT_FALSE(segment_exists());
    return read_file(path("rt.log"));
  }
  /// The left arm as it should be beside the shipped right one: nodes 11..14, master 126, no SYNC.
  std::vector<std::pair<std::string, std::string>> good_left() const {
    return {{"node_ids", "[11, 12, 13, 14]"}, {"buttons_node", "14"}, {"master_node_id", "126"}, {"sync_producer", "false"}};
  }
};

TEST_F(TwoCanopenArms, OneBusTakesOneSyncProducerAndItIsTheRightHandsArm) {
  const std::string right = config("right", {});
  auto left_keys = good_left();
  left_keys.back().second = "true";
  std::string log = refused(right, config("left", left_keys));
  EXPECT_NE(log.find("both arms are on CAN interface can0, which takes exactly one SYNC producer (CiA 301), the right hand's arm"),
            std::string::npos) << log;
  EXPECT_NE(log.find("expected bus.canopen.sync_producer = true in " + right + " (--config, right) and false in " + path("left.toml") +
                     " (--left-config, left), found true and true"),
            std::string::npos) << log;
  // The left hand's arm producing and the right's not: refused too (the left is read second).
  log = refused(config("right", {{"sync_producer", "false"}}), config("left", left_keys));
  EXPECT_NE(log.find("found false and true"), std::string::npos) << log;
  left_keys.back().second = "false";
  log = refused(config("right", {{"sync_producer", "false"}}), config("left", left_keys));
  EXPECT_NE(log.find("found false and false"), std::string::npos) << log;
  EXPECT_EQ(log.find("node id"), std::string::npos) << "nothing else is wrong\n" << log;
}

TEST_F(TwoCanopenArms, NodeIdsAndMasterNodeIdsMayNotOverlap) {
  const std::string right = config("right", {});
  auto left_keys = good_left();
  left_keys[0].second = "[4, 12, 13, 14]";   // the right arm's roll drive
  left_keys[2].second = "1";                 // the left master on the right arm's yaw drive
  const std::string left = config("left", left_keys);
  const std::string log = refused(right, left);
  EXPECT_NE(log.find("use node id 4: bus.canopen.node_ids[3] in " + right + " (right) and bus.canopen.node_ids[0] in " + left + " (left)"),
            std::string::npos) << log;
  EXPECT_NE(log.find("use node id 1: bus.canopen.node_ids[0] in " + right + " (right) and bus.canopen.master_node_id in " + left + " (left)"),
            std::string::npos) << log;
  EXPECT_EQ(log.find("SYNC producer"), std::string::npos) << "the SYNC producers are right\n" << log;
  // Both masters on the default id 127.
  left_keys = good_left();
  left_keys[2].second = "127";
  const std::string log2 = refused(right, config("left", left_keys));
  EXPECT_NE(log2.find("use node id 127: bus.canopen.master_node_id in " + right + " (right) and bus.canopen.master_node_id in"),
            std::string::npos) << log2;
}

TEST_F(TwoCanopenArms, BothArmsHaveOneSyncPeriod) {
  auto left_keys = good_left();
  left_keys.emplace_back("sync_period_us", "2000");
  const std::string right = config("right", {}), left = config("left", left_keys);
  const std::string log = refused(right, left);
  EXPECT_NE(log.find("one SYNC for both: expected the same bus.canopen.sync_period_us, found 1000 in " + right + " (right) and 2000 in " +
                     left + " (left)"),
            std::string::npos) << log;
  EXPECT_EQ(log.find("--period-us"), std::string::npos) << "refused as a pair first\n" << log;
}

TEST_F(TwoCanopenArms, ArmsOnTwoInterfacesEachProduceTheirOwnSync) {
  // Both producing, both on the default master id and nodes: fine on two buses. lancet-rt then
  // goes on to open them (refused here for want of CAN or of can1, not for the pair).
  const std::string log = refused(config("right", {}), config("left", {{"interface", "\"can1\""}}));
  EXPECT_EQ(log.find("both arms are on CAN interface"), std::string::npos) << log;
}

}  // namespace
}  // namespace lancet
