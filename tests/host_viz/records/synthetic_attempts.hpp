#pragma once
// Attempts made by hand for the records' page tests: a trainee who learns (each metric nears its
// band's mean as attempts go on), with three banded metrics of the kinds the scorer writes.

#include <cmath>
#include <string>

#include "records/store.hpp"

namespace lancet::records::test {

/// The `i`-th (from 0) attempt of `trainee` at `scenario`, started `i` minutes after 2026-11-01T08:00Z
/// plus `day` days; proficient when every banded metric passes.
inline Attempt learning_attempt(const std::string& trainee, const std::string& scenario, int i, int day = 0) {
  Attempt a;
  a.content_hash = trainee + "-" + scenario + "-" + std::to_string(day) + "-" + std::to_string(i);
  a.trainee_id = trainee;
  a.scenario = scenario;
  a.scenario_hash = "h-" + scenario;
  a.recording = "/data/recordings/" + trainee + "/" + scenario + "-" + std::to_string(i) + ".h5";
  const int minute = i % 60, hour = 8 + i / 60 % 12;
  a.started = "2026-11-" + std::string(day + 1 < 10 ? "0" : "") + std::to_string(day + 1) + "T" + (hour < 10 ? "0" : "") + std::to_string(hour) + ":" +
              (minute < 10 ? "0" : "") + std::to_string(minute) + ":00Z";
  a.ended = a.started;
  a.duration_s = 60;
  a.build = "0.0.0-test";
  const double wobble = std::sin(1.7 * i + scenario.size());  // deterministic scatter
  const double learnt = std::exp(-i / 4.0);                   // 1 at the start, 0 when learnt
  auto metric = [&](const char* name, const char* unit, const char* better, double value, double mean, double sd) {
    AttemptMetric m{name, value, unit, better, true, mean, sd, 2, 0, false, "right"};
    m.band_limit = std::string(better) == "lower" ? mean + 2 * sd : mean - 2 * sd;
    m.pass = std::string(better) == "lower" ? value <= m.band_limit : value >= m.band_limit;
    a.metrics.push_back(m);
  };
  metric("task_time_s", "s", "lower", 30 + 60 * learnt + 6 * wobble, 30, 5);
  metric("path_length_mm", "mm", "lower", 120 + 150 * learnt + 15 * wobble, 120, 12);
  metric("incision_coverage_pct", "%", "higher", 96 - 40 * learnt + 3 * wobble, 95, 3);
  a.banded = 3;
  for (const AttemptMetric& m : a.metrics) a.passed += m.pass ? 1 : 0;
  a.proficient = a.passed == a.banded;
  a.verdict = a.proficient ? "proficient" : "not_yet";
  return a;
}

}  // namespace lancet::records::test
