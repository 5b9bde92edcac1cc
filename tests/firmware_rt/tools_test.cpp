// The jitter rig's tools: cyclictest's histogram file parsed into a Distribution (good files,
// bad files, random damage), cyclictest run as a child process (fake ones standing in for the
// failure modes; the real one when installed and root), and the SVG plot being well-formed XML.

#include <sys/stat.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include "tools/cyclictest_runner.hpp"
#include "tools/jitter_plot.hpp"

namespace lancet::tools {
namespace {

// cyclictest -m -p 80 -i 1000 -t 1 -q -D 2 -h 25 --histfile=...: 2000 samples, none above 25 µs.
// Avg says 18 because cyclictest truncates; the buckets give 37992 / 2000 = 18.996.
constexpr const char* kNoOverflows = R"(# Histogram
000000 000000
000001 000000
000002 000000
000003 000000
000004 000000
000005 000000
000006 000000
000007 000000
000008 000000
000009 000000
000010 000000
000011 000000
000012 000000
000013 000001
000014 000000
000015 000001
000016 000046
000017 000222
000018 000526
000019 000576
000020 000384
000021 000119
000022 000059
000023 000019
000024 000047
# Total: 000002000
# Min Latencies: 00013
# Avg Latencies: 00018
# Max Latencies: 00024
# Histogram Overflows: 00000
# Histogram Overflow at cycle number:
# Thread 0:

)";

// A real 1 s run with -h 18 on this machine: most samples overflow. "# Total:" counts only the
// 115 inside the histogram; the 883 overflows come on top (998 samples in all), and cyclictest
// lists the first overflowing cycle numbers, then "# N others".
constexpr const char* kOverflows = R"(# Histogram
000000 000000
000001 000000
000002 000000
000003 000000
000004 000000
000005 000000
000006 000000
000007 000000
000008 000000
000009 000000
000010 000000
000011 000000
000012 000000
000013 000000
000014 000000
000015 000002
000016 000017
000017 000096
# Total: 000000115
# Min Latencies: 00015
# Avg Latencies: 00021
# Max Latencies: 02716
# Histogram Overflows: 00883
# Histogram Overflow at cycle number:
# Thread 0: 00000 00002 00006 00007 00012 00016 00017 00018 00019 00020 00021 00022 00023 00024 00025 00026 00028 00029 # 00865 others

)";

// The line of text with 1-based number n.
std::string line_of(const std::string& text, int n) {
  std::istringstream in(text);
  std::string line;
  for (int i = 0; i < n && std::getline(in, line); ++i) {
  }
  return line;
}

// text with line n (1-based) replaced by replacement (or removed when replacement is null).
std::string with_line(const std::string& text, int n, const char* replacement) {
  std::istringstream in(text);
  std::string line, out;
  for (int i = 1; std::getline(in, line); ++i) {
    if (i != n) {
      out += line + "\n";
    } else if (replacement != nullptr) {
      out += std::string(replacement) + "\n";
    }
  }
  return out;
}

// The error of parsing text, or a failure when it parses.
std::string parse_error_of(const std::string& text, int histogram_max_us) {
  auto r = parse_cyclictest_histogram(text, histogram_max_us);
  if (r.ok()) {
    ADD_FAILURE() << "parsed, but should not have:\n" << text;
    return {};
  }
  EXPECT_EQ(r.error().code, ErrorCode::kInvalid);
  return r.error().message;
}

TEST(CyclictestHistogram, ParsesAFileWithoutOverflows) {
  auto r = parse_cyclictest_histogram(kNoOverflows, 25);
  ASSERT_TRUE(r.ok()) << r.error().message;
  const rt::Distribution& d = r.value();
  EXPECT_EQ(d.name, "cyclictest");
  EXPECT_EQ(d.count, 2000u);
  EXPECT_EQ(d.overflows, 0u);
  EXPECT_EQ(d.overflow_above_us, 25.0);
  EXPECT_EQ(d.min_us, 13.0);
  EXPECT_EQ(d.max_us, 24.0);
  EXPECT_DOUBLE_EQ(d.avg_us, 37992.0 / 2000.0);  // from the buckets, not the truncated Avg line
  ASSERT_EQ(d.buckets.size(), 11u);               // only the non-empty ones
  EXPECT_EQ(d.buckets.front(), (std::pair<double, std::uint64_t>{13.0, 1}));
  EXPECT_EQ(d.buckets[2], (std::pair<double, std::uint64_t>{16.0, 46}));
  EXPECT_EQ(d.buckets.back(), (std::pair<double, std::uint64_t>{24.0, 47}));

  // Nearest rank over the cumulative counts 1 (13), 2 (15), 48 (16), 270 (17), 796 (18),
  // 1372 (19), 1756 (20), 1875 (21), 1934 (22), 1953 (23), 2000 (24).
  EXPECT_EQ(d.percentile_us(0), 13.0);     // rank 1
  EXPECT_EQ(d.percentile_us(2.39), 16.0);  // rank 48 (47.8 rounded up)
  EXPECT_EQ(d.percentile_us(2.46), 17.0);  // rank 50
  EXPECT_EQ(d.percentile_us(50), 19.0);    // rank 1000
  EXPECT_EQ(d.percentile_us(90), 21.0);    // rank 1800
  EXPECT_EQ(d.percentile_us(96.6), 22.0);  // rank 1932
  EXPECT_EQ(d.percentile_us(96.8), 23.0);  // rank 1936
  EXPECT_EQ(d.percentile_us(99), 24.0);    // rank 1980
  EXPECT_EQ(d.percentile_us(99.9), 24.0);
  EXPECT_EQ(d.percentile_us(100), 24.0);
}

TEST(CyclictestHistogram, OverflowsCountAsSamplesAboveTheRange) {
  auto r = parse_cyclictest_histogram(kOverflows, 18);
  ASSERT_TRUE(r.ok()) << r.error().message;
  const rt::Distribution& d = r.value();
  EXPECT_EQ(d.count, 115u + 883u);
  EXPECT_EQ(d.overflows, 883u);
  EXPECT_EQ(d.overflow_above_us, 18.0);
  EXPECT_EQ(d.min_us, 15.0);
  EXPECT_EQ(d.max_us, 2716.0);
  EXPECT_EQ(d.avg_us, 21.0);  // the Avg line: the buckets cannot say where the overflows lie
  ASSERT_EQ(d.buckets.size(), 3u);
  // Cumulative 2 (15), 19 (16), 115 (17), then 883 overflows.
  EXPECT_EQ(d.percentile_us(1), 16.0);       // rank 10
  EXPECT_EQ(d.percentile_us(10), 17.0);      // rank 100
  EXPECT_EQ(d.percentile_us(11.5), 17.0);    // rank 115
  EXPECT_EQ(d.percentile_us(11.6), 2716.0);  // rank 116: an overflow, reported as max
  EXPECT_EQ(d.percentile_us(50), 2716.0);
}

TEST(CyclictestHistogram, ToleratesCrlfBlankLinesAndNoHeader) {
  std::string crlf;
  for (const char c : std::string(kNoOverflows)) {
    if (c == '\n') crlf += "\r\n\r\n";
    else crlf += c;
  }
  auto r = parse_cyclictest_histogram(crlf, 25);
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r.value().count, 2000u);

  auto no_header = parse_cyclictest_histogram(with_line(kNoOverflows, 1, nullptr), 25);
  ASSERT_TRUE(no_header.ok()) << no_header.error().message;
  EXPECT_EQ(no_header.value().count, 2000u);
}

TEST(CyclictestHistogram, EmptyRunGivesAnEmptyDistribution) {
  std::string text = "# Histogram\n000000 000000\n000001 000000\n# Total: 000000000\n# Min Latencies: 1000000\n"
                     "# Avg Latencies: 00000\n# Max Latencies: 00000\n# Histogram Overflows: 00000\n"
                     "# Histogram Overflow at cycle number:\n# Thread 0:\n";
  auto r = parse_cyclictest_histogram(text, 2);
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r.value().count, 0u);
  EXPECT_EQ(r.value().min_us, 0.0);
  EXPECT_EQ(r.value().percentile_us(50), 0.0);
}

TEST(CyclictestHistogram, MalformedInputNamesTheLine) {
  const std::string good = kNoOverflows;
  // Line numbers: 1 "# Histogram", bucket k on line k + 2, "# Total:" on 27, "# Thread 0:" on 33.
  ASSERT_EQ(line_of(good, 19), "000017 000222");
  ASSERT_EQ(line_of(good, 27), "# Total: 000002000");

  struct Case {
    std::string text;
    int histogram_max_us;
    std::vector<std::string> expected;  // substrings of the message
  };
  const std::vector<Case> cases = {
      {"", 25, {"line 1:", "end of file", "empty"}},
      {"\n\n  \n", 25, {"line 4:", "end of file"}},
      {with_line(good, 19, "000017"), 25, {"line 19:", "two unsigned integers", "'000017'"}},           // truncated line
      {with_line(good, 19, "000017 00x222"), 25, {"line 19:", "'000017 00x222'"}},                   // letters
      {with_line(good, 19, "abc def"), 25, {"line 19:", "'abc def'"}},
      {with_line(good, 19, "000017 -00222"), 25, {"line 19:", "negative"}},                        // negative count
      {with_line(good, 19, "-00017 000222"), 25, {"line 19:", "negative"}},
      {with_line(good, 19, "000018 000222"), 25, {"line 19:", "expected bucket 17, found bucket 18"}},  // out of order
      {with_line(good, 19, nullptr), 25, {"line 19:", "expected bucket 17"}},                      // a bucket missing
      {with_line(good, 19, "000017 000222\t000100"), 25, {"line 19:", "-t 1"}},                    // two threads
      {with_line(good, 19, "000017 99999999999999999999999"), 25, {"line 19:"}},                   // does not fit
      {good.substr(0, good.find("# Total")), 25, {"line 27:", "'# Total: <unsigned integer>'", "end of file"}},  // no trailer
      {good.substr(0, good.find("# Max")), 25, {"line 30:", "'# Max Latencies: <unsigned integer>'", "end of file"}},
      {good.substr(0, good.find("# Thread")), 25, {"line 33:", "'# Thread 0", "end of file"}},
      {with_line(good, 27, "# Total: 000001999"), 25, {"line 27:", "says 1999", "add up to 2000"}},
      {with_line(good, 27, "# Total:"), 25, {"line 27:", "'# Total: <unsigned integer>'"}},
      {with_line(good, 28, "# Min Latencies: 00013 00014"), 25, {"line 28:", "-t 1"}},
      {with_line(good, 29, "# Avg Latencies: 00030"), 25, {"line 29:", "within [Min, Max] = [13, 24]"}},
      {with_line(good, 30, "# Max Latencies: 00012"), 25, {"line 30:", "Max Latencies >= Min"}},
      {with_line(good, 29, "# Max Latencies: 00024"), 25, {"line 29:", "'# Avg Latencies:"}},     // lines swapped
      {with_line(good, 32, "# Overflow:"), 25, {"line 32:", "'# Histogram Overflow at cycle number:'"}},
      {good + "000000 000001\n", 25, {"line 35:", "end of the file"}},                              // junk after
      {good, 30, {"line 27:", "expected bucket 25", "-h 30"}},                                      // -h mismatch
      {good, 20, {"line 22:", "after the last bucket (19", "-h 20"}},
      {good, 0, {"histogram_max_us", "> 0"}},
      {std::string("000000 000000\n\x01\xff\n"), 2, {"line 2:", "'\\x01\\xff'"}},                   // binary garbage
  };
  for (const auto& c : cases) {
    const std::string message = parse_error_of(c.text, c.histogram_max_us);
    for (const auto& e : c.expected) EXPECT_NE(message.find(e), std::string::npos) << "'" << e << "' not in: " << message;
  }
}

// Random damage to a good file: never a crash or a hang; either a consistent distribution or an
// error that names a line.
TEST(CyclictestHistogram, SurvivesRandomMutations) {
  std::mt19937 rng(20240611);
  auto pick = [&](std::size_t n) { return n == 0 ? std::size_t{0} : std::uniform_int_distribution<std::size_t>(0, n - 1)(rng); };
  const std::string bases[] = {kNoOverflows, kOverflows};
  const int histmax[] = {25, 18};
  const std::string interesting = "0123456789-# \n\r\tx:\xff";
  int parsed = 0, rejected = 0;
  for (int iter = 0; iter < 2000; ++iter) {
    const std::size_t which = static_cast<std::size_t>(iter) % 2;
    std::string t = bases[which];
    const int n_mutations = 1 + static_cast<int>(pick(3));
    for (int m = 0; m < n_mutations && !t.empty(); ++m) {
      switch (pick(8)) {
        case 0: t[pick(t.size())] = static_cast<char>(pick(256)); break;
        case 1: t.insert(pick(t.size() + 1), 1, interesting[pick(interesting.size())]); break;
        case 2: t.erase(pick(t.size()), 1 + pick(20)); break;
        case 3: t.resize(pick(t.size())); break;
        case 4: {  // a digit replaced by a digit (often still well-formed, but inconsistent)
          const std::size_t p = t.find_first_of("0123456789", pick(t.size()));
          if (p != std::string::npos) t[p] = static_cast<char>('0' + pick(10));
          break;
        }
        case 5: {  // a line duplicated
          const std::size_t a = t.rfind('\n', pick(t.size()));
          const std::size_t s = a == std::string::npos ? 0 : a + 1;
          const std::size_t e = t.find('\n', s);
          if (e != std::string::npos) t.insert(s, t.substr(s, e - s + 1));
          break;
        }
        case 6: {  // a line deleted
          const std::size_t s = t.find('\n', pick(t.size()));
          if (s != std::string::npos) t.erase(s, t.find('\n', s + 1) - s);
          break;
        }
        default: t.insert(pick(t.size() + 1), "99999999999999999999999"); break;
      }
    }
    auto r = parse_cyclictest_histogram(t, histmax[which]);
    if (r.ok()) {
      ++parsed;
      const rt::Distribution& d = r.value();
      std::uint64_t sum = d.overflows;
      double prev = -1;
      for (const auto& [edge, n] : d.buckets) {
        EXPECT_GT(edge, prev);
        EXPECT_LT(edge, histmax[which]);
        EXPECT_GT(n, 0u);
        prev = edge;
        sum += n;
      }
      EXPECT_EQ(sum, d.count);
      if (d.count != 0) {
        EXPECT_LE(d.min_us, d.max_us);
        EXPECT_LE(d.percentile_us(99), d.max_us);
      }
    } else {
      ++rejected;
      EXPECT_EQ(r.error().message.rfind("line ", 0), 0u) << r.error().message;
    }
  }
  RecordProperty("parsed", parsed);
  RecordProperty("rejected", rejected);
  EXPECT_GT(parsed, 0);
  EXPECT_GT(rejected, 1000);
}

// ---------------------------------------------------------------------------------------------
// run_cyclictest

// A scratch folder, removed (with its files) at the end.
struct TempDir {
  std::string path;
  TempDir() {
    std::string t = std::string(std::getenv("TMPDIR") != nullptr ? std::getenv("TMPDIR") : "/tmp") + "/lancet-tools-test-XXXXXX";
    if (::mkdtemp(t.data()) != nullptr) path = t;
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  ~TempDir() {
    std::error_code ec;
    if (!path.empty()) std::filesystem::remove_all(path, ec);
  }
  // An executable shell script standing in for cyclictest.
  std::string script(const std::string& name, const std::string& body) const {
    const std::string p = path + "/" + name;
    std::ofstream(p) << "#!/bin/sh\n" << body << "\n";
    ::chmod(p.c_str(), 0755);
    return p;
  }
};

std::string slurp(const std::string& path) {
  std::ifstream f(path);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

TEST(CyclictestRunner, ArgumentsMatchTheOptions) {
  CyclictestOptions o;
  o.priority = 70;
  o.interval_us = 500;
  o.cpu = 1;
  o.duration_s = 2.01;  // rounded up: cyclictest takes whole seconds
  o.histogram_max_us = 2000;
  const std::vector<std::string> expected = {"cyclictest", "-m", "-q", "-t", "1", "-p", "70", "-i", "500", "-a", "1",
                                             "-D", "3", "-h", "2000", "--histfile=/tmp/x.hist"};
  EXPECT_EQ(cyclictest_arguments(o, "/tmp/x.hist"), expected);

  o.cpu = -1;
  o.mlockall = false;
  o.duration_s = 0.3;  // "0.3" would read as 0, which cyclictest takes as "forever": at least 1
  const std::vector<std::string> expected2 = {"cyclictest", "-q", "-t", "1", "-p", "70", "-i", "500",
                                              "-D", "1", "-h", "2000", "--histfile=/tmp/x.hist"};
  EXPECT_EQ(cyclictest_arguments(o, "/tmp/x.hist"), expected2);
  o.duration_s = 2.0;
  EXPECT_EQ(cyclictest_arguments(o, "h")[9], "2");
}

TEST(CyclictestRunner, RejectsBadOptions) {
  auto check = [](CyclictestOptions o, const char* field) {
    auto r = run_cyclictest(o);
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, ErrorCode::kInvalid);
    EXPECT_NE(r.error().message.find(field), std::string::npos) << r.error().message;
  };
  CyclictestOptions o;
  o.interval_us = 0;
  check(o, "interval_us");
  o = {};
  o.priority = 100;
  check(o, "priority");
  o = {};
  o.cpu = -2;
  check(o, "cpu");
  o = {};
  o.duration_s = 0;
  check(o, "duration_s");
  o.duration_s = std::nan("");
  check(o, "duration_s");
  o = {};
  o.histogram_max_us = -5;
  check(o, "histogram_max_us");
  EXPECT_EQ(check_cyclictest_options(CyclictestOptions{}), "");
}

TEST(CyclictestRunner, MissingExecutableSaysHowToInstallIt) {
  CyclictestOptions o;
  o.executable = "/nonexistent/cyclictest";
  o.duration_s = 1;
  auto r = run_cyclictest(o);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kNotFound);
  EXPECT_NE(r.error().message.find("cyclictest not found"), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find("/nonexistent/cyclictest"), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find("install Debian package rt-tests (./lancet setup does)"), std::string::npos)
      << r.error().message;

  o.executable = "lancet-no-such-cyclictest";
  r = run_cyclictest(o);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kNotFound);
  EXPECT_NE(r.error().message.find("not on PATH"), std::string::npos) << r.error().message;
}

TEST(CyclictestRunner, NonZeroExitShowsItsOutput) {
  TempDir dir;
  ASSERT_FALSE(dir.path.empty());
  CyclictestOptions o;
  o.executable = dir.script("cyclictest", "echo '# /dev/cpu_dma_latency set to 0us'\n"
                                          "echo 'Unable to change scheduling policy!' >&2\n"
                                          "echo 'Probably missing capabilities, either run as root or increase RLIMIT_RTPRIO limits.' >&2\n"
                                          "exit 1");
  o.duration_s = 1;
  auto r = run_cyclictest(o);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kSystem);
  const std::string& m = r.error().message;
  EXPECT_NE(m.find("exited with status 1"), std::string::npos) << m;
  EXPECT_NE(m.find("Unable to change scheduling policy!"), std::string::npos) << m;
  EXPECT_NE(m.find("either run as root"), std::string::npos) << m;

  // An argument it rejects: the reason comes first, then pages of usage text, left out.
  o.executable = dir.script("cyclictest2", "echo 'libnuma: Warning: cpu argument 7 is out of range' >&2\n"
                                           "printf '\\ncyclictest V 2.40\\nUsage:\\ncyclictest <options>\\n\\n-a [CPUSET] --affinity\\n'\n"
                                           "exit 1");
  o.cpu = 7;
  r = run_cyclictest(o);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("status 1: libnuma: Warning: cpu argument 7 is out of range; [usage text omitted"),
            std::string::npos) << r.error().message;
  EXPECT_EQ(r.error().message.find("<options>"), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find("-a 7"), std::string::npos) << r.error().message;  // the command line
}

TEST(CyclictestRunner, ReadsTheHistogramItWrites) {
  TempDir dir;
  ASSERT_FALSE(dir.path.empty());
  std::ofstream(dir.path + "/canned.hist") << kNoOverflows;
  CyclictestOptions o;
  o.executable = dir.script("cyclictest", "echo \"$@\" > '" + dir.path + "/args'\n"
                                          "for a in \"$@\"; do case \"$a\" in --histfile=*) f=\"${a#--histfile=}\";; esac; done\n"
                                          "cat '" + dir.path + "/canned.hist' > \"$f\"");
  o.duration_s = 0.2;
  o.cpu = 0;
  o.histogram_max_us = 25;
  auto r = run_cyclictest(o);
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r.value().count, 2000u);
  EXPECT_EQ(r.value().percentile_us(50), 19.0);
  const std::string args = slurp(dir.path + "/args");
  EXPECT_EQ(args.rfind("-m -q -t 1 -p 80 -i 1000 -a 0 -D 1 -h 25 --histfile=", 0), 0u) << args;
  // The histogram file was a temporary: gone afterwards.
  const std::string hist = args.substr(args.find("--histfile=") + 11, args.find('\n') - args.find("--histfile=") - 11);
  EXPECT_NE(::access(hist.c_str(), F_OK), 0) << hist;
}

TEST(CyclictestRunner, NoHistogramOrABadOneIsAnError) {
  TempDir dir;
  ASSERT_FALSE(dir.path.empty());
  CyclictestOptions o;
  o.duration_s = 1;
  o.executable = dir.script("silent", "echo 'opening histogram file:: No such file or directory' >&2\nexit 0");
  auto r = run_cyclictest(o);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kSystem);
  EXPECT_NE(r.error().message.find("wrote no histogram"), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find("opening histogram file"), std::string::npos) << r.error().message;

  o.executable = dir.script("garbage", "for a in \"$@\"; do case \"$a\" in --histfile=*) f=\"${a#--histfile=}\";; esac; done\n"
                                       "printf '# Histogram\\n000000 000001\\nbanana\\n' > \"$f\"");
  r = run_cyclictest(o);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kInvalid);
  const std::string& m = r.error().message;
  EXPECT_NE(m.find("line 3:"), std::string::npos) << m;
  EXPECT_NE(m.find("'banana'"), std::string::npos) << m;
  // The file is named and kept for inspection.
  const auto b = m.find('/'), e = m.find(".hist");
  ASSERT_NE(b, std::string::npos);
  ASSERT_NE(e, std::string::npos);
  const std::string kept = m.substr(b, e + 5 - b);
  EXPECT_EQ(::access(kept.c_str(), F_OK), 0) << kept;
  ::unlink(kept.c_str());
}

TEST(CyclictestRunner, KilledWhenItOverruns) {
  TempDir dir;
  ASSERT_FALSE(dir.path.empty());
  CyclictestOptions o;
  // It says it started (and leaves a mark that it did, after the line is in its output), then hangs.
  const std::string mark = dir.path + "/started";
  o.executable = dir.script("stuck", "echo started\ntouch '" + mark + "'\nexec sleep 600");
  o.duration_s = 0.1;  // rounded to 1 s
  // What it printed before the kill must be in the error. That needs the stub to have printed
  // before it was killed: on a loaded machine a shell may not even start within a short margin,
  // so the margin grows until it has (0.3 s, the short test, nearly always does).
  for (const double margin_s : {0.3, 5.0, 60.0}) {
    SCOPED_TRACE("timeout margin " + std::to_string(margin_s) + " s");
    o.timeout_margin_s = margin_s;
    auto r = run_cyclictest(o);
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, ErrorCode::kSystem);
    std::ostringstream within;
    within << "did not finish within " << 1 + margin_s << " s";
    EXPECT_NE(r.error().message.find(within.str()), std::string::npos) << r.error().message;
    if (::access(mark.c_str(), F_OK) != 0) continue;  // killed before it printed: try a wider margin
    EXPECT_NE(r.error().message.find("started"), std::string::npos) << r.error().message;
    return;
  }
  FAIL() << "the stub never got as far as printing, even with a minute's margin";
}

bool on_path(const std::string& name) {
  const char* path = std::getenv("PATH");
  std::istringstream dirs(path != nullptr ? path : "");
  for (std::string d; std::getline(dirs, d, ':');) {
    if (!d.empty() && ::access((d + "/" + name).c_str(), X_OK) == 0) return true;
  }
  return false;
}

TEST(CyclictestRunner, RealCyclictestForOneSecond) {
  if (!on_path("cyclictest")) GTEST_SKIP() << "cyclictest is not on PATH (Debian package rt-tests)";
  if (::geteuid() != 0) GTEST_SKIP() << "cyclictest needs root for SCHED_FIFO priority 80";
  CyclictestOptions o;
  o.duration_s = 1;
  o.histogram_max_us = 10000;
  auto r = run_cyclictest(o);
  ASSERT_TRUE(r.ok()) << r.error().message;
  const rt::Distribution& d = r.value();
  EXPECT_EQ(d.name, "cyclictest");
  EXPECT_GT(d.count, 0u);  // how many of the 1000 wake-ups the host lets it make is not ours to bound
  EXPECT_LE(d.min_us, d.percentile_us(50));
  EXPECT_LE(d.percentile_us(50), d.max_us);
  EXPECT_GT(d.avg_us, 0.0);
}

// ---------------------------------------------------------------------------------------------
// jitter_svg

// A small XML well-formedness check: one root element, tags balanced, attributes quoted, '&' only
// in the five predefined entities or character references, '<' never in text or attributes,
// valid UTF-8. Returns "" when fine, else the first problem; *root gets the root element's name.
std::string check_xml(const std::string& s, std::string* root) {
  // UTF-8 first.
  for (std::size_t i = 0; i < s.size();) {
    const auto c = static_cast<unsigned char>(s[i]);
    const std::size_t len = c < 0x80 ? 1 : (c >> 5) == 6 ? 2 : (c >> 4) == 14 ? 3 : (c >> 3) == 30 ? 4 : 0;
    if (len == 0 || i + len > s.size()) return "bad UTF-8 at byte " + std::to_string(i);
    for (std::size_t k = 1; k < len; ++k) {
      if ((static_cast<unsigned char>(s[i + k]) & 0xc0) != 0x80) return "bad UTF-8 at byte " + std::to_string(i);
    }
    if (len == 1 && c < 0x20 && c != '\n' && c != '\t' && c != '\r') return "control character at byte " + std::to_string(i);
    i += len;
  }
  auto entity_ok = [&](std::size_t amp) {
    const std::size_t semi = s.find(';', amp);
    if (semi == std::string::npos || semi - amp > 10) return false;
    const std::string e = s.substr(amp + 1, semi - amp - 1);
    if (e == "amp" || e == "lt" || e == "gt" || e == "quot" || e == "apos") return true;
    return e.size() > 1 && e[0] == '#' && e.find_first_not_of("0123456789", 1) == std::string::npos;
  };
  auto is_name = [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_' || c == ':' || c == '.'; };
  std::vector<std::string> open;
  bool root_done = false;
  std::size_t i = 0;
  if (s.rfind("<?xml", 0) == 0) i = s.find("?>") + 2;
  while (i < s.size()) {
    if (s[i] != '<') {
      if (s[i] == '&' && !entity_ok(i)) return "bad entity at byte " + std::to_string(i);
      if (open.empty() && !std::isspace(static_cast<unsigned char>(s[i]))) return "text outside the root at byte " + std::to_string(i);
      ++i;
      continue;
    }
    if (s.compare(i, 4, "<!--") == 0) {
      const std::size_t e = s.find("-->", i);
      if (e == std::string::npos) return "unterminated comment";
      i = e + 3;
      continue;
    }
    const bool closing = s.compare(i, 2, "</") == 0;
    std::size_t j = i + (closing ? 2 : 1);
    const std::size_t name_start = j;
    while (j < s.size() && is_name(s[j])) ++j;
    const std::string name = s.substr(name_start, j - name_start);
    if (name.empty()) return "empty tag name at byte " + std::to_string(i);
    if (closing) {
      while (j < s.size() && std::isspace(static_cast<unsigned char>(s[j]))) ++j;
      if (j >= s.size() || s[j] != '>') return "bad end tag at byte " + std::to_string(i);
      if (open.empty() || open.back() != name) return "</" + name + "> does not match at byte " + std::to_string(i);
      open.pop_back();
      if (open.empty()) root_done = true;
      i = j + 1;
      continue;
    }
    if (root_done || (open.empty() && !root->empty())) return "a second root element <" + name + ">";
    if (open.empty()) *root = name;
    // Attributes.
    for (;;) {
      while (j < s.size() && std::isspace(static_cast<unsigned char>(s[j]))) ++j;
      if (j >= s.size()) return "unterminated tag <" + name + ">";
      if (s[j] == '>') {
        open.push_back(name);
        ++j;
        break;
      }
      if (s.compare(j, 2, "/>") == 0) {
        if (open.empty()) root_done = true;
        j += 2;
        break;
      }
      const std::size_t a = j;
      while (j < s.size() && is_name(s[j])) ++j;
      if (j == a || j + 1 >= s.size() || s[j] != '=' || (s[j + 1] != '"' && s[j + 1] != '\'')) {
        return "bad attribute in <" + name + "> at byte " + std::to_string(a);
      }
      const char q = s[j + 1];
      const std::size_t end = s.find(q, j + 2);
      if (end == std::string::npos) return "unterminated attribute in <" + name + ">";
      for (std::size_t k = j + 2; k < end; ++k) {
        if (s[k] == '<') return "'<' in an attribute of <" + name + ">";
        if (s[k] == '&' && !entity_ok(k)) return "bad entity in an attribute of <" + name + ">";
      }
      j = end + 1;
    }
    i = j;
  }
  if (!open.empty()) return "<" + open.back() + "> is never closed";
  if (root->empty()) return "no root element";
  return {};
}

TEST(XmlCheck, CatchesTheUsualMistakes) {
  std::string root;
  EXPECT_EQ(check_xml("<?xml version=\"1.0\"?>\n<svg a=\"1\"><g><text>a &amp; b</text></g><line/></svg>\n", &root), "");
  EXPECT_EQ(root, "svg");
  for (const char* bad : {"<svg><g></svg>", "<svg>", "<svg></svg><svg/>", "<svg>a & b</svg>", "<svg a=1/>",
                          "<svg a=\"<\"/>", "<svg>\xff</svg>", "text<svg/>", "<svg></g></svg>"}) {
    root.clear();
    EXPECT_NE(check_xml(bad, &root), "") << bad;
  }
}

rt::Distribution make_dist(std::string name, std::vector<std::pair<double, std::uint64_t>> buckets, std::uint64_t overflows = 0) {
  rt::Distribution d;
  d.name = std::move(name);
  d.buckets = std::move(buckets);
  d.overflows = overflows;
  double sum = 0;
  for (const auto& [e, n] : d.buckets) {
    d.count += n;
    sum += e * static_cast<double>(n);
  }
  d.count += overflows;
  d.min_us = d.buckets.front().first;
  d.max_us = overflows != 0 ? 13500 : d.buckets.back().first;
  d.avg_us = sum / static_cast<double>(d.count);
  d.overflow_above_us = 10000;
  return d;
}

TEST(JitterSvg, WritesWellFormedSvgNamingEveryDistribution) {
  // A loop that mostly wakes within a microsecond (the [0, 1) bucket) with a tail into
  // LatencyHistogram's 10 µs buckets above 1 ms, and a cyclictest-like one around 20 µs.
  auto lancet = make_dist("lancet <loop> & \"co\"", {{0, 52000}, {1, 3000}, {5, 2000}, {40, 500}, {760, 60}, {1850, 3}});
  auto cyclic = make_dist("cyclictest", {{13, 10}, {17, 20000}, {19, 30000}, {21, 9000}, {150, 400}, {900, 20}}, 2);
  TimeSeries ts{"lancet <loop> & \"co\"", 0.1, {}};
  for (int i = 0; i < 100; ++i) ts.max_us.push_back(i == 37 ? 0 : 5 + (i * 37) % 700);
  TimeSeries other{"cyclictest", 0.5, {30, 45, 900, 25, 13500}};

  TempDir dir;
  ASSERT_FALSE(dir.path.empty());
  const std::string path = dir.path + "/jitter.svg";
  std::string error;
  ASSERT_TRUE(write_jitter_svg(path, {lancet, cyclic}, {ts, other}, "jitter: lancet vs cyclictest <1 kHz>", &error)) << error;
  const std::string svg = slurp(path);
  std::string root;
  EXPECT_EQ(check_xml(svg, &root), "") << svg;
  EXPECT_EQ(root, "svg");
  EXPECT_NE(svg.find("lancet &lt;loop&gt; &amp; &quot;co&quot;"), std::string::npos);
  EXPECT_NE(svg.find(">cyclictest<"), std::string::npos);
  EXPECT_NE(svg.find("jitter: lancet vs cyclictest &lt;1 kHz&gt;"), std::string::npos);
  EXPECT_NE(svg.find(">p99.9<"), std::string::npos);
  EXPECT_NE(svg.find("2 overflows (above 10.0 ms)"), std::string::npos);
  EXPECT_EQ(svg, jitter_svg({lancet, cyclic}, {ts, other}, "jitter: lancet vs cyclictest <1 kHz>"));
}

TEST(JitterSvg, OddInputsStillGiveWellFormedSvg) {
  rt::Distribution empty;
  empty.name = "empty";
  auto bad_name = make_dist(std::string("bad\x01name\xff\xfe\xc3"), {{3, 1}});
  auto single = make_dist("single", {{0, 1}});
  TimeSeries nan_series{"NaN series", 0.01, {std::nan(""), -1, 0, 1e30}};
  TimeSeries zero_window{"zero window", 0, {1, 2, 3}};
  const std::vector<std::vector<rt::Distribution>> dist_sets = {{}, {empty}, {bad_name, single}, {empty, single}};
  const std::vector<std::vector<TimeSeries>> series_sets = {{}, {nan_series}, {zero_window, nan_series}};
  for (const auto& dists : dist_sets) {
    for (const auto& series : series_sets) {
      const std::string svg = jitter_svg(dists, series, "odd \xe2\x82\xac & \xed\xa0\x80");  // "€", then a surrogate
      std::string root;
      EXPECT_EQ(check_xml(svg, &root), "") << svg;
      EXPECT_EQ(svg.find("nan"), std::string::npos);  // no "nan" or "inf" coordinates
      EXPECT_EQ(svg.find("inf"), std::string::npos);
    }
  }
  EXPECT_NE(jitter_svg({}, {}, "t").find("no samples"), std::string::npos);
  EXPECT_NE(jitter_svg({}, {}, "t").find("no time series"), std::string::npos);
}

TEST(JitterSvg, UnwritablePathIsAnError) {
  std::string error;
  EXPECT_FALSE(write_jitter_svg("/nonexistent/dir/x.svg", {}, {}, "t", &error));
  EXPECT_NE(error.find("cannot write /nonexistent/dir/x.svg"), std::string::npos) << error;
  EXPECT_FALSE(write_jitter_svg("/nonexistent/dir/x.svg", {}, {}, "t", nullptr));
}

}  // namespace
}  // namespace lancet::tools
