// The learning-curve CUSUM, and the progress and cohort pages' content (the numbers, the links,
// the escaping), from attempts made by hand.

#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "records/cohort_page.hpp"
#include "records/cusum.hpp"
#include "records/progress_page.hpp"
#include "synthetic_attempts.hpp"

namespace lancet::records {
namespace {

using test::learning_attempt;

std::size_t count(const std::string& s, const std::string& what) {
  std::size_t n = 0;
  for (std::size_t at = s.find(what); at != std::string::npos; at = s.find(what, at + what.size())) ++n;
  return n;
}

TEST(Cusum, DesignIsWaldsFromTheRates) {
  const CusumRule rule;  // p0 0.2, p1 0.4, alpha = beta = 0.1
  ASSERT_TRUE(valid(rule));
  const CusumDesign d = design(rule);
  const double p = std::log(2.0), q = std::log(0.8 / 0.6);
  EXPECT_NEAR(d.s, q / (p + q), 1e-12);
  EXPECT_NEAR(d.s, 0.2933, 1e-4);
  EXPECT_NEAR(d.h0, std::log(9.0) / (p + q), 1e-12);
  EXPECT_NEAR(d.h1, d.h0, 1e-12);  // alpha == beta
  EXPECT_NEAR(d.h1, 2.2401, 1e-4);
  // Unequal error rates: h1 follows alpha, h0 follows beta.
  const CusumDesign e = design(CusumRule{0.1, 0.3, 0.05, 0.2});
  EXPECT_NEAR(e.h1, std::log(0.8 / 0.05) / (std::log(3.0) + std::log(0.9 / 0.7)), 1e-12);
  EXPECT_NEAR(e.h0, std::log(0.95 / 0.2) / (std::log(3.0) + std::log(0.9 / 0.7)), 1e-12);
}

TEST(Cusum, InvalidRulesAreRefused) {
  EXPECT_FALSE(valid(CusumRule{0.4, 0.2, 0.1, 0.1}));
  EXPECT_FALSE(valid(CusumRule{0.2, 0.2, 0.1, 0.1}));
  EXPECT_FALSE(valid(CusumRule{0, 0.2, 0.1, 0.1}));
  EXPECT_FALSE(valid(CusumRule{0.2, 1, 0.1, 0.1}));
  EXPECT_FALSE(valid(CusumRule{0.2, 0.4, 0, 0.1}));
  EXPECT_FALSE(valid(CusumRule{0.2, 0.4, 0.1, 1}));
}

TEST(Cusum, FailuresClimbSuccessesFallAndTheLimitsSignal) {
  const CusumDesign d = design(CusumRule{});
  const bool fails[6] = {false, false, false, false, false, false};
  const CusumResult up = cusum(d, fails);
  ASSERT_EQ(up.sum.size(), 6u);
  EXPECT_NEAR(up.sum[0], 1 - d.s, 1e-12);
  EXPECT_NEAR(up.sum[5], 6 * (1 - d.s), 1e-12);
  EXPECT_EQ(up.unacceptable_at, 4u);  // 3 × 0.707 = 2.12 < 2.24 <= 4 × 0.707
  EXPECT_EQ(up.acceptable_at, 0u);

  std::vector<char> passes(12, 1);
  const CusumResult down = cusum(d, std::span<const bool>(reinterpret_cast<const bool*>(passes.data()), passes.size()));
  EXPECT_NEAR(down.sum[11], -12 * d.s, 1e-12);
  EXPECT_EQ(down.acceptable_at, 8u);  // 7 × 0.293 = 2.05 < 2.24 <= 8 × 0.293
  EXPECT_EQ(down.unacceptable_at, 0u);

  // At the failure rate s the sum drifts neither way: one failure, then successes s/(1-s)... in the
  // simplest case p0 = 1 - p1 makes s = 1/2 and a pass after a fail returns it to 0.
  const CusumDesign half = design(CusumRule{0.3, 0.7, 0.1, 0.1});
  EXPECT_NEAR(half.s, 0.5, 1e-12);
  const bool alternate[4] = {false, true, false, true};
  EXPECT_NEAR(cusum(half, alternate).sum[3], 0, 1e-12);
  EXPECT_TRUE(cusum(d, std::span<const bool>()).sum.empty());
}

// A trainee with 16 attempts at "incision" (learning), 2 at "suture" and one outside the curriculum.
struct Fixture {
  Trainee trainee{"t<1>", "Ann & \"Bo\" <script>", "c&1"};
  Curriculum curriculum{"Basics <1>", {{"incision", "h-incision", 3, 2}, {"suture", "h-suture", 2, 2}, {"knot", "h-knot", 1, 1}}};
  std::vector<Attempt> attempts;
  Fixture() {
    for (int i = 0; i < 16; ++i) attempts.push_back(learning_attempt(trainee.id, "incision", i));
    for (int i = 0; i < 2; ++i) attempts.push_back(learning_attempt(trainee.id, "suture", i, 1));
    attempts.push_back(learning_attempt(trainee.id, "elsewhere", 0, 2));
    attempts.back().recording = "/data/my recordings/a#1<x>.h5";
  }
};

TEST(ProgressPage, HoldsTheStandingCurvesCusumAndLinks) {
  const Fixture f;
  const Progress p = progress(f.trainee, f.curriculum, f.attempts);
  ASSERT_TRUE(p.steps[0].standing.proficient);
  const std::size_t met_at = p.steps[0].standing.proficient_at;
  std::size_t incision_passes = 0;
  for (int i = 0; i < 16; ++i) incision_passes += f.attempts[static_cast<std::size_t>(i)].proficient ? 1 : 0;
  const std::string page = progress_html(p, f.attempts, ProgressPageOptions{{}, "/data", {}});

  EXPECT_EQ(page.rfind("<!DOCTYPE html>", 0), 0u);
  EXPECT_EQ(page.find("<script"), std::string::npos) << "no script, and the name is escaped";
  EXPECT_NE(page.find("Ann &amp; &quot;Bo&quot; &lt;script&gt;"), std::string::npos);
  EXPECT_NE(page.find("t&lt;1&gt;"), std::string::npos);
  EXPECT_NE(page.find("Basics &lt;1&gt;"), std::string::npos);
  EXPECT_EQ(page.find("http://"), page.find("http://www.w3.org/2000/svg")) << "no link off the machine";
  EXPECT_NE(page.find("met at attempt " + std::to_string(met_at)), std::string::npos);
  // The next step (suture: two attempts, not met) is the highlighted row.
  const std::size_t next_row = page.find("<tr class=\"next\">");
  ASSERT_NE(next_row, std::string::npos);
  EXPECT_NE(page.substr(next_row, 200).find("suture"), std::string::npos);
  EXPECT_EQ(count(page, "<tr class=\"next\">"), 1u);
  EXPECT_NE(page.find("<b id=\"next\">suture</b>"), std::string::npos);
  // Per step with attempts: a CUSUM and three learning curves; the knot step has none.
  EXPECT_EQ(count(page, "<figure class=\"cusum\">"), 2u);
  EXPECT_EQ(count(page, "<figure class=\"curve\""), 6u);
  EXPECT_NE(page.find("No attempts yet."), std::string::npos);
  EXPECT_NE(page.find("data-metric=\"incision_coverage_pct\""), std::string::npos);
  // Markers: one per measured value, pass/fail as the metric's.
  std::size_t passes = 0, fails = 0;
  for (const Attempt& a : f.attempts) {
    if (a.scenario == "elsewhere") continue;
    for (const AttemptMetric& m : a.metrics) (m.pass ? passes : fails) += 1;
  }
  EXPECT_EQ(count(page, "<circle class=\"pass\""), passes);
  EXPECT_EQ(count(page, "<circle class=\"fail\""), fails);
  // The CUSUM's parameters are stated.
  EXPECT_NE(page.find("p0 = 0.2, unacceptable p1 = 0.4, alpha = 0.1, beta = 0.1"), std::string::npos);
  EXPECT_NE(page.find("h1 = 2.24"), std::string::npos);
  EXPECT_NE(page.find(std::to_string(incision_passes) + " proficient"), std::string::npos);
  // Every attempt in the table, linked relative to the page's folder and percent-encoded.
  EXPECT_EQ(count(page, "<a href=\"recordings/t%3C1%3E/"), 18u);
  EXPECT_NE(page.find("href=\"my%20recordings/a%231%3Cx%3E.h5\""), std::string::npos);
  EXPECT_NE(page.find("/data/my recordings/a#1&lt;x&gt;.h5</a>"), std::string::npos);
  EXPECT_NE(page.find("1 attempts at scenarios outside the curriculum"), std::string::npos);
}

TEST(ProgressPage, WithoutAPageFolderLinksAreAsStored) {
  Fixture f;
  f.attempts.resize(1);
  f.attempts[0].recording = "rel/a b.h5";
  const std::string page = progress_html(progress(f.trainee, f.curriculum, f.attempts), f.attempts, {});
  EXPECT_NE(page.find("href=\"rel/a%20b.h5\""), std::string::npos);
}

TEST(CohortPage, StepsAttemptsAndWhoIsStuck) {
  const Curriculum curriculum{"Basics", {{"incision", "h-incision", 3, 3}, {"suture", "h-suture", 1, 1}}};
  const std::vector<Trainee> trainees{{"a", "Al <A>", "k"}, {"b", "Bea", "k"}, {"c", "Cy", "k"}};
  std::vector<Attempt> attempts;
  for (int i = 0; i < 4; ++i) {  // a: four failures on incision: stuck with stuck_after 4
    attempts.push_back(learning_attempt("a", "incision", 0, i));
  }
  for (int i = 0; i < 30; ++i) attempts.push_back(learning_attempt("b", "incision", i));  // b: learns it, on to suture
  const Cohort c = cohort("k", trainees, curriculum, attempts, 4);
  ASSERT_EQ(c.members.size(), 3u);
  EXPECT_TRUE(c.members[0].stuck);
  EXPECT_EQ(c.members[0].on_step, 4u);
  EXPECT_EQ(*c.members[0].progress.next, 0u);
  EXPECT_EQ(c.members[0].last_attempt, "2026-11-04T08:00:00Z");
  EXPECT_FALSE(c.members[1].stuck);
  EXPECT_EQ(*c.members[1].progress.next, 1u);
  EXPECT_EQ(c.members[1].attempts, 30u);
  EXPECT_EQ(c.members[1].on_step, 0u);
  EXPECT_FALSE(c.members[2].stuck);
  EXPECT_EQ(c.members[2].last_attempt, "");

  const std::string text = cohort_text(c);
  EXPECT_NE(text.find("STUCK"), std::string::npos) << text;
  EXPECT_NE(text.find("never"), std::string::npos) << text;
  EXPECT_NE(text.find("on 1. incision"), std::string::npos) << text;

  const std::string page = cohort_html(c);
  EXPECT_NE(page.find("Al &lt;A&gt;"), std::string::npos);
  EXPECT_EQ(page.find("Al <A>"), std::string::npos);
  EXPECT_EQ(count(page, "<tr class=\"stuck\">"), 1u);
  EXPECT_NE(page.find("<b id=\"stuck-count\">1</b>"), std::string::npos);
  EXPECT_NE(page.find("after 4 or more attempts"), std::string::npos);
  EXPECT_NE(page.find(">2 (1 stuck)</text>"), std::string::npos);  // a and c on incision, a stuck
  EXPECT_EQ(count(page, "<rect class=\"bar-on\""), 3u);            // two steps and "done"
}

}  // namespace
}  // namespace lancet::records
