#pragma once
// Runs cyclictest (Debian package rt-tests) as a child process and reads its latency histogram
// into a Distribution, so the jitter rig can put our loop's wake-up latency beside the reference
// tool's, measured with the same interval, priority and CPU.
//
// Nothing here is real-time safe: run_cyclictest blocks for the whole measurement (seconds) and
// allocates; call it from a tool's main thread, never from the loop.

#include <string>
#include <vector>

#include "lancet/shared_model/result.hpp"
#include "rt/distribution.hpp"

namespace lancet::tools {

struct CyclictestOptions {
  int interval_us = 1000;        ///< wake-up period (µs, > 0): cyclictest -i
  int priority = 80;             ///< SCHED_FIFO priority, 0..99 (0: SCHED_OTHER): cyclictest -p
  int cpu = -1;                  ///< pin the measuring thread to this CPU (-a); -1: no affinity
  double duration_s = 10;        ///< run time (s, > 0); rounded up to whole seconds, at least 1 (-D)
  int histogram_max_us = 10000;  ///< histogram range [0, this) µs in 1 µs buckets (-h); above: overflows
  bool mlockall = true;          ///< lock memory (-m)
  std::string executable = "cyclictest";  ///< a name looked up on PATH, or a path
  double timeout_margin_s = 30;  ///< killed when it runs longer than the rounded duration plus this
};

/// The arguments run_cyclictest passes (argv[0] = options.executable), writing the histogram to
/// histfile: `cyclictest -m -q -t 1 -p PRIO -i INTERVAL [-a CPU] -D SECONDS -h HISTMAX
/// --histfile=PATH`. SECONDS is duration_s rounded up, at least 1 (cyclictest's -D takes whole
/// seconds; a fraction such as "0.5" would read as 0, which means "run forever").
/// Precondition: check_cyclictest_options(options) is empty.
std::vector<std::string> cyclictest_arguments(const CyclictestOptions& options, const std::string& histfile);

/// Checks the ranges documented on CyclictestOptions. Returns an empty string when they are all
/// valid, else a message naming the field, expected vs found.
std::string check_cyclictest_options(const CyclictestOptions& options);

/// Runs cyclictest with one measuring thread (posix_spawnp, no shell; stdout and stderr captured
/// to a temporary file; the histogram written to another temporary file, both removed afterwards)
/// and returns its latency distribution, named "cyclictest". Blocks for about the rounded duration.
/// Errors, each with what to do:
///   kInvalid   an option out of range;
///   kNotFound  the executable is missing ("install Debian package rt-tests");
///   kSystem    it could not be started, exited non-zero or by a signal (its captured output is in
///              the message: e.g. "Unable to change scheduling policy! ... run as root"), ran past
///              duration + timeout_margin_s (then it is killed), or wrote no histogram;
///   kInvalid   the histogram does not parse (the message names the file, which is then kept for
///              inspection, and the line).
Result<rt::Distribution> run_cyclictest(const CyclictestOptions& options);

/// Parses the text cyclictest writes with `-t 1 -h HISTMAX --histfile=PATH` (rt-tests 2.x):
///
///   # Histogram
///   000000 000000          one line per bucket 0 .. HISTMAX-1: latency µs, samples
///   ...
///   # Total: 000001990     samples inside the histogram (overflows not included)
///   # Min Latencies: 00013
///   # Avg Latencies: 00019  over all samples, truncated to whole µs
///   # Max Latencies: 02716
///   # Histogram Overflows: 00010
///   # Histogram Overflow at cycle number:
///   # Thread 0: 00002 00006 ... [# 00865 others]
///
/// Bucket lines must come in order and number exactly histogram_max_us; the trailer lines must all
/// be there, in this order; blank lines and a trailing '\r' are ignored. The result: count = Total
/// + Overflows (every sample, as Distribution::count means), buckets = the non-empty ones (lower
/// edge µs; each is [k, k+1) µs since cyclictest truncates to whole µs), avg_us = the histogram's
/// mean when there are no overflows (exact; the Avg line is truncated), else the Avg line,
/// overflow_above_us = histogram_max_us. Never throws and never crashes on garbage: an error
/// (kInvalid) says "line N: expected ..., found ...".
Result<rt::Distribution> parse_cyclictest_histogram(const std::string& text, int histogram_max_us);

}  // namespace lancet::tools
