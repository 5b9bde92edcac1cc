// Record → replay, end to end: the real lancet-rt (a scripted hand) and lancet-viz --record on each
// shipped scenario, then lancet-viz --replay (headless) and the replay in this process. The
// replay must be bit-exact (every servo state hash, every sample's outputs, every scene hash), the
// metrics of the replayed ticks must equal the recorded ones, and broken or foreign files must be
// refused with a clear message.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "lancet/shared_model/shared_state.hpp"
#include "process_test.hpp"  // tests/support
#include "record/hdf5_io.hpp"
#include "record/metrics.hpp"
#include "record/replay.hpp"
#include "record/report.hpp"
#include "shared_data.hpp"  // tests/support

namespace lancet {
namespace {

using namespace std::chrono_literals;
using test::json_number;
using test::read_file;
using test::Child;

const std::string kRt = std::string(LANCET_BINARY_DIR) + "/firmware_rt/lancet-rt";
const std::string kViz = std::string(LANCET_BINARY_DIR) + "/host_viz/lancet-viz";
const std::string kReport = std::string(LANCET_BINARY_DIR) + "/host_viz/lancet-report";
const std::string kSrc = LANCET_SOURCE_DIR;

class RecordReplay : public test::ProcessTest {
 public:
  RecordReplay() : ProcessTest("rec") {}
  void SetUp() override {
    unsetenv("DISPLAY");  // headless through EGL
    ProcessTest::SetUp();
  }

  /// Records `seconds` of the scenario with lancet-rt replaying `trajectory`; returns the file.
  std::string record(const std::string& scenario, const std::string& trajectory, int seconds,
                     const std::vector<std::string>& extra = {}, const std::vector<std::string>& rt_extra = {}) {
    const std::string file = path("session.h5");
    std::vector<std::string> argv{kViz, "--headless", "--shm", shm_, "--width", "320", "--height", "200", "--scenario",
                                  kSrc + "/host_viz/scenarios/" + scenario + ".toml", "--tool", "none", "--duration",
                                  std::to_string(seconds), "--record", file};
    argv.insert(argv.end(), extra.begin(), extra.end());
    Child viz(argv, path("viz.log"), {"LSAN_OPTIONS=detect_leaks=0"});
    for (int i = 0; i < 900 && read_file(path("viz.log")).find("is lancet-rt running") == std::string::npos; ++i)
      std::this_thread::sleep_for(100ms);
    std::vector<std::string> rt_argv{kRt, "--shm", shm_, "-q", "--trajectory", kSrc + "/docs/examples/" + trajectory};
    rt_argv.insert(rt_argv.end(), rt_extra.begin(), rt_extra.end());
    Child rt(rt_argv, path("rt.log"));
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
    const record::Metrics live = record::compute_metrics(r, &parsed.value());
    const record::Metrics again = record::compute_metrics(replayed, &parsed.value());
    EXPECT_EQ(record::report_json({{file, &r, live}}), record::report_json({{file, &replayed, again}}));
  }
};

TEST_F(RecordReplay, TheDemoIncisionReplaysBitExactly) {
  const std::string file = record("skin_incision", "demo_incision.csv", 8);
  const auto [rc, log] = replay_cli(file);
  EXPECT_EQ(rc, 0) << log;
  EXPECT_NE(log.find(": bit-exact"), std::string::npos) << log;
  replay_in_process(file, 6000);
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
}

TEST_F(RecordReplay, TheDrillingScenarioReplaysBitExactly) {
  const std::string file = record("bone_drilling", "drill_window.csv", 7);
  const auto [rc, log] = replay_cli(file);
  EXPECT_EQ(rc, 0) << log;
  EXPECT_NE(log.find(": bit-exact"), std::string::npos) << log;
  replay_in_process(file, 5000);
}

TEST_F(RecordReplay, TheCtIncisionReplaysBitExactly) {
  LANCET_SHARED_VOLUMES_OR_RETURN(volumes);
  const std::string file =
      record("ct_incision", "demo_incision.csv", 6, {"--volume", volumes + "/head_ct_headsq/headsq_64x64x93_int16.mhd"});
  const auto [rc, log] = replay_cli(file);
  EXPECT_EQ(rc, 0) << log;
  EXPECT_NE(log.find(": bit-exact"), std::string::npos) << log;
  replay_in_process(file, 4000);
}

// An arm's session (the simulated PHANToM-style arm: its kinematics, its Device, its torque
// limits): replays bit-exactly from the model lancet-rt published, and carries the arm's file.
TEST_F(RecordReplay, AnArmsSessionReplaysBitExactlyAndCarriesItsConfiguration) {
  const std::string config = kSrc + "/hw_configs/sim_3dof.toml";
  const std::string file = record("skin_incision", "demo_incision.csv", 5, {}, {"--config", config});
  replay_in_process(file, 3000);
  auto rec = record::read_recording(file);
  ASSERT_TRUE(rec.ok()) << rec.error().message;
  EXPECT_EQ(rec.value().arm_config.substr(0, 200), read_file(config).substr(0, 200));
  EXPECT_EQ(rec.value().samples[1000].n_joints, 3u);
  auto model = servo::model_from_blob(rec.value().servo_model);
  ASSERT_TRUE(model.ok()) << model.error().message;
  EXPECT_EQ(model.value().kinematics.model(), arm::KinematicModel::kPhantom);
}

// A truncated or overwritten file, and a recording of another layout, are refused with the reason.
TEST_F(RecordReplay, BrokenAndForeignRecordingsAreRefused) {
  const std::string file = record("skin_incision", "demo_incision.csv", 6);  // long enough to bleed
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

  auto rec = record::read_recording(file);
  ASSERT_TRUE(rec.ok()) << rec.error().message;
  record::Recording old = rec.value();
  old.layout_hash ^= 0x5a5a;
  old.protocol = 3;
  auto rp = record::Replay::create(old);
  ASSERT_FALSE(rp.ok());
  char mine[24];
  std::snprintf(mine, sizeof mine, "%016llx", static_cast<unsigned long long>(kSharedLayoutHash));
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
    EXPECT_GT(ck.value().scene_hash_mismatches, 0u) << "the blood is in the scene's hash";
  }
  // A model blob written by another build is refused too.
  record::Recording foreign = rec.value();
  foreign.servo_model.layout ^= 1;
  rp = record::Replay::create(foreign);
  ASSERT_FALSE(rp.ok());
  EXPECT_NE(rp.error().message.find("another build"), std::string::npos) << rp.error().message;
}

}  // namespace
}  // namespace lancet
