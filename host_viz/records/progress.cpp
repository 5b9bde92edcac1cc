// Progress and the CSV export (records/progress.hpp).

#include "records/progress.hpp"

#include <charconv>
#include <cmath>
#include <map>
#include <memory>

#include "text/text.hpp"

namespace lancet::records {
namespace {

// A CSV field: quoted when it holds a comma, a quote or a line break.
std::string csv_field(const std::string& s) {
  if (s.find_first_of(",\"\r\n") == std::string::npos) return s;
  std::string out = "\"";
  for (const char c : s) {
    if (c == '"') out += '"';
    out += c;
  }
  return out + '"';
}

// The shortest text that reads back as `v`, '.' whatever the locale; "" when not finite.
std::string csv_number(double v) {
  if (!std::isfinite(v)) return {};
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, r.ptr);
}

}  // namespace

Progress progress(const Trainee& trainee, const Curriculum& curriculum, const std::vector<Attempt>& attempts) {
  Progress p;
  p.trainee = trainee;
  p.curriculum = curriculum.name;
  for (const CurriculumStep& step : curriculum.steps) {
    const auto passed = std::make_unique<bool[]>(attempts.size());  // not vector<bool>: evaluate takes a span
    std::size_t n = 0;
    StepProgress sp{step, {}, 0};
    for (const Attempt& a : attempts) {
      if (a.scenario != step.scenario) continue;
      passed[n++] = a.proficient;
      if (a.scenario_hash != step.scenario_hash) ++sp.other_versions;
    }
    const ProficiencyRule rule{static_cast<std::size_t>(step.required), static_cast<std::size_t>(step.consecutive)};
    sp.standing = evaluate(rule, std::span<const bool>(passed.get(), n));
    if (!sp.standing.proficient && !p.next) p.next = p.steps.size();
    p.steps.push_back(sp);
  }
  for (const Attempt& a : attempts) {
    bool in = false;
    for (const CurriculumStep& step : curriculum.steps) in = in || a.scenario == step.scenario;
    if (!in) ++p.outside;
  }
  return p;
}

std::string progress_text(const Progress& p) {
  std::string s = text::format("%s (%s%s%s), curriculum \"%s\"\n", p.trainee.id.c_str(), p.trainee.name.c_str(), p.trainee.cohort.empty() ? "" : ", cohort ",
                               p.trainee.cohort.c_str(), p.curriculum.c_str());
  for (std::size_t i = 0; i < p.steps.size(); ++i) {
    const StepProgress& sp = p.steps[i];
    const Standing& st = sp.standing;
    s += text::format("  %zu. %-20s %3zu attempts, %3zu proficient (%zu in a row at most); needs %lld, %lld in a row: %s", i + 1,
                      sp.step.scenario.c_str(), st.attempts, st.passes, st.longest_run, static_cast<long long>(sp.step.required),
                      static_cast<long long>(sp.step.consecutive), st.proficient ? "proficient" : "not yet");
    if (st.proficient) s += text::format(" (at attempt %zu)", st.proficient_at);
    if (sp.other_versions > 0) s += text::format("; %zu scored against another version of the scenario", sp.other_versions);
    s += '\n';
  }
  if (p.outside > 0) s += text::format("  %zu attempts at scenarios outside the curriculum\n", p.outside);
  s += p.next ? "next: " + p.steps[*p.next].step.scenario + "\n" : std::string("next: none, the curriculum is done\n");
  return s;
}

std::string export_csv(const std::vector<Attempt>& attempts, const std::vector<Trainee>& trainees) {
  std::map<std::string, const Trainee*> by_id;
  for (const Trainee& t : trainees) by_id[t.id] = &t;
  std::string out =
      "trainee,name,cohort,scenario,scenario_hash,content_hash,recording,started,ended,duration_s,build,scored_by,verdict,proficient,"
      "metric,value,unit,better,band_mean,band_sd,band_k,band_limit,pass,hand\r\n";
  for (const Attempt& a : attempts) {
    const auto it = by_id.find(a.trainee_id);
    const Trainee* t = it != by_id.end() ? it->second : nullptr;
    std::string head;
    for (const std::string& f : {a.trainee_id, t != nullptr ? t->name : "", t != nullptr ? t->cohort : "", a.scenario, a.scenario_hash,
                                 a.content_hash, a.recording, a.started, a.ended, csv_number(a.duration_s), a.build, a.scored_by, a.verdict,
                                 std::string(a.proficient ? "1" : "0")}) {
      head += csv_field(f) + ',';
    }
    if (a.metrics.empty()) out += head + ",,,,,,,,,\r\n";
    for (const AttemptMetric& m : a.metrics) {
      const auto band = [&](double v) { return m.has_band ? csv_number(v) : std::string(); };
      out += head + csv_field(m.name) + ',' + csv_number(m.value) + ',' + csv_field(m.unit) + ',' + m.better + ',' + band(m.band_mean) + ',' +
             band(m.band_sd) + ',' + band(m.band_k) + ',' + band(m.band_limit) + ',' + (m.has_band ? (m.pass ? "1" : "0") : "") + ',' + m.hand +
             "\r\n";
    }
  }
  return out;
}

}  // namespace lancet::records
