// A trainee's progress through the curriculum and the CSV export, from attempts made by hand.

#include <gtest/gtest.h>

#include <limits>

#include "records/progress.hpp"

namespace lancet::records {
namespace {

Attempt attempt(const std::string& hash, const std::string& scenario, bool proficient, const std::string& scenario_hash = "h") {
  Attempt a;
  a.content_hash = hash;
  a.trainee_id = "t1";
  a.scenario = scenario;
  a.scenario_hash = scenario_hash;
  a.proficient = proficient;
  return a;
}

const Curriculum kCurriculum{"basics", {{"a", "h", 2, 2}, {"b", "h", 1, 1}}};

TEST(Progress, StepsFollowTheRuleAndNextIsTheFirstNotProficient) {
  const std::vector<Attempt> attempts{attempt("1", "a", true), attempt("2", "b", true), attempt("3", "a", false), attempt("4", "a", true),
                                      attempt("5", "zz", true)};
  const Progress p = progress({"t1", "Al", "c"}, kCurriculum, attempts);
  ASSERT_EQ(p.steps.size(), 2u);
  EXPECT_EQ(p.steps[0].standing.attempts, 3u);
  EXPECT_EQ(p.steps[0].standing.passes, 2u);
  EXPECT_FALSE(p.steps[0].standing.proficient);  // never two in a row
  EXPECT_TRUE(p.steps[1].standing.proficient);
  ASSERT_TRUE(p.next.has_value());
  EXPECT_EQ(*p.next, 0u);
  EXPECT_EQ(p.outside, 1u);
  const std::string text = progress_text(p);
  EXPECT_NE(text.find("next: a"), std::string::npos) << text;
  EXPECT_NE(text.find("not yet"), std::string::npos) << text;
}

TEST(Progress, DoneWhenEveryStepIsProficient) {
  const std::vector<Attempt> attempts{attempt("1", "a", true), attempt("2", "a", true, "other"), attempt("3", "b", true)};
  const Progress p = progress({"t1", "Al", ""}, kCurriculum, attempts);
  EXPECT_FALSE(p.next.has_value());
  EXPECT_EQ(p.steps[0].other_versions, 1u);
  EXPECT_NE(progress_text(p).find("the curriculum is done"), std::string::npos);
}

TEST(ExportCsv, OneRowPerMetricQuotedAndExact) {
  Attempt a = attempt("1", "a", true);
  a.recording = "/data/with,comma \"q\".h5";
  a.metrics.push_back(AttemptMetric{"task_time_s", 0.1, "s", "lower", true, 30, 10, 2, 50, true, "both"});
  a.metrics.push_back(AttemptMetric{"jerk", std::numeric_limits<double>::quiet_NaN(), "m/s³", "lower", false, 0, 0, 0, 0, false, "right"});
  Attempt b = attempt("2", "b", false);
  b.trainee_id = "";
  const std::string csv = export_csv({a, b}, {{"t1", "Al", "c1"}});
  EXPECT_EQ(csv.rfind("trainee,name,cohort,scenario,", 0), 0u);
  EXPECT_NE(csv.find("t1,Al,c1,a,h,1,\"/data/with,comma \"\"q\"\".h5\","), std::string::npos) << csv;
  EXPECT_NE(csv.find(",task_time_s,0.1,s,lower,30,10,2,50,1,both\r\n"), std::string::npos) << csv;
  EXPECT_NE(csv.find(",jerk,,m/s³,lower,,,,,,right\r\n"), std::string::npos) << csv;
  // Header, two metric rows, one row for the attempt without metrics.
  std::size_t lines = 0;
  for (std::size_t i = csv.find("\r\n"); i != std::string::npos; i = csv.find("\r\n", i + 2)) ++lines;
  EXPECT_EQ(lines, 4u);
}

}  // namespace
}  // namespace lancet::records
