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
  const Trajectory& t = r.value();
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
  EXPECT_NE(err("0,0,0\n").find("t.csv:1: expected 4 or 5 values"), std::string::npos);
  EXPECT_NE(err("0,0,0,0,0,0\n").find("t.csv:1: expected 4 or 5 values"), std::string::npos);
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
  const Trajectory& tr = r.value();
  ASSERT_EQ(tr.tools.size(), 2u);
  EXPECT_EQ(tr.tools[0].t, 0.0);
  EXPECT_EQ(tr.tools[0].mode, ToolMode::kScalpel);
  EXPECT_EQ(tr.tools[1].t, 0.4);
  EXPECT_EQ(tr.tools[1].mode, ToolMode::kRetractor);
  // The servo replaying it takes each tool when its time comes; a key in between holds until the
  // script's next change.
  app::RtModel model;
  model.trajectory = &tr;
  auto shared = std::make_unique<SharedState>();
  std::int64_t t = 1'000'000'000;
  app::RtServo servo(model, *shared, t);
  rt::Watchdog wd;
  rt::LoopLive live;
  ToolMode at_100ms = ToolMode::kProbe, at_600ms = ToolMode::kProbe;
  for (std::uint64_t n = 1; n <= 700; ++n) {
    t += model.servo.period_ns;
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
  model.trajectory = &tr;
  auto shared = std::make_unique<SharedState>();
  std::int64_t t = 1'000'000'000;
  app::RtServo servo(model, *shared, t);
  rt::Watchdog wd;
  rt::LoopLive live;
  for (std::uint64_t n = 1; n <= 2000; ++n) {
    t += model.servo.period_ns;
    servo.tick(rt::TickContext{t, t, n, wd, live});
    ToolSample s;
    while (shared->samples.try_pop(s)) {
    }
  }
  EXPECT_LT(norm(servo.data().servo.tool - tr.p.back()), 0.001) << "the hand spring brings the stylus to the recording's end";
}

}  // namespace
}  // namespace lancet::device
