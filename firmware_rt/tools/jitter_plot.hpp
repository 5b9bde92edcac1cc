#pragma once
// The jitter rig's picture: one standalone SVG file (no scripts, no external resources) with
//   top:    the latency histograms of every distribution overlaid as step lines, with vertical
//           markers at p50, p99 and p99.9 of each and a legend of their summary numbers;
//   bottom: the worst wake-up latency of each time window, over the run, per series.
// Allocating; written once at the end of a run, never on the real-time path.

#include <string>
#include <vector>

#include "rt/distribution.hpp"

namespace lancet::tools {

/// The worst wake-up latency in each consecutive window of a run.
struct TimeSeries {
  std::string name;            ///< legend label, e.g. "lancet"; the same name as a distribution gets its colour
  double window_s = 0;         ///< window length (s, > 0)
  std::vector<double> max_us;  ///< worst latency in window i, covering [i·window_s, (i+1)·window_s) (µs, #windows);
                               ///< values <= 0 or not finite are drawn as gaps
};

/// The SVG document as text (UTF-8).
///
/// Top panel: x is latency on a "symlog" axis, linear over [0, 1) µs (so sub-microsecond samples,
/// which a log axis cannot show, stay visible) and logarithmic from 1 µs to the largest max_us
/// rounded up to 1, 2 or 5 × 10^k; y is samples per bin on a log axis, with 20 bins per decade
/// above 1 µs and one bin for [0, 1) µs. Each bucket of a distribution is spread evenly over its
/// width (1 µs below 1 ms, as LatencyHistogram and cyclictest both have; coarser above, as
/// LatencyHistogram has, bounded by the next bucket), so distributions with different bucket grids
/// compare. Overflows, which have no position, are listed in the legend.
/// Bottom panel: x is time (s), y the latency (log µs).
/// Names and the title are XML-escaped (invalid UTF-8 and control characters become '?').
/// Empty inputs give a valid document that says "no samples" / "no time series".
std::string jitter_svg(const std::vector<rt::Distribution>& dists, const std::vector<TimeSeries>& series,
                       const std::string& title);

/// Writes jitter_svg(dists, series, title) to path. Returns false on failure with the reason
/// ("cannot write <path>: <errno text>") in *error when error is not null.
bool write_jitter_svg(const std::string& path, const std::vector<rt::Distribution>& dists,
                      const std::vector<TimeSeries>& series, const std::string& title, std::string* error);

}  // namespace lancet::tools
