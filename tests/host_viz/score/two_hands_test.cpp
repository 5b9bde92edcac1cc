// Two hands in the score: on a synthetic two-handed recording whose figures are known by
// construction, each hand's path and economy of motion, the left hand's idle time, the time both
// tools touch at once, the task window of either hand, the force of both hands counted per tick;
// the right hand's figures are those of the same motion recorded alone (interleaving changes
// nothing); a band on a two-hand metric is applied; the report has a Two hands section in the
// hands' colours only when there are two hands.

#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <string_view>

#include "score/metrics.hpp"
#include "score/report.hpp"
#include "synthetic_recording.hpp"

namespace lancet::score {

namespace test = record::test;
namespace {

using test::make_recording;
using test::make_two_hand_recording;
using test::parse_or_fail;

double value_of(const Metrics& m, std::string_view name) {
  const Metric* x = find_metric(m, name);
  EXPECT_NE(x, nullptr) << "no metric " << name;
  return x ? x->value : std::nan("");
}

std::size_t count(std::string_view text, std::string_view needle) {
  std::size_t n = 0;
  for (std::size_t at = text.find(needle); at != std::string_view::npos; at = text.find(needle, at + needle.size())) ++n;
  return n;
}

// The right hand's motion: 30 mm along the incision line (x from -15 to 15 mm at y = -12 mm) in
// 3 s, in contact throughout, 1 N on the hand but 4 N on ticks 1250..1349.
void right_hand(std::size_t i, double t, ToolSample& s) {
  s.tool.position = Vec3{-0.015 + 0.010 * t, -0.012, 0};
  s.force = Vec3{0, 0, i >= 1250 && i < 1350 ? 4.0 : 1.0};
  s.stage = Stage::kCutting;
}

// 3001 ticks (3 s). The right hand as above. The left hand holds still at (0, 20, 0) mm for 2 s,
// then moves 20 mm along y in the last second; it touches (a retractor pulling) on ticks
// 1000..1499 only, 5 N on ticks 1200..1299 and none otherwise.
Recording two_handed() {
  return make_two_hand_recording(3001, [](std::size_t i, double t, ToolSample& s) {
    if (s.hand == Hand::kRight) {
      right_hand(i, t, s);
      return;
    }
    s.tool.position = Vec3{0, 0.020 + 0.020 * std::max(0.0, t - 2.0), 0};
    s.stage = i >= 1000 && i < 1500 ? Stage::kPulling : Stage::kFree;
    s.force = Vec3{i >= 1200 && i < 1300 ? 5.0 : 0.0, 0, 0};
  });
}

TEST(TwoHands, FiguresKnownByConstruction) {
  const Recording rec = two_handed();
  const scenario::Scenario inc = parse_or_fail(test::incision_toml());
  const Metrics m = compute_metrics(rec, &inc);
  EXPECT_EQ(m.hands, 2u);
  EXPECT_EQ(value_of(m, "task_time_s"), 3.0);
  EXPECT_NEAR(value_of(m, "right_path_length_mm"), 30.0, 1e-9);
  EXPECT_NEAR(value_of(m, "left_path_length_mm"), 20.0, 1e-9);
  EXPECT_NEAR(value_of(m, "right_economy_of_motion_ratio"), 1.0, 1e-9);  // straight lines
  EXPECT_NEAR(value_of(m, "left_economy_of_motion_ratio"), 1.0, 1e-9);
  // Still for 2 s, holding the tissue on ticks 1000..1499: those ticks fall in blocks 9..14 (a
  // block holds the ticks in (start + k·100 ms, start + (k + 1)·100 ms]), six blocks of work, not
  // idleness: 14 idle blocks; then 20 mm/s, above the 5 mm/s threshold.
  EXPECT_NEAR(value_of(m, "left_idle_time_s"), 1.4, 1e-12);
  // Both touch on ticks 1000..1499: 500 ticks of 1 ms.
  EXPECT_EQ(value_of(m, "both_hands_contact_time_s"), 0.5);
  // The dominant hand's path and economy against the task line; the force of both.
  EXPECT_NEAR(value_of(m, "path_length_mm"), 30.0, 1e-9);
  EXPECT_NEAR(value_of(m, "economy_of_motion_ratio"), 1.0, 1e-9);
  EXPECT_EQ(value_of(m, "force_peak_n"), 5.0);                // the left hand's
  EXPECT_EQ(value_of(m, "time_above_force_limit_s"), 0.15);   // ticks 1200..1349, either hand, each once
  EXPECT_NEAR(value_of(m, "force_mean_n"), (2901 * 1.0 + 100 * 4.0) / 3001, 1e-12);  // the right hand's contact ticks
  // Whose each figure is.
  EXPECT_EQ(find_metric(m, "path_length_mm")->hand, HandScope::kRight);
  EXPECT_EQ(find_metric(m, "task_time_s")->hand, HandScope::kBoth);
  EXPECT_EQ(find_metric(m, "left_idle_time_s")->hand, HandScope::kLeft);
  EXPECT_EQ(find_metric(m, "both_hands_contact_time_s")->hand, HandScope::kBoth);
  EXPECT_EQ(find_metric(m, "blood_loss_ml")->hand, HandScope::kScene);
  EXPECT_NE(find_metric(m, "left_idle_time_s")->description.find("5 mm/s over 100 ms blocks"), std::string::npos);
  // The two-hand metrics come last, in their list's order.
  ASSERT_GE(m.metrics.size(), scenario::kTwoHandScoreMetrics.size());
  const std::size_t first = m.metrics.size() - scenario::kTwoHandScoreMetrics.size();
  for (std::size_t k = 0; k < scenario::kTwoHandScoreMetrics.size(); ++k) {
    EXPECT_EQ(m.metrics[first + k].name, scenario::kTwoHandScoreMetrics[k].name);
  }
}

TEST(TwoHands, InterleavingDoesNotChangeTheRightHandsFigures) {
  // The same right-hand motion recorded alone and beside a left hand that jumps around: every
  // right-hand figure is bit-identical.
  const Recording alone = make_recording(3001, right_hand);
  const Recording both = make_two_hand_recording(3001, [](std::size_t i, double t, ToolSample& s) {
    if (s.hand == Hand::kRight) {
      right_hand(i, t, s);
    } else {
      s.tool.position = Vec3{0.05 * std::sin(90 * t), 0.04, 0.01 * static_cast<double>(i % 2)};
      s.stage = Stage::kFree;
    }
  });
  const scenario::Scenario inc = parse_or_fail(test::incision_toml());
  const Metrics a = compute_metrics(alone, &inc), b = compute_metrics(both, &inc);
  for (const char* name : {"path_length_mm", "angular_path_rad", "economy_of_motion_ratio", "movement_count", "jerk_rms_m_s3",
                           "force_mean_n", "task_time_s"}) {
    EXPECT_EQ(value_of(a, name), value_of(b, name)) << name;
  }
  EXPECT_EQ(value_of(b, "right_path_length_mm"), value_of(a, "path_length_mm"));
  // Taken across the alternating samples the path would be many times longer.
  double interleaved = 0;
  for (std::size_t i = 1; i < both.samples.size(); ++i) interleaved += norm(both.samples[i].tool.position - both.samples[i - 1].tool.position);
  EXPECT_GT(interleaved * 1e3, 10 * value_of(b, "path_length_mm"));
  // One hand has none of the two-hand metrics.
  EXPECT_EQ(a.hands, 1u);
  for (const auto& info : scenario::kTwoHandScoreMetrics) EXPECT_EQ(find_metric(a, info.name), nullptr) << info.name;
}

TEST(TwoHands, TheTaskWindowSpansEitherHand) {
  // The right hand touches from 1.0 to 2.0 s, the left from 0.5 to 2.5 s: the window is 0.5..2.5 s,
  // the right hand's path over it (moving 10 mm/s throughout) 20 mm.
  const Recording rec = make_two_hand_recording(3001, [](std::size_t i, double t, ToolSample& s) {
    s.tool.position = Vec3{0.010 * t, s.hand == Hand::kRight ? 0.0 : 0.03, 0};
    const bool right = s.hand == Hand::kRight;
    s.stage = (right ? i >= 1000 && i <= 2000 : i >= 500 && i <= 2500) ? Stage::kDeform : Stage::kFree;
  });
  const Metrics m = compute_metrics(rec, nullptr);
  EXPECT_EQ(m.window_begin_s, 0.5);
  EXPECT_EQ(m.window_end_s, 2.5);
  EXPECT_EQ(value_of(m, "task_time_s"), 2.0);
  EXPECT_NEAR(value_of(m, "path_length_mm"), 20.0, 1e-9);
  EXPECT_EQ(value_of(m, "both_hands_contact_time_s"), 1.001);  // ticks 1000..2000
  EXPECT_EQ(value_of(m, "left_idle_time_s"), 0.0);             // 10 mm/s throughout
}

TEST(TwoHands, EconomyIsNotMeasuredForAHandThatEndsWhereItBegan) {
  // The left hand goes 10 mm out and back: it ends where it began.
  const Recording rec = make_two_hand_recording(2001, [](std::size_t, double t, ToolSample& s) {
    if (s.hand == Hand::kLeft) s.tool.position = Vec3{0.010 * (1 - std::abs(t - 1)), 0, 0};
  });
  const Metrics m = compute_metrics(rec, nullptr);
  EXPECT_NEAR(value_of(m, "left_path_length_mm"), 20.0, 1e-9);
  EXPECT_TRUE(std::isnan(value_of(m, "left_economy_of_motion_ratio")));
  EXPECT_TRUE(std::isnan(value_of(m, "right_economy_of_motion_ratio")));  // the right hand never moved
  EXPECT_EQ(value_of(m, "left_idle_time_s"), 0.0);
}

TEST(TwoHands, BandsApplyToTheTwoHandMetrics) {
  const scenario::Scenario s = parse_or_fail(test::incision_toml(
      "[score.bands]\nleft_idle_time_s = { mean = 0.8, sd = 0.25 }\nboth_hands_contact_time_s = { mean = 0.6, sd = 0.1 }\n"));
  ASSERT_EQ(s.score.bands.size(), 2u);
  const Metrics m = compute_metrics(two_handed(), &s);
  const Metric* idle = find_metric(m, "left_idle_time_s");
  ASSERT_NE(idle, nullptr);
  ASSERT_TRUE(idle->band.has_value());
  EXPECT_EQ(idle->band->limit, 1.3);
  EXPECT_FALSE(idle->pass);  // 1.4 s idle
  const Metric* both = find_metric(m, "both_hands_contact_time_s");
  ASSERT_NE(both, nullptr);
  EXPECT_TRUE(both->pass);  // 0.5 s >= 0.6 - 2 x 0.1
  EXPECT_EQ(m.verdict, Verdict::kNotYet);
  // On a one-handed attempt the same bands are not there to check.
  const Metrics one = compute_metrics(make_recording(100), &s);
  EXPECT_EQ(one.banded, 0u);
  EXPECT_EQ(one.verdict, Verdict::kNotAssessed);
}

// ---- the report --------------------------------------------------------------------------------

TEST(TwoHandsReport, TwoHandedHasTheSectionInTheHandsColours) {
  const Recording rec = two_handed();
  const scenario::Scenario inc = parse_or_fail(test::incision_toml());
  const ReportInput in{"both.h5", &rec, compute_metrics(rec, &inc)};
  const std::string page = report_html({in});
  EXPECT_EQ(count(page, "<h3>Two hands</h3>"), 1u);
  EXPECT_EQ(count(page, "<svg"), 3u);  // the right hand's path, the force, both hands' paths
  EXPECT_GE(count(page, "#4d80f2"), 3u);
  EXPECT_GE(count(page, "#f29926"), 3u);
  for (const auto& info : scenario::kTwoHandScoreMetrics) EXPECT_EQ(count(page, std::string(info.name)), 1u) << info.name;
  EXPECT_NE(page.find("<td>right</td>"), std::string::npos);  // the Hand column
  for (const char* bad : {">nan<", ">-nan<", ">inf<", ">-inf<"}) EXPECT_EQ(page.find(bad), std::string::npos) << bad;  // "dominant" has "nan"
  // Every plot stays within kMaxPlotPoints points.
  for (std::size_t at = page.find("<svg"); at != std::string::npos; at = page.find("<svg", at + 1)) {
    const std::string_view svg = std::string_view(page).substr(at, page.find("</svg>", at) - at);
    std::size_t points = 0;
    for (std::size_t p = svg.find("points=\""); p != std::string_view::npos; p = svg.find("points=\"", p + 1)) {
      points += count(svg.substr(p, svg.find('"', p + 8) - p), ",");
    }
    EXPECT_LE(points, kMaxPlotPoints);
  }

  const std::string json = report_json({in});
  EXPECT_NE(json.find("\"hands\": 2"), std::string::npos);
  EXPECT_NE(json.find("\"two_hands\": {\"dominant\": \"right\", \"right\": {\"colour\": \"#4d80f2\", \"path_length_mm\": 30"),
            std::string::npos)
      << json;
  EXPECT_NE(json.find("\"idle_time_s\": 1.4"), std::string::npos);
  EXPECT_NE(json.find("\"both_hands_contact_time_s\": 0.5"), std::string::npos);
  EXPECT_NE(json.find("\"left_idle_time_s\": {\"value\": 1.4"), std::string::npos);
  EXPECT_NE(json.find("\"hand\": \"left\""), std::string::npos);
  for (const char* bad : {": nan", ": -nan", ": inf", ": -inf"}) EXPECT_EQ(json.find(bad), std::string::npos) << bad;
}

TEST(TwoHandsReport, OneHandedHasNoTwoHandsSection) {
  const Recording rec = make_recording(3001, right_hand);
  const scenario::Scenario inc = parse_or_fail(test::incision_toml());
  const ReportInput in{"one.h5", &rec, compute_metrics(rec, &inc)};
  const std::string page = report_html({in});
  EXPECT_EQ(page.find("Two hands"), std::string::npos);
  EXPECT_EQ(page.find("#f29926"), std::string::npos);
  EXPECT_EQ(page.find("<th>Hand</th>"), std::string::npos);
  EXPECT_EQ(count(page, "<svg"), 2u);
  const std::string json = report_json({in});
  EXPECT_NE(json.find("\"hands\": 1"), std::string::npos);
  EXPECT_NE(json.find("\"two_hands\": null"), std::string::npos);
  for (const auto& info : scenario::kTwoHandScoreMetrics) EXPECT_EQ(json.find(std::string(info.name)), std::string::npos) << info.name;
}

}  // namespace
}  // namespace lancet::score
