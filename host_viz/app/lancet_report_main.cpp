// lancet-report: the skill metrics of recorded sessions as a self-contained HTML page and JSON.
//   lancet-report FILE.h5 [FILE2.h5 ...] -o report.html [--json out.json|-]
// Each FILE is a recording written by lancet-viz (recording/hdf5_io.hpp); its metrics are scored
// against the [score] section of the scenario it was recorded with (the text stored in the file),
// or of the scenario file given with --scenario (bands recalibrated since).
// Several files give one page with a comparison table. A one-line verdict per file goes to stdout
// (stderr when the JSON goes to stdout); for a two-handed recording each two-hand figure follows it
// on a line of its own.
// Exit status: 0 done, 2 bad arguments, a file that cannot be read, or an output that cannot be written.

#include <CLI/CLI.hpp>

#include <cmath>
#include <cstdio>
#include <exception>
#include <fstream>
#include <new>
#include <optional>
#include <string>
#include <vector>

#include "app/tool_main.hpp"
#include "recording/hdf5_io.hpp"
#include "score/metrics.hpp"
#include "score/report.hpp"
#include "scenarios/scenario.hpp"

namespace {

using namespace lancet;
using namespace lancet::record;
using namespace lancet::score;

int fail(const std::string& message) {
  std::fprintf(stderr, "lancet-report: %s\n", message.c_str());
  return 2;
}

// Writes `text` to `path`; an error names the file.
Result<void> write_text(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (out) out.write(text.data(), static_cast<std::streamsize>(text.size()));
  if (out) out.close();
  if (!out) return Error{ErrorCode::kSystem, path + ": cannot write the report"};
  return {};
}

// The first line of a multi-line message.
std::string first_line(const std::string& s) { return s.substr(0, s.find('\n')); }

// A two-handed attempt's own figures, one a line under its verdict (nothing for one hand).
void print_two_hands(std::FILE* out, const Metrics& m) {
  if (m.hands < 2) return;
  std::fprintf(out, "  two hands (the report's path, angle, economy, movements, jerk and mean force are the right hand's; idle: slower than %g mm/s "
                    "over %g ms):\n",
               kIdleSpeed * 1e3, static_cast<double>(kIdleBlockNs) / 1e6);
  for (const scenario::ScoreMetricInfo& info : scenario::kTwoHandScoreMetrics) {
    const Metric* x = find_metric(m, info.name);
    if (x == nullptr) continue;
    const std::string name(x->name);
    const char* result = !x->band ? "" : x->pass ? " (pass)" : " (fail)";
    if (std::isfinite(x->value)) {
      std::fprintf(out, "    %-30s %.3g %s%s\n", name.c_str(), x->value, x->unit.c_str(), result);
    } else {
      std::fprintf(out, "    %-30s not measured%s\n", name.c_str(), result);
    }
  }
}

struct Args {
  std::vector<std::string> files;
  std::string html;
  std::string json;
  std::string scenario;  ///< --scenario: score against this file's [score] instead of the recorded one
};

int run(int argc, char** argv) {
  CLI::App app{"lancet-report: skill metrics of recorded sessions as an HTML page and JSON"};
  Args a;
  app.add_option("files", a.files, "recordings (.h5) written by lancet-viz")->required();
  app.add_option("-o,--output", a.html, "the HTML report to write");
  app.add_option("--json", a.json, "also write the metrics as JSON to this file ('-': stdout)");
  app.add_option("--scenario", a.scenario,
                 "score against this scenario file (its task and its [score] bands, e.g. recalibrated ones) instead of the "
                 "scenario each recording holds; its name must match the recording's");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : 2;
  }
  if (a.html.empty() && a.json.empty()) return fail("nothing to write: give -o report.html and/or --json out.json|-");

  std::optional<scenario::Scenario> override_scenario;
  if (!a.scenario.empty()) {
    auto s = scenario::load_scenario(a.scenario);
    if (!s.ok()) return fail(s.error().message);
    override_scenario = std::move(s.value());
  }

  // Everything is read before anything is written: a bad file leaves no half report behind.
  std::vector<Recording> recordings;
  recordings.reserve(a.files.size());
  std::vector<std::string> notes(a.files.size());
  std::vector<std::optional<scenario::Scenario>> scenarios(a.files.size());
  for (std::size_t i = 0; i < a.files.size(); ++i) {
    const std::string& path = a.files[i];
    auto r = read_recording(path);
    if (!r.ok()) {
      const std::string& m = r.error().message;
      return fail(m.find(path) == std::string::npos ? path + ": " + m : m);
    }
    recordings.push_back(std::move(r.value()));
    const Recording& rec = recordings.back();
    if (override_scenario) {
      if (override_scenario->name != rec.scenario_name)
        return fail(path + ": recorded on scenario \"" + rec.scenario_name + "\", not on --scenario's \"" + override_scenario->name + "\"");
      scenarios[i] = override_scenario;
      notes[i] = "scored against " + a.scenario + " (--scenario), not the scenario recorded with it";
      continue;
    }
    if (rec.scenario_toml.empty()) continue;
    // The scenario as recorded; one this build cannot read is reported without bands.
    auto s = scenario::parse_scenario(rec.scenario_toml, rec.scenario_file.empty() ? path + ":/meta/scenario" : rec.scenario_file);
    if (s.ok()) {
      scenarios[i] = std::move(s.value());
    } else {
      notes[i] = "the recorded scenario does not load in this build, so no task metrics and no bands: " + first_line(s.error().message);
      std::fprintf(stderr, "lancet-report: warning: %s: %s\n", path.c_str(), notes[i].c_str());
    }
  }

  std::vector<ReportInput> inputs;
  for (std::size_t i = 0; i < a.files.size(); ++i) {
    Metrics m = compute_metrics(recordings[i], scenarios[i] ? &*scenarios[i] : nullptr);
    if (!notes[i].empty()) m.notes.push_back(notes[i]);
    inputs.push_back(ReportInput{a.files[i], &recordings[i], std::move(m)});
  }

  if (!a.html.empty()) {
    if (auto w = write_text(a.html, report_html(inputs)); !w.ok()) return fail(w.error().message);
  }
  const bool json_to_stdout = a.json == "-";
  if (json_to_stdout) {
    const std::string json = report_json(inputs);
    std::fwrite(json.data(), 1, json.size(), stdout);
  } else if (!a.json.empty()) {
    if (auto w = write_text(a.json, report_json(inputs)); !w.ok()) return fail(w.error().message);
  }
  for (const ReportInput& in : inputs) {
    const Metrics& m = in.metrics;
    const char* verdict = m.verdict == Verdict::kProficient ? "proficient" : m.verdict == Verdict::kNotYet ? "not yet proficient" : "not assessed (no bands)";
    std::FILE* text_out = json_to_stdout ? stderr : stdout;
    std::fprintf(text_out, "%s: %s, %zu of %zu banded metrics pass\n", in.file.c_str(), verdict, m.passed, m.banded);
    print_two_hands(text_out, m);
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return lancet::app::guarded_main([&] { return run(argc, argv); }, [](const std::string& m) { return fail(m); });
}
