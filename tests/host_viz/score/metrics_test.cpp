// Skill metrics on synthetic recordings with known answers: path length and economy of a
// straight path, the angle of a steady rotation, the incision's deviation and coverage, time
// above the force limit, movements of a stop-go path, jerk of constant-velocity and cubic paths,
// bands and the verdict, the frames' figures, and that the result is a pure function.

#include "score/metrics.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <numbers>
#include <string>
#include <vector>

#include "synthetic_recording.hpp"

namespace lancet::score {

namespace test = record::test;
namespace {

using test::make_recording;
using test::parse_or_fail;

double value_of(const Metrics& m, std::string_view name) {
  const Metric* x = find_metric(m, name);
  EXPECT_NE(x, nullptr) << "no metric " << name;
  return x ? x->value : std::nan("");
}

::testing::AssertionResult near_rel(double got, double want, double rel) {
  if (std::abs(got - want) <= rel * std::abs(want)) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "got " << got << ", want " << want << " within " << rel << " relative";
}

// ---- time and motion ---------------------------------------------------------------------------

TEST(Metrics, StraightPathAtConstantSpeedHasItsLength) {
  // 1 s along (3, 4, 0)/5 at 25 mm/s: 25 mm.
  const Vec3 dir{0.6, 0.8, 0};
  const Recording rec = make_recording(1001, [&](std::size_t, double t, ToolSample& s) {
    s.tool.position = Vec3{-0.01, -0.012, 0} + (0.025 * t) * dir;
  });
  const double length_mm = norm(rec.samples.back().tool.position - rec.samples.front().tool.position) * 1e3;
  ASSERT_TRUE(near_rel(length_mm, 25, 1e-12));

  const scenario::Scenario inc = parse_or_fail(test::incision_toml());
  const Metrics m = compute_metrics(rec, &inc);
  EXPECT_TRUE(near_rel(value_of(m, "path_length_mm"), length_mm, 1e-9));
  EXPECT_EQ(value_of(m, "task_time_s"), 1.0);
  EXPECT_TRUE(near_rel(value_of(m, "economy_of_motion_ratio"), length_mm / 30.0, 1e-9));  // the line: 30 mm
  EXPECT_EQ(value_of(m, "angular_path_rad"), 0.0);  // identity orientation throughout

  const scenario::Scenario drill = parse_or_fail(test::drill_toml());
  const Metrics d = compute_metrics(rec, &drill);
  EXPECT_TRUE(near_rel(value_of(d, "economy_of_motion_ratio"), length_mm / 8.0, 1e-9));  // 2 x 4 mm deep
}

TEST(Metrics, PathCountsOnlyTheTaskWindow) {
  // Free motion before and after the contact does not count: 0.5 s of contact at 20 mm/s = 10 mm.
  const Recording rec = make_recording(2001, [](std::size_t i, double t, ToolSample& s) {
    s.tool.position = Vec3{0.02 * t, 0, 0};
    s.stage = i >= 500 && i <= 1000 ? Stage::kCutting : Stage::kFree;
  });
  const Metrics m = compute_metrics(rec, nullptr);
  EXPECT_TRUE(near_rel(value_of(m, "path_length_mm"), 10.0, 1e-9));
  EXPECT_EQ(value_of(m, "task_time_s"), 0.5);
  EXPECT_EQ(m.window_begin_s, 0.5);
  EXPECT_EQ(m.window_end_s, 1.0);
}

// Hamilton product a * b.
Quat multiply(Quat a, Quat b) {
  return Quat{a.w * b.w - a.x * b.x - a.y * b.y - a.z * b.z, a.w * b.x + a.x * b.w + a.y * b.z - a.z * b.y,
              a.w * b.y - a.x * b.z + a.y * b.w + a.z * b.x, a.w * b.z + a.x * b.y - a.y * b.x + a.z * b.w};
}

TEST(Metrics, AngularPathOfASteadyRotation) {
  // 1 rad about z over 1 s, then 0.5 rad back about x: 1.5 rad of turning.
  const Recording rec = make_recording(2001, [](std::size_t i, double t, ToolSample& s) {
    const double a = i <= 1000 ? t : 1.0;
    const double b = i <= 1000 ? 0.0 : 0.5 * (t - 1.0);
    const Quat qz{std::cos(a / 2), 0, 0, std::sin(a / 2)};
    const Quat qx{std::cos(b / 2), -std::sin(b / 2), 0, 0};
    s.tool.orientation = multiply(qz, qx);
  });
  const Metrics m = compute_metrics(rec, nullptr);
  EXPECT_TRUE(near_rel(value_of(m, "angular_path_rad"), 1.5, 1e-9));
}

// Stop 0.5 s, go 0.5 s at `speed`, stop 0.5 s, go 0.5 s, stop 0.5 s.
Recording stop_go(double speed) {
  return make_recording(2501, [speed](std::size_t, double t, ToolSample& s) {
    const double moving = std::clamp(t - 0.5, 0.0, 0.5) + std::clamp(t - 1.5, 0.0, 0.5);
    s.tool.position = Vec3{speed * moving, 0, 0};
  });
}

TEST(Metrics, StopGoStopGoIsTwoMovements) {
  const Metrics m = compute_metrics(stop_go(0.05), nullptr);  // 50 mm/s against the default 20
  EXPECT_EQ(value_of(m, "movement_count"), 2.0);
  const Metric* x = find_metric(m, "movement_count");
  ASSERT_NE(x, nullptr);
  EXPECT_NE(x->description.find("20 mm/s"), std::string::npos) << x->description;  // the report states both
  EXPECT_NE(x->description.find("10 Hz"), std::string::npos) << x->description;
  // Slower than the threshold: none.
  EXPECT_EQ(value_of(compute_metrics(stop_go(0.015), nullptr), "movement_count"), 0.0);
  // The scenario's threshold is used.
  const scenario::Scenario s = parse_or_fail(test::incision_toml("[score]\nmovement_speed_mm_s = 10\n"));
  EXPECT_EQ(value_of(compute_metrics(stop_go(0.015), &s), "movement_count"), 2.0);
}

TEST(Metrics, JerkOfConstantVelocityIsZero) {
  // The filter settles during 0.5 s of free motion at the same velocity before the contact.
  const Recording rec = make_recording(2001, [](std::size_t i, double t, ToolSample& s) {
    s.tool.position = Vec3{0.03 * t, -0.01 * t, 0.002};
    s.stage = i >= 500 ? Stage::kDeform : Stage::kFree;
  });
  const Metrics m = compute_metrics(rec, nullptr);
  EXPECT_LT(value_of(m, "jerk_rms_m_s3"), 1e-4);  // rounding of m-sized positions over (1 ms)^3
}

TEST(Metrics, JerkOfACubicPathIsSixA) {
  // x = a t^3 from rest: jerk 6a. The 10 Hz filter's start-up (time constant 16 ms) takes about
  // 1.5 x 16 ms / 2 s off the mean square: under 1 % here.
  constexpr double a = 0.005;  // m/s^3: 40 mm in 2 s
  const Recording rec = make_recording(2001, [](std::size_t, double t, ToolSample& s) { s.tool.position = Vec3{a * t * t * t, 0, 0}; });
  const Metrics m = compute_metrics(rec, nullptr);
  EXPECT_TRUE(near_rel(value_of(m, "jerk_rms_m_s3"), 6 * a, 0.03));
}

TEST(Metrics, NoInteractionLeavesTheWindowMetricsUnmeasured) {
  const Recording rec = make_recording(100, [](std::size_t, double, ToolSample& s) { s.stage = Stage::kFree; });
  const Metrics m = compute_metrics(rec, nullptr);
  for (const char* name : {"task_time_s", "path_length_mm", "movement_count", "jerk_rms_m_s3", "force_mean_n"}) {
    EXPECT_TRUE(std::isnan(value_of(m, name))) << name;
  }
  EXPECT_TRUE(std::isnan(m.window_begin_s));
  EXPECT_FALSE(m.notes.empty());
}

// ---- force -------------------------------------------------------------------------------------

TEST(Metrics, TimeAboveTheForceLimitIsExact) {
  // |F| = (i + 0.5) mN over 10 000 ticks: above 3 N from tick 3000 on, 7000 ticks = 7 s.
  const Recording rec = make_recording(10'000, [](std::size_t i, double, ToolSample& s) {
    const double f = (static_cast<double>(i) + 0.5) * 1e-3;
    s.force = Vec3{0.6 * f, 0, 0.8 * f};
  });
  const Metrics m = compute_metrics(rec, nullptr);  // the default limit: 3 N
  EXPECT_EQ(m.score.force_limit, 3.0);
  EXPECT_EQ(value_of(m, "time_above_force_limit_s"), 7.0);
  EXPECT_TRUE(near_rel(value_of(m, "force_peak_n"), 9.9995, 1e-12));
  EXPECT_TRUE(near_rel(value_of(m, "force_mean_n"), 5.0, 1e-9));
  // The scenario's limit: above 4.5 N from tick 4500 on, 5500 ticks.
  const scenario::Scenario s = parse_or_fail(test::incision_toml("[score]\nforce_limit_n = 4.5\n"));
  EXPECT_EQ(value_of(compute_metrics(rec, &s), "time_above_force_limit_s"), 5.5);
}

TEST(Metrics, MeanForceCountsOnlyContactTicks) {
  const Recording rec = make_recording(1000, [](std::size_t i, double, ToolSample& s) {
    s.stage = i < 500 ? Stage::kFree : Stage::kDeform;
    s.force = i < 500 ? Vec3{0, 0, 5} : Vec3{0, 0, 2};  // a force while free (a virtual wall) is not tissue
  });
  const Metrics m = compute_metrics(rec, nullptr);
  EXPECT_EQ(value_of(m, "force_mean_n"), 2.0);
  EXPECT_EQ(value_of(m, "force_peak_n"), 5.0);
}

// ---- the incision ------------------------------------------------------------------------------

// A cut progress event every 0.5 mm from x0 to x1 (mm) at y (mm), starting with a rupture.
void cut(Recording& rec, std::size_t& tick, double x0, double x1, double y) {
  ToolSample& r = rec.samples.at(tick++);
  r.events |= event::kRupture | event::kContactBegin;
  r.payload = EventPayload{Vec3{x0 * 1e-3, y * 1e-3, -0.004}, 3.2};
  for (double x = x0 + 0.5; x <= x1 + 1e-9; x += 0.5) {
    ToolSample& s = rec.samples.at(tick++);
    s.events |= event::kCutProgress;
    s.payload = EventPayload{Vec3{x * 1e-3, y * 1e-3, -0.004}, 0};
  }
}

TEST(Metrics, DeviationOfCutPointsTwoMillimetresOffTheLine) {
  Recording rec = make_recording(200);
  std::size_t tick = 10;
  cut(rec, tick, -15, 15, -10);  // the line is at y = -12 mm
  const scenario::Scenario s = parse_or_fail(test::incision_toml());
  const Metrics m = compute_metrics(rec, &s);
  EXPECT_TRUE(near_rel(value_of(m, "incision_deviation_mean_mm"), 2.0, 1e-9));
  EXPECT_TRUE(near_rel(value_of(m, "incision_deviation_max_mm"), 2.0, 1e-9));
  EXPECT_GT(value_of(m, "incision_coverage_pct"), 99.0);  // within the 3 mm tolerance all along
  EXPECT_EQ(find_metric(m, "drill_progress_pct"), nullptr);
  EXPECT_EQ(find_metric(m, "drilled_outside_mm3"), nullptr);
}

TEST(Metrics, CoverageSplitsTheCutsAtEachRupture) {
  // Two 10 mm cuts with a 10 mm gap: two thirds of the line. Joined, they would cover it all.
  Recording rec = make_recording(200);
  std::size_t tick = 10;
  cut(rec, tick, -15, -5, -12);
  cut(rec, tick, 5, 15, -12);
  const scenario::Scenario s = parse_or_fail(test::incision_toml());
  const Metrics m = compute_metrics(rec, &s);
  EXPECT_NEAR(value_of(m, "incision_coverage_pct"), 200.0 / 3.0, 2.0);
  EXPECT_NEAR(value_of(m, "incision_deviation_max_mm"), 0.0, 1e-9);
}

TEST(Metrics, NoCutLeavesTheDeviationUnmeasured) {
  const scenario::Scenario s = parse_or_fail(test::incision_toml());
  const Metrics m = compute_metrics(make_recording(100), &s);
  EXPECT_TRUE(std::isnan(value_of(m, "incision_deviation_mean_mm")));
  EXPECT_EQ(value_of(m, "incision_coverage_pct"), 0.0);
}

// ---- the frames' figures -----------------------------------------------------------------------

TEST(Metrics, DamageAndBloodFromTheLastFrame) {
  Recording rec = make_recording(100);
  rec.frames.resize(3);
  rec.frames[1].damaged = 0b01;
  rec.frames[1].blood_lost_ml = 0.4;
  rec.frames[2].damaged = 0b11;
  rec.frames[2].blood_lost_ml = 1.25;
  rec.frames[2].task_progress = 0.8;
  rec.frames[2].drilled_outside_mm3 = 3.5;
  const scenario::Scenario inc = parse_or_fail(test::incision_toml());
  const Metrics m = compute_metrics(rec, &inc);
  EXPECT_EQ(value_of(m, "damaged_structures_count"), 2.0);
  EXPECT_EQ(m.damaged, (std::vector<std::string>{"radial artery", "nerve <b>"}));
  EXPECT_EQ(value_of(m, "blood_loss_ml"), 1.25);

  const scenario::Scenario drill = parse_or_fail(test::drill_toml());
  const Metrics d = compute_metrics(rec, &drill);
  EXPECT_EQ(value_of(d, "drill_progress_pct"), 80.0);
  EXPECT_EQ(value_of(d, "drilled_outside_mm3"), 3.5);
  EXPECT_EQ(d.damaged, (std::vector<std::string>{"avoid[0]", "avoid[1]"}));  // the drill scenario lists none
  EXPECT_EQ(find_metric(d, "incision_coverage_pct"), nullptr);
}

TEST(Metrics, NoFramesLeavesTheirFiguresUnmeasured) {
  const Metrics m = compute_metrics(make_recording(10), nullptr);
  EXPECT_TRUE(std::isnan(value_of(m, "damaged_structures_count")));
  EXPECT_TRUE(std::isnan(value_of(m, "blood_loss_ml")));
}

// ---- bands and the verdict ---------------------------------------------------------------------

Recording scored_attempt() {
  // 1 s of contact, 25 mm of path, peak force 2 N, one clean cut along the whole line.
  Recording rec = make_recording(1001, [](std::size_t, double t, ToolSample& s) {
    s.tool.position = Vec3{-0.0125 + 0.025 * t, -0.012, 0};
    s.force = Vec3{0, 0, 2};
  });
  std::size_t tick = 100;
  cut(rec, tick, -15, 15, -12);
  rec.frames.resize(1);
  return rec;
}

TEST(MetricsBands, PassFailAndTheVerdict) {
  const Recording rec = scored_attempt();
  // Time 1 s: passes <= 0.8 + 2 x 0.2 = 1.2. Coverage ~100 %: passes >= 95 - 2 x 2 = 91.
  const scenario::Scenario ok = parse_or_fail(test::incision_toml(
      "[score.bands]\ntask_time_s = { mean = 0.8, sd = 0.2 }\nincision_coverage_pct = { mean = 95, sd = 2 }\n"));
  const Metrics m = compute_metrics(rec, &ok);
  EXPECT_EQ(m.banded, 2u);
  EXPECT_EQ(m.passed, 2u);
  EXPECT_EQ(m.verdict, Verdict::kProficient);
  const Metric* t = find_metric(m, "task_time_s");
  ASSERT_NE(t, nullptr);
  ASSERT_TRUE(t->band.has_value());
  EXPECT_EQ(t->band->mean, 0.8);
  EXPECT_EQ(t->band->sd, 0.2);
  EXPECT_EQ(t->band->k, 2.0);
  EXPECT_NEAR(t->band->limit, 1.2, 1e-12);
  EXPECT_TRUE(t->pass);
  EXPECT_FALSE(find_metric(m, "path_length_mm")->band.has_value());
  EXPECT_FALSE(find_metric(m, "path_length_mm")->pass);

  // k = 1: time passes up to 0.9 + 0.2 = 1.1 s; path 25 mm > 20 + 1 x 4: fails.
  const scenario::Scenario strict = parse_or_fail(test::incision_toml(
      "[score]\nsd_multiple = 1\n[score.bands]\ntask_time_s = { mean = 0.9, sd = 0.2 }\npath_length_mm = { mean = 20, sd = 4 }\n"));
  const Metrics f = compute_metrics(rec, &strict);
  EXPECT_TRUE(find_metric(f, "task_time_s")->pass);
  EXPECT_FALSE(find_metric(f, "path_length_mm")->pass);
  EXPECT_EQ(f.banded, 2u);
  EXPECT_EQ(f.passed, 1u);
  EXPECT_EQ(f.verdict, Verdict::kNotYet);

  // Higher is better: 100 % is below 100.5 - 2 x 0.1.
  const scenario::Scenario high = parse_or_fail(test::incision_toml("[score.bands]\nincision_coverage_pct = { mean = 100.5, sd = 0.1 }\n"));
  EXPECT_FALSE(find_metric(compute_metrics(rec, &high), "incision_coverage_pct")->pass);
}

TEST(MetricsBands, NoBandsIsNotAssessedAndUnmeasuredNeverPasses) {
  const Recording rec = scored_attempt();
  EXPECT_EQ(compute_metrics(rec, nullptr).verdict, Verdict::kNotAssessed);
  const scenario::Scenario plain = parse_or_fail(test::incision_toml());
  EXPECT_EQ(compute_metrics(rec, &plain).verdict, Verdict::kNotAssessed);
  // Blood without frames is NaN: it fails even a generous band.
  Recording no_frames = rec;
  no_frames.frames.clear();
  const scenario::Scenario blood = parse_or_fail(test::incision_toml("[score.bands]\nblood_loss_ml = { mean = 100, sd = 100 }\n"));
  const Metrics m = compute_metrics(no_frames, &blood);
  EXPECT_FALSE(find_metric(m, "blood_loss_ml")->pass);
  EXPECT_EQ(m.verdict, Verdict::kNotYet);
  EXPECT_EQ(verdict_key(m.verdict), "not_yet");
}

// ---- the set of metrics and purity -------------------------------------------------------------

TEST(Metrics, NamesAreTheScenarioListInItsOrder) {
  const Recording rec = scored_attempt();
  for (const std::string& text : {test::incision_toml(), test::drill_toml()}) {
    const scenario::Scenario s = parse_or_fail(text);
    const Metrics m = compute_metrics(rec, &s);
    std::size_t k = 0;
    for (const Metric& x : m.metrics) {
      while (k < scenario::kScoreMetrics.size() && scenario::kScoreMetrics[k].name != x.name) ++k;
      ASSERT_LT(k, scenario::kScoreMetrics.size()) << x.name << " is not in kScoreMetrics, or out of order";
      EXPECT_TRUE(s.task == scenario::TaskKind::kIncision ? scenario::kScoreMetrics[k].incision : scenario::kScoreMetrics[k].drill)
          << x.name;
      EXPECT_FALSE(x.unit.empty()) << x.name;
      EXPECT_FALSE(x.description.empty()) << x.name;
    }
    // Every metric of the task is there.
    std::size_t expected = 0;
    for (const auto& info : scenario::kScoreMetrics) expected += (s.task == scenario::TaskKind::kIncision ? info.incision : info.drill) ? 1 : 0;
    EXPECT_EQ(m.metrics.size(), expected);
  }
  // Without a scenario: no task metrics.
  const Metrics none = compute_metrics(rec, nullptr);
  EXPECT_EQ(find_metric(none, "economy_of_motion_ratio"), nullptr);
  EXPECT_EQ(find_metric(none, "incision_coverage_pct"), nullptr);
  EXPECT_FALSE(none.has_task);
}

TEST(Metrics, SameInputGivesBitIdenticalOutput) {
  Recording rec = make_recording(5000, [](std::size_t i, double t, ToolSample& s) {
    s.tool.position = Vec3{0.01 * std::sin(3 * t), 0.02 * std::cos(2 * t), 0.001 * std::sin(17 * t)};
    s.tool.orientation = Quat{std::cos(0.1 * t), std::sin(0.1 * t), 0, 0};
    s.force = Vec3{std::sin(40 * t), 0, 2 + std::cos(7 * t)};
    s.stage = i % 700 < 500 ? Stage::kCutting : Stage::kFree;
  });
  std::size_t tick = 100;
  cut(rec, tick, -15, 0, -11);
  const scenario::Scenario s = parse_or_fail(test::incision_toml("[score.bands]\njerk_rms_m_s3 = { mean = 1, sd = 1 }\n"));
  const Metrics a = compute_metrics(rec, &s);
  const Metrics b = compute_metrics(rec, &s);
  ASSERT_EQ(a.metrics.size(), b.metrics.size());
  for (std::size_t i = 0; i < a.metrics.size(); ++i) {
    EXPECT_EQ(std::memcmp(&a.metrics[i].value, &b.metrics[i].value, sizeof(double)), 0) << a.metrics[i].name;
    EXPECT_EQ(a.metrics[i].description, b.metrics[i].description);
    EXPECT_EQ(a.metrics[i].pass, b.metrics[i].pass);
  }
  EXPECT_EQ(a.notes, b.notes);
}

}  // namespace
}  // namespace lancet::score
