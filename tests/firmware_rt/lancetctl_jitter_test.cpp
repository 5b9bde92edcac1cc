// lancetctl jitter as a test rig runs it: the exit status follows the bounds, the JSON holds the
// percentiles (of cyclictest too, when asked) and accounts for every deadline, errors are clear.
// What the figures are on a given host is the rig's output, not a bound here (they belong in
// docs/PERFORMANCE.md): these tests check the report's structure and its accounting only.

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <string>

#include "process.hpp"
#include "recording/hdf5_io.hpp"

namespace lancet {
namespace {

using namespace std::chrono_literals;
using test::Child;
using test::json_number;
using test::read_file;

const std::string kCtl = std::string(LANCET_BINARY_DIR) + "/firmware_rt/lancetctl";

class LancetctlJitter : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("lancetctl-" + std::to_string(getpid()) + "-" + ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override {
    if (!HasFailure()) std::filesystem::remove_all(dir_);
  }
  std::string path(const std::string& f) const { return (dir_ / f).string(); }
  // Runs lancetctl with args; returns its exit status (-1 if it did not exit normally).
  int run(std::vector<std::string> args) {
    args.insert(args.begin(), kCtl);
    Child c(args, path("out.txt"));
    const auto st = c.wait_exit(120s);
    if (!st || !WIFEXITED(*st)) return -1;
    return WEXITSTATUS(*st);
  }
  std::filesystem::path dir_;
};

// The JSON object that starts at "key": {, as text up to its end (nested objects included).
std::string json_object(const std::string& json, const std::string& key) {
  const auto at = json.find("\"" + key + "\": {");
  if (at == std::string::npos) return "";
  int depth = 0;
  for (auto i = json.find('{', at); i < json.size(); ++i) {
    if (json[i] == '{') ++depth;
    if (json[i] == '}' && --depth == 0) return json.substr(at, i + 1 - at);
  }
  return "";
}

// A latency distribution as the report writes it is consistent: samples counted, percentiles in
// order between min and max.
void expect_consistent_distribution(const std::string& d, const std::string& what) {
  SCOPED_TRACE(what + ": " + d);
  ASSERT_FALSE(d.empty());
  const double min = json_number(d, "min_us").value_or(-1), p50 = json_number(d, "p50_us").value_or(-1),
               p99 = json_number(d, "p99_us").value_or(-1), max = json_number(d, "max_us").value_or(-1);
  EXPECT_GT(json_number(d, "count").value_or(0), 0);
  EXPECT_GE(min, 0);
  EXPECT_LE(min, p50);
  EXPECT_LE(p50, p99);
  EXPECT_LE(p99, max);
}

// The loop's own accounting in the report: every deadline of every round is a tick or a skipped
// one (`deadlines` of them), one wake-up and one compute time per tick, missed ⊇ skipped.
void expect_every_deadline_accounted(const std::string& j, double deadlines) {
  const std::string lancet = json_object(j, "lancet");
  ASSERT_FALSE(lancet.empty()) << j;
  const double ticks = json_number(lancet, "ticks").value_or(-1), overruns = json_number(lancet, "overruns").value_or(-1);
  EXPECT_GT(ticks, 0) << lancet;
  EXPECT_EQ(ticks + overruns, deadlines) << lancet;
  EXPECT_GE(json_number(lancet, "missed").value_or(-1), overruns) << lancet;
  EXPECT_EQ(json_number(json_object(lancet, "wake_latency"), "count").value_or(-1), ticks) << lancet;
  EXPECT_EQ(json_number(json_object(lancet, "compute"), "count").value_or(-1), ticks) << lancet;
  expect_consistent_distribution(json_object(lancet, "wake_latency"), "wake-up latency");
}

TEST_F(LancetctlJitter, ReportsPercentilesAndPassesWithoutBounds) {
  ASSERT_EQ(run({"jitter", "--duration", "1", "--json", path("j.json"), "--plot", path("j.svg")}), 0)
      << read_file(path("out.txt"));
  const std::string out = read_file(path("out.txt"));
  EXPECT_NE(out.find("T: 0 ("), std::string::npos) << out;  // the cyclictest-style line
  EXPECT_NE(out.find("p99.99"), std::string::npos) << out;
  const std::string j = read_file(path("j.json"));
  EXPECT_EQ(json_number(j, "interval_us").value_or(-1), 1000) << j;
  expect_every_deadline_accounted(j, 1000);  // 1 s at 1 kHz (two rounds of 500)
  EXPECT_NE(j.find("\"cyclictest\": null"), std::string::npos) << j;
#if !defined(__SANITIZE_ADDRESS__)  // lancetctl is ASan-instrumented too: its shadow memory faults in lazily
  // Locked memory (root, as CI runs) must not fault in the loop; without the lock nothing is promised.
  if (j.find("\"memory_locked\": true") != std::string::npos) {
    EXPECT_EQ(json_number(j, "page_faults").value_or(-1), 0) << j;
  } else {
    std::printf("[ info     ] page faults not checked: mlockall was refused (run as root, as CI does)\n");
  }
#endif
  const std::string svg = read_file(path("j.svg"));
  EXPECT_NE(svg.find("<svg"), std::string::npos);
  EXPECT_NE(svg.find("lancet"), std::string::npos);
}

TEST_F(LancetctlJitter, BoundsSetTheExitStatus) {
  // Nothing wakes up within a nanosecond: the bound fails, exit 1, and the report says FAIL.
  EXPECT_EQ(run({"jitter", "--duration", "0.5", "--max-us", "0.001", "--json", path("f.json")}), 1)
      << read_file(path("out.txt"));
  EXPECT_NE(read_file(path("out.txt")).find("result: FAIL"), std::string::npos);
  EXPECT_NE(read_file(path("f.json")).find("\"pass\": false"), std::string::npos);
  // Generous bounds hold: exit 0.
  EXPECT_EQ(run({"jitter", "--duration", "0.5", "--max-us", "10000000", "--max-p99-us", "10000000", "--max-missed",
                 "1000000"}),
            0)
      << read_file(path("out.txt"));
  EXPECT_NE(read_file(path("out.txt")).find("result: PASS"), std::string::npos);
}

TEST_F(LancetctlJitter, ComparesWithCyclictestInTheSameRun) {
  if (getuid() != 0) GTEST_SKIP() << "cyclictest needs root for SCHED_FIFO; CI runs as root";
  ASSERT_EQ(run({"jitter", "--duration", "2", "--compare-cyclictest", "--json", path("c.json")}), 0)
      << read_file(path("out.txt"));
  const std::string out = read_file(path("out.txt"));
  EXPECT_NE(out.find("lancet/cyclictest"), std::string::npos) << out;
  const std::string j = read_file(path("c.json"));
  expect_every_deadline_accounted(j, 2000);  // two rounds of 1 s at 1 kHz
  const std::string cyc = json_object(j, "cyclictest");
  ASSERT_FALSE(cyc.empty()) << j;
  expect_consistent_distribution(cyc, "cyclictest");
  const std::string ratio = json_object(j, "ratio");
  ASSERT_FALSE(ratio.empty()) << j;
  EXPECT_TRUE(json_number(ratio, "p50").has_value()) << ratio;
  EXPECT_TRUE(json_number(ratio, "p99").has_value()) << ratio;
}

// Recording on and off in one run: the recorder drains and writes every sample (nothing lost, the
// file reads back with every tick, in order), and the report shows both rounds' wake-up latency
// side by side. How much recording disturbs the servo is the rig's measurement (the figures are in
// docs/PERFORMANCE.md), not a bound here.
TEST_F(LancetctlJitter, ComparesRecordingOnAndOffInTheSameRun) {
  ASSERT_EQ(run({"jitter", "--duration", "2", "--rounds", "2", "--compare-recording", "--record-file", path("r.h5"), "--json",
                 path("r.json")}),
            0)
      << read_file(path("out.txt"));
  const std::string out = read_file(path("out.txt"));
  EXPECT_NE(out.find("recording off   recording on"), std::string::npos) << out;
  const std::string j = read_file(path("r.json"));
  expect_every_deadline_accounted(j, 2000);  // two rounds of 1 s at 1 kHz
  const std::string rec = json_object(j, "recording");
  ASSERT_FALSE(rec.empty()) << j;
  const std::string off = json_object(rec, "off"), on = json_object(rec, "on");
  expect_consistent_distribution(off, "recording off");
  expect_consistent_distribution(on, "recording on");
  std::printf("[ info     ] wake-up p50 %.1f us recording off, %.1f us on; p99 %.1f / %.1f us\n",
              json_number(off, "p50_us").value_or(0), json_number(on, "p50_us").value_or(0), json_number(off, "p99_us").value_or(0),
              json_number(on, "p99_us").value_or(0));
  // The rounds split the loop's wake-ups between them.
  EXPECT_EQ(json_number(off, "count").value_or(-1) + json_number(on, "count").value_or(-1),
            json_number(json_object(j, "lancet"), "ticks").value_or(-2));
  // The recorder's rows: every tick of the "on" rounds, one sample for each of the two hands (what
  // the consumer had not drained when a round ended is drained then, into that round's recording).
  const std::string after_on = rec.substr(rec.find(on) + on.size());
  EXPECT_EQ(json_number(after_on, "lost").value_or(-1), 0) << rec;
  const double samples = json_number(after_on, "samples").value_or(-1);
  EXPECT_EQ(samples, 2 * json_number(on, "count").value_or(-2)) << rec;
  EXPECT_NE(rec.find("\"error\": \"\""), std::string::npos) << rec;
  auto file = record::read_recording(path("r.h5"));
  ASSERT_TRUE(file.ok()) << file.error().message;
  EXPECT_EQ(static_cast<double>(file.value().samples.size()), samples);
  EXPECT_EQ(file.value().gaps, 0u);
  EXPECT_EQ(file.value().hands, 2u);
  const auto& s = file.value().samples;
  for (std::size_t i = 0; i < s.size(); ++i) {
    ASSERT_EQ(s[i].hand, i % 2 == 0 ? Hand::kRight : Hand::kLeft) << "the right hand's sample, then the left's";
    if (i >= 2) {
      ASSERT_EQ(s[i].seq, s[i - 2].seq + 1) << "every tick, in order";
    }
  }
}

TEST_F(LancetctlJitter, AMissingCyclictestIsAClearErrorNotACrash) {
  EXPECT_EQ(run({"jitter", "--duration", "0.3", "--compare-cyclictest", "--cyclictest", "/nonexistent/cyclictest"}), 2);
  EXPECT_NE(read_file(path("out.txt")).find("rt-tests"), std::string::npos) << read_file(path("out.txt"));
}

TEST_F(LancetctlJitter, BadArgumentsAreRefused) {
  EXPECT_NE(run({"jitter", "--strategy", "nap"}), 0);
  EXPECT_NE(run({"jitter", "--priority", "99"}), 0);
  EXPECT_NE(run({"jitter", "--duration", "-1"}), 0);
  EXPECT_NE(run({}), 0);
}

}  // namespace
}  // namespace lancet
