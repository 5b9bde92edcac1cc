// A cohort as text and as a page (records/cohort_page.hpp).

#include "records/cohort_page.hpp"

#include <algorithm>
#include <map>

#include "records/svg_chart.hpp"
#include "text/text.hpp"

namespace lancet::records {
namespace {

using text::xml_escape;

// The current step's scenario, "done" when there is none.
std::string current_step(const CohortMember& m) {
  return m.progress.next ? std::to_string(*m.progress.next + 1) + ". " + m.progress.steps[*m.progress.next].step.scenario : std::string("done");
}

// Per step (and one more: done), how many trainees are on it and how many of them are stuck.
struct StepCount {
  std::size_t on = 0, stuck = 0;
};
std::vector<StepCount> step_counts(const Cohort& c) {
  std::vector<StepCount> counts(c.steps.size() + 1);
  for (const CohortMember& m : c.members) {
    StepCount& k = counts[m.progress.next ? *m.progress.next : c.steps.size()];
    ++k.on;
    if (m.stuck) ++k.stuck;
  }
  return counts;
}

// Horizontal bars, one per step: trainees on it, the stuck ones in red.
std::string step_chart(const Cohort& c) {
  const std::vector<StepCount> counts = step_counts(c);
  const double row = 24, label_w = 240, bar_w = 420, top = 8;
  const double height = top + row * static_cast<double>(counts.size()) + 8;
  std::size_t most = 1;
  for (const StepCount& k : counts) most = std::max(most, k.on);
  std::string s = "<svg id=\"steps-chart\" xmlns=\"http://www.w3.org/2000/svg\" width=\"" + html::num(label_w + bar_w + 140, 0) + "\" height=\"" +
                  html::num(height, 0) + "\" role=\"img\" aria-label=\"trainees per step\">\n";
  for (std::size_t i = 0; i < counts.size(); ++i) {
    const double y = top + row * static_cast<double>(i);
    const std::string label = i < c.steps.size() ? std::to_string(i + 1) + ". " + c.steps[i] : std::string("done");
    const double on = bar_w * static_cast<double>(counts[i].on) / static_cast<double>(most);
    const double stuck = bar_w * static_cast<double>(counts[i].stuck) / static_cast<double>(most);
    s += "<text x=\"" + html::num(label_w - 6) + "\" y=\"" + html::num(y + 15) + "\" text-anchor=\"end\">" + xml_escape(label) + "</text>";
    s += "<rect class=\"bar-on\" x=\"" + html::num(label_w) + "\" y=\"" + html::num(y + 3) + "\" width=\"" + html::num(on) + "\" height=\"18\"/>";
    s += "<rect class=\"bar-stuck\" x=\"" + html::num(label_w) + "\" y=\"" + html::num(y + 3) + "\" width=\"" + html::num(stuck) + "\" height=\"18\"/>";
    s += "<text x=\"" + html::num(label_w + on + 5) + "\" y=\"" + html::num(y + 15) + "\">" + std::to_string(counts[i].on) +
         (counts[i].stuck > 0 ? " (" + std::to_string(counts[i].stuck) + " stuck)" : std::string()) + "</text>\n";
  }
  return s + "</svg>\n";
}

}  // namespace

Cohort cohort(const std::string& name, const std::vector<Trainee>& trainees, const Curriculum& curriculum, const std::vector<Attempt>& attempts,
              std::size_t stuck_after) {
  Cohort c;
  c.name = name;
  c.curriculum = curriculum.name;
  c.stuck_after = stuck_after;
  for (const CurriculumStep& s : curriculum.steps) c.steps.push_back(s.scenario);
  std::map<std::string, std::vector<Attempt>> by_trainee;
  for (const Attempt& a : attempts) by_trainee[a.trainee_id].push_back(a);
  for (const Trainee& t : trainees) {
    const std::vector<Attempt>& own = by_trainee[t.id];
    CohortMember m;
    m.progress = progress(t, curriculum, own);
    m.attempts = own.size();
    for (const Attempt& a : own) m.last_attempt = std::max(m.last_attempt, a.started);
    if (m.progress.next) m.on_step = m.progress.steps[*m.progress.next].standing.attempts;
    m.stuck = m.progress.next && m.on_step >= stuck_after;
    c.members.push_back(std::move(m));
  }
  return c;
}

std::string cohort_text(const Cohort& c) {
  std::string s = text::format("cohort \"%s\", curriculum \"%s\": %zu trainees; stuck: %zu or more attempts at the current step without meeting it\n",
                               c.name.c_str(), c.curriculum.c_str(), c.members.size(), c.stuck_after);
  for (const CohortMember& m : c.members) {
    const Trainee& t = m.progress.trainee;
    s += text::format("  %-12s %-24s %-28s %3zu at it, %4zu attempts, last %s%s\n", t.id.c_str(), t.name.c_str(), current_step(m).c_str(), m.on_step,
                      m.attempts, m.last_attempt.empty() ? "never" : m.last_attempt.c_str(), m.stuck ? "  STUCK" : "");
  }
  const std::vector<StepCount> counts = step_counts(c);
  for (std::size_t i = 0; i < counts.size(); ++i) {
    const std::string label = i < c.steps.size() ? std::to_string(i + 1) + ". " + c.steps[i] : std::string("done");
    s += text::format("  on %-28s %zu trainees, %zu stuck\n", label.c_str(), counts[i].on, counts[i].stuck);
  }
  return s;
}

std::string cohort_html(const Cohort& c) {
  std::string s = html::page_head("Cohort " + c.name);
  std::size_t stuck = 0;
  for (const CohortMember& m : c.members) stuck += m.stuck ? 1 : 0;
  s += "<h1>Cohort " + xml_escape(c.name) + "</h1>\n<p>Curriculum: <b>" + xml_escape(c.curriculum) + "</b>. " + std::to_string(c.members.size()) +
       " trainees, <b id=\"stuck-count\">" + std::to_string(stuck) + "</b> stuck. A trainee is <i>stuck</i> after " + std::to_string(c.stuck_after) +
       " or more attempts at the current step without meeting its rule (<code>--stuck-after N</code>).</p>\n";
  s += "<h2>Trainees per step</h2>\n" + step_chart(c);
  s += "<h2>Trainees</h2>\n<table id=\"trainees\"><tr><th>trainee</th><th>name</th><th>current step</th><th>attempts at it</th>"
       "<th>attempts</th><th>steps met</th><th>last attempt</th><th></th></tr>\n";
  for (const CohortMember& m : c.members) {
    const Trainee& t = m.progress.trainee;
    std::size_t met = 0;
    for (const StepProgress& sp : m.progress.steps) met += sp.standing.proficient ? 1 : 0;
    s += std::string(m.stuck ? "<tr class=\"stuck\">" : "<tr>") + "<td>" + xml_escape(t.id) + "</td><td>" + xml_escape(t.name) + "</td><td>" +
         xml_escape(current_step(m)) + "</td><td class=\"num\">" + std::to_string(m.on_step) + "</td><td class=\"num\">" + std::to_string(m.attempts) +
         "</td><td class=\"num\">" + std::to_string(met) + " / " + std::to_string(c.steps.size()) + "</td><td>" +
         (m.last_attempt.empty() ? std::string("never") : xml_escape(m.last_attempt)) + "</td><td>" + (m.stuck ? "stuck" : "") + "</td></tr>\n";
  }
  return s + "</table>\n" + html::page_tail();
}

}  // namespace lancet::records
