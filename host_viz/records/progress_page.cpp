// A trainee's progress page (records/progress_page.hpp).

#include "records/progress_page.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <memory>

#include "records/svg_chart.hpp"
#include "text/text.hpp"

namespace lancet::records {
namespace {

using text::xml_escape;

// One metric over a trainee's attempts at one scenario.
struct Series {
  std::string name, unit, better;
  std::vector<const AttemptMetric*> at;  // at[i]: attempt i + 1's (null: the attempt has no such metric)
};

// The metrics of `attempts` in the order they first appear, each over every attempt.
std::vector<Series> metric_series(const std::vector<const Attempt*>& attempts) {
  std::vector<Series> out;
  std::map<std::string, std::size_t> index;
  for (std::size_t i = 0; i < attempts.size(); ++i) {
    for (const AttemptMetric& m : attempts[i]->metrics) {
      auto [it, added] = index.emplace(m.name, out.size());
      if (added) out.push_back(Series{m.name, m.unit, m.better, std::vector<const AttemptMetric*>(attempts.size(), nullptr)});
      out[it->second].at[i] = &m;
    }
  }
  return out;
}

// The step's rule met or not, in words.
std::string standing_cell(const Standing& st) {
  if (st.proficient) return "<td class=\"met\">met at attempt " + std::to_string(st.proficient_at) + "</td>";
  return "<td class=\"notyet\">not yet</td>";
}

std::string curriculum_table(const Progress& p) {
  std::string s = "<table id=\"curriculum\"><tr><th>step</th><th>scenario</th><th>rule</th><th>attempts</th><th>proficient</th>"
                  "<th>longest run</th><th>standing</th></tr>\n";
  for (std::size_t i = 0; i < p.steps.size(); ++i) {
    const StepProgress& sp = p.steps[i];
    const Standing& st = sp.standing;
    const bool next = p.next && *p.next == i;
    s += std::string(next ? "<tr class=\"next\">" : "<tr>") + "<td class=\"num\">" + std::to_string(i + 1) + "</td><td><a href=\"#step-" +
         std::to_string(i + 1) + "\">" + xml_escape(sp.step.scenario) + "</a>" + (next ? " (next)" : "") + "</td><td>" +
         std::to_string(sp.step.required) + " proficient, " + std::to_string(sp.step.consecutive) + " in a row</td><td class=\"num\">" +
         std::to_string(st.attempts) + "</td><td class=\"num\">" + std::to_string(st.passes) + "</td><td class=\"num\">" +
         std::to_string(st.longest_run) + "</td>" + standing_cell(st) + "</tr>\n";
  }
  return s + "</table>\n";
}

// The passing side of each run of attempts with the same band, shaded, with its limit and mean.
std::string band_runs(const html::Chart& c, const Series& m) {
  std::string s;
  const std::size_t n = m.at.size();
  for (std::size_t i = 0; i < n;) {
    const AttemptMetric* a = m.at[i];
    std::size_t j = i + 1;
    if (a == nullptr || !a->has_band) {
      i = j;
      continue;
    }
    while (j < n && m.at[j] != nullptr && m.at[j]->has_band && m.at[j]->band_limit == a->band_limit && m.at[j]->band_mean == a->band_mean) ++j;
    const double xa = c.sx(static_cast<double>(i) + 0.5), xb = c.sx(static_cast<double>(j) + 0.5);
    const double yl = c.sy(a->band_limit), edge = a->better == "higher" ? c.margin_top : c.height - c.margin_bottom;
    s += "<rect class=\"band\" x=\"" + html::num(xa) + "\" y=\"" + html::num(std::min(yl, edge)) + "\" width=\"" + html::num(xb - xa) +
         "\" height=\"" + html::num(std::abs(edge - yl)) + "\"/>";
    s += "<line class=\"limit\" x1=\"" + html::num(xa) + "\" x2=\"" + html::num(xb) + "\" y1=\"" + html::num(yl) + "\" y2=\"" + html::num(yl) + "\"/>";
    s += "<line class=\"mean\" x1=\"" + html::num(xa) + "\" x2=\"" + html::num(xb) + "\" y1=\"" + html::num(c.sy(a->band_mean)) + "\" y2=\"" +
         html::num(c.sy(a->band_mean)) + "\"/>\n";
    i = j;
  }
  return s;
}

// A metric's learning curve: the value of each attempt, its band, pass or fail.
std::string learning_curve(const Series& m, const std::string& id) {
  html::Chart c;
  const std::size_t n = m.at.size();
  c.x0 = 0.5;
  c.x1 = static_cast<double>(n) + 0.5;
  c.y0 = HUGE_VAL;
  c.y1 = -HUGE_VAL;
  for (const AttemptMetric* a : m.at) {
    if (a == nullptr) continue;
    for (const double v : {a->value, a->has_band ? a->band_limit : NAN, a->has_band ? a->band_mean : NAN}) {
      if (!std::isfinite(v)) continue;
      c.y0 = std::min(c.y0, v);
      c.y1 = std::max(c.y1, v);
    }
  }
  if (!(c.y0 <= c.y1)) c.y0 = c.y1 = 0;  // nothing measured
  c.pad_y(0.08);
  const std::string unit = m.unit.empty() ? "" : " (" + m.unit + ")";
  std::string s = "<figure class=\"curve\" data-metric=\"" + xml_escape(m.name) + "\">" +
                  c.open("learning curve of " + m.name, id, "attempt", m.name + unit, true);
  s += "<g clip-path=\"url(#" + id + ")\">" + band_runs(c, m);
  std::string line, marks;
  const double r = n > 150 ? 1.8 : n > 40 ? 2.6 : 3.6;
  for (std::size_t i = 0; i < n; ++i) {
    const AttemptMetric* a = m.at[i];
    if (a == nullptr || !std::isfinite(a->value)) continue;
    const double x = c.sx(static_cast<double>(i + 1)), y = c.sy(a->value);
    line += html::num(x) + "," + html::num(y) + " ";
    const char* cls = !a->has_band ? "noband" : a->pass ? "pass" : "fail";
    marks += "<circle class=\"" + std::string(cls) + "\" cx=\"" + html::num(x) + "\" cy=\"" + html::num(y) + "\" r=\"" + html::num(r) + "\"><title>attempt " +
             std::to_string(i + 1) + ": " + text::format("%.4g", a->value) + xml_escape(unit) + (a->has_band ? (a->pass ? ", pass" : ", fail") : "") +
             "</title></circle>";
  }
  s += "<polyline class=\"curve\" points=\"" + line + "\"/>\n" + marks + "</g></svg><figcaption>" + xml_escape(m.name) + xml_escape(unit) + ", " +
       xml_escape(m.better) + " is better; shaded: within the band (passes)</figcaption></figure>\n";
  return s;
}

// The CUSUM of failures at one scenario, with its decision limits and where the rule was met.
std::string cusum_chart(const CusumResult& r, const CusumDesign& d, const Standing& st, const std::string& id) {
  html::Chart c;
  c.width = 760;
  c.height = 240;
  c.x0 = 0;
  c.x1 = std::max<double>(1, static_cast<double>(r.sum.size()));
  c.y0 = -d.h0;
  c.y1 = d.h1;
  for (const double v : r.sum) {
    c.y0 = std::min(c.y0, v);
    c.y1 = std::max(c.y1, v);
  }
  c.pad_y(0.06);
  std::string s = "<figure class=\"cusum\">" + c.open("CUSUM of failures", id, "attempt", "CUSUM", true);
  s += c.hline(d.h1, "h1", "h1 = " + text::format("%.2f", d.h1) + ": failure rate unacceptable");
  s += c.hline(-d.h0, "h0", "-h0 = " + text::format("%.2f", -d.h0) + ": failure rate acceptable", false);
  s += c.hline(0, "grid", "");
  if (st.proficient) {
    const double x = c.sx(static_cast<double>(st.proficient_at));
    s += "<line class=\"met-at\" x1=\"" + html::num(x) + "\" x2=\"" + html::num(x) + "\" y1=\"" + html::num(c.margin_top) + "\" y2=\"" +
         html::num(c.height - c.margin_bottom) + "\"><title>rule met at attempt " + std::to_string(st.proficient_at) + "</title></line>";
  }
  std::string line = html::num(c.sx(0)) + "," + html::num(c.sy(0)) + " ";
  for (std::size_t i = 0; i < r.sum.size(); ++i) line += html::num(c.sx(static_cast<double>(i + 1))) + "," + html::num(c.sy(r.sum[i])) + " ";
  s += "<g clip-path=\"url(#" + id + ")\"><polyline class=\"cusum\" points=\"" + line + "\"/></g></svg><figcaption>";
  s += "CUSUM after " + std::to_string(r.sum.size()) + " attempts: " + text::format("%.2f", r.sum.empty() ? 0.0 : r.sum.back());
  if (r.acceptable_at > 0) s += "; reached -h0 (acceptable) at attempt " + std::to_string(r.acceptable_at);
  if (r.unacceptable_at > 0) s += "; reached h1 (unacceptable) at attempt " + std::to_string(r.unacceptable_at);
  if (st.proficient) s += "; the green vertical line: the curriculum's rule met";
  s += ". Going down: failing less often than s = " + text::format("%.3f", d.s) + " of attempts; up: more often";
  return s + "</figcaption></figure>\n";
}

// One curriculum step: its standing, its CUSUM and its metrics' learning curves.
std::string step_section(std::size_t i, const StepProgress& sp, const std::vector<const Attempt*>& at, const CusumDesign& d) {
  const std::string n = std::to_string(i + 1);
  std::string s = "<section class=\"step\" id=\"step-" + n + "\"><h2>" + n + ". " + xml_escape(sp.step.scenario) + "</h2>\n";
  s += "<p>" + std::to_string(at.size()) + " attempts, " + std::to_string(sp.standing.passes) + " proficient; needs " +
       std::to_string(sp.step.required) + ", " + std::to_string(sp.step.consecutive) + " in a row: " +
       (sp.standing.proficient ? "met at attempt " + std::to_string(sp.standing.proficient_at) : std::string("not yet")) + ".";
  if (sp.other_versions > 0) s += " " + std::to_string(sp.other_versions) + " scored against another version of the scenario's text.";
  s += "</p>\n";
  if (at.empty()) return s + "<p class=\"note\">No attempts yet.</p></section>\n";
  const auto passed = std::make_unique<bool[]>(at.size());
  for (std::size_t k = 0; k < at.size(); ++k) passed[k] = at[k]->proficient;
  s += cusum_chart(cusum(d, std::span<const bool>(passed.get(), at.size())), d, sp.standing, "cusum-" + n);
  s += "<h3>Learning curves</h3><div class=\"charts\">\n";
  const std::vector<Series> series = metric_series(at);
  for (std::size_t k = 0; k < series.size(); ++k) s += learning_curve(series[k], "curve-" + n + "-" + std::to_string(k + 1));
  return s + "</div></section>\n";
}

std::string attempts_table(const std::vector<Attempt>& attempts, const std::string& page_dir, const std::vector<std::string>& reports) {
  const bool with_reports = !reports.empty();
  std::string s = "<h2>Attempts</h2>\n<p class=\"note\">";
  s += with_reports ? "Each report is lancet-report's page for the attempt, written beside this page (none where the recording "
                      "could no longer be read). "
                    : "No report pages were written (<code>progress --reports</code> writes them): ";
  s += "The recording links open the recording itself (relative to this page's folder when it was imported by an absolute path, "
       "else as imported); <code>lancet-report RECORDING -o report.html</code> writes its report.</p>\n"
       "<table id=\"attempts\"><tr><th>#</th><th>started</th><th>scenario</th><th>at it</th><th>verdict</th>"
       "<th>passed / banded</th><th>duration</th>";
  s += with_reports ? "<th>report</th><th>recording</th></tr>\n" : "<th>recording</th></tr>\n";
  std::map<std::string, std::size_t> count;
  for (std::size_t i = 0; i < attempts.size(); ++i) {
    const Attempt& a = attempts[i];
    s += "<tr><td class=\"num\">" + std::to_string(i + 1) + "</td><td>" + xml_escape(a.started) + "</td><td>" + xml_escape(a.scenario) +
         "</td><td class=\"num\">" + std::to_string(++count[a.scenario]) + "</td><td class=\"" + (a.proficient ? "met" : "notyet") + "\">" +
         xml_escape(a.verdict) + "</td><td class=\"num\">" + std::to_string(a.passed) + " / " + std::to_string(a.banded) + "</td><td class=\"num\">" +
         html::num(a.duration_s) + " s</td>";
    if (with_reports) {
      const std::string& r = i < reports.size() ? reports[i] : std::string();
      s += r.empty() ? "<td class=\"note\">none</td>" : "<td><a class=\"report\" href=\"" + html::file_href(r, "") + "\">report</a></td>";
    }
    s += "<td><a href=\"" + html::file_href(a.recording, page_dir) + "\">" + xml_escape(a.recording) + "</a></td></tr>\n";
  }
  return s + "</table>\n";
}

}  // namespace

std::string progress_html(const Progress& p, const std::vector<Attempt>& attempts, const ProgressPageOptions& options) {
  const CusumRule& rule = options.cusum;
  const CusumDesign d = design(rule);
  std::string s = html::page_head("Progress of " + p.trainee.id);
  s += "<h1>" + xml_escape(p.trainee.name) + " <span class=\"note\">(" + xml_escape(p.trainee.id) + ")</span></h1>\n<p>Cohort: " +
       (p.trainee.cohort.empty() ? std::string("none") : xml_escape(p.trainee.cohort)) + ". Curriculum: <b>" + xml_escape(p.curriculum) + "</b>. " +
       std::to_string(attempts.size()) + " attempts. Next: <b id=\"next\">" +
       (p.next ? xml_escape(p.steps[*p.next].step.scenario) : std::string("none, the curriculum is done")) + "</b>.</p>\n";
  s += curriculum_table(p);
  if (p.outside > 0) s += "<p class=\"note\">" + std::to_string(p.outside) + " attempts at scenarios outside the curriculum (in the table below).</p>\n";
  s += "<p class=\"note\">The CUSUM (Williams et al. 1992; Bolsin &amp; Colson 2000): a failure is an attempt that is not proficient; "
       "acceptable failure rate p0 = " + text::format("%g", rule.p0) + ", unacceptable p1 = " + text::format("%g", rule.p1) +
       ", alpha = " + text::format("%g", rule.alpha) + ", beta = " + text::format("%g", rule.beta) + "; each failure adds 1 - s = " +
       text::format("%.3f", 1 - d.s) + ", each success subtracts s = " + text::format("%.3f", d.s) + ". Crossing h1 = " +
       text::format("%.2f", d.h1) + " upward signals an unacceptable failure rate; crossing -h0 = " + text::format("%.2f", -d.h0) +
       " downward, an acceptable one.</p>\n";
  for (std::size_t i = 0; i < p.steps.size(); ++i) {
    std::vector<const Attempt*> at;
    for (const Attempt& a : attempts) {
      if (a.scenario == p.steps[i].step.scenario) at.push_back(&a);
    }
    s += step_section(i, p.steps[i], at, d);
  }
  s += attempts_table(attempts, options.page_dir, options.reports);
  return s + html::page_tail();
}

}  // namespace lancet::records
