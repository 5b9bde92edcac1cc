// lancetctl jitter as a test rig runs it: the exit status follows the bounds, the JSON holds the
// percentiles (of cyclictest too, when asked), errors are clear.

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <string>

#include "process.hpp"
#include "record/hdf5_io.hpp"

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

TEST_F(LancetctlJitter, ReportsPercentilesAndPassesWithoutBounds) {
  ASSERT_EQ(run({"jitter", "--duration", "1", "--json", path("j.json"), "--plot", path("j.svg")}), 0)
      << read_file(path("out.txt"));
  const std::string out = read_file(path("out.txt"));
  EXPECT_NE(out.find("T: 0 ("), std::string::npos) << out;  // the cyclictest-style line
  EXPECT_NE(out.find("p99.99"), std::string::npos) << out;
  const std::string j = read_file(path("j.json"));
  EXPECT_GE(json_number(j, "ticks").value_or(0), 900) << j;
  EXPECT_GT(json_number(j, "p99_us").value_or(-1), -1) << j;
  EXPECT_NE(j.find("\"cyclictest\": null"), std::string::npos) << j;
#if !defined(__SANITIZE_ADDRESS__)  // lancetctl is ASan-instrumented too: its shadow memory faults in lazily
  EXPECT_EQ(json_number(j, "page_faults").value_or(-1), 0) << j;
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
  const auto cyc = j.find("\"cyclictest\": {");
  ASSERT_NE(cyc, std::string::npos) << j;
  EXPECT_GE(json_number(j.substr(cyc), "count").value_or(0), 800) << j;
  EXPECT_GT(json_number(j.substr(cyc), "p99_us").value_or(0), 0) << j;
  EXPECT_NE(j.find("\"ratio\": {"), std::string::npos) << j;
}

// Recording on and off in one run: the recorder drains and writes every sample (nothing lost, the
// file reads back with every tick), and the servo's wake-up latency with it stays within noise of
// without (a loose bound: this machine is noisy; the figures are in docs/PERFORMANCE.md).
TEST_F(LancetctlJitter, ComparesRecordingOnAndOffInTheSameRun) {
  ASSERT_EQ(run({"jitter", "--duration", "2", "--rounds", "2", "--compare-recording", "--record-file", path("r.h5"), "--json",
                 path("r.json")}),
            0)
      << read_file(path("out.txt"));
  const std::string out = read_file(path("out.txt"));
  EXPECT_NE(out.find("recording off   recording on"), std::string::npos) << out;
  const std::string j = read_file(path("r.json"));
  const auto at = j.find("\"recording\": {");
  ASSERT_NE(at, std::string::npos) << j;
  const std::string rec = j.substr(at);
  const auto off = rec.find("\"off\": {"), on = rec.find("\"on\": {");
  ASSERT_NE(off, std::string::npos);
  ASSERT_NE(on, std::string::npos);
  const double p50_off = json_number(rec.substr(off), "p50_us").value_or(0), p50_on = json_number(rec.substr(on), "p50_us").value_or(0);
  std::printf("[ info     ] wake-up p50 %.1f us recording off, %.1f us on (ratio %.2f); p99 %.1f / %.1f us\n", p50_off, p50_on,
              p50_on / p50_off, json_number(rec.substr(off), "p99_us").value_or(0), json_number(rec.substr(on), "p99_us").value_or(0));
  EXPECT_GT(p50_off, 0);
  EXPECT_LT(p50_on, 3 * p50_off + 50) << "recording must not disturb the servo beyond noise";
  EXPECT_EQ(json_number(rec, "lost").value_or(-1), 0) << j;
  const double samples = json_number(rec, "samples").value_or(0);
  EXPECT_GE(samples, 900) << j;  // one round of about 1 s at 1 kHz
  auto file = record::read_recording(path("r.h5"));
  ASSERT_TRUE(file.ok()) << file.error().message;
  EXPECT_EQ(static_cast<double>(file.value().samples.size()), samples);
  EXPECT_EQ(file.value().gaps, 0u);
  for (std::size_t i = 1; i < file.value().samples.size(); ++i)
    ASSERT_EQ(file.value().samples[i].seq, file.value().samples[i - 1].seq + 1) << "every tick, in order";
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
