// Starts the real lancet-rt and lancet-viz (headless, under Xvfb) and checks that they talk:
// samples arrive in order without loss, the tissue patch reaches lancet-rt and produces a force,
// the screenshot is not blank, killing the viz fades the force to zero within the configured
// time while lancet-rt keeps running, and the viz survives lancet-rt going away.

#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/mman.h>

#include <cstdlib>
#include <filesystem>
#include <string>

#include "lancet/shared_model/shared_state.hpp"
#include "process.hpp"  // tests/support

namespace lancet {
namespace {

using namespace std::chrono_literals;
using test::Child;
using test::json_number;
using test::read_file;

const std::string kRt = std::string(LANCET_BINARY_DIR) + "/firmware_rt/lancet-rt";
const std::string kViz = std::string(LANCET_BINARY_DIR) + "/host_viz/lancet-viz";
constexpr double kTimeoutMs = 150, kFadeMs = 100;

class TwoProcess : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_NE(std::getenv("DISPLAY"), nullptr) << "run under xvfb-run (ctest does this)";
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = std::filesystem::temp_directory_path() / ("lancet-it-" + std::to_string(getpid()) + "-" + info->name());
    std::filesystem::create_directories(dir_);
    shm_ = "/lancet-it-" + std::to_string(getpid()) + "-" + info->name();
  }
  void TearDown() override {
    shm_unlink(shm_.c_str());  // a killed lancet-rt leaves its segment behind
    if (!HasFailure()) std::filesystem::remove_all(dir_);
  }
  std::string path(const std::string& f) const { return (dir_ / f).string(); }

  std::unique_ptr<Child> start_rt() {
    auto rt = std::make_unique<Child>(std::vector<std::string>{kRt, "--shm", shm_, "-q", "--stats", path("rt.json"),
                                                               "--viz-timeout-ms", std::to_string(kTimeoutMs),
                                                               "--fade-ms", std::to_string(kFadeMs)},
                                      path("rt.log"));
    // Wait until its segment is ready.
    for (int i = 0; i < 500; ++i) {
      if (SharedChannel::open(shm_)) break;
      std::this_thread::sleep_for(10ms);
    }
    return rt;
  }
  std::unique_ptr<Child> start_viz(const std::vector<std::string>& extra) {
    std::vector<std::string> argv{kViz, "--headless", "--shm", shm_, "--width", "640", "--height", "400"};
    argv.insert(argv.end(), extra.begin(), extra.end());
    // Mesa's GL driver leaks a little at context teardown and is unloaded before LeakSanitizer
    // reports, so the report cannot be suppressed by name: leak checking is off for lancet-viz in
    // sanitizer builds (its session logic is leak-checked by the host_viz unit tests).
    return std::make_unique<Child>(argv, path("viz.log"), std::vector<std::string>{"LSAN_OPTIONS=detect_leaks=0"});
  }
  // Polls RtStatus until pred holds or timeout; returns the last status read.
  template <class Pred>
  RtStatus wait_status(SharedState& s, Pred pred, std::chrono::milliseconds timeout, bool& ok) {
    RtStatus st{};
    const auto end = std::chrono::steady_clock::now() + timeout;
    ok = false;
    while (std::chrono::steady_clock::now() < end) {
      if (s.rt_status.try_read(st) == ReadStatus::kOk && pred(st)) {
        ok = true;
        break;
      }
      std::this_thread::sleep_for(1ms);
    }
    return st;
  }

  std::filesystem::path dir_;
  std::string shm_;
};

TEST_F(TwoProcess, SamplesPatchForceAndScreenshot) {
  auto rt = start_rt();
  ASSERT_TRUE(rt->running());
  auto viz = start_viz({"--duration", "2", "--screenshot", path("shot.png"), "--stats", path("viz.json")});
  const auto vs = viz->wait_exit(60s);
  ASSERT_TRUE(vs.has_value()) << "lancet-viz did not finish";
  EXPECT_TRUE(WIFEXITED(*vs) && WEXITSTATUS(*vs) == 0) << read_file(path("viz.log"));

  const std::string v = read_file(path("viz.json"));
  ASSERT_FALSE(v.empty()) << read_file(path("viz.log"));
  EXPECT_GE(json_number(v, "samples_received").value_or(0), 1900) << v;
  EXPECT_EQ(json_number(v, "lost").value_or(-1), 0) << v;
  EXPECT_EQ(json_number(v, "out_of_order").value_or(-1), 0) << v;
  EXPECT_GT(json_number(v, "patches_published").value_or(0), 0) << v;
  // Not blank: the surface, tool and overlay give a clearly non-uniform image.
  EXPECT_GT(json_number(v, "screenshot_variance").value_or(0), 200.0) << v;
  ASSERT_TRUE(std::filesystem::exists(path("shot.png")));
  EXPECT_GT(std::filesystem::file_size(path("shot.png")), 10'000u);

  rt->signal(SIGTERM);
  const auto rs = rt->wait_exit(10s);
  ASSERT_TRUE(rs.has_value());
  EXPECT_TRUE(WIFEXITED(*rs) && WEXITSTATUS(*rs) == 0) << read_file(path("rt.log"));
  const std::string r = read_file(path("rt.json"));
  EXPECT_GT(json_number(r, "patches_received").value_or(0), 0) << r;
  EXPECT_GT(json_number(r, "contact_ticks").value_or(0), 0) << r;
  EXPECT_GT(json_number(r, "max_force_n").value_or(0), 0.2) << r;
  EXPECT_EQ(json_number(r, "nan_guards").value_or(-1), 0) << r;
  EXPECT_FALSE(std::filesystem::exists("/dev/shm" + shm_)) << "lancet-rt did not unlink its segment";
}

// The CT phantom's marching-cubes skin as the tissue: the stylus touches it and feels it.
TEST_F(TwoProcess, PhantomSkinTissueGivesContactAndForce) {
  auto rt = start_rt();
  ASSERT_TRUE(rt->running());
  auto viz = start_viz({"--duration", "2.5", "--tissue", "phantom", "--stats", path("viz.json")});
  const auto vs = viz->wait_exit(60s);
  ASSERT_TRUE(vs.has_value()) << "lancet-viz did not finish";
  EXPECT_TRUE(WIFEXITED(*vs) && WEXITSTATUS(*vs) == 0) << read_file(path("viz.log"));
  EXPECT_GT(json_number(read_file(path("viz.json")), "patches_published").value_or(0), 0);
  rt->signal(SIGTERM);
  const auto rs = rt->wait_exit(10s);
  ASSERT_TRUE(rs.has_value());
  const std::string r = read_file(path("rt.json"));
  EXPECT_GT(json_number(r, "contact_ticks").value_or(0), 0) << r;
  EXPECT_GT(json_number(r, "max_force_n").value_or(0), 0.2) << r;
}

TEST_F(TwoProcess, KillingTheVizFadesTheForceToZeroAndRtKeepsRunning) {
  auto rt = start_rt();
  auto ch = SharedChannel::open(shm_);
  ASSERT_TRUE(ch) << ch.error().message;
  SharedState& s = ch.value().state();
  auto viz = start_viz({});
  bool ok = false;
  const RtStatus pressing = wait_status(
      s, [](const RtStatus& st) { return st.viz_alive && st.contact && st.force_scale == 1.0 && norm(st.force) > 0.2; },
      20s, ok);
  ASSERT_TRUE(ok) << "no contact force within 20 s; last force " << norm(pressing.force) << "\n"
                  << read_file(path("viz.log")) << read_file(path("rt.log"));

  viz->signal(SIGKILL);
  ASSERT_TRUE(viz->wait_exit(5s).has_value());
  const RtStatus faded = wait_status(
      s, [](const RtStatus& st) { return !st.viz_alive && st.force_zero_ns != 0; }, 5s, ok);
  ASSERT_TRUE(ok) << "force never reached zero after the viz was killed";
  EXPECT_EQ(faded.force, Vec3{});
  // Measured on lancet-rt's own clock: from the viz's last heartbeat to the first zero-force tick.
  const double ms = static_cast<double>(faded.force_zero_ns - faded.viz_last_beat_ns) / 1e6;
  EXPECT_GT(ms, kTimeoutMs - 1) << "the force must not drop before the timeout";
  EXPECT_LE(ms, kTimeoutMs + kFadeMs + 2.0);

  // lancet-rt keeps running, at zero force.
  const std::uint64_t tick = faded.tick;
  const RtStatus later = wait_status(s, [tick](const RtStatus& st) { return st.tick > tick + 200; }, 5s, ok);
  ASSERT_TRUE(ok);
  EXPECT_EQ(later.force, Vec3{});
  EXPECT_TRUE(rt->running());
  rt->signal(SIGTERM);
  const auto rs = rt->wait_exit(10s);
  ASSERT_TRUE(rs.has_value());
  EXPECT_TRUE(WIFEXITED(*rs) && WEXITSTATUS(*rs) == 0);
}

TEST_F(TwoProcess, VizSurvivesRtGoingAwayAndSaysSo) {
  auto rt = start_rt();
  auto ch = SharedChannel::open(shm_);
  ASSERT_TRUE(ch) << ch.error().message;
  auto viz = start_viz({"--duration", "4", "--stats", path("viz.json"), "--screenshot", path("lost.png")});
  bool ok = false;
  (void)wait_status(ch.value().state(), [](const RtStatus& st) { return st.viz_alive != 0; }, 20s, ok);
  ASSERT_TRUE(ok) << read_file(path("viz.log"));
  rt->signal(SIGKILL);
  ASSERT_TRUE(rt->wait_exit(5s).has_value());

  const auto vs = viz->wait_exit(60s);
  ASSERT_TRUE(vs.has_value());
  EXPECT_TRUE(WIFEXITED(*vs) && WEXITSTATUS(*vs) == 0) << read_file(path("viz.log"));
  const std::string v = read_file(path("viz.json"));
  EXPECT_EQ(json_number(v, "rt_losses").value_or(0), 1) << v;
  EXPECT_NE(v.find("\"link\": \"lost\""), std::string::npos) << v;
  EXPECT_NE(read_file(path("viz.log")).find("lancet-rt is not running"), std::string::npos) << read_file(path("viz.log"));
}

TEST_F(TwoProcess, MismatchedPeerIsRefusedWithBothHashes) {
  // A segment made with another layout hash (as by an older build of lancet-rt).
  auto seg = ShmSegment::create(shm_, sizeof(SharedState), kSharedLayoutHash ^ 0x1234, {});
  ASSERT_TRUE(seg) << seg.error().message;
  seg.value().mark_ready();
  auto viz = start_viz({"--duration", "1"});
  ASSERT_TRUE(viz->wait_exit(30s).has_value());
  const std::string log = read_file(path("viz.log"));
  EXPECT_NE(log.find("layout hash mismatch"), std::string::npos) << log;
  char ours[32];
  std::snprintf(ours, sizeof ours, "0x%016llx", static_cast<unsigned long long>(kSharedLayoutHash));
  EXPECT_NE(log.find(ours), std::string::npos) << log;
}

}  // namespace
}  // namespace lancet
