// lancetctl's bring-up commands on the simulated arm, and the calibration file they write.

#include <gtest/gtest.h>

#include <cstring>

#include "lancet/shared_model/validate.hpp"

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include "arm/arm_config.hpp"
#include "temp_files.hpp"
#include "tools/bringup.hpp"

#include <unistd.h>

#include "device/device.hpp"
#include "lancet/shared_model/shared_state.hpp"

namespace lancet::tools {
namespace {

class Bringup : public test::TempDirTest {
 protected:
  void SetUp() override {
    TempDirTest::SetUp();
    config_ = (dir_ / "arm.toml").string();
    std::filesystem::copy_file(std::string(LANCET_SOURCE_DIR) + "/hw_configs/sim_3dof.toml", config_);
  }
  // Runs fn with a temporary FILE* and returns (exit code, output).
  template <class F>
  std::pair<int, std::string> capture(F&& fn) {
    std::FILE* f = std::tmpfile();
    const int code = fn(f);
    std::rewind(f);
    std::string out;
    char buf[4096];
    for (std::size_t n; (n = std::fread(buf, 1, sizeof buf, f)) > 0;) out.append(buf, n);
    std::fclose(f);
    return {code, out};
  }
  std::string config_;
};

TEST_F(Bringup, ListAlwaysAnswers) {
  const auto [code, out] = capture([](std::FILE* f) { return run_list(f); });
  EXPECT_EQ(code, 0);
  EXPECT_NE(out.find("USB devices:"), std::string::npos);
  EXPECT_NE(out.find("CAN interfaces:"), std::string::npos);
  EXPECT_NE(out.find("Serial ports"), std::string::npos);
}

TEST_F(Bringup, ProbeReadsTheArmOnce) {
  const auto [code, out] = capture([&](std::FILE* f) { return run_probe(config_, f); });
  EXPECT_EQ(code, 0) << out;
  EXPECT_NE(out.find("arm 'sim-3dof'"), std::string::npos) << out;
  EXPECT_NE(out.find("joint 2 elbow"), std::string::npos) << out;
  EXPECT_NE(out.find("not calibrated"), std::string::npos) << out;
  const auto [bad, msg] = capture([&](std::FILE* f) { return run_probe((dir_ / "missing.toml").string(), f); });
  EXPECT_EQ(bad, 2);
  EXPECT_NE(msg.find("missing.toml"), std::string::npos) << msg;
}

TEST_F(Bringup, MonitorPrintsLinesAtItsRate) {
  const auto [code, out] = capture([&](std::FILE* f) { return run_monitor(config_, 0.25, 20, f); });
  EXPECT_EQ(code, 0) << out;
  std::size_t lines = 0;
  for (char c : out) lines += c == '\n';
  EXPECT_GE(lines, 3u);
  EXPECT_NE(out.find("bus ok"), std::string::npos);
}

TEST_F(Bringup, CalibrateWritesOffsetsBesideTheConfigThatMakeTheHomePoseRead) {
  const double home[3] = {10, -20, 30};
  const auto [dry, dry_out] = capture([&](std::FILE* f) { return run_calibrate(config_, home, false, f); });
  EXPECT_EQ(dry, 0);
  EXPECT_NE(dry_out.find("dry run"), std::string::npos);
  EXPECT_FALSE(std::filesystem::exists(arm::calibration_path(config_)));
  const auto [code, out] = capture([&](std::FILE* f) { return run_calibrate(config_, home, true, f); });
  ASSERT_EQ(code, 0) << out;
  ASSERT_TRUE(std::filesystem::exists(dir_ / "arm.calibration.toml"));
  // The config itself is untouched; loading it and then the calibration gives the new offsets.
  auto cfg = arm::load_arm_config(config_).value();
  const double before = cfg.joints[1].offset;
  ASSERT_TRUE(arm::apply_calibration_file(cfg, arm::calibration_path(config_)).value());
  EXPECT_NEAR(cfg.joints[1].offset - before, -20.0 * 3.14159265358979 / 180.0, 1e-6);
  const auto [pcode, pout] = capture([&](std::FILE* f) { return run_probe(config_, f); });
  EXPECT_EQ(pcode, 0);
  EXPECT_NE(pout.find(", calibrated"), std::string::npos) << pout;
  const double wrong[2] = {1, 2};
  EXPECT_EQ(capture([&](std::FILE* f) { return run_calibrate(config_, wrong, true, f); }).first, 2);
}

TEST_F(Bringup, CalibrationFilesAreChecked) {
  auto cfg = arm::load_arm_config(config_).value();
  EXPECT_FALSE(arm::apply_calibration_file(cfg, (dir_ / "none.toml").string()).value()) << "no file: nothing applied";
  const auto bad = [&](const std::string& text, const std::string& expect) {
    const std::string p = write("cal.toml", text);
    auto c = cfg;
    auto r = arm::apply_calibration_file(c, p);
    ASSERT_FALSE(r.ok()) << text;
    EXPECT_NE(r.error().message.find(expect), std::string::npos) << r.error().message;
  };
  bad("arm = \"other\"\n", "this calibration is for 'other'");
  bad("arm = \"sim-3dof\"\n[[joints]]\nname = \"base_yaw\"\noffset_deg = 1\n", "expected 3 [[joints]]");
  bad("arm = \"sim-3dof\"\nbogus = 1\n", ":2:1: bogus: unknown key \"bogus\"; known keys here: arm, joints");
  bad("arm = \"sim-3dof\"\n[[joints]\n", ":2:");
  bad("arm = \"sim-3dof\"\n[[joints]]\nname = \"base_yaw\"\noffset_deg = \"x\"\n[[joints]]\nname = \"shoulder\"\noffset_deg = 0\n"
      "[[joints]]\nname = \"elbow\"\noffset_deg = 0\n",
      "joints[0].offset_deg: expected a finite number");
  bad("arm = \"sim-3dof\"\n[[joints]]\nname = \"wrong\"\noffset_deg = 1\n[[joints]]\nname = \"shoulder\"\noffset_deg = 0\n"
      "[[joints]]\nname = \"elbow\"\noffset_deg = 0\n",
      "joints[0].name: expected 'base_yaw', found 'wrong'");
  // Every problem at once, each at its line, in the config's form.
  const std::string p = write("cal.toml", "arm = \"sim-3dof\"\n[[joints]]\nname = \"base_yaw\"\noffset_deg = 1\noffset_dg = 2\n"
                                          "[[joints]]\nname = \"shoulder\"\noffset_deg = 0\n[[joints]]\nname = \"elbow\"\noffset_mm = 0\n");
  auto c = cfg;
  auto r = arm::apply_calibration_file(c, p);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().message,
            p + ":5:1: joints[0].offset_dg: unknown key \"offset_dg\" (did you mean \"offset_deg\"?); known keys here: name, offset_deg\n" +
            p + ":9:1: joints[2].offset_deg: required key is missing; expected a finite number\n" +
            p + ":11:1: joints[2].offset_mm: unknown key \"offset_mm\"; known keys here: name, offset_deg");
  EXPECT_EQ(c.joints[0].offset, cfg.joints[0].offset) << "nothing applied";
}

TEST_F(Bringup, MonitorFollowsARunningServoThroughSharedMemory) {
  const std::string shm = "/lancet-bringup-" + std::to_string(getpid());
  EXPECT_EQ(capture([&](std::FILE* f) { return run_monitor_rt(shm, 0.1, 10, f); }).first, 1) << "no lancet-rt yet";
  auto ch = SharedChannel::create(shm, {});
  ASSERT_TRUE(ch.ok()) << ch.error().message;
  RtStatus st{};
  st.period_ns = 1'000'000;
  st.hands = 2;
  HandStatus& r = st.hand[0];
  r.tool = {0.001, 0.002, -0.003};
  r.force = {0, 0, 1.5};
  r.force_scale = 1;
  r.contact = 1;
  r.device_state = device::Lifecycle::kFault;
  r.device_fault_cause = device::IoStatus::kTimeout;
  r.device_errors = 7;
  r.has_arm = 1;
  std::strcpy(r.fault_text, "3 timeouts in a row on 127.0.0.1:1502");
  r.fault_node = -1;  // the bus as a whole
  HandStatus& l = st.hand[1];  // the left hand: the built-in stylus, holding a scalpel
  l.tool = {0.0, 0.04, 0.02};
  l.force_scale = 1;
  l.mode = ToolMode::kScalpel;
  ch.value().state().rt_status.write(st);
  const auto [code, out] = capture([&](std::FILE* f) { return run_monitor_rt(shm, 0.2, 20, f); });
  EXPECT_EQ(code, 0);
  // A line for each hand.
  EXPECT_NE(out.find("right: tool    1.00    2.00   -3.00 mm"), std::string::npos) << out;
  EXPECT_NE(out.find("force   0.00   0.00   1.50 N (x1.00) contact  probe"), std::string::npos) << out;
  EXPECT_NE(out.find("arm fault (timeout): 3 timeouts in a row on 127.0.0.1:1502  errors 7"), std::string::npos) << out;
  EXPECT_NE(out.find("left:  tool    0.00   40.00   20.00 mm  force   0.00   0.00   0.00 N (x1.00)  scalpel  arm built-in simulated stylus  errors 0"),
            std::string::npos) << out;
  // --json: one object a line, for rigs and scripts (scripts/soak reads it).
  const auto [jcode, jout] = capture([&](std::FILE* f) { return run_monitor_rt(shm, 0.2, 20, f, true); });
  EXPECT_EQ(jcode, 0);
  const std::string first = jout.substr(0, jout.find('\n'));
  EXPECT_EQ(first.front(), '{') << jout;
  EXPECT_EQ(first.back(), '}') << jout;
  EXPECT_NE(first.find("\"alive\": true"), std::string::npos) << first;
  EXPECT_NE(first.find("\"force_n\": [0, 0, 1.5]"), std::string::npos) << first;
  EXPECT_NE(first.find("\"tool_mm\": [1, 2, -3]"), std::string::npos) << first;
  EXPECT_NE(first.find("\"device_state\": \"fault\", \"fault_cause\": \"timeout\""), std::string::npos) << first;
  EXPECT_NE(first.find("\"fault_text\": \"3 timeouts in a row on 127.0.0.1:1502\""), std::string::npos) << first;
  EXPECT_NE(first.find("\"device_errors\": 7"), std::string::npos) << first;
  // Each hand's, in "hands" (the top-level keys are the right hand's).
  EXPECT_NE(first.find("\"hand_count\": 2, \"hands\": [{\"hand\": \"right\", \"force_n\": [0, 0, 1.5]"), std::string::npos) << first;
  EXPECT_NE(first.find("{\"hand\": \"left\", \"force_n\": [0, 0, 0], \"force_scale\": 1, \"contact\": false, \"tool_mm\": [0, 40, 20], "
                       "\"tool\": \"scalpel\""),
            std::string::npos)
      << first;
  // What lancet-rt's segment says is checked before it is printed: no "inf", no 3e142 N.
  st.hand[1].force = {3e142, 0, 0};  // the left hand's is checked as the right's
  ch.value().state().rt_status.write(st);
  const auto [code2, out2] = capture([&](std::FILE* f) { return run_monitor_rt(shm, 0.15, 20, f); });
  EXPECT_EQ(code2, 0);
  EXPECT_NE(out2.find("status rejected (rt_status.hand[].force: not finite or above 1000 N)"), std::string::npos) << out2;
  EXPECT_EQ(out2.find("e+142"), std::string::npos) << out2;
  const auto [jcode2, jout2] = capture([&](std::FILE* f) { return run_monitor_rt(shm, 0.15, 20, f, true); });
  EXPECT_NE(jout2.find("\"rejected\": \"rt_status.hand[].force: not finite or above 1000 N\""), std::string::npos) << jout2;
  EXPECT_EQ(jout2.find("e+142"), std::string::npos) << jout2;
  // A lancet-rt whose servo stopped ticking: its last status is not presented as the arm's state.
  ch.value().state().rt_heartbeat.beat(monotonic_ns() - 2'000'000'000, static_cast<std::int32_t>(getpid()));
  const auto [code3, out3] = capture([&](std::FILE* f) { return run_monitor_rt(shm, 0.15, 20, f); });
  EXPECT_EQ(code3, 0);
  EXPECT_NE(out3.find("lancet-rt is NOT TICKING: last heartbeat"), std::string::npos) << out3;
  EXPECT_EQ(out3.find("arm fault"), std::string::npos) << out3;
}

TEST_F(Bringup, RearmShowsTheFaultAsksAndSendsASealedRequest) {
  const std::string shm = "/lancet-rearm-" + std::to_string(getpid());
  EXPECT_EQ(capture([&](std::FILE* f) { return run_rearm_rt(shm, true, 0.2, nullptr, f); }).first, 1) << "no lancet-rt yet";
  auto ch = SharedChannel::create(shm, {});
  ASSERT_TRUE(ch.ok()) << ch.error().message;
  SharedState& shared = ch.value().state();
  RtStatus st{};
  st.period_ns = 1'000'000;
  st.hands = 2;
  for (HandStatus& h : st.hand) {
    h.force_scale = 1;
    h.has_arm = 1;
    h.device_state = device::Lifecycle::kActive;
  }
  shared.rt_status.write(st);
  auto [idle, idle_out] = capture([&](std::FILE* f) { return run_rearm_rt(shm, false, 0.2, nullptr, f); });
  EXPECT_EQ(idle, 0);
  EXPECT_NE(idle_out.find("nothing to re-arm"), std::string::npos) << idle_out;

  HandStatus& left = st.hand[1];
  left.device_state = device::Lifecycle::kFault;
  left.device_fault_cause = device::IoStatus::kDeviceFault;
  std::strcpy(left.fault_text, "node 1: EMCY 0x2310 continuous over-current");
  left.fault_node = 1;
  left.fault_code = 0x2310;
  shared.rt_status.write(st);
  // Only the right hand asked for: its arm is active, nothing to do.
  auto [right_only, right_out] = capture([&](std::FILE* f) { return run_rearm_rt(shm, false, 0.2, nullptr, f, "right"); });
  EXPECT_EQ(right_only, 0);
  EXPECT_NE(right_out.find("nothing to re-arm"), std::string::npos) << right_out;
  EXPECT_EQ(right_out.find("left arm"), std::string::npos) << right_out;
  EXPECT_EQ(capture([&](std::FILE* f) { return run_rearm_rt(shm, true, 0.2, nullptr, f, "middle"); }).first, 2);
  // Asked, answered "no": nothing is sent.
  std::FILE* no = fmemopen(const_cast<char*>("no\n"), 3, "r");
  auto [refused, refused_out] = capture([&](std::FILE* f) { return run_rearm_rt(shm, false, 0.2, no, f); });
  std::fclose(no);
  EXPECT_EQ(refused, 1);
  EXPECT_NE(refused_out.find("left arm: fault (device fault): node 1: EMCY 0x2310 continuous over-current\n"), std::string::npos)
      << refused_out;
  EXPECT_NE(refused_out.find("right arm: active\n"), std::string::npos) << refused_out;
  EXPECT_NE(refused_out.find("Type 'yes' to re-arm"), std::string::npos) << refused_out;
  EXPECT_NE(refused_out.find("not re-armed"), std::string::npos) << refused_out;
  EXPECT_EQ(shared.operator_request.version(), 0u);
  // --yes: a sealed request goes out; with no servo to take it, the wait ends with exit 1.
  auto [unanswered, unanswered_out] = capture([&](std::FILE* f) { return run_rearm_rt(shm, true, 0.3, nullptr, f); });
  EXPECT_EQ(unanswered, 1);
  EXPECT_NE(unanswered_out.find("lancet-rt did not take the request"), std::string::npos) << unanswered_out;
  OperatorRequest req{};
  ASSERT_EQ(shared.operator_request.try_read(req), ReadStatus::kOk);
  EXPECT_EQ(wire::check(req, monotonic_ns()), nullptr);
  EXPECT_EQ(req.pid, static_cast<std::int32_t>(getpid()));
  EXPECT_EQ(req.hands, 0b11) << "both hands by default";
  // --hand left: the request names the left hand only.
  (void)capture([&](std::FILE* f) { return run_rearm_rt(shm, true, 0.2, nullptr, f, "left"); });
  ASSERT_EQ(shared.operator_request.try_read(req), ReadStatus::kOk);
  EXPECT_EQ(wire::check(req, monotonic_ns()), nullptr);
  EXPECT_EQ(req.hands, 0b10);
  // A lancet-rt driving one hand has no left arm to re-arm.
  st.hands = 1;
  shared.rt_status.write(st);
  const auto [one, one_out] = capture([&](std::FILE* f) { return run_rearm_rt(shm, true, 0.2, nullptr, f, "left"); });
  EXPECT_EQ(one, 2);
  EXPECT_NE(one_out.find("--hand left: lancet-rt on " + shm + " drives 1 hand (right)"), std::string::npos) << one_out;
}

TEST_F(Bringup, JogNeedsConfirmationAndStaysWithinItsBounds) {
  EXPECT_EQ(capture([&](std::FILE* f) { return run_jog(config_, 0, 0.01, 0.2, false, f); }).first, 2) << "no --yes";
  const auto [big, big_out] = capture([&](std::FILE* f) { return run_jog(config_, 0, 100.0, 0.2, true, f); });
  EXPECT_EQ(big, 2);
  EXPECT_NE(big_out.find("10% of joint 0's max_joint_torque"), std::string::npos) << big_out;
  EXPECT_EQ(capture([&](std::FILE* f) { return run_jog(config_, 7, 0.01, 0.2, true, f); }).first, 2) << "no joint 7";
  EXPECT_EQ(capture([&](std::FILE* f) { return run_jog(config_, 0, 0.01, 5.0, true, f); }).first, 2) << "too long";
  const auto [code, out] = capture([&](std::FILE* f) { return run_jog(config_, 0, 0.01, 0.2, true, f); });
  EXPECT_EQ(code, 0) << out;
  EXPECT_NE(out.find("torque off"), std::string::npos);
}

}  // namespace
}  // namespace lancet::tools
