#pragma once
// The report of one or more recorded attempts: a self-contained HTML page for people (inline CSS
// and inline SVG, no scripts, no external resources) and JSON with the same metrics for machines.
// lancet-report (host_viz/app/lancet_report_main.cpp) writes both.
//
// The page: a title with the scenario and the date; per attempt a verdict (proficient / not yet /
// not assessed), the tool tip's path seen from above (x-y, mm) coloured by interaction stage with
// the planned incision line (and its tolerance) or the drill window, the force on the hand over
// time with the force limit, and the metrics table (value, unit, band, pass or fail, how it was
// measured); with several attempts first a comparison table, one column per attempt. A two-handed
// recording (Metrics::hands == 2): the stage-coloured path is the right hand's, the force plot
// has one line per hand in its colour (right steel blue #4d80f2, left amber #f29926), the metrics
// table says whose each figure is, and a "Two hands" section follows it: both hands' paths from
// above in their colours and scenario::kTwoHandScoreMetrics. A one-handed recording has no such
// section. Long series
// are reduced to at most kMaxPlotPoints points per plot (the force keeps each bucket's minimum and
// maximum, so peaks survive). All text from the recording or the file names is HTML-escaped.
//
// The JSON: {"format": "lancet-report", "version": 1, "attempts": [{"file", "scenario",
// "created", "lancet_version", "task" ("incision", "drill" or null), "duration_s", "samples",
// "frames", "samples_lost", "hands", "window_s": [begin, end], "settings": {"force_limit_n",
// "movement_speed_mm_s", "movement_filter_hz", "sd_multiple"}, "verdict" ("proficient",
// "not_yet", "not_assessed"), "proficient", "banded", "passed", "damaged": [names], "notes":
// [text], "metrics": {name: {"value", "unit", "better" ("lower"/"higher"), "band": {"mean",
// "sd", "k", "limit"} or null, "pass": bool or null, "hand" ("right", "left", "both", "scene"),
// "description"}}, "two_hands": null for one hand, or {"dominant": "right", "right": {"colour",
// "path_length_mm", "economy_of_motion_ratio"}, "left": {"colour", "path_length_mm",
// "economy_of_motion_ratio", "idle_time_s"}, "both_hands_contact_time_s", "idle_speed_mm_s",
// "idle_block_ms"}}]}, metrics in scenario::kScoreMetrics order, then kTwoHandScoreMetrics'.
// Keys are stable; every number is finite or null.
//
// Both are pure functions of their input (allocating; tools only).

#include <cstddef>
#include <string>
#include <vector>

#include "score/metrics.hpp"
#include "recording/recording.hpp"

namespace lancet::score {

using record::FrameRecord;
using record::Recording;
using record::SceneEvent;

/// Most points one plot draws.
inline constexpr std::size_t kMaxPlotPoints = 2000;

/// One attempt to report.
struct ReportInput {
  std::string file;                      ///< the attempt's name as shown (usually its file name)
  const Recording* recording = nullptr;  ///< not owned; must not be null and must outlive the call
  Metrics metrics;                       ///< compute_metrics(*recording, scenario)
};

/// The HTML page (UTF-8). `attempts` must not be empty.
[[nodiscard]] std::string report_html(const std::vector<ReportInput>& attempts);

/// The JSON document (UTF-8; strings that are not valid UTF-8 get U+FFFD).
[[nodiscard]] std::string report_json(const std::vector<ReportInput>& attempts);

}  // namespace lancet::score
