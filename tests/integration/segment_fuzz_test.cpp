// Both real processes on one segment while this test garbles random bytes of it: ring indices and
// their cached copies, ring slots, the patch's triple buffer (published word, claim, doorbell,
// slots), seqlock counters and payloads (stylus target, status, operator request), heartbeats and
// the segment header. The garbling goes on until both have lived through it (lancet-rt a
// thousand ticks, lancet-viz thirty frames, counted by their own counters), whatever the
// machine's speed. Neither process may hang (both end when asked), the force lancet-rt commands
// stays finite and within its clamp, and both count what they rejected.

#include <gtest/gtest.h>
#include <sys/mman.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <random>
#include <string>

#include "lancet/shared_model/shared_state.hpp"
#include "process.hpp"  // tests/support
#include "wait.hpp"     // tests/support

namespace lancet {
namespace {

using namespace std::chrono_literals;
using test::Child;
using test::json_number;
using test::read_file;

const std::string kRt = std::string(LANCET_BINARY_DIR) + "/firmware_rt/lancet-rt";
const std::string kViz = std::string(LANCET_BINARY_DIR) + "/host_viz/lancet-viz";

/// A part of the segment to garble, and how often (weight).
struct Region {
  const char* name;
  std::size_t offset;  ///< from the payload start (negative regions: the header, below)
  std::size_t size;
  int weight;
};

template <class Ring>
void add_ring(std::vector<Region>& out, const char* name, std::size_t base) {
  out.push_back({name, base + Ring::head_offset(), 8, 6});        // producer index
  out.push_back({name, base + Ring::head_offset() + 64, 8, 2});   // producer's cached tail
  out.push_back({name, base + Ring::tail_offset(), 8, 6});        // consumer index
  out.push_back({name, base + Ring::tail_offset() + 64, 8, 2});   // consumer's cached head
  out.push_back({name, base + Ring::tail_offset() + 128, sizeof(Ring) - Ring::tail_offset() - 128, 4});  // slots
}
template <class Lock>
void add_seqlock(std::vector<Region>& out, const char* name, std::size_t base, int weight) {
  out.push_back({name, base, 8, weight});                      // the sequence counter
  out.push_back({name, base + 64, sizeof(Lock) - 64, weight});  // the payload words
}

TEST(SegmentFuzz, BothProcessesSurviveRandomBytesAcrossTheLiveSegment) {
  // lancet-viz renders headless through EGL: no X server, and none may be assumed.
  unsetenv("DISPLAY");
  const auto dir = std::filesystem::temp_directory_path() / ("lancet-segfuzz-" + std::to_string(getpid()));
  std::filesystem::create_directories(dir);
  const std::string shm = "/lancet-segfuzz-" + std::to_string(getpid());
  const auto path = [&](const char* f) { return (dir / f).string(); };
  constexpr double kMaxForce = 6;

  Child rt({kRt, "--shm", shm, "-q", "--no-rt", "--duration", "600", "--max-force", std::to_string(kMaxForce), "--stats",
            path("rt.json")},
           path("rt.log"));
  ASSERT_TRUE(test::eventually([&] { return SharedChannel::open(shm).ok(); })) << read_file(path("rt.log"));
  auto ch = SharedChannel::open(shm);
  ASSERT_TRUE(ch.ok()) << ch.error().message;
  SharedState& state = ch.value().state();
  Child viz({kViz, "--headless", "--shm", shm, "--width", "320", "--height", "200", "--duration", "600", "--stats",
             path("viz.json")},
            path("viz.log"), {"LSAN_OPTIONS=detect_leaks=0"});
  // Connected and touching before the garbling starts: lancet-rt uses a patch of the viz's.
  const auto status = [&] {
    RtStatus st{};
    return state.rt_status.try_read(st) == ReadStatus::kOk ? st : RtStatus{};
  };
  ASSERT_TRUE(test::eventually([&] { return status().viz_alive != 0 && status().hand[0].patch_version != 0; }))
      << read_file(path("viz.log"));

  std::vector<Region> regions;
  add_ring<decltype(SharedState::samples)>(regions, "samples", offsetof(SharedState, samples));
  add_ring<decltype(SharedState::commands)>(regions, "commands", offsetof(SharedState, commands));
  // Each hand's patch and stylus target.
  using PatchBuffer = std::remove_extent_t<decltype(SharedState::patch)>;
  using TargetLock = std::remove_extent_t<decltype(SharedState::stylus_target)>;
  for (std::size_t h = 0; h < kHandCount; ++h) {
    add_seqlock<PatchBuffer>(regions, "patch", offsetof(SharedState, patch) + h * sizeof(PatchBuffer), 4);
    add_seqlock<TargetLock>(regions, "stylus_target", offsetof(SharedState, stylus_target) + h * sizeof(TargetLock), 3);
  }
  add_seqlock<decltype(SharedState::rt_status)>(regions, "rt_status", offsetof(SharedState, rt_status), 3);
  add_seqlock<decltype(SharedState::operator_request)>(regions, "operator_request", offsetof(SharedState, operator_request), 2);
  regions.push_back({"rt_heartbeat", offsetof(SharedState, rt_heartbeat), sizeof(Heartbeat), 2});
  // The viz's heartbeat: its time stamp only (its beat count is how this test counts the viz's
  // frames; the count is no input to lancet-rt).
  regions.push_back({"viz_heartbeat", offsetof(SharedState, viz_heartbeat), sizeof(std::int64_t), 2});
  std::vector<int> weights;
  for (const Region& r : regions) weights.push_back(r.weight);
  weights.push_back(1);  // the segment header
  std::discrete_distribution<std::size_t> pick(weights.begin(), weights.end());

  auto* payload = reinterpret_cast<unsigned char*>(&ch.value().state());
  auto* header = payload - kSegmentPayloadOffset;
  std::mt19937_64 rng(20261124);
  std::uint64_t writes = 0;
  // Until both have lived through enough of it: lancet-rt's own tick counter (kept in its process;
  // read from the stats it writes at the end, so here its status, when readable) and the viz's
  // beat count (one a frame).
  std::uint64_t rt_ticks_seen = 0;
  const std::uint64_t viz_beats0 = state.viz_heartbeat.count();
  const auto deadline = std::chrono::steady_clock::now() + 3 * test::kHangTimeout;
  const auto lived_through = [&] {
    if (const std::uint64_t t = status().tick; t > rt_ticks_seen && t < rt_ticks_seen + 1'000'000'000) rt_ticks_seen = t;
    return writes >= 20'000 && state.viz_heartbeat.count() >= viz_beats0 + 30;
  };
  const std::uint64_t rt_tick0 = status().tick;
  while (!lived_through() || rt_ticks_seen < rt_tick0 + 1000) {
    ASSERT_LT(std::chrono::steady_clock::now(), deadline) << "after " << writes << " writes: lancet-rt at tick " << rt_ticks_seen
                                                          << " (from " << rt_tick0 << "), the viz " << state.viz_heartbeat.count() - viz_beats0
                                                          << " frames in: one of them stopped";
    const std::size_t k = pick(rng);
    unsigned char* base = k < regions.size() ? payload + regions[k].offset : header;
    const std::size_t size = k < regions.size() ? regions[k].size : sizeof(SegmentHeader);
    const std::size_t n = 1 + rng() % 8;
    const std::size_t at = size > n ? rng() % (size - n) : 0;
    for (std::size_t i = 0; i < n && at + i < size; ++i) base[at + i] = static_cast<unsigned char>(rng());
    ++writes;
    if (writes % 4 == 0) std::this_thread::sleep_for(200us);
  }

  // Both still answer: asked to end, they end, cleanly.
  viz.signal(SIGINT);
  const auto viz_status = viz.wait_exit(120s);
  rt.signal(SIGTERM);
  const auto rt_status = rt.wait_exit(120s);
  ASSERT_TRUE(rt_status.has_value()) << "lancet-rt hung\n" << read_file(path("rt.log"));
  ASSERT_TRUE(viz_status.has_value()) << "lancet-viz hung\n" << read_file(path("viz.log"));
  EXPECT_TRUE(WIFEXITED(*rt_status) && WEXITSTATUS(*rt_status) == 0) << read_file(path("rt.log"));
  EXPECT_TRUE(WIFEXITED(*viz_status) && WEXITSTATUS(*viz_status) == 0) << read_file(path("viz.log"));

  const std::string rs = read_file(path("rt.json")), vs = read_file(path("viz.json"));
  const double max_force = json_number(rs, "max_force_n").value_or(-1);
  EXPECT_TRUE(std::isfinite(max_force) && max_force >= 0) << rs;
  EXPECT_LE(max_force, kMaxForce + 1e-9) << rs;
  EXPECT_GE(json_number(rs, "ticks").value_or(0), static_cast<double>(rt_tick0 + 1000)) << "the servo kept ticking\n" << rs;
  const double rt_rejected = json_number(rs, "ring_resets").value_or(0) + json_number(rs, "commands_rejected").value_or(0) +
                             json_number(rs, "patches_rejected").value_or(0) + json_number(rs, "targets_rejected").value_or(0) +
                             json_number(rs, "sample_ring_resets").value_or(0);
  EXPECT_GT(rt_rejected, 0) << "lancet-rt counts what it rejected\n" << rs;
  const double viz_rejected = json_number(vs, "samples_rejected").value_or(0) + json_number(vs, "sample_ring_resets").value_or(0) +
                              json_number(vs, "status_rejected").value_or(0);
  EXPECT_GT(viz_rejected, 0) << "lancet-viz counts what it rejected\n" << vs;
  std::printf("garbled %llu times; lancet-rt rejected/reset %.0f, lancet-viz %.0f; max force %.3f N\n",
              static_cast<unsigned long long>(writes), rt_rejected, viz_rejected, max_force);
  shm_unlink(shm.c_str());
  if (!HasFailure()) std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace lancet
