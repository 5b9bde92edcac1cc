#pragma once
// `lancetctl jitter`: runs the real servo loop (two simulated hands, as lancet-rt runs by
// default, each with its own 1024-triangle patch, the right hand pressing into its: the contact
// search, safety and sample pushes of every tick) on the real-time thread for a duration, optionally alternating with cyclictest in the same run, and reports both wake-up
// latency distributions side by side, with pass/fail bounds for test rigs.

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "app/rt_cli.hpp"
#include "rt/distribution.hpp"
#include "rt/latency_histogram.hpp"
#include "rt/rt_setup.hpp"

namespace lancet::tools {

struct JitterOptions {
  app::RtCliOptions rt;
  double duration_s = 10;               ///< in all; with cyclictest, each round is rounded up to whole seconds
  bool compare_cyclictest = false;
  int rounds = 2;                       ///< ours and cyclictest alternate this many times
  std::optional<double> max_p99_us;     ///< fail when our wake-up p99 is above
  std::optional<double> max_us;         ///< fail when our worst wake-up is above
  std::optional<std::uint64_t> max_missed;  ///< fail when more deadlines were missed
  std::string json_path;
  std::string plot_path;
  std::string cyclictest = "cyclictest";
  bool servo_workload = true;           ///< false: an empty tick (the loop's own cost, for diagnosis)
  /// Alternate rounds without and with a session recording (the ring drained every 16 ms by a
  /// consumer thread, as lancet-viz does, which in the "on" rounds also writes every sample to an
  /// HDF5 file through record::Recorder): the two wake-up distributions side by side.
  bool compare_recording = false;
  std::string record_path;              ///< where the "on" rounds write (default: a file in /tmp, removed after)
};

struct JitterResult {
  rt::RtSetupReport setup;
  int cpu = -1;
  rt::LatencyHistogram wake, compute, period_error;
  std::uint64_t ticks = 0, overruns = 0, missed = 0, watchdog_trips = 0;
  std::int64_t longest_stall_ns = 0;
  long minor_faults = 0, major_faults = 0;
  std::vector<double> window_max_us;    ///< worst wake-up per 100 ms, rounds concatenated
  std::optional<rt::Distribution> cyclictest;
  /// compare_recording: the rounds without and with the recording.
  std::optional<rt::LatencyHistogram> recording_off, recording_on;
  std::uint64_t recorded_samples = 0, recorded_lost = 0, record_bytes = 0;
  std::string record_error;
  std::string cyclictest_error;
  struct Bound {
    std::string what;
    double limit, value;
    bool pass;
  };
  std::vector<Bound> bounds;
  [[nodiscard]] bool pass() const;
};

/// Runs the measurement. Errors at setup time throw std::runtime_error.
JitterResult run_jitter(const JitterOptions& options);

/// The cyclictest-style text report.
std::string format_jitter_text(const JitterOptions& options, const JitterResult& result);
/// The JSON report (both distributions' percentiles, the bounds, the setup).
std::string format_jitter_json(const JitterOptions& options, const JitterResult& result);

}  // namespace lancet::tools
