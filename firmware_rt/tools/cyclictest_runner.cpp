#include "tools/cyclictest_runner.hpp"

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>
#include <string_view>
#include <thread>
#include <utility>

namespace lancet::tools {
namespace {

// ---------------------------------------------------------------------------------------------
// Histogram parsing

constexpr std::string_view kWhitespace = " \t\r";

std::string_view trim(std::string_view s) {
  const auto b = s.find_first_not_of(kWhitespace);
  if (b == std::string_view::npos) return {};
  return s.substr(b, s.find_last_not_of(kWhitespace) - b + 1);
}

std::vector<std::string_view> split_fields(std::string_view s) {
  std::vector<std::string_view> out;
  std::size_t i = 0;
  while (i < s.size()) {
    while (i < s.size() && kWhitespace.find(s[i]) != std::string_view::npos) ++i;
    const std::size_t b = i;
    while (i < s.size() && kWhitespace.find(s[i]) == std::string_view::npos) ++i;
    if (i > b) out.push_back(s.substr(b, i - b));
  }
  return out;
}

// A line as it may appear in a message: quoted, at most 60 characters, bytes outside printable
// ASCII shown as \xNN so garbage input still gives a readable one-line error.
std::string quote(std::string_view s) {
  constexpr std::size_t kMax = 60;
  std::string out = "'";
  for (std::size_t i = 0; i < s.size() && i < kMax; ++i) {
    const auto c = static_cast<unsigned char>(s[i]);
    if (c >= 0x20 && c < 0x7f) {
      out += static_cast<char>(c);
    } else {
      static constexpr char kHex[] = "0123456789abcdef";
      out += "\\x";
      out += kHex[c >> 4];
      out += kHex[c & 15];
    }
  }
  out += s.size() > kMax ? "'..." : "'";
  return out;
}

// An unsigned decimal of digits only (cyclictest pads with zeros). False on anything else,
// including a sign or a value that does not fit in 64 bits.
bool parse_unsigned(std::string_view s, std::uint64_t& out) {
  if (s.empty()) return false;
  for (const char c : s) {
    if (c < '0' || c > '9') return false;
  }
  const auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), out);
  return ec == std::errc{} && p == s.data() + s.size();
}

Error parse_error(std::size_t line, const std::string& what) {
  return Error{ErrorCode::kInvalid, "line " + std::to_string(line) + ": " + what};
}

// The text's lines, numbered from 1, blank ones skipped; a missing line reads as end of file.
class LineReader {
 public:
  explicit LineReader(std::string_view text) : text_(text) { advance(); }
  [[nodiscard]] bool at_end() const { return at_end_; }
  [[nodiscard]] std::string_view line() const { return line_; }  // trimmed
  [[nodiscard]] std::size_t number() const { return number_; }
  [[nodiscard]] std::string found() const { return at_end_ ? std::string("end of file") : quote(line_); }
  void advance() {
    while (pos_ < text_.size()) {
      const auto nl = text_.find('\n', pos_);
      const auto end = nl == std::string_view::npos ? text_.size() : nl;
      const std::string_view t = trim(text_.substr(pos_, end - pos_));
      pos_ = end == text_.size() ? end : end + 1;
      ++physical_;
      if (!t.empty()) {
        line_ = t;
        number_ = physical_;
        return;
      }
    }
    at_end_ = true;
    line_ = {};
    number_ = physical_ + 1;
  }

 private:
  std::string_view text_;
  std::size_t pos_ = 0;
  std::size_t physical_ = 0;
  bool at_end_ = false;
  std::string_view line_;
  std::size_t number_ = 0;
};

// Reads "<label> <unsigned>" (e.g. "# Total: 000002000") from the reader's current line.
Result<std::uint64_t> read_labelled(LineReader& in, std::string_view label) {
  const std::string expected = "'" + std::string(label) + " <unsigned integer>'";
  if (in.at_end() || in.line().substr(0, label.size()) != label) {
    return parse_error(in.number(), "expected " + expected + ", found " + in.found());
  }
  const auto fields = split_fields(in.line().substr(label.size()));
  std::uint64_t v = 0;
  if (fields.size() != 1 || !parse_unsigned(fields[0], v)) {
    std::string why = "expected " + expected + ", found " + in.found();
    if (fields.size() > 1) why += " (several values: run cyclictest with -t 1)";
    return parse_error(in.number(), why);
  }
  in.advance();
  return v;
}

// ---------------------------------------------------------------------------------------------
// Child process plumbing

// A temporary file, removed when this goes out of scope unless keep is set.
struct TempFile {
  std::string path;
  int fd = -1;
  bool keep = false;

  TempFile() = default;
  TempFile(const TempFile&) = delete;
  TempFile& operator=(const TempFile&) = delete;
  ~TempFile() {
    if (fd >= 0) ::close(fd);
    if (!keep && !path.empty()) ::unlink(path.c_str());
  }
  // Creates <$TMPDIR or /tmp>/lancet-cyclictest-XXXXXX<suffix>, open (O_CLOEXEC) in fd.
  bool create(const char* suffix, std::string* error) {
    const char* dir = std::getenv("TMPDIR");
    std::string templ = std::string(dir != nullptr && *dir != '\0' ? dir : "/tmp") + "/lancet-cyclictest-XXXXXX" + suffix;
    const int suffix_len = static_cast<int>(std::strlen(suffix));
    fd = ::mkostemps(templ.data(), suffix_len, O_CLOEXEC);
    if (fd < 0) {
      *error = "cannot create a temporary file " + templ + ": " + std::strerror(errno) + " (set TMPDIR to a writable folder)";
      return false;
    }
    path = templ;
    return true;
  }
};

// A child's captured output for a one-line message: its non-blank lines joined by "; ", the usage
// text cyclictest prints when it rejects its arguments replaced by a note (the reason comes before
// it, e.g. "libnuma: Warning: cpu argument 7 is out of range"), the middle elided when long.
std::string read_output(const std::string& path) {
  constexpr std::size_t kKeep = 1000;  // characters kept from each end
  std::ifstream f(path, std::ios::binary);
  std::vector<std::string> lines;
  for (std::string line; lines.size() < 10000 && std::getline(f, line);) {
    const auto t = trim(line);
    if (t == "Usage:") {
      if (!lines.empty() && lines.back().rfind("cyclictest V", 0) == 0) lines.pop_back();
      lines.emplace_back("[usage text omitted: cyclictest rejected its arguments]");
      break;
    }
    if (!t.empty()) lines.emplace_back(t);
  }
  std::string out;
  for (const auto& l : lines) out += (out.empty() ? "" : "; ") + l;
  if (out.size() > 2 * kKeep) out = out.substr(0, kKeep) + " ... " + out.substr(out.size() - kKeep);
  return out.empty() ? std::string("(no output)") : out;
}

std::string read_file(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

// RAII for the spawn attribute objects.
struct SpawnSetup {
  posix_spawn_file_actions_t actions{};
  posix_spawnattr_t attr{};
  SpawnSetup() {
    posix_spawn_file_actions_init(&actions);
    posix_spawnattr_init(&attr);
  }
  SpawnSetup(const SpawnSetup&) = delete;
  SpawnSetup& operator=(const SpawnSetup&) = delete;
  ~SpawnSetup() {
    posix_spawnattr_destroy(&attr);
    posix_spawn_file_actions_destroy(&actions);
  }
};

std::string seconds_text(double s) {
  std::ostringstream o;
  o << s;
  return o.str();
}

long rounded_duration_s(double duration_s) {
  return std::max(1L, static_cast<long>(std::ceil(duration_s)));
}

}  // namespace

std::string check_cyclictest_options(const CyclictestOptions& o) {
  auto bad = [](const char* field, const std::string& expected, const std::string& found) {
    return std::string("cyclictest option ") + field + ": expected " + expected + ", found " + found;
  };
  if (o.interval_us <= 0) return bad("interval_us", "> 0 µs", std::to_string(o.interval_us));
  if (o.priority < 0 || o.priority > 99) return bad("priority", "0..99", std::to_string(o.priority));
  if (o.cpu < -1) return bad("cpu", "a CPU number or -1 (no affinity)", std::to_string(o.cpu));
  // Bounded so the rounded value fits cyclictest's int and the timeout arithmetic stays exact.
  if (!(o.duration_s > 0 && o.duration_s <= 1e7)) return bad("duration_s", "0 < s <= 1e7", seconds_text(o.duration_s));
  if (o.histogram_max_us <= 0) return bad("histogram_max_us", "> 0 µs", std::to_string(o.histogram_max_us));
  if (!(o.timeout_margin_s >= 0 && o.timeout_margin_s <= 1e7)) {
    return bad("timeout_margin_s", "0 <= s <= 1e7", seconds_text(o.timeout_margin_s));
  }
  if (o.executable.empty()) return bad("executable", "a name or path", "an empty string");
  return {};
}

std::vector<std::string> cyclictest_arguments(const CyclictestOptions& o, const std::string& histfile) {
  std::vector<std::string> a = {o.executable};
  if (o.mlockall) a.emplace_back("-m");
  a.insert(a.end(), {"-q", "-t", "1", "-p", std::to_string(o.priority), "-i", std::to_string(o.interval_us)});
  if (o.cpu >= 0) a.insert(a.end(), {"-a", std::to_string(o.cpu)});
  a.insert(a.end(), {"-D", std::to_string(rounded_duration_s(o.duration_s)), "-h", std::to_string(o.histogram_max_us),
                     "--histfile=" + histfile});
  return a;
}

Result<rt::Distribution> parse_cyclictest_histogram(const std::string& text, int histogram_max_us) {
  if (histogram_max_us <= 0) {
    return Error{ErrorCode::kInvalid, "histogram_max_us: expected > 0, found " + std::to_string(histogram_max_us)};
  }
  const auto n_buckets = static_cast<std::uint64_t>(histogram_max_us);
  rt::Distribution d;
  d.name = "cyclictest";
  d.overflow_above_us = histogram_max_us;

  LineReader in(text);
  if (in.at_end()) {
    return parse_error(in.number(), "expected '# Histogram' or a bucket line, found end of file (the histogram file is empty)");
  }
  if (in.line() == "# Histogram") in.advance();

  // Bucket lines "<µs> <count>", every bucket 0 .. histogram_max_us-1 in order.
  std::uint64_t next_bucket = 0;
  std::uint64_t in_buckets = 0;
  double weighted_sum = 0;  // Σ µs·count, for the exact mean
  while (!in.at_end() && in.line().front() != '#') {
    const auto fields = split_fields(in.line());
    std::uint64_t bucket = 0, n = 0;
    const std::string expected = "'<bucket µs> <count>' (two unsigned integers)";
    if (fields.size() != 2 || !parse_unsigned(fields[0], bucket) || !parse_unsigned(fields[1], n)) {
      std::string why = "expected " + expected + ", found " + in.found();
      if (fields.size() > 2) why += " (several count columns: run cyclictest with -t 1)";
      if (in.line().find('-') != std::string_view::npos) why += " (negative numbers are not valid here)";
      return parse_error(in.number(), why);
    }
    if (next_bucket >= n_buckets) {
      return parse_error(in.number(), "expected '# Total: <count>' after the last bucket (" + std::to_string(n_buckets - 1) +
                                          "; -h " + std::to_string(histogram_max_us) + "), found " + in.found());
    }
    if (bucket != next_bucket) {
      return parse_error(in.number(), "expected bucket " + std::to_string(next_bucket) + ", found bucket " +
                                          std::to_string(bucket) + " in " + in.found());
    }
    if (n > std::numeric_limits<std::uint64_t>::max() - in_buckets) {
      return parse_error(in.number(), "bucket counts overflow 64 bits at " + in.found());
    }
    if (n != 0) d.buckets.emplace_back(static_cast<double>(bucket), n);
    in_buckets += n;
    weighted_sum += static_cast<double>(bucket) * static_cast<double>(n);
    ++next_bucket;
    in.advance();
  }
  if (next_bucket != n_buckets) {
    return parse_error(in.number(), "expected bucket " + std::to_string(next_bucket) + " ('<bucket µs> <count>'; the histogram has " +
                                        std::to_string(n_buckets) + " buckets: -h " + std::to_string(histogram_max_us) +
                                        "), found " + in.found());
  }

  // The trailer, in cyclictest's order.
  const std::size_t total_line = in.number();
  auto total = read_labelled(in, "# Total:");
  if (!total) return total.error();
  if (total.value() != in_buckets) {
    return parse_error(total_line, "'# Total:' says " + std::to_string(total.value()) + " but the bucket lines add up to " +
                                       std::to_string(in_buckets));
  }
  auto min = read_labelled(in, "# Min Latencies:");
  if (!min) return min.error();
  const std::size_t avg_line = in.number();
  auto avg = read_labelled(in, "# Avg Latencies:");
  if (!avg) return avg.error();
  const std::size_t max_line = in.number();
  auto max = read_labelled(in, "# Max Latencies:");
  if (!max) return max.error();
  const std::size_t overflow_line = in.number();
  auto overflows = read_labelled(in, "# Histogram Overflows:");
  if (!overflows) return overflows.error();
  if (in.at_end() || in.line() != "# Histogram Overflow at cycle number:") {
    return parse_error(in.number(), "expected '# Histogram Overflow at cycle number:', found " + in.found());
  }
  in.advance();
  if (in.at_end() || in.line().substr(0, 10) != "# Thread 0") {
    return parse_error(in.number(), "expected '# Thread 0: [cycle numbers]', found " + in.found());
  }
  in.advance();
  // Anything after: only comment lines (later rt-tests versions may add some).
  for (; !in.at_end(); in.advance()) {
    if (in.line().front() != '#') {
      return parse_error(in.number(), "expected the end of the file after '# Thread 0:', found " + in.found());
    }
  }

  if (overflows.value() > std::numeric_limits<std::uint64_t>::max() - in_buckets) {
    return parse_error(overflow_line, "'# Histogram Overflows:' plus '# Total:' overflow 64 bits");
  }
  d.overflows = overflows.value();
  d.count = in_buckets + d.overflows;
  if (d.count == 0) return d;  // nothing measured: min, avg and max stay 0

  if (min.value() > max.value()) {
    return parse_error(max_line, "expected Max Latencies >= Min Latencies (" + std::to_string(min.value()) + "), found " +
                                     std::to_string(max.value()));
  }
  if (avg.value() < min.value() || avg.value() > max.value()) {
    return parse_error(avg_line, "expected Avg Latencies within [Min, Max] = [" + std::to_string(min.value()) + ", " +
                                     std::to_string(max.value()) + "], found " + std::to_string(avg.value()));
  }
  d.min_us = static_cast<double>(min.value());
  d.max_us = static_cast<double>(max.value());
  d.avg_us = d.overflows == 0 ? weighted_sum / static_cast<double>(d.count) : static_cast<double>(avg.value());
  return d;
}

Result<rt::Distribution> run_cyclictest(const CyclictestOptions& o) {
  if (auto why = check_cyclictest_options(o); !why.empty()) return Error{ErrorCode::kInvalid, why};

  std::string err;
  TempFile hist, output;
  if (!hist.create(".hist", &err) || !output.create(".out", &err)) return Error{ErrorCode::kSystem, err};
  ::close(hist.fd);  // cyclictest opens it by name
  hist.fd = -1;

  const std::vector<std::string> args = cyclictest_arguments(o, hist.path);
  std::vector<char*> argv;
  argv.reserve(args.size() + 1);
  for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));  // posix_spawn's signature; not written
  argv.push_back(nullptr);
  std::string command_line;
  for (const auto& a : args) command_line += (command_line.empty() ? "" : " ") + a;

  // stdin from /dev/null, stdout and stderr into the output file; default signal handling and an
  // empty signal mask whatever the caller has set up (so SIGINT/SIGTERM stop it as usual).
  SpawnSetup setup;
  posix_spawn_file_actions_addopen(&setup.actions, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_adddup2(&setup.actions, output.fd, STDOUT_FILENO);
  posix_spawn_file_actions_adddup2(&setup.actions, output.fd, STDERR_FILENO);
  sigset_t defaults, mask;
  sigemptyset(&defaults);
  for (const int s : {SIGINT, SIGTERM, SIGHUP, SIGQUIT, SIGPIPE, SIGCHLD, SIGALRM, SIGUSR1, SIGUSR2}) sigaddset(&defaults, s);
  sigemptyset(&mask);
  posix_spawnattr_setsigdefault(&setup.attr, &defaults);
  posix_spawnattr_setsigmask(&setup.attr, &mask);
  posix_spawnattr_setflags(&setup.attr, POSIX_SPAWN_SETSIGDEF | POSIX_SPAWN_SETSIGMASK);

  pid_t pid = -1;
  const int rc = ::posix_spawnp(&pid, o.executable.c_str(), &setup.actions, &setup.attr, argv.data(), environ);
  const bool is_path = o.executable.find('/') != std::string::npos;
  if (rc == ENOENT) {
    return Error{ErrorCode::kNotFound, "cyclictest not found ('" + o.executable + "' " +
                                           (is_path ? "does not exist" : "is not on PATH") +
                                           "): install Debian package rt-tests (./lancet setup does)"};
  }
  if (rc != 0) {
    return Error{ErrorCode::kSystem, "cannot start cyclictest ('" + o.executable + "'): " + std::strerror(rc) +
                                         (rc == EACCES ? " (not an executable file?)" : "")};
  }

  // Wait, polling, until the rounded duration plus the margin has passed; then kill it.
  const double limit_s = static_cast<double>(rounded_duration_s(o.duration_s)) + o.timeout_margin_s;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(limit_s);
  int status = 0;
  for (;;) {
    const pid_t r = ::waitpid(pid, &status, WNOHANG);
    if (r == pid) break;
    if (r < 0 && errno != EINTR) {
      const int e = errno;
      ::kill(pid, SIGKILL);
      return Error{ErrorCode::kSystem, std::string("waiting for cyclictest failed: ") + std::strerror(e) +
                                           (e == ECHILD ? " (is SIGCHLD ignored in this process?)" : "")};
    }
    if (std::chrono::steady_clock::now() >= deadline) {
      ::kill(pid, SIGKILL);
      while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
      }
      return Error{ErrorCode::kSystem, "cyclictest did not finish within " + seconds_text(limit_s) +
                                           " s (its duration plus " + seconds_text(o.timeout_margin_s) +
                                           " s) and was killed; command: " + command_line +
                                           "; its output: " + read_output(output.path)};
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }

  if (WIFSIGNALED(status)) {
    const int sig = WTERMSIG(status);
    return Error{ErrorCode::kSystem, "cyclictest was killed by signal " + std::to_string(sig) + " (" + strsignal(sig) +
                                         "); command: " + command_line + "; its output: " + read_output(output.path)};
  }
  const int code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  if (code != 0) {
    const std::string out = read_output(output.path);
    if (code == 127 && out == "(no output)") {  // a libc whose posix_spawnp reports exec failure this way
      return Error{ErrorCode::kNotFound, "cyclictest not found ('" + o.executable +
                                             "' could not be executed): install Debian package rt-tests (./lancet setup does)"};
    }
    return Error{ErrorCode::kSystem, "cyclictest exited with status " + std::to_string(code) + ": " + out +
                                         " (command: " + command_line + ")"};
  }

  const std::string text = read_file(hist.path);
  if (text.empty()) {
    return Error{ErrorCode::kSystem, "cyclictest exited normally but wrote no histogram to " + hist.path +
                                         " (command: " + command_line + "); its output: " + read_output(output.path)};
  }
  auto d = parse_cyclictest_histogram(text, o.histogram_max_us);
  if (!d) {
    hist.keep = true;
    return Error{ErrorCode::kInvalid, "cyclictest histogram " + hist.path + " (kept for inspection): " + d.error().message};
  }
  return d;
}

}  // namespace lancet::tools
