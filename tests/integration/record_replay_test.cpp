// Record → replay, end to end: the real lancet-rt (a scripted hand) and lancet-viz --record on each
// shipped scenario, then lancet-viz --replay (headless) and the replay in this process. The
// replay must be bit-exact (every servo state hash, every sample's outputs, every scene hash), the
// metrics of the replayed ticks must equal the recorded ones, and broken or foreign files must be
// refused with a clear message.
#include <gtest/gtest.h>

#include <algorithm>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <vector>

#include "lancet/shared_model/shared_state.hpp"
#include "process_test.hpp"  // tests/support
#include "recording/hdf5_io.hpp"
#include "score/metrics.hpp"
#include "record/replay.hpp"
#include "score/report.hpp"
#include "shared_data.hpp"  // tests/support
#include "wait.hpp"         // tests/support

namespace lancet {
namespace {

using namespace std::chrono_literals;
using test::json_number;
using test::read_file;
using test::Child;

const std::string kRt = std::string(LANCET_BINARY_DIR) + "/firmware_rt/lancet-rt";
const std::string kViz = std::string(LANCET_BINARY_DIR) + "/host_viz/lancet-viz";
const std::string kReport = std::string(LANCET_BINARY_DIR) + "/host_viz/lancet-report";
const std::string kRecords = std::string(LANCET_BINARY_DIR) + "/host_viz/lancet-records";
const std::string kSrc = LANCET_SOURCE_DIR;

class RecordReplay : public test::ProcessTest {
 public:
  RecordReplay() : ProcessTest("rec") {}
  void SetUp() override {
    unsetenv("DISPLAY");  // headless through EGL
    ProcessTest::SetUp();
  }

  /// Seconds of servo ticks the recording at `file` holds so far (read while it is being written,
  /// as a SWMR reader; 0 while it has none or cannot be read yet).
  static double recorded_s(const std::string& file) {
    if (!std::filesystem::exists(file)) return 0;
    auto rec = record::read_recording(file);
    if (!rec.ok() || rec.value().samples.size() < 2) return 0;
    return static_cast<double>(rec.value().samples.back().t_ns - rec.value().samples.front().t_ns) * 1e-9;
  }

  /// Starts lancet-viz recording the scenario to `file` (headless, until it is stopped).
  Child start_recording_viz(const std::string& scenario, const std::string& file, const std::vector<std::string>& extra = {},
                            const std::string& log = "viz.log") {
    std::vector<std::string> argv{kViz, "--headless", "--shm", shm_, "--width", "320", "--height", "200", "--scenario",
                                  kSrc + "/host_viz/scenarios/" + scenario + ".toml", "--tool", "none", "--duration",
                                  "600", "--record", file};
    argv.insert(argv.end(), extra.begin(), extra.end());
    return Child(argv, path(log), {"LSAN_OPTIONS=detect_leaks=0"});
  }

  /// Records the scenario with lancet-rt replaying `trajectory` until the recording holds
  /// `seconds` of servo ticks (of the trajectory's time, whatever the machine's speed), then
  /// stops the viz; returns the file.
  std::string record(const std::string& scenario, const std::string& trajectory, int seconds,
                     const std::vector<std::string>& extra = {}, const std::vector<std::string>& rt_extra = {},
                     const std::function<bool(const record::Recording&)>& also = {}) {
    const std::string file = path("session.h5");
    Child viz = start_recording_viz(scenario, file, extra);
    EXPECT_TRUE(test::eventually([&] { return read_file(path("viz.log")).find("is lancet-rt running") != std::string::npos; }, 120s))
        << read_file(path("viz.log"));
    std::vector<std::string> rt_argv{kRt, "--shm", shm_, "-q", "--trajectory", kSrc + "/docs/examples/" + trajectory};
    rt_argv.insert(rt_argv.end(), rt_extra.begin(), rt_extra.end());
    Child rt(rt_argv, path("rt.log"));
    EXPECT_TRUE(test::eventually(
        [&] {
          if (recorded_s(file) < seconds) return false;
          if (!also) return true;
          auto rec = record::read_recording(file);
          return rec.ok() && also(rec.value());
        },
        180s, 300ms))
        << "the recording never held " << seconds << " s of ticks: " << read_file(path("viz.log"));
    viz.signal(SIGINT);
    const auto vs = viz.wait_exit(120s);
    EXPECT_TRUE(vs.has_value() && WIFEXITED(*vs) && WEXITSTATUS(*vs) == 0) << read_file(path("viz.log"));
    rt.signal(SIGTERM);
    (void)rt.wait_exit(10s);
    EXPECT_NE(read_file(path("viz.log")).find("(0 lost in 0 gaps)"), std::string::npos) << read_file(path("viz.log"));
    return file;
  }

  /// lancet-viz --replay FILE --headless: its exit status and log.
  std::pair<int, std::string> replay_cli(const std::string& file) {
    Child viz({kViz, "--headless", "--width", "320", "--height", "200", "--replay", file}, path("replay.log"),
              {"LSAN_OPTIONS=detect_leaks=0"});
    const auto vs = viz.wait_exit(120s);
    const int rc = vs.has_value() && WIFEXITED(*vs) ? WEXITSTATUS(*vs) : -1;
    return {rc, read_file(path("replay.log"))};
  }

  /// Replays in this process; checks bit-exactness and live = replayed metrics.
  void replay_in_process(const std::string& file, std::uint64_t min_ticks) {
    auto rec = record::read_recording(file);
    ASSERT_TRUE(rec.ok()) << rec.error().message;
    const record::Recording& r = rec.value();
    EXPECT_GE(r.samples.size(), min_ticks);
    EXPECT_EQ(r.samples_lost, 0u);
    auto rp = record::Replay::create(r);
    ASSERT_TRUE(rp.ok()) << rp.error().message;
    auto check = rp.value()->run();
    ASSERT_TRUE(check.ok()) << check.error().message;
    const record::ReplayCheck& ck = check.value();
    EXPECT_EQ(ck.ticks, r.samples.size());
    EXPECT_EQ(ck.frames, r.frames.size());
    EXPECT_GE(ck.servo_hashes, r.samples.size() / servo::kServoHashEvery - 1);
    EXPECT_GE(ck.scene_hashes, r.frames.size() / record::kSceneHashEvery);
    EXPECT_TRUE(ck.exact()) << "servo hashes " << ck.servo_hash_mismatches << "/" << ck.servo_hashes << " differ, samples "
                            << ck.sample_mismatches << ", scene hashes " << ck.scene_hash_mismatches << "/" << ck.scene_hashes
                            << "; first at tick " << ck.first_bad_seq << ", frame " << ck.first_bad_frame;
    // The metrics: computed from the file, and from the replayed ticks: the same.
    auto parsed = scenario::parse_scenario(r.scenario_toml, r.scenario_file);
    ASSERT_TRUE(parsed.ok()) << parsed.error().message;
    record::Recording replayed = r;
    replayed.samples = rp.value()->replayed();
    const score::Metrics live = score::compute_metrics(r, &parsed.value());
    const score::Metrics again = score::compute_metrics(replayed, &parsed.value());
    EXPECT_EQ(score::report_json({{file, &r, live}}), score::report_json({{file, &replayed, again}}));
  }
};

TEST_F(RecordReplay, TheDemoIncisionReplaysBitExactly) {
  const std::string file = record("skin_incision", "demo_incision.csv", 8);
  const auto [rc, log] = replay_cli(file);
  EXPECT_EQ(rc, 0) << log;
  EXPECT_NE(log.find(": bit-exact"), std::string::npos) << log;
  replay_in_process(file, 8000 * 9 / 10);
  // The report, for a person and for a machine.
  Child report({kReport, file, "-o", path("report.html"), "--json", path("report.json")}, path("report.log"));
  const auto rs = report.wait_exit(60s);
  ASSERT_TRUE(rs.has_value() && WIFEXITED(*rs) && WEXITSTATUS(*rs) == 0) << read_file(path("report.log"));
  EXPECT_NE(read_file(path("report.html")).find("<svg"), std::string::npos);
  // Scored again against a scenario file (bands recalibrated since), but only the same scenario.
  Child again({kReport, file, "--scenario", kSrc + "/host_viz/scenarios/skin_incision.toml", "--json", path("again.json")},
              path("again.log"));
  const auto as = again.wait_exit(60s);
  ASSERT_TRUE(as.has_value() && WIFEXITED(*as) && WEXITSTATUS(*as) == 0) << read_file(path("again.log"));
  EXPECT_NE(read_file(path("again.json")).find("(--scenario)"), std::string::npos) << read_file(path("again.json"));
  Child other({kReport, file, "--scenario", kSrc + "/host_viz/scenarios/bone_drilling.toml", "--json", path("other.json")},
              path("other.log"));
  const auto os = other.wait_exit(60s);
  ASSERT_TRUE(os.has_value() && WIFEXITED(*os));
  EXPECT_EQ(WEXITSTATUS(*os), 2);
  EXPECT_NE(read_file(path("other.log")).find("bone-drilling"), std::string::npos) << read_file(path("other.log"));
  EXPECT_TRUE(json_number(read_file(path("report.json")), "blood_loss_ml").has_value() ||
              read_file(path("report.json")).find("\"blood_loss_ml\"") != std::string::npos);
  // The training records score it as the report does, and store it once.
  const std::string json = read_file(path("report.json"));
  const auto passed = json_number(json, "passed"), banded = json_number(json, "banded");
  ASSERT_TRUE(passed && banded) << json;
  const std::size_t v = json.find("\"verdict\": \"");
  ASSERT_NE(v, std::string::npos) << json;
  const std::string verdict = json.substr(v + 12, json.find('"', v + 12) - (v + 12));
  for (const char* expected : {"", ", already stored"}) {
    Child records({kRecords, "--db", path("records.db"), "import", file}, path("records.log"));
    const auto st = records.wait_exit(60s);
    ASSERT_TRUE(st.has_value() && WIFEXITED(*st) && WEXITSTATUS(*st) == 0) << read_file(path("records.log"));
    char line[200];
    std::snprintf(line, sizeof line, ": skin-incision, %s (%d of %d banded metrics pass)%s\n", verdict.c_str(), static_cast<int>(*passed),
                  static_cast<int>(*banded), expected);
    EXPECT_NE(read_file(path("records.log")).find(line), std::string::npos) << line << "\n" << read_file(path("records.log"));
  }
}

// The two-handed demo (what ./lancet demo runs): both hands recorded, each hand's servo re-stepped
// with its own model, the scene driven by both streams in tick order: bit-exact; the report scores
// both hands.
TEST_F(RecordReplay, TheTwoHandedDemoReplaysBitExactly) {
  const std::string file = record("skin_incision", "demo_two_hands.csv", 13, {}, {"--hands", "2"});
  const auto [rc, log] = replay_cli(file);
  EXPECT_EQ(rc, 0) << log;
  EXPECT_NE(log.find(": bit-exact"), std::string::npos) << log;
  replay_in_process(file, 2 * 13000 * 9 / 10);
  auto rec = record::read_recording(file);
  ASSERT_TRUE(rec.ok()) << rec.error().message;
  EXPECT_EQ(rec.value().hands, 2u);
  std::size_t left = 0, left_pulling = 0, both_cutting_and_holding = 0;
  const auto& s = rec.value().samples;
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s[i].hand != Hand::kLeft) continue;
    ++left;
    left_pulling += s[i].stage == Stage::kPulling ? 1 : 0;
    // The right hand's sample of the same tick comes just before: cutting while the left holds.
    if (i > 0 && s[i - 1].seq == s[i].seq && s[i - 1].stage == Stage::kCutting && s[i].stage == Stage::kPulling) ++both_cutting_and_holding;
  }
  EXPECT_GT(left, 12000u);
  EXPECT_GT(left_pulling, 5000u) << "the left hand holds the incision for seconds";
  EXPECT_GT(both_cutting_and_holding, 500u) << "the right hand cuts while the left holds";
  Child report({kReport, file, "--json", path("report.json")}, path("report.log"));
  const auto rs = report.wait_exit(60s);
  ASSERT_TRUE(rs.has_value() && WIFEXITED(*rs) && WEXITSTATUS(*rs) == 0) << read_file(path("report.log"));
  const std::string j = read_file(path("report.json"));
  EXPECT_NE(j.find("\"two_hands\": {"), std::string::npos) << j;
  // Both in contact: the right hand's second cut and its swabbing while the left holds (2.2 s when
  // written); the left hand holds for most of the session, so it is idle for little of it.
  EXPECT_GT(json_number(j, "both_hands_contact_time_s").value_or(0), 1.0) << j;
  EXPECT_LT(json_number(j, "idle_time_s").value_or(99), 5.0) << j;
}

TEST_F(RecordReplay, TheDrillingScenarioReplaysBitExactly) {
  const std::string file = record("bone_drilling", "drill_window.csv", 7);
  const auto [rc, log] = replay_cli(file);
  EXPECT_EQ(rc, 0) << log;
  EXPECT_NE(log.find(": bit-exact"), std::string::npos) << log;
  replay_in_process(file, 7000 * 9 / 10);
}

TEST_F(RecordReplay, TheCtIncisionReplaysBitExactly) {
  LANCET_SHARED_VOLUMES_OR_RETURN(volumes);
  const std::string file =
      record("ct_incision", "demo_incision.csv", 6, {"--volume", volumes + "/head_ct_headsq/headsq_64x64x93_int16.mhd"});
  const auto [rc, log] = replay_cli(file);
  EXPECT_EQ(rc, 0) << log;
  EXPECT_NE(log.find(": bit-exact"), std::string::npos) << log;
  replay_in_process(file, 6000 * 9 / 10);
}

// An arm's session (the simulated PHANToM-style arm: its kinematics, its Device, its torque
// limits): replays bit-exactly from the model lancet-rt published, and carries the arm's file.
TEST_F(RecordReplay, AnArmsSessionReplaysBitExactlyAndCarriesItsConfiguration) {
  const std::string config = kSrc + "/hw_configs/sim_3dof.toml";
  const std::string file = record("skin_incision", "demo_incision.csv", 5, {}, {"--config", config});
  replay_in_process(file, 5000 * 9 / 10);
  auto rec = record::read_recording(file);
  ASSERT_TRUE(rec.ok()) << rec.error().message;
  EXPECT_EQ(rec.value().arm_config.substr(0, 200), read_file(config).substr(0, 200));
  EXPECT_EQ(rec.value().samples[1000].n_joints, 3u);
  auto model = servo::model_from_blob(rec.value().servo_model[0]);
  ASSERT_TRUE(model.ok()) << model.error().message;
  EXPECT_EQ(model.value().kinematics.model(), arm::KinematicModel::kPhantom);
}

// A station restarts lancet-viz between attempts while lancet-rt runs on: a recording made by a
// viz that attached to a running servo (whose last patch came from the viz before it) replays.
TEST_F(RecordReplay, AVizStartedWhileLancetRtRunsRecordsASessionThatReplays) {
  Child rt({kRt, "--shm", shm_, "-q", "--trajectory", kSrc + "/docs/examples/demo_incision.csv"}, path("rt.log"));
  {
    Child first({kViz, "--headless", "--shm", shm_, "--width", "320", "--height", "200", "--scenario",
                 kSrc + "/host_viz/scenarios/skin_incision.toml", "--tool", "none", "--duration", "600"},
                path("viz1.log"), {"LSAN_OPTIONS=detect_leaks=0"});
    ASSERT_TRUE(test::eventually([&] { return read_file(path("viz1.log")).find("connected to lancet-rt") != std::string::npos; }, 120s))
        << read_file(path("viz1.log"));
    first.signal(SIGKILL);  // its patch stays the servo's until the next viz publishes
    ASSERT_TRUE(first.wait_exit(30s).has_value());
  }
  const std::string file = path("second.h5");
  Child viz = start_recording_viz("skin_incision", file);
  ASSERT_TRUE(test::eventually([&] { return recorded_s(file) >= 2; }, 180s, 300ms)) << read_file(path("viz.log"));
  viz.signal(SIGINT);
  const auto vs = viz.wait_exit(120s);
  ASSERT_TRUE(vs.has_value() && WIFEXITED(*vs) && WEXITSTATUS(*vs) == 0) << read_file(path("viz.log"));
  const auto [rc, log] = replay_cli(file);
  EXPECT_EQ(rc, 0) << log;
  EXPECT_NE(log.find(": bit-exact\n"), std::string::npos) << log;
  replay_in_process(file, 1800);
}

// lancet-rt killed and started again while the viz records: the servo's state is gone, so the
// attempt's recording ends there (complete, replayable), and the next attempt is recorded, on a
// fresh scene, to FILE-2.h5 once lancet-rt is back; it replays too.
TEST_F(RecordReplay, ARestartedLancetRtEndsTheAttemptAndTheNextIsRecordedToo) {
  const std::string file = path("attempt.h5"), next = path("attempt-2.h5");
  Child viz = start_recording_viz("skin_incision", file);
  {
    Child rt({kRt, "--shm", shm_, "-q", "--trajectory", kSrc + "/docs/examples/demo_incision.csv"}, path("rt1.log"));
    ASSERT_TRUE(test::eventually([&] { return recorded_s(file) >= 1.5; }, 180s, 300ms)) << read_file(path("viz.log"));
    rt.signal(SIGKILL);
    ASSERT_TRUE(rt.wait_exit(30s).has_value());
  }
  Child rt({kRt, "--shm", shm_, "-q", "--trajectory", kSrc + "/docs/examples/demo_incision.csv"}, path("rt2.log"));
  ASSERT_TRUE(test::eventually([&] { return recorded_s(next) >= 1.5; }, 180s, 300ms)) << read_file(path("viz.log"));
  viz.signal(SIGINT);
  const auto vs = viz.wait_exit(120s);
  ASSERT_TRUE(vs.has_value() && WIFEXITED(*vs) && WEXITSTATUS(*vs) == 0) << read_file(path("viz.log"));
  for (const std::string& f : {file, next}) {
    auto rec = record::read_recording(f);
    ASSERT_TRUE(rec.ok()) << rec.error().message;
    EXPECT_FALSE(rec.value().cut_short) << f << ": finished when its servo went away";
    const auto [rc, log] = replay_cli(f);
    EXPECT_EQ(rc, 0) << log;
    EXPECT_NE(log.find(": bit-exact\n"), std::string::npos) << log;
  }
}

// lancet-viz killed while it records (a crash, a power cut): the file keeps what was flushed,
// says it was cut short, and replays bit-exactly up to its end.
TEST_F(RecordReplay, ARecordingCutShortByAKilledVizReplaysUpToItsEnd) {
  const std::string file = path("killed.h5");
  Child viz = start_recording_viz("skin_incision", file);
  Child rt({kRt, "--shm", shm_, "-q", "--trajectory", kSrc + "/docs/examples/demo_incision.csv"}, path("rt.log"));
  ASSERT_TRUE(test::eventually([&] { return recorded_s(file) >= 2; }, 180s, 300ms)) << read_file(path("viz.log"));
  viz.signal(SIGKILL);
  ASSERT_TRUE(viz.wait_exit(30s).has_value());
  auto rec = record::read_recording(file);
  ASSERT_TRUE(rec.ok()) << rec.error().message;
  EXPECT_TRUE(rec.value().cut_short);
  EXPECT_GE(rec.value().samples.size(), 1800u) << "the ticks flushed before the kill";
  const auto [rc, log] = replay_cli(file);
  EXPECT_EQ(rc, 0) << log;
  EXPECT_NE(log.find("cut short"), std::string::npos) << log;
  EXPECT_NE(log.find(": bit-exact\n"), std::string::npos) << log;
  replay_in_process(file, 1800);
  // The report scores it, and says so.
  Child report({kReport, file, "--json", path("report.json")}, path("report.log"));
  const auto rs = report.wait_exit(60s);
  ASSERT_TRUE(rs.has_value() && WIFEXITED(*rs) && WEXITSTATUS(*rs) == 0) << read_file(path("report.log"));
  EXPECT_NE(read_file(path("report.json")).find("\"cut_short\": true"), std::string::npos);
}

// lancet-viz stopped (SIGSTOP: a laptop swapping, a debugger) for longer than the old 4 s ring
// held: the servo's ticks wait in the ring, and the recording loses none.
TEST_F(RecordReplay, AVizStoppedForSixSecondsOfTicksLosesNone) {
  const std::string file = path("stopped.h5");
  Child viz = start_recording_viz("skin_incision", file);
  Child rt({kRt, "--shm", shm_, "-q", "--trajectory", kSrc + "/docs/examples/demo_incision.csv"}, path("rt.log"));
  ASSERT_TRUE(test::eventually([&] { return recorded_s(file) >= 1; }, 180s, 300ms)) << read_file(path("viz.log"));
  auto channel = SharedChannel::open(shm_);
  ASSERT_TRUE(channel.ok()) << channel.error().message;
  const auto pushed = [&] {
    RtStatus st{};
    return channel.value().state().rt_status.try_read(st) == ReadStatus::kOk ? st.samples_pushed : 0;
  };
  viz.signal(SIGSTOP);
  const std::uint64_t at_stop = pushed();
  // 6 s of ticks while the viz cannot drain them (the ring holds 16 s).
  ASSERT_TRUE(test::eventually([&] { return pushed() >= at_stop + 6000; }, 120s)) << "lancet-rt stopped ticking";
  viz.signal(SIGCONT);
  const double before = recorded_s(file);
  ASSERT_TRUE(test::eventually([&] { return recorded_s(file) >= before + 7; }, 180s, 300ms)) << read_file(path("viz.log"));
  viz.signal(SIGINT);
  const auto vs = viz.wait_exit(120s);
  ASSERT_TRUE(vs.has_value() && WIFEXITED(*vs) && WEXITSTATUS(*vs) == 0) << read_file(path("viz.log"));
  EXPECT_NE(read_file(path("viz.log")).find("(0 lost in 0 gaps)"), std::string::npos) << read_file(path("viz.log"));
  replay_in_process(file, 7000);
}

// A truncated or overwritten file, and a recording of another layout, are refused with the reason.
TEST_F(RecordReplay, BrokenAndForeignRecordingsAreRefused) {
  // Long enough to bleed, and for a scene hash to be taken after the blood came (however slowly
  // this machine draws frames).
  const auto hashed_blood = [](const record::Recording& r) {
    return std::any_of(r.frames.begin(), r.frames.end(),
                       [](const record::FrameRecord& f) { return f.scene_hash != 0 && f.blood_on_tissue_ml > 0.01; });
  };
  const std::string file = record("skin_incision", "demo_incision.csv", 6, {}, {}, hashed_blood);
  const std::string cut = path("cut.h5");
  std::filesystem::copy_file(file, cut);
  std::filesystem::resize_file(cut, std::filesystem::file_size(cut) / 3);
  auto [rc, log] = replay_cli(cut);
  EXPECT_EQ(rc, 2) << log;
  EXPECT_NE(log.find(cut), std::string::npos) << log;
  Child report({kReport, cut, "-o", path("cut.html")}, path("cut_report.log"));
  const auto rs = report.wait_exit(60s);
  ASSERT_TRUE(rs.has_value() && WIFEXITED(*rs));
  EXPECT_EQ(WEXITSTATUS(*rs), 2) << read_file(path("cut_report.log"));
  EXPECT_NE(read_file(path("cut_report.log")).find(cut), std::string::npos) << read_file(path("cut_report.log"));
  Child records({kRecords, "--db", path("records.db"), "import", cut}, path("cut_records.log"));
  const auto cs = records.wait_exit(60s);
  ASSERT_TRUE(cs.has_value() && WIFEXITED(*cs));
  EXPECT_EQ(WEXITSTATUS(*cs), 2) << read_file(path("cut_records.log"));
  EXPECT_NE(read_file(path("cut_records.log")).find(cut), std::string::npos) << read_file(path("cut_records.log"));

  auto rec = record::read_recording(file);
  ASSERT_TRUE(rec.ok()) << rec.error().message;
  record::Recording old = rec.value();
  old.recorded_layout_hash ^= 0x5a5a;  // a ToolSample or TissuePatch laid out otherwise
  old.protocol = 3;
  auto rp = record::Replay::create(old);
  ASSERT_FALSE(rp.ok());
  char mine[24];
  std::snprintf(mine, sizeof mine, "%016llx", static_cast<unsigned long long>(kRecordedLayoutHash));
  EXPECT_NE(rp.error().message.find(mine), std::string::npos) << rp.error().message;
  EXPECT_NE(rp.error().message.find("protocol 3"), std::string::npos) << rp.error().message;
  // The checks catch a difference: one reading moved by a micrometre, or one frame's blood step.
  {
    record::Recording moved = rec.value();
    const std::size_t at = moved.samples.size() / 2;
    moved.samples[at].q[0] += 1e-6;
    auto again = record::Replay::create(moved);
    ASSERT_TRUE(again.ok()) << again.error().message;
    auto ck = again.value()->run();
    ASSERT_TRUE(ck.ok());
    EXPECT_FALSE(ck.value().exact());
    EXPECT_EQ(ck.value().first_bad_seq, moved.samples[at].seq);
  }
  {
    record::Recording slower = rec.value();
    ASSERT_GT(slower.frames.back().blood_lost_ml, 0) << "the cut bled";
    for (auto& f : slower.frames) f.blood_dt *= 1.5;
    auto again = record::Replay::create(slower);
    ASSERT_TRUE(again.ok()) << again.error().message;
    auto ck = again.value()->run();
    ASSERT_TRUE(ck.ok());
    EXPECT_GT(ck.value().scene_hash_mismatches, 0u) << "the blood is in the scene's hash (" << ck.value().scene_hashes
                                                    << " checked over " << ck.value().frames << " frames, " << ck.value().ticks << " ticks)";
  }
  // A model blob written by another build is refused too.
  record::Recording foreign = rec.value();
  foreign.servo_model[0].layout ^= 1;
  rp = record::Replay::create(foreign);
  ASSERT_FALSE(rp.ok());
  EXPECT_NE(rp.error().message.find("another build"), std::string::npos) << rp.error().message;
}

}  // namespace
}  // namespace lancet
