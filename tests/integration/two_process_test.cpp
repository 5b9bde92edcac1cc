// Starts the real lancet-rt and lancet-viz (headless, through EGL) and checks that they talk:
// samples arrive in order without loss, the tissue patch reaches lancet-rt and produces a force,
// the screenshot is not blank, killing the viz fades the force to zero within the configured
// time while lancet-rt keeps running, and the viz survives lancet-rt going away.
//
// Every run lasts until what it checks has happened (a number of ticks drained by the viz, a
// contact, the end of the scripted hand's trajectory), read from the segment as events, never a
// fixed time: a slower or busier machine only makes the tests take longer. The scripted hands
// start when the tissue does (lancet-rt --script-waits-for-tissue).

#include <fcntl.h>
#include <gtest/gtest.h>
#include <stb/stb_image.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "lancet/shared_model/shared_state.hpp"
#include "process_test.hpp"  // tests/support
#include "shared_data.hpp"   // tests/support
#include "wait.hpp"          // tests/support

namespace lancet {
namespace {

using namespace std::chrono_literals;
using test::Child;
using test::json_number;
using test::read_file;

const std::string kRt = std::string(LANCET_BINARY_DIR) + "/firmware_rt/lancet-rt";
const std::string kViz = std::string(LANCET_BINARY_DIR) + "/host_viz/lancet-viz";
constexpr double kTimeoutMs = 150, kFadeMs = 100;

class TwoProcess : public test::ProcessTest {
 public:
  TwoProcess() : ProcessTest("it") {}
  void SetUp() override {
    // lancet-viz renders headless through EGL: no X server, and none may be assumed.
    unsetenv("DISPLAY");
    // Core files as large as the system allows, so that a crash of lancet-viz can be read after
    // (see ended_how).
    rlimit core{};
    if (getrlimit(RLIMIT_CORE, &core) == 0) {
      core.rlim_cur = core.rlim_max;
      (void)setrlimit(RLIMIT_CORE, &core);
    }
    ProcessTest::SetUp();
  }

  std::unique_ptr<Child> start_rt(const std::vector<std::string>& extra = {}) {
    std::vector<std::string> argv{kRt, "--shm", shm_, "-q", "--stats", path("rt.json"), "--fade-ms", std::to_string(kFadeMs)};
    if (std::find(extra.begin(), extra.end(), "--viz-timeout-ms") == extra.end())
      argv.insert(argv.end(), {"--viz-timeout-ms", std::to_string(kTimeoutMs)});
    argv.insert(argv.end(), extra.begin(), extra.end());
    auto rt = std::make_unique<Child>(argv, path("rt.log"));
    rt_ = rt.get();
    // Wait until its segment is ready, and keep it open to watch the servo.
    EXPECT_TRUE(test::eventually([&] {
      auto ch = SharedChannel::open(shm_);
      if (!ch) return false;
      channel_.emplace(std::move(ch).value());
      return true;
    })) << read_file(path("rt.log"));
    return rt;
  }
  std::unique_ptr<Child> start_viz(const std::vector<std::string>& extra) {
    std::vector<std::string> argv{kViz, "--headless", "--shm", shm_};
    if (std::find(extra.begin(), extra.end(), "--width") == extra.end()) argv.insert(argv.end(), {"--width", "640", "--height", "400"});
    argv.insert(argv.end(), extra.begin(), extra.end());
    // Mesa's GL driver leaks a little at context teardown and is unloaded before LeakSanitizer
    // reports, so the report cannot be suppressed by name: leak checking is off for lancet-viz in
    // sanitizer builds (its session logic is leak-checked by the host_viz unit tests).
    // In this test's folder: a core it dumps lands there (core_pattern "core"), for ended_how().
    auto viz = std::make_unique<Child>(argv, path("viz.log"), std::vector<std::string>{"LSAN_OPTIONS=detect_leaks=0"}, dir_.string());
    viz_ = viz.get();
    return viz;
  }
  /// lancet-rt's latest status (a zero one before the first).
  RtStatus status() {
    RtStatus st{};
    if (channel_) (void)channel_->state().rt_status.try_read(st);
    return st;
  }
  /// Waits (a hang-catching deadline) until lancet-rt's status satisfies pred; returns it.
  template <class Pred>
  RtStatus wait_status(Pred pred, bool& ok) {
    RtStatus st{};
    ok = test::eventually([&] {
      st = status();
      return st.tick > 0 && pred(st);
    });
    return st;
  }
  /// The newest servo tick the viz has applied, as its latest patch says (0: no patch yet).
  std::uint64_t viz_applied() {
    if (!channel_) return 0;
    auto p = std::make_unique<TissuePatch>();
    return channel_->state().patch[0].try_peek(*p) == ReadStatus::kOk ? p->samples_applied : 0;
  }
  /// Waits until the viz has applied `ticks` servo ticks after the first one it applied with a
  /// patch in use by the servo (the scripted hand's clock starts there with
  /// --script-waits-for-tissue). Fails at once, saying how, where either process ends first.
  ::testing::AssertionResult wait_viz_applied_after_tissue(std::uint64_t ticks) {
    bool ok = false;
    const RtStatus first = wait_status([this](const RtStatus& st) { return st.hand[0].patch_version != 0 || ended(); }, ok);
    if (ended()) return ::testing::AssertionFailure() << ended_how();
    if (!ok) return ::testing::AssertionFailure() << "no tissue patch reached the servo";
    // Well inside the test's own time-out, so that a hang is reported here with the logs.
    (void)test::eventually([&] { return viz_applied() >= first.tick + ticks || ended(); }, std::chrono::seconds(120));
    if (ended()) return ::testing::AssertionFailure() << ended_how();
    if (viz_applied() < first.tick + ticks)
      return ::testing::AssertionFailure() << "the viz applied " << viz_applied() - first.tick << " of " << ticks << " ticks in 120 s";
    return ::testing::AssertionSuccess();
  }
  /// Whether the last lancet-viz or lancet-rt started has ended (a run's wait stops there).
  bool ended() {
    using namespace std::chrono_literals;
    return (viz_ != nullptr && viz_->wait_exit(0ms).has_value()) || (rt_ != nullptr && rt_->wait_exit(0ms).has_value());
  }
  std::string ended_how() {
    using namespace std::chrono_literals;
    std::string how;
    for (auto [child, name] : {std::pair{viz_, "lancet-viz"}, std::pair{rt_, "lancet-rt"}}) {
      const auto st = child != nullptr ? child->wait_exit(0ms) : std::nullopt;
      if (!st) continue;
      how += std::string(name) + (WIFSIGNALED(*st) ? " was killed by signal " + std::to_string(WTERMSIG(*st)) + " (" + strsignal(WTERMSIG(*st)) + ")"
                                                   : " exited with status " + std::to_string(WEXITSTATUS(*st))) +
             " before the run was over\n";
      if (child == viz_ && WIFSIGNALED(*st)) how += viz_backtrace();
    }
    return how + "rt.log:\n" + read_file(path("rt.log"));
  }
  /// Every thread's stack in the core lancet-viz dumped in this test's folder, read with gdb
  /// (a rare crash is then explained by the run that had it), or why there is none.
  std::string viz_backtrace() {
    std::error_code ec;
    for (const auto& e : std::filesystem::directory_iterator(dir_, ec)) {
      const std::string name = e.path().filename().string();
      if (name.rfind("core", 0) != 0) continue;
      if (access("/usr/bin/gdb", X_OK) != 0) return "its core is " + e.path().string() + " (gdb is not installed to read it)\n";
      const std::string out = path("viz-backtrace.txt");
      const std::string gdb = "/usr/bin/gdb -batch -q -ex 'thread apply all bt 30' '" + kViz + "' '" + e.path().string() + "' > '" + out + "' 2>&1";
      (void)std::system(gdb.c_str());
      return "its threads at the crash (gdb on " + e.path().string() + ", also in " + out + "):\n" + read_file(out).substr(0, 60'000) + "\n";
    }
    return "it left no core file in " + dir_.string() + " (core_pattern: " + read_file("/proc/sys/kernel/core_pattern") + ")\n";
  }
  /// Asks the viz to end (SIGINT, as Ctrl-C does) and checks that it did, cleanly.
  void stop_viz(Child& viz) {
    viz.signal(SIGINT);
    const auto vs = viz.wait_exit(120s);
    ASSERT_TRUE(vs.has_value()) << "lancet-viz did not end after SIGINT";
    EXPECT_TRUE(WIFEXITED(*vs) && WEXITSTATUS(*vs) == 0) << read_file(path("viz.log"));
  }
  void stop_rt(Child& rt) {
    rt.signal(SIGTERM);
    const auto rs = rt.wait_exit(30s);
    ASSERT_TRUE(rs.has_value());
    EXPECT_TRUE(WIFEXITED(*rs) && WEXITSTATUS(*rs) == 0) << read_file(path("rt.log"));
  }

 private:
  std::optional<SharedChannel> channel_;
  Child* viz_ = nullptr;  // the last started (each test's own, alive through its body)
  Child* rt_ = nullptr;
};

TEST_F(TwoProcess, SamplesPatchForceAndScreenshot) {
  auto rt = start_rt();
  ASSERT_TRUE(rt->running());
  auto viz = start_viz({"--duration", "600", "--screenshot", path("shot.png"), "--stats", path("viz.json")});
  // The viz drains 2000 ticks, publishes patches, and the servo feels the tissue.
  std::uint64_t first = 0;
  ASSERT_TRUE(test::eventually([&] {
    const std::uint64_t a = viz_applied();
    if (first == 0) first = a;
    return first != 0 && a >= first + 2000;
  })) << read_file(path("viz.log"));
  bool ok = false;
  (void)wait_status([](const RtStatus& st) { return st.hand[0].contact != 0 && norm(st.hand[0].force) > 0.2; }, ok);
  ASSERT_TRUE(ok) << "no contact force";
  stop_viz(*viz);

  const std::string v = read_file(path("viz.json"));
  ASSERT_FALSE(v.empty()) << read_file(path("viz.log"));
  // Every tick of both hands (lancet-rt drives two by default) from the first the viz took to the
  // last: in order, none lost (the first and last tick may have brought one hand's sample only).
  EXPECT_EQ(json_number(v, "hands").value_or(0), 2) << v;
  const double received = json_number(v, "samples_received").value_or(0);
  const double ticks = json_number(v, "last_seq").value_or(0) - json_number(v, "first_seq").value_or(0) + 1;
  EXPECT_GE(received, 2000) << v;
  EXPECT_GE(received, 2 * ticks - 2) << v;
  EXPECT_LE(received, 2 * ticks) << v;
  EXPECT_EQ(json_number(v, "lost").value_or(-1), 0) << v;
  EXPECT_EQ(json_number(v, "out_of_order").value_or(-1), 0) << v;
  EXPECT_GT(json_number(v, "patches_published").value_or(0), 0) << v;
  // Not blank: the surface, tool and overlay give a clearly non-uniform image.
  EXPECT_GT(json_number(v, "screenshot_variance").value_or(0), 200.0) << v;
  ASSERT_TRUE(std::filesystem::exists(path("shot.png")));
  EXPECT_GT(std::filesystem::file_size(path("shot.png")), 10'000u);

  stop_rt(*rt);
  const std::string r = read_file(path("rt.json"));
  EXPECT_GT(json_number(r, "patches_received").value_or(0), 0) << r;
  EXPECT_GT(json_number(r, "contact_ticks").value_or(0), 0) << r;
  EXPECT_GT(json_number(r, "max_force_n").value_or(0), 0.2) << r;
  EXPECT_EQ(json_number(r, "nan_guards").value_or(-1), 0) << r;
  EXPECT_FALSE(std::filesystem::exists("/dev/shm" + shm_)) << "lancet-rt did not unlink its segment";
}

// The patch sent to lancet-rt is a developer's view: drawn (cyan wireframe) only with
// --show-patch (or T in the window), never in the default picture.
TEST_F(TwoProcess, ThePatchWireframeIsDrawnOnlyWhenAsked) {
  auto rt = start_rt();
  ASSERT_TRUE(rt->running());
  std::size_t cyan[2] = {0, 0};
  for (const bool show : {false, true}) {
    const std::string png = path(show ? "with_patch.png" : "default.png");
    // Large enough that the panel leaves the tissue in view.
    std::vector<std::string> args{"--duration", "600", "--screenshot", png, "--width", "1280", "--height", "720"};
    if (show) args.push_back("--show-patch");
    auto viz = start_viz(args);
    // Patches published and in use (the picture's last frame has one to draw, or not).
    const std::uint64_t from = status().tick;
    ASSERT_TRUE(test::eventually([&] { return viz_applied() > from + 500; })) << read_file(path("viz.log"));
    stop_viz(*viz);
    int w = 0, h = 0, n = 0;
    unsigned char* px = stbi_load(png.c_str(), &w, &h, &n, 3);
    ASSERT_NE(px, nullptr) << png;
    for (int i = 0; i < w * h; ++i) {
      const unsigned char r = px[3 * i], g = px[3 * i + 1], b = px[3 * i + 2];
      if (r < 100 && g > 180 && b > 200 && std::abs(int{g} - int{b}) < 60) ++cyan[show ? 1 : 0];  // the wireframe's (0.2, 0.85, 0.95)
    }
    stbi_image_free(px);
  }
  RecordProperty("cyan_pixels_default", static_cast<int>(cyan[0]));
  RecordProperty("cyan_pixels_with_patch", static_cast<int>(cyan[1]));
  EXPECT_EQ(cyan[0], 0u) << "the default picture shows the patch's wireframe";
  EXPECT_GT(cyan[1], 500u) << "--show-patch draws no wireframe";
  stop_rt(*rt);
}

// The CT phantom's marching-cubes skin as the tissue: the stylus touches it and feels it.
TEST_F(TwoProcess, PhantomSkinTissueGivesContactAndForce) {
  auto rt = start_rt();
  ASSERT_TRUE(rt->running());
  auto viz = start_viz({"--duration", "600", "--tissue", "phantom", "--stats", path("viz.json")});
  bool ok = false;
  (void)wait_status([](const RtStatus& st) { return st.hand[0].contact != 0 && norm(st.hand[0].force) > 0.2; }, ok);
  ASSERT_TRUE(ok) << "no contact force on the phantom's skin\n" << read_file(path("viz.log"));
  stop_viz(*viz);
  EXPECT_GT(json_number(read_file(path("viz.json")), "patches_published").value_or(0), 0);
  stop_rt(*rt);
  const std::string r = read_file(path("rt.json"));
  EXPECT_GT(json_number(r, "contact_ticks").value_or(0), 0) << r;
  EXPECT_GT(json_number(r, "max_force_n").value_or(0), 0.2) << r;
}

// One line of lancet-viz --trace: a ToolSample as the viz received it (mm and N).
struct TraceRow {
  double t = 0;
  int stage = 0;
  std::uint32_t events = 0;
  Vec3 tool, proxy, force;
  std::uint64_t patch_version = 0;
};

/// The rows of one hand (`want`: "right" or "left") of a --trace file.
std::vector<TraceRow> read_trace(const std::string& file, const std::string& want = "right") {
  std::vector<TraceRow> rows;
  std::ifstream in(file);
  std::string line;
  std::getline(in, line);  // header
  while (std::getline(in, line)) {
    double v[13];
    std::istringstream ss(line);
    char comma = 0;
    for (int k = 0; k < 13; ++k) {
      ss >> v[k];
      ss >> comma;
    }
    std::string hand;
    ss >> hand;
    EXPECT_TRUE(ss) << file << ": " << line;
    if (!ss) break;
    if (hand != want) continue;
    rows.push_back({v[0], static_cast<int>(v[1]), static_cast<std::uint32_t>(v[2]), {v[3], v[4], v[5]}, {v[6], v[7], v[8]},
                    {v[9], v[10], v[11]}, static_cast<std::uint64_t>(v[12])});
  }
  return rows;
}

// What is felt and what is seen agree: the hand holds the stylus 3 mm below the tissue block for
// seconds; every tick from contact on renders k·depth. (The viz once published its dented mesh
// as the haptic patch, so the surface, and the proxy on it, followed the tool down and the force
// shrank while the stylus stayed below the surface; and a stylus that was already below the
// surface when the first patch came was never touched by it.) With `pressed_first`, lancet-viz
// starts once the stylus is already pressed in. The fades' timeouts are generous: this test is
// about the force against the depth, not about how fast a loaded machine draws.
void held_press_is_felt(TwoProcess& fx, bool pressed_first, double hold_s, bool two_hands = false) {
  constexpr double kStiffness = 300;  // N/m, every material
  // With two hands the left one presses too, elsewhere on the block and less deep: each hand
  // against its own patch.
  struct Press {
    const char* hand;
    double x_mm, y_mm, depth_mm;
  };
  std::vector<Press> presses{{"right", 0, 0, 3.0}};
  if (two_hands) presses.push_back({"left", 12, 9, 2.0});
  {
    std::ofstream csv(fx.path("press.csv"));
    csv << "t_s,x_mm,y_mm,z_mm,tool,hand\n";
    for (const Press& p : presses) {
      for (int i = 0; i <= 100 * 600; i += i < 200 ? 1 : 100) {  // then held for ten minutes
        const double t = i * 0.01;
        const double a = t < 1.0 ? 0.5 - 0.5 * std::cos(M_PI * t) : 1.0;  // 10 mm above → depth below z = 0 in 1 s
        csv << t << "," << p.x_mm << "," << p.y_mm << "," << 10.0 + a * (-p.depth_mm - 10.0) << ",," << p.hand << "\n";
      }
    }
  }
  auto rt = fx.start_rt({"--trajectory", fx.path("press.csv"), "--stiffness", std::to_string(kStiffness), "--viz-timeout-ms",
                         "10000", "--stale-patch-ms", "10000", "--hands", two_hands ? "2" : "1"});
  ASSERT_TRUE(rt->running());
  bool ok = false;
  if (pressed_first) {
    (void)fx.wait_status([](const RtStatus& st) { return st.hand[0].tool.z < -0.0025; }, ok);
    ASSERT_TRUE(ok) << "the scripted hand never pressed in";
  }
  auto viz = fx.start_viz({"--duration", "600", "--trace", fx.path("trace.csv"), "--stats", fx.path("viz.json")});
  // Held: from the first contact, hold_s of ticks applied by the viz (so all of them are traced).
  const RtStatus contact = fx.wait_status(
      [two_hands](const RtStatus& st) { return st.hand[0].contact != 0 && (!two_hands || st.hand[1].contact != 0); }, ok);
  ASSERT_TRUE(ok) << "no contact at all\n" << read_file(fx.path("viz.log"));
  const auto hold_ticks = static_cast<std::uint64_t>(hold_s * 1000);
  ASSERT_TRUE(test::eventually([&] { return fx.viz_applied() >= contact.tick + hold_ticks; }, std::chrono::seconds(180)))
      << read_file(fx.path("viz.log"));
  fx.stop_viz(*viz);
  fx.stop_rt(*rt);

  // How deep the proxy sphere (radius 1 mm, HapticParams::proxy_radius) centred on the tool point
  // reaches into the tissue block's rest surface (surface/triangle_mesh: a·sin(x/L)·cos(y/L),
  // a = 3 mm, L = 30 mm), along its normal: k times this is the force to feel.
  const auto depth_m = [](double x, double y, double z) {
    constexpr double a = 0.003, L = 0.03, kProxyRadius = 0.001;
    const double h = a * std::sin(x / L) * std::cos(y / L);
    const double gx = a / L * std::cos(x / L) * std::cos(y / L), gy = -a / L * std::sin(x / L) * std::sin(y / L);
    return (h - z) / std::sqrt(1 + gx * gx + gy * gy) + kProxyRadius;
  };
  for (const Press& press : presses) {
    SCOPED_TRACE(std::string("the ") + press.hand + " hand");
    constexpr std::size_t kSettle = 500;  // ticks after contact while the hand settles against the tissue
    std::size_t rows = 0, since_contact = 0, checked = 0, free_after_contact = 0, faded = 0;
    double worst = 0, min_depth = 1, worst_t = 0, depth_at_contact = 0, contact_t = -1;
    int first_patch_stage = -1;
    for (const TraceRow& r : read_trace(fx.path("trace.csv"), press.hand)) {
      ++rows;
      const double d = depth_m(r.tool.x * 1e-3, r.tool.y * 1e-3, r.tool.z * 1e-3);
      if (first_patch_stage < 0 && r.patch_version != 0) first_patch_stage = r.stage;
      if (contact_t < 0) {
        if (r.stage != 0) contact_t = r.t, depth_at_contact = d;
        continue;
      }
      if (++since_contact < kSettle) continue;
      if (r.stage == 0) ++free_after_contact;
      if ((r.events & event::kForceFaded) != 0) {
        ++faded;
        continue;
      }
      const double f = norm(r.force);
      const double err = std::abs(f - kStiffness * d) / (kStiffness * d);
      if (err > worst) worst = err, worst_t = r.t - contact_t;
      min_depth = std::min(min_depth, d);
      ++checked;
    }
    ASSERT_GE(contact_t, 0) << "no contact in the trace (" << rows << " rows)\n" << read_file(fx.path("viz.log"));
    if (pressed_first) {
      EXPECT_GT(depth_at_contact, 0.003) << "the stylus was already pressed in when the tissue appeared";
      EXPECT_NE(first_patch_stage, 0) << "the first tick with a patch is in contact: the stylus is pushed out at once";
    }
    EXPECT_GE(since_contact + 1, hold_ticks) << "the trace holds every tick of the hold";
    EXPECT_GE(checked + faded, hold_ticks - kSettle);
    EXPECT_EQ(faded, 0u) << "ticks faded (the fades' timeouts are 10 s here)";
    EXPECT_EQ(free_after_contact, 0u) << "ticks without contact while the stylus is held below the surface";
    EXPECT_GT(min_depth, press.depth_mm * 1e-3 - 0.001) << "the stylus stays well below the surface";
    EXPECT_LT(worst, 0.10) << "force against k·depth, worst " << worst * 100 << " % at " << worst_t << " s after contact";
  }
  const std::string viz_stats = read_file(fx.path("viz.json"));
  EXPECT_EQ(json_number(viz_stats, "lost").value_or(-1), 0) << viz_stats;
}

TEST_F(TwoProcess, APressHeldBelowTheSurfaceIsFeltForAsLongAsItLasts) { held_press_is_felt(*this, false, 7); }

TEST_F(TwoProcess, AStylusAlreadyBelowTheSurfaceWhenTheTissueAppearsIsPushedOut) { held_press_is_felt(*this, true, 4); }

// Two hands pressing at once, each somewhere else and to its own depth: each hand's force is its
// own k·depth, against its own patch, tick after tick.
TEST_F(TwoProcess, TwoHandsPressingEachFeelTheirOwnDepth) { held_press_is_felt(*this, false, 5, true); }

// The drill: every patch carries the voxel brick around the tool, lancet-rt's drill passes the
// soft tissue, stops at the bone and removes it voxel by voxel as the hand presses on; lancet-viz
// carves the same removals into its volume (that newer bricks keep them, frame by frame, is
// DrillReconcile's test, in one process). The hand goes down at (0, y_mm) to target_mm,
// below the bone's top, which lies between top_lo_mm and top_hi_mm (the burr rests on it).
void drill_meets_bone(TwoProcess& fx, const std::string& tissue, double y_mm, double target, double top_lo_mm,
                      double top_hi_mm) {
  {
    std::ofstream csv(fx.path("drill.csv"));
    csv << "t_s,x_mm,y_mm,z_mm\n";
    for (int i = 0; i <= 900; ++i) {
      const double t = i * 0.01;
      const double a = t < 2.0 ? 0.5 - 0.5 * std::cos(M_PI * t / 2.0) : 1.0;
      csv << t << ",0," << y_mm << "," << 10.0 + a * (target - 10.0) << "\n";
    }
  }
  // The hand must not be in the bone before the first brick comes (a drill that starts inside bone
  // is not pushed out): its trajectory starts with the tissue. It runs 9 s; the viz applies them all.
  auto viz = fx.start_viz({"--duration", "600", "--tissue", tissue, "--tool", "drill", "--trace", fx.path("trace.csv"), "--stats",
                           fx.path("viz.json")});
  auto rt = fx.start_rt({"--trajectory", fx.path("drill.csv"), "--script-waits-for-tissue"});
  ASSERT_TRUE(rt->running());
  ASSERT_TRUE(fx.wait_viz_applied_after_tissue(9'100)) << read_file(fx.path("viz.log"));
  fx.stop_viz(*viz);
  fx.stop_rt(*rt);

  double first_contact_z = 1, deepest_proxy = 1, max_force = 0, tool_at_contact = 0;
  std::size_t drilling = 0, removals = 0;
  for (const TraceRow& r : read_trace(fx.path("trace.csv"))) {
    if (r.stage != static_cast<int>(Stage::kDrilling)) continue;
    const double proxy_z = r.proxy.z;
    if (drilling++ == 0) first_contact_z = proxy_z, tool_at_contact = r.tool.z;
    if ((r.events & event::kDrillRemove) != 0) ++removals;
    deepest_proxy = std::min(deepest_proxy, proxy_z);
    max_force = std::max(max_force, norm(r.force));
  }
  const std::string stats = read_file(fx.path("viz.json"));
  std::printf("[ info     ] drill on the %s: bone met at z = %.2f mm (tool %.2f mm), %zu ticks drilling, %zu removals, proxy "
              "down to %.2f mm, max force %.2f N\n",
              tissue.c_str(), first_contact_z, tool_at_contact, drilling, removals, deepest_proxy, max_force);
  ASSERT_GT(drilling, 500u) << "the drill met the bone and pressed on it\n" << stats;
  EXPECT_LT(first_contact_z, top_hi_mm) << "the drill passed the skin, fat and muscle";
  EXPECT_GT(first_contact_z, top_lo_mm) << "and stopped at the bone";
  EXPECT_GT(max_force, 2.0) << "the bone resists";
  EXPECT_GT(removals, 3u) << "pressing on, the drill removes bone";
  EXPECT_LT(deepest_proxy, first_contact_z - 1.0) << "and sinks into it as it does";
  EXPECT_EQ(json_number(stats, "drill_removals").value_or(-1), static_cast<double>(removals)) << stats;
  EXPECT_GT(json_number(stats, "voxels_drilled").value_or(0), 0) << stats;
}

// The phantom's bone (radius 13 mm, centre 4 mm below the limb's axis, at y = 6 mm in the world)
// under a skin whose top is at z = 0 at the far end of the tapering limb.
TEST_F(TwoProcess, TheDrillStopsAtThePhantomsBoneAndTheVizKeepsWhatItRemoved) {
  drill_meets_bone(*this, "phantom", 6, -40, -35, -25);
}

// The block's bone plate: 20 mm under its surface (2 mm skin, 6 mm fat, 12 mm muscle).
TEST_F(TwoProcess, TheDrillStopsAtTheBlocksBonePlate) { drill_meets_bone(*this, "block", 0, -28, -23, -17); }

// The demo's scripted hand (docs/examples/demo_incision.csv, what ./lancet demo runs): the scalpel
// presses until the skin ruptures, cuts along the line, lifts out; the retractor grabs beside the
// incision and pulls it open; the swab sweeps the opening. Measured on the viz's mesh: one cut, its
// length, its opening; and the blood: it bled, the swab took some, the ledger held.
TEST_F(TwoProcess, TheDemosScriptedHandCutsAndOpensAnIncision) {
  // As ./lancet demo runs it: lancet-viz on the skin-incision scenario, lancet-rt with the scripted
  // hand, whose 14 s script starts with the tissue; the viz applies all of it.
  auto viz = start_viz({"--scenario", std::string(LANCET_SOURCE_DIR) + "/host_viz/scenarios/skin_incision.toml", "--tool",
                        "none", "--duration", "600", "--trace", path("trace.csv"), "--stats", path("viz.json"), "--screenshot",
                        path("demo.png")});
  auto rt = start_rt({"--trajectory", std::string(LANCET_SOURCE_DIR) + "/docs/examples/demo_incision.csv", "--script-waits-for-tissue"});
  ASSERT_TRUE(rt->running());
  ASSERT_TRUE(wait_viz_applied_after_tissue(14'100)) << read_file(path("viz.log"));
  stop_viz(*viz);
  stop_rt(*rt);
  std::size_t ruptures = 0, cutting = 0, pulls = 0;
  for (const TraceRow& r : read_trace(path("trace.csv"))) {
    ruptures += (r.events & event::kRupture) != 0 ? 1 : 0;
    pulls += (r.events & event::kPull) != 0 ? 1 : 0;
    cutting += r.stage == static_cast<int>(Stage::kCutting) ? 1 : 0;
  }
  const std::string stats = read_file(path("viz.json"));
  std::printf("[ info     ] demo hand: %zu rupture, %zu ticks cutting, %zu pull events; viz: %s cut(s), longest %s mm, "
              "opened %s mm\n",
              ruptures, cutting, pulls, std::to_string(json_number(stats, "cuts").value_or(-1)).c_str(),
              std::to_string(json_number(stats, "longest_cut_mm").value_or(-1)).c_str(),
              std::to_string(json_number(stats, "cut_opening_mm").value_or(-1)).c_str());
  EXPECT_EQ(ruptures, 1u) << "the skin ruptures once under the scalpel";
  EXPECT_GT(cutting, 2000u) << "then the blade cuts for seconds";
  EXPECT_GT(pulls, 5u) << "the retractor pulls";
  EXPECT_EQ(json_number(stats, "cuts").value_or(-1), 1) << stats;
  EXPECT_GT(json_number(stats, "longest_cut_mm").value_or(0), 25) << "the 30 mm line, cut" << stats;
  EXPECT_GT(json_number(stats, "cut_opening_mm").value_or(0), 3) << "and opened, lip to lip on the mesh" << stats;
  // The viz heard lancet-rt's events too (what its overlay tells the trainee).
  EXPECT_EQ(json_number(stats, "ruptures").value_or(-1), 1) << stats;
  EXPECT_GE(json_number(stats, "grabs").value_or(0), 1) << stats;
  EXPECT_GE(json_number(stats, "contacts").value_or(0), 1) << stats;
  // The cut went into the volume along the task's line, and its groove opened with the incision.
  EXPECT_EQ(json_number(stats, "grooves").value_or(-1), 1) << stats;
  EXPECT_GT(json_number(stats, "groove_width_mm").value_or(0), 3) << stats;
  EXPECT_GT(json_number(stats, "groove_depth_mm").value_or(0), 5) << stats;
  EXPECT_GT(json_number(stats, "task_progress").value_or(0), 0.8) << "the line is cut along most of its length" << stats;
  EXPECT_EQ(json_number(stats, "task_damaged").value_or(-1), 0) << "the artery 29 mm down is untouched" << stats;
  EXPECT_GT(json_number(stats, "blood_lost_ml").value_or(0), 0.2) << "the fresh incision oozes" << stats;
  EXPECT_GT(json_number(stats, "blood_swabbed_ml").value_or(0), 0.0) << "the swab took blood from the opening" << stats;
  EXPECT_LT(json_number(stats, "blood_ledger_error").value_or(1), 1e-5) << stats;
  EXPECT_EQ(stats.find("\"vessel_bleeding\": true"), std::string::npos) << "no vessel under the line" << stats;
}

// The two-handed demo (docs/examples/demo_two_hands.csv, what ./lancet demo runs): the right hand
// cuts the first half of the line; the left hand's retractor grabs the incision and holds it open;
// under the held incision the right hand cuts the second half and swabs. The held incision stays
// open while the other hand cuts; the demo is good technique: the safety clamp never limits a
// force.
TEST_F(TwoProcess, TheTwoHandedDemoHoldsTheIncisionOpenWhileTheOtherHandCuts) {
  auto viz = start_viz({"--scenario", std::string(LANCET_SOURCE_DIR) + "/host_viz/scenarios/skin_incision.toml", "--tool",
                        "none", "--duration", "600", "--trace", path("trace.csv"), "--stats", path("viz.json")});
  auto rt = start_rt({"--hands", "2", "--trajectory", std::string(LANCET_SOURCE_DIR) + "/docs/examples/demo_two_hands.csv",
                      "--script-waits-for-tissue"});
  ASSERT_TRUE(rt->running());
  ASSERT_TRUE(wait_viz_applied_after_tissue(13'700)) << read_file(path("viz.log"));
  stop_viz(*viz);
  stop_rt(*rt);
  // Tick by tick (a tick's two rows share its time): the right hand cutting while the left holds.
  std::map<double, int> left_stage;
  std::size_t left_pulls = 0;
  for (const TraceRow& r : read_trace(path("trace.csv"), "left")) {
    left_stage[r.t] = r.stage;
    left_pulls += (r.events & event::kPull) != 0 ? 1 : 0;
  }
  std::size_t cutting = 0, cutting_while_held = 0, ruptures = 0;
  for (const TraceRow& r : read_trace(path("trace.csv"), "right")) {
    ruptures += (r.events & event::kRupture) != 0 ? 1 : 0;
    if (r.stage != static_cast<int>(Stage::kCutting)) continue;
    ++cutting;
    const auto l = left_stage.find(r.t);
    if (l != left_stage.end() && l->second == static_cast<int>(Stage::kPulling)) ++cutting_while_held;
  }
  const std::string stats = read_file(path("viz.json"));
  std::printf("[ info     ] two hands: %zu ruptures, %zu ticks cutting, %zu of them while the left hand held, %zu left pulls; "
              "viz: %s\n",
              ruptures, cutting, cutting_while_held, left_pulls, stats.substr(stats.find("\"cut_widths_mm\"")).c_str());
  // At least twice. Once in about thirty runs (a CI run, 2026-11-27) the blade opened the skin a third
  // time: this is a live run, and where the viz applies a cut later than the scripted blade moves,
  // the blade can meet unopened skin again (its extra cut stays 0 wide). A replay reproduces
  // whatever its recording did, bit for bit (`RecordReplay.*`); a live count depends on the
  // scheduler, which a test must not.
  EXPECT_GE(ruptures, 2u) << "the right hand opens the skin at least twice: the line's two halves";
  EXPECT_LE(ruptures, 3u) << "and at most once more where the blade met unopened skin again";
  EXPECT_GT(cutting_while_held, 1000u) << "the second half is cut under the held incision";
  EXPECT_GT(left_pulls, 5u);
  EXPECT_EQ(json_number(stats, "hands").value_or(0), 2) << stats;
  EXPECT_EQ(json_number(stats, "cuts").value_or(-1), static_cast<double>(ruptures)) << "a cut per rupture" << stats;
  // The held incision was open (its D) at the end, the one cut under it not pulled by the left hand.
  const std::size_t w = stats.find("\"cut_widths_mm\": [");
  ASSERT_NE(w, std::string::npos) << stats;
  double first = 0, second = -1;
  ASSERT_EQ(std::sscanf(stats.c_str() + w, "\"cut_widths_mm\": [%lf, %lf]", &first, &second), 2) << stats;
  EXPECT_GT(first, 3.0) << "the held incision stays open" << stats;
  EXPECT_LT(second, 0.5) << "the left hand pulls only the incision it grabbed" << stats;
  EXPECT_GT(json_number(stats, "task_progress").value_or(0), 0.8) << "the line is cut along most of its length" << stats;
  EXPECT_EQ(json_number(stats, "task_damaged").value_or(-1), 0) << stats;
  EXPECT_GT(json_number(stats, "blood_swabbed_ml").value_or(0), 0.0) << "the right hand's swab took blood from the opening" << stats;
  EXPECT_EQ(json_number(stats, "clamped_ticks").value_or(-1), 0) << "good technique: the safety clamp never limited a force" << stats;
  const std::string r = read_file(path("rt.json"));
  EXPECT_EQ(json_number(r, "clamps").value_or(-1), 0) << r;
  EXPECT_EQ(json_number(r, "nan_guards").value_or(-1), 0) << r;
}

// The bone-drilling scenario with a scripted drill: the burr stops at the exposed bone, lancet-rt
// removes the cortex under it, and the viz carves what it reports into the scene's volume and
// counts it against the window.
// The first 6 s of docs/examples/drill_window.csv: down onto the bone and pressing into it
// harder and harder. (Held on for its last 3 s, a burr may get through the cortex to the canal:
// how far it gets then depends on how often the viz's bricks arrive.)
constexpr std::uint64_t kDrillWindowMs = 6'000;
TEST_F(TwoProcess, TheDrillingScenarioRemovesBoneInTheWindow) {
  auto viz = start_viz({"--scenario", std::string(LANCET_SOURCE_DIR) + "/host_viz/scenarios/bone_drilling.toml", "--tool",
                        "none", "--duration", "600", "--stats", path("viz.json"), "--screenshot", path("drill.png")});
  auto rt = start_rt({"--trajectory", std::string(LANCET_SOURCE_DIR) + "/docs/examples/drill_window.csv", "--script-waits-for-tissue"});
  ASSERT_TRUE(rt->running());
  ASSERT_TRUE(wait_viz_applied_after_tissue(kDrillWindowMs)) << read_file(path("viz.log"));
  stop_viz(*viz);
  stop_rt(*rt);
  const std::string stats = read_file(path("viz.json"));
  std::printf("[ info     ] drilling scenario: %s removals, %s voxels, window %s%% done\n",
              std::to_string(json_number(stats, "drill_removals").value_or(-1)).c_str(),
              std::to_string(json_number(stats, "voxels_drilled").value_or(-1)).c_str(),
              std::to_string(100 * json_number(stats, "task_progress").value_or(-1)).c_str());
  EXPECT_GT(json_number(stats, "drill_removals").value_or(0), 3) << stats;
  EXPECT_GT(json_number(stats, "voxels_drilled").value_or(0), 20) << stats;
  EXPECT_GE(json_number(stats, "bone_updates").value_or(0), 1) << "the bone surface was re-extracted" << stats;
  EXPECT_GT(json_number(stats, "task_progress").value_or(0), 0.02) << "bone of the window is gone" << stats;
  EXPECT_EQ(json_number(stats, "task_damaged").value_or(-1), 0) << "the nerve canal 12 mm below is untouched" << stats;
}

// Every shipped scenario runs (alone: lancet-rt is not needed to look), the CT one on a real scan;
// a broken scenario or a missing CT is refused with the reason and exit status 2.
TEST_F(TwoProcess, EveryShippedScenarioRuns) {
  const std::string dir = std::string(LANCET_SOURCE_DIR) + "/host_viz/scenarios/";
  for (const char* name : {"skin_incision", "bone_drilling"}) {
    // The drilling scenario shows its volume too (ray cast on the GPU path, llvmpipe here).
    const bool drill = std::string(name) == "bone_drilling";
    auto viz = start_viz({"--scenario", dir + name + ".toml", "--duration", "1", "--stats", path("viz.json"), "--view",
                          drill ? "volume" : "mesh", "--preset", drill ? "CT-Bone" : "CT-Soft-Tissue"});
    const auto vs = viz->wait_exit(90s);
    ASSERT_TRUE(vs.has_value() && WIFEXITED(*vs) && WEXITSTATUS(*vs) == 0) << name << "\n" << read_file(path("viz.log"));
    EXPECT_NE(read_file(path("viz.json")).find("\"scenario\": \""), std::string::npos);
    EXPECT_NE(read_file(path("viz.log")).find("task: "), std::string::npos) << read_file(path("viz.log"));
  }
  {  // the CT scenario wants its scan
    auto viz = start_viz({"--scenario", dir + "ct_incision.toml", "--duration", "1"});
    const auto vs = viz->wait_exit(30s);
    ASSERT_TRUE(vs.has_value() && WIFEXITED(*vs));
    EXPECT_EQ(WEXITSTATUS(*vs), 2);
    EXPECT_NE(read_file(path("viz.log")).find("give the CT with --volume PATH"), std::string::npos) << read_file(path("viz.log"));
  }
  {  // a scenario file with a mistake names its line
    std::ofstream(path("bad.toml")) << "schema_version = 1\nname = \"x\"\ndescription = \"y\"\ntools = [\"probe\", \"saw\"]\n";
    auto viz = start_viz({"--scenario", path("bad.toml"), "--duration", "1"});
    const auto vs = viz->wait_exit(30s);
    ASSERT_TRUE(vs.has_value() && WIFEXITED(*vs));
    EXPECT_EQ(WEXITSTATUS(*vs), 2);
    EXPECT_NE(read_file(path("viz.log")).find("bad.toml:4"), std::string::npos) << read_file(path("viz.log"));
  }
  const std::string volumes = test::shared_volumes_dir();
  if (volumes.empty()) return;
  auto viz = start_viz({"--scenario", dir + "ct_incision.toml", "--volume", volumes + "/head_ct_headsq/headsq_64x64x93_int16.mhd",
                        "--duration", "1", "--stats", path("ct.json"), "--screenshot", path("ct.png")});
  const auto vs = viz->wait_exit(90s);
  ASSERT_TRUE(vs.has_value() && WIFEXITED(*vs) && WEXITSTATUS(*vs) == 0) << read_file(path("viz.log"));
  EXPECT_GT(json_number(read_file(path("ct.json")), "screenshot_variance").value_or(0), 100) << "the head is drawn";
}

TEST_F(TwoProcess, KillingTheVizFadesTheForceToZeroAndRtKeepsRunning) {
  auto rt = start_rt();
  auto viz = start_viz({"--duration", "600"});
  bool ok = false;
  const RtStatus pressing =
      wait_status([](const RtStatus& st) { return st.viz_alive && st.hand[0].contact && st.hand[0].force_scale == 1.0 && norm(st.hand[0].force) > 0.2; }, ok);
  ASSERT_TRUE(ok) << "no contact force; last force " << norm(pressing.hand[0].force) << "\n"
                  << read_file(path("viz.log")) << read_file(path("rt.log"));

  viz->signal(SIGKILL);
  ASSERT_TRUE(viz->wait_exit(30s).has_value());
  const RtStatus faded = wait_status([](const RtStatus& st) { return !st.viz_alive && st.force_zero_ns != 0; }, ok);
  ASSERT_TRUE(ok) << "force never reached zero after the viz was killed";
  EXPECT_EQ(faded.hand[0].force, Vec3{});
  EXPECT_EQ(faded.hand[1].force, Vec3{}) << "the viz is both hands': both are at zero";
  // Measured on lancet-rt's own clock: from the viz's last heartbeat to the first zero-force tick.
  // Not before the timeout; by timeout + fade, give or take the gaps between the servo's ticks (the
  // fade counts the servo's time, so a host that stalls the loop delays zero force by the stall
  // at most: force_fade.hpp).
  const double ms = static_cast<double>(faded.force_zero_ns - faded.viz_last_beat_ns) / 1e6;
  const double gap_ms = std::max(1.0, static_cast<double>(faded.longest_stall_ns) / 1e6);
  EXPECT_GT(ms, kTimeoutMs - 1) << "the force must not drop before the timeout";
  EXPECT_LE(ms, kTimeoutMs + kFadeMs + 2 * gap_ms + 1.0) << "the longest gap between ticks was " << gap_ms << " ms";

  // lancet-rt keeps running, at zero force.
  const std::uint64_t tick = faded.tick;
  const RtStatus later = wait_status([tick](const RtStatus& st) { return st.tick > tick + 200; }, ok);
  ASSERT_TRUE(ok);
  EXPECT_EQ(later.hand[0].force, Vec3{});
  EXPECT_EQ(later.hand[1].force, Vec3{});
  EXPECT_TRUE(rt->running());
  stop_rt(*rt);
}

TEST_F(TwoProcess, VizSurvivesRtGoingAwayAndSaysSo) {
  auto rt = start_rt();
  auto viz = start_viz({"--duration", "600", "--stats", path("viz.json"), "--screenshot", path("lost.png")});
  bool ok = false;
  (void)wait_status([](const RtStatus& st) { return st.viz_alive != 0; }, ok);
  ASSERT_TRUE(ok) << read_file(path("viz.log"));
  rt->signal(SIGKILL);
  ASSERT_TRUE(rt->wait_exit(30s).has_value());
  ASSERT_TRUE(test::eventually([&] { return read_file(path("viz.log")).find("lancet-rt is not running") != std::string::npos; }))
      << read_file(path("viz.log"));
  EXPECT_TRUE(viz->running()) << "lancet-viz keeps running without lancet-rt";
  stop_viz(*viz);
  const std::string v = read_file(path("viz.json"));
  EXPECT_EQ(json_number(v, "rt_losses").value_or(0), 1) << v;
  EXPECT_NE(v.find("\"link\": \"lost\""), std::string::npos) << v;
}

// Ctrl-C right after launching ends lancet-viz, also while it is still building its tissue and
// when it was started in the background, where the shell leaves SIGINT ignored (a soak found it
// ignored there until the viz installed its handler, after the build).
TEST_F(TwoProcess, ASigintWhileTheVizBuildsItsTissueEndsIt) {
  struct sigaction ignore {}, old {};
  ignore.sa_handler = SIG_IGN;
  sigemptyset(&ignore.sa_mask);
  ASSERT_EQ(sigaction(SIGINT, &ignore, &old), 0);
  auto viz = start_viz({"--scenario", std::string(LANCET_SOURCE_DIR) + "/host_viz/scenarios/skin_incision.toml", "--duration", "600"});
  sigaction(SIGINT, &old, nullptr);
  ASSERT_TRUE(test::eventually([&] { return read_file(path("viz.log")).find("building the tissue") != std::string::npos; }))
      << read_file(path("viz.log"));
  viz->signal(SIGINT);  // during the build (the phantom's skin takes a while), or at the latest its first frame
  const auto vs = viz->wait_exit(120s);
  ASSERT_TRUE(vs.has_value()) << "SIGINT during start-up was lost: lancet-viz runs on\n" << read_file(path("viz.log"));
  EXPECT_TRUE(WIFEXITED(*vs) && WEXITSTATUS(*vs) == 0) << read_file(path("viz.log"));
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
