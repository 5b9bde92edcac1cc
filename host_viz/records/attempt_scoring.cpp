// A recording scored into an attempt (records/attempt_scoring.hpp).

#include "records/attempt_scoring.hpp"

#include <cmath>
#include <ctime>
#include <vector>

#include "recording/hdf5_io.hpp"
#include "records/content_hash.hpp"
#include "records/utc_time.hpp"
#include "scenarios/scenario.hpp"
#include "score/metrics.hpp"
#include "score/report.hpp"

namespace lancet::records {
namespace {

// The recorded span: first to last sample, plus the last tick's period (s).
double duration_s(const record::Recording& rec) {
  if (rec.samples.empty()) return 0;
  const auto span = rec.samples.back().t_ns - rec.samples.front().t_ns + rec.period_ns;
  return static_cast<double>(span) * 1e-9;
}

// `started` (ISO 8601 UTC, as recordings write it) plus `seconds`; `started` itself when it does
// not read as a time.
std::string iso_plus(const std::string& started, double seconds) {
  std::tm tm{};
  const char* end = strptime(started.c_str(), "%Y-%m-%dT%H:%M:%S", &tm);
  if (end == nullptr || !std::isfinite(seconds)) return started;
  return iso_utc(timegm(&tm) + static_cast<std::time_t>(std::llround(seconds)));
}

std::string scenario_names(const Curriculum& c) {
  std::string s;
  for (const CurriculumStep& step : c.steps) s += (s.empty() ? "" : ", ") + step.scenario;
  return s;
}

AttemptMetric stored(const score::Metric& m) {
  AttemptMetric a{m.name, m.value, m.unit, m.better == score::Better::kLower ? "lower" : "higher", m.band.has_value(), 0, 0, 0, 0,
                  m.pass, std::string(score::hand_scope_key(m.hand))};
  if (m.band) {
    a.band_mean = m.band->mean;
    a.band_sd = m.band->sd;
    a.band_k = m.band->k;
    a.band_limit = m.band->limit;
  }
  return a;
}

// The recording at `path`; an error names the file.
Result<record::Recording> read_named(const std::string& path) {
  auto read = record::read_recording(path);
  if (!read.ok()) {
    const std::string& m = read.error().message;
    return Error{ErrorCode::kInvalid, m.find(path) == std::string::npos ? path + ": " + m : m};
  }
  return read;
}

// The scenario the recording holds, as lancet-report reads it.
Result<scenario::Scenario> recorded_scenario(const record::Recording& rec, const std::string& path) {
  return scenario::parse_scenario(rec.scenario_toml, rec.scenario_file.empty() ? path + ":/meta/scenario" : rec.scenario_file);
}

}  // namespace

Result<Attempt> score_attempt(const std::string& path, const std::string& trainee_id, const Curriculum& curriculum) {
  auto hash = sha256_file(path);
  if (!hash.ok()) return hash.error();
  auto read = read_named(path);
  if (!read.ok()) return read.error();
  const record::Recording& rec = read.value();
  if (rec.scenario_toml.empty())
    return Error{ErrorCode::kInvalid, path + ": recorded without a scenario, so there is nothing to score it against"};
  auto sc = recorded_scenario(rec, path);
  if (!sc.ok()) {
    const std::string& m = sc.error().message;
    return Error{ErrorCode::kInvalid, path + ": its scenario \"" + rec.scenario_name + "\" is unknown to this build: " + m.substr(0, m.find('\n'))};
  }
  if (!curriculum.steps.empty()) {
    bool found = false;
    for (const CurriculumStep& step : curriculum.steps) found = found || step.scenario == sc.value().name;
    if (!found)
      return Error{ErrorCode::kInvalid, path + ": scenario \"" + sc.value().name + "\" is not in the curriculum \"" + curriculum.name +
                                            "\" (its scenarios: " + scenario_names(curriculum) + ")"};
  }
  const score::Metrics m = score::compute_metrics(rec, &sc.value());

  Attempt a;
  a.content_hash = hash.value();
  a.trainee_id = trainee_id;
  a.scenario = sc.value().name;
  a.scenario_hash = sha256_hex(rec.scenario_toml);
  a.recording = path;
  a.started = rec.created;
  a.duration_s = duration_s(rec);
  a.ended = iso_plus(rec.created, a.duration_s);
  a.verdict = std::string(score::verdict_key(m.verdict));
  a.proficient = m.verdict == score::Verdict::kProficient;
  a.banded = static_cast<std::int64_t>(m.banded);
  a.passed = static_cast<std::int64_t>(m.passed);
  a.build = rec.lancet_version;
  for (const score::Metric& x : m.metrics) a.metrics.push_back(stored(x));
  return a;
}

Result<std::string> attempt_report_html(const std::string& path, const std::string& shown) {
  auto read = read_named(path);
  if (!read.ok()) return read.error();
  const record::Recording& rec = read.value();
  auto sc = recorded_scenario(rec, path);
  if (rec.scenario_toml.empty() || !sc.ok()) return Error{ErrorCode::kInvalid, path + ": no scenario this build reads, so no report"};
  std::vector<score::ReportInput> input;
  input.push_back(score::ReportInput{shown, &rec, score::compute_metrics(rec, &sc.value())});
  return score::report_html(input);
}

}  // namespace lancet::records
