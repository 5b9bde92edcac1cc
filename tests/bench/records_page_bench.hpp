#pragma once
// lancet-bench-records' progress page figures (bench_records.cpp): one trainee with N attempts
// (default 500) at the curriculum's scenario, each with the scored attempt's metrics (values
// varied along a learning curve), stored in a fresh database; then, best of 3, what
// `lancet-records progress TRAINEE -o page.html` does: read the trainee, the curriculum and the
// attempts with their metrics, progress(), progress_html(). Prints one JSON field.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>

#include "records/progress_page.hpp"
#include "records/store.hpp"

namespace lancet::bench {

// Fills `s` with the trainee "bench", a one-step curriculum and `n` attempts made from `a`.
inline bool fill_trainee(records::Store& s, const records::Attempt& a, int n) {
  if (!s.add_trainee(records::Trainee{"bench", "Bench Trainee", "bench-cohort"}).ok()) return false;
  if (!s.set_curriculum(records::Curriculum{"bench", {{a.scenario, a.scenario_hash, 3, 2}}}).ok()) return false;
  for (int i = 0; i < n; ++i) {
    records::Attempt x = a;
    x.trainee_id = "bench";
    x.content_hash = a.content_hash.substr(0, 54) + std::to_string(1'000'000'000 + i);
    x.started = "2026-" + std::to_string(10 + i / 28 / 24 % 3) + "-" + std::to_string(10 + i / 24 % 18) + "T" + std::to_string(10 + i % 12) + ":00:00Z";
    x.recording = "/data/recordings/bench/attempt-" + std::to_string(i) + ".h5";
    const double learnt = std::exp(-i / 60.0), wobble = std::sin(1.3 * i);
    x.passed = 0;
    for (records::AttemptMetric& m : x.metrics) {
      m.value *= 1 + learnt * (m.better == "lower" ? 1.5 : -0.5) + 0.05 * wobble;
      if (m.has_band) m.pass = m.better == "lower" ? m.value <= m.band_limit : m.value >= m.band_limit;
      x.passed += m.has_band && m.pass ? 1 : 0;
    }
    x.proficient = x.passed == x.banded;
    if (auto r = s.add_attempt(x); !r.ok() || !r.value()) return false;
  }
  return true;
}

// Times the progress page over `db` (which must be empty); prints `"label": {...}`.
inline void bench_progress_page(const char* label, const std::string& db, const records::Attempt& a, int n, double score_ms, bool last) {
  using Clock = std::chrono::steady_clock;
  const char* comma = last ? "" : ",";
  auto opened = records::Store::open(db);
  if (!opened.ok() || !fill_trainee(*opened.value(), a, n)) {
    std::printf("  \"%s\": {\"error\": \"cannot open or fill %s\"}%s\n", label, db.c_str(), comma);
    return;
  }
  records::Store& s = *opened.value();
  double best_s = 1e30, best_html_s = 1e30;
  std::size_t bytes = 0, metrics = 0;
  for (int rep = 0; rep < 3; ++rep) {
    const auto t0 = Clock::now();
    auto t = s.find_trainee("bench");
    auto c = s.curriculum();
    auto attempts = s.attempts(records::AttemptFilter{"bench", std::nullopt, true});
    if (!t.ok() || !t.value() || !c.ok() || !attempts.ok()) {
      std::printf("  \"%s\": {\"error\": \"read failed\"}%s\n", label, comma);
      return;
    }
    const auto t1 = Clock::now();
    const records::Progress p = records::progress(*t.value(), c.value(), attempts.value());
    const std::string page = records::progress_html(p, attempts.value(), records::ProgressPageOptions{{}, "/data", {}});
    const auto t2 = Clock::now();
    best_s = std::min(best_s, std::chrono::duration<double>(t2 - t0).count());
    best_html_s = std::min(best_html_s, std::chrono::duration<double>(t2 - t1).count());
    bytes = page.size();
    metrics = attempts.value().empty() ? 0 : attempts.value().front().metrics.size();
  }
  std::printf("  \"%s\": {\"attempts\": %d, \"metrics_per_attempt\": %zu, \"page_ms\": %.2f, \"of_which_html_ms\": %.2f, \"page_bytes\": %zu, "
              "\"page_to_score_ratio\": %.3f}%s\n",
              label, n, metrics, best_s * 1e3, best_html_s * 1e3, bytes, best_s * 1e3 / score_ms, comma);
}

}  // namespace lancet::bench
