// Recorded hand trajectories: the CSV loader's errors, interpolation, and the servo following one.

#include "device/trajectory.hpp"

#include <gtest/gtest.h>

#include <memory>

#include "app/rt_servo.hpp"
#include "temp_files.hpp"

namespace lancet::device {
namespace {

class TrajectoryFile : public test::TempDirTest {};

TEST_F(TrajectoryFile, LoadsWithHeaderCommentsAndInterpolates) {
  const auto p = write("t.csv", "# a recorded stroke\nt_s, x_mm, y_mm, z_mm\n0, 0, 0, 10\n1.0, 10, 0, 0  # down\n\n2.0, 10, 20, 0\n");
  auto r = load_trajectory_csv(p);
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Trajectory& t = r.value()[hand_index(Hand::kRight)];
  EXPECT_TRUE(r.value()[hand_index(Hand::kLeft)].t.empty()) << "no hand cell: every row is the right hand's";
  EXPECT_EQ(t.t.size(), 3u);
  EXPECT_DOUBLE_EQ(t.duration(), 2.0);
  EXPECT_NEAR(norm(t.at(-1) - Vec3{0, 0, 0.01}), 0, 1e-15);
  EXPECT_NEAR(norm(t.at(0.5) - Vec3{0.005, 0, 0.005}), 0, 1e-15);
  EXPECT_NEAR(norm(t.at(1.5) - Vec3{0.01, 0.01, 0}), 0, 1e-15);
  EXPECT_NEAR(norm(t.at(99) - Vec3{0.01, 0.02, 0}), 0, 1e-15);
}

TEST_F(TrajectoryFile, ErrorsNameTheLineAndField) {
  const auto err = [&](const std::string& text) {
    auto r = load_trajectory_csv(write("t.csv", text));
    EXPECT_FALSE(r.ok()) << text;
    return r.ok() ? std::string() : r.error().message;
  };
  EXPECT_NE(err("0,0,0,0\n1,abc,0,0\n").find("t.csv:2: x_mm: expected a number, found 'abc'"), std::string::npos);
  EXPECT_NE(err("0,0,0,0\n0,1,1,1\n").find("t.csv:2: t_s: times must increase"), std::string::npos);
  EXPECT_NE(err("0,0,0\n").find("t.csv:1: expected 4 to 6 values"), std::string::npos);
  EXPECT_NE(err("0,0,0,0,,right,0\n").find("t.csv:1: expected 4 to 6 values"), std::string::npos);
  EXPECT_NE(err("0,0,0,0,,right\n1,0,0,0,,middle\n").find("t.csv:2: hand: expected right or left, found 'middle'"), std::string::npos);
  EXPECT_NE(err("0,0,0,0,,left\n0,1,1,1,,left\n").find("t.csv:2: t_s: times must increase (per hand): 0 follows 0.000000 of the left hand"),
            std::string::npos);
  EXPECT_NE(err("0,0,0,0,probe\n1,0,0,0,knife\n").find("t.csv:2: tool: expected probe, scalpel, retractor or drill, found 'knife'"),
            std::string::npos);
  EXPECT_NE(err("-1,0,0,0\n").find("t_s: expected >= 0"), std::string::npos);
  EXPECT_NE(err("# nothing\n").find("no trajectory points"), std::string::npos);
  EXPECT_NE(err("0,0,0,nan\n").find("z_mm: expected a number"), std::string::npos);
  auto missing = load_trajectory_csv((dir_ / "none.csv").string());
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code, ErrorCode::kNotFound);
}

TEST_F(TrajectoryFile, AFifthCellPicksTheToolFromThatTimeOn) {
  const auto p = write("t.csv", "t_s,x_mm,y_mm,z_mm,tool\n0,0,0,30,scalpel\n0.2,0,0,30\n0.4,0,0,30,retractor\n0.6,0,0,30,\n");
  auto r = load_trajectory_csv(p);
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Trajectory& tr = r.value()[0];
  ASSERT_EQ(tr.tools.size(), 2u);
  EXPECT_EQ(tr.tools[0].t, 0.0);
  EXPECT_EQ(tr.tools[0].mode, ToolMode::kScalpel);
  EXPECT_EQ(tr.tools[1].t, 0.4);
  EXPECT_EQ(tr.tools[1].mode, ToolMode::kRetractor);
  // The servo replaying it takes each tool when its time comes; a key in between holds until the
  // script's next change.
  app::RtModel model;
  model.hand[0].trajectory = &tr;
  auto shared = std::make_unique<SharedState>();
  std::int64_t t = 1'000'000'000;
  app::RtServo servo(model, *shared, t);
  rt::Watchdog wd;
  rt::LoopLive live;
  ToolMode at_100ms = ToolMode::kProbe, at_600ms = ToolMode::kProbe;
  for (std::uint64_t n = 1; n <= 700; ++n) {
    t += model.period_ns;
    servo.tick(rt::TickContext{t, t, n, wd, live});
    ToolSample s;
    while (shared->samples.try_pop(s)) {
      if (n == 100) at_100ms = s.mode;
      if (n == 600) at_600ms = s.mode;
    }
  }
  EXPECT_EQ(at_100ms, ToolMode::kScalpel);
  EXPECT_EQ(at_600ms, ToolMode::kRetractor);
}

TEST(TrajectoryServo, TheSimulatedHandFollowsTheRecording) {
  Trajectory tr;
  tr.t = {0.0, 0.5};
  tr.p = {Vec3{0.0, 0.0, 0.02}, Vec3{0.01, -0.005, 0.03}};  // in the air: no tissue to touch
  app::RtModel model;
  model.hand[0].trajectory = &tr;
  auto shared = std::make_unique<SharedState>();
  std::int64_t t = 1'000'000'000;
  app::RtServo servo(model, *shared, t);
  rt::Watchdog wd;
  rt::LoopLive live;
  for (std::uint64_t n = 1; n <= 2000; ++n) {
    t += model.period_ns;
    servo.tick(rt::TickContext{t, t, n, wd, live});
    ToolSample s;
    while (shared->samples.try_pop(s)) {
    }
  }
  EXPECT_LT(norm(servo.hand(Hand::kRight).servo.tool - tr.p.back()), 0.001) << "the hand spring brings the stylus to the recording's end";
}

TEST_F(TrajectoryFile, ASixthCellSaysWhoseRowItIsAndEachHandHasItsOwnTimesAndTools) {
  const auto p = write("t.csv",
                       "t_s,x_mm,y_mm,z_mm,tool,hand\n"
                       "0,0,0,30,scalpel,right\n"
                       "0,0,40,20,retractor,left\n"
                       "0.5,10,0,30,,\n"          // empty: the right hand's
                       "0.3,0,40,10,,left\n"      // the left hand's times go on from its own last
                       "1.0,0,40,0,drill,left\n");
  auto r = load_trajectory_csv(p);
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Trajectory& right = r.value()[hand_index(Hand::kRight)];
  const Trajectory& left = r.value()[hand_index(Hand::kLeft)];
  ASSERT_EQ(right.t.size(), 2u);
  ASSERT_EQ(left.t.size(), 3u);
  EXPECT_NEAR(norm(right.at(0.5) - Vec3{0.01, 0, 0.03}), 0, 1e-15);
  EXPECT_NEAR(norm(left.at(0.3) - Vec3{0, 0.04, 0.01}), 0, 1e-15);
  ASSERT_EQ(right.tools.size(), 1u);
  EXPECT_EQ(right.tools[0].mode, ToolMode::kScalpel);
  ASSERT_EQ(left.tools.size(), 2u);
  EXPECT_EQ(left.tools[0].mode, ToolMode::kRetractor);
  EXPECT_EQ(left.tools[1].t, 1.0);
  EXPECT_EQ(left.tools[1].mode, ToolMode::kDrill);
  // Only the left hand's rows: the right hand has none (it follows its built-in script).
  auto only_left = load_trajectory_csv(write("l.csv", "0,0,40,20,,left\n"));
  ASSERT_TRUE(only_left.ok()) << only_left.error().message;
  EXPECT_TRUE(only_left.value()[0].t.empty());
  EXPECT_EQ(only_left.value()[1].t.size(), 1u);
}

TEST(TrajectoryServo, EachHandFollowsItsOwnTrajectoryOrItsScriptAndChangesItsOwnTools) {
  Trajectory left;
  left.t = {0.0, 0.5};
  left.p = {Vec3{0.0, 0.03, 0.02}, Vec3{0.01, 0.03, 0.03}};  // in the air
  left.tools = {{0.1, ToolMode::kRetractor}};
  app::RtModel model;
  model.hands = 2;
  model.hand[1].trajectory = &left;  // the right hand has no rows: its built-in script
  auto shared = std::make_unique<SharedState>();
  std::int64_t t = 1'000'000'000;
  app::RtServo servo(model, *shared, t);
  rt::Watchdog wd;
  rt::LoopLive live;
  for (std::uint64_t n = 1; n <= 2000; ++n) {
    t += model.period_ns;
    servo.tick(rt::TickContext{t, t, n, wd, live});
    ToolSample s;
    while (shared->samples.try_pop(s)) {
    }
  }
  EXPECT_LT(norm(servo.hand(Hand::kLeft).servo.tool - left.p.back()), 0.001);
  EXPECT_EQ(servo.hand(Hand::kLeft).servo.mode, ToolMode::kRetractor);
  EXPECT_EQ(servo.hand(Hand::kRight).servo.mode, ToolMode::kProbe) << "the left hand's tool change is the left hand's";
  EXPECT_LT(norm(servo.hand(Hand::kRight).servo.tool - scripted_target(2.0, model.hand[0].script_depth)), 0.002)
      << "the right hand follows its built-in script";
}

}  // namespace
}  // namespace lancet::device
