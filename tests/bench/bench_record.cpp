// lancet-bench-record: what recording a session costs and how fast it replays. Prints one JSON
// object on stdout.
//
//   lancet-bench-record [--recording FILE.h5] [--quick]
//
// - RT side: a recording adds nothing to lancet-rt's tick but the ToolSample it always pushes,
//   which grew from 400 to sizeof(ToolSample) bytes to carry the step's inputs, plus the servo
//   state hash every kServoHashEvery ticks. Measured: the push of a 400-byte and of the real
//   ToolSample on an SpscRing (single thread, push then pop), the state hash, and the servo step
//   itself on a 128-triangle plane; all as ns and as a share of the 1 ms tick.
// - File size: a 60 s session of the servo step driven by a scripted hand (pressing, cutting),
//   frames every 16 ms, written through record::Recorder: MB per minute.
// - With --recording (a real session, e.g. from scripts/record-demo): its size per minute, the
//   replay's speed (headless, record::Replay::run: recorded seconds per second of replay), and the
//   report's time (metrics + HTML).
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <unistd.h>

#include "lancet/shared_model/spsc_ring.hpp"
#include "recording/hdf5_io.hpp"
#include "score/metrics.hpp"
#include "record/replay.hpp"
#include "score/report.hpp"
#include "servo/servo_step.hpp"
#include "patch_sheet.hpp"  // tests/support

namespace {

using namespace lancet;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

struct OldSample {  // the ToolSample before it carried the step's inputs (protocol 6)
  std::uint8_t bytes[400];
};

template <class T>
double push_pop_ns(std::size_t n) {
  auto ring = std::make_unique<SpscRing<T, 4096>>();
  T v{}, out{};
  double best = 1e30;
  for (int rep = 0; rep < 5; ++rep) {
    const auto t0 = Clock::now();
    for (std::size_t i = 0; i < n; ++i) {
      (void)ring->try_push(v);
      (void)ring->try_pop(out);
    }
    best = std::min(best, seconds_since(t0) * 1e9 / static_cast<double>(n));
  }
  return best;
}

std::unique_ptr<TissuePatch> plane_patch() {
  auto p = std::make_unique<TissuePatch>();
  constexpr int n = 8;
  constexpr float half = 0.04f, s = 2 * half / n;
  test::add_sheet(*p, n, n, -half, -half, s, s, [](float x, float y) { return Vec3f{x, y, 0}; });
  p->seq = 1;
  return p;
}

// One tick of a scripted hand: down onto the plane, press, then a slow figure along x and y.
servo::ServoInput scripted(std::uint64_t i, const TissuePatch* patch, std::span<const std::uint8_t> cmds) {
  servo::ServoInput in;
  in.deadline_ns = static_cast<std::int64_t>(i) * 1'000'000;
  in.woke_ns = in.deadline_ns + 20'000;
  const double t = static_cast<double>(i) * 1e-3;
  in.reading.n = 3;
  in.reading.q = {0.02 * std::sin(0.7 * t), 0.01 * std::sin(0.3 * t), std::max(-0.004, 0.01 - 0.02 * t) + 0.0005 * std::sin(9 * t)};
  in.reading.qd = {0.014 * std::cos(0.7 * t), 0.003 * std::cos(0.3 * t), 0.0045 * std::cos(9 * t)};
  in.commands = cmds;
  in.patch = patch;
  in.patch_version = 1 + i / 16;
  in.viz_alive = true;
  return in;
}

}  // namespace

int main(int argc, char** argv) {
  std::string recording_path;
  bool quick = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--quick") {
      quick = true;
    } else if (a == "--recording" && i + 1 < argc) {
      recording_path = argv[++i];
    } else {
      std::fprintf(stderr, "usage: lancet-bench-record [--recording FILE.h5] [--quick]\n");
      return 2;
    }
  }
  const std::size_t n = quick ? 200'000 : 2'000'000;

  // RT side.
  const double push_old = push_pop_ns<OldSample>(n), push_new = push_pop_ns<ToolSample>(n);
  servo::ServoModel model;
  model.max_joint_torque[0] = model.max_joint_torque[1] = model.max_joint_torque[2] = model.haptic.safety.max_force;
  const auto patch = plane_patch();
  servo::ServoData data;
  servo::ServoOutput out;
  const std::uint8_t scalpel[] = {servo::pack_command(CommandKind::kSetToolMode, ToolMode::kScalpel)};
  const std::size_t ticks = quick ? 20'000 : 60'000;  // 60 s of session
  std::vector<ToolSample> session;
  session.reserve(ticks);
  auto t0 = Clock::now();
  for (std::uint64_t i = 1; i <= ticks; ++i) {
    servo::servo_step(model, data, scripted(i, patch.get(), i == 5 ? std::span<const std::uint8_t>(scalpel) : std::span<const std::uint8_t>{}), out);
    session.push_back(out.sample);
  }
  const double step_ns = seconds_since(t0) * 1e9 / static_cast<double>(ticks);
  t0 = Clock::now();
  std::uint64_t sink = 0;
  const std::size_t hashes = quick ? 20'000 : 200'000;
  for (std::size_t i = 0; i < hashes; ++i) {
    data.tick += 1;
    sink ^= servo::state_hash(data);
  }
  const double hash_ns = seconds_since(t0) * 1e9 / static_cast<double>(hashes);

  // File size of a scripted session.
  record::Recording synth;
  synth.lancet_version = "bench";
  synth.servo_hash_every = servo::kServoHashEvery;
  synth.samples = session;
  for (std::uint64_t k = 0; k * 16 < ticks; ++k) {
    record::FrameRecord f;
    f.frame = k;
    f.t_ns = static_cast<std::int64_t>(k) * 16'000'000;
    f.last_seq = std::min<std::uint64_t>(ticks, (k + 1) * 16);
    f.ticks = f.last_seq - std::min<std::uint64_t>(ticks, k * 16);
    f.blood_dt = 0.016;
    f.patch_version = k + 2;
    f.blood_lost_ml = 0.001 * static_cast<double>(k);
    synth.frames.push_back(f);
  }
  const std::string tmp = (std::filesystem::temp_directory_path() / ("lancet-bench-record-" + std::to_string(getpid()) + ".h5")).string();
  t0 = Clock::now();
  if (const auto w = record::write_recording(tmp, synth); !w.ok()) {
    std::fprintf(stderr, "lancet-bench-record: %s\n", w.error().message.c_str());
    return 1;
  }
  const double write_s = seconds_since(t0);
  const double synth_mb_min = static_cast<double>(std::filesystem::file_size(tmp)) / 1e6 / (static_cast<double>(ticks) * 1e-3 / 60.0);
  std::filesystem::remove(tmp);

  std::printf("{\n  \"tool_sample_bytes\": %zu,\n  \"old_tool_sample_bytes\": %zu,\n", sizeof(ToolSample), sizeof(OldSample));
  std::printf("  \"ring_push_pop_ns\": {\"old\": %.1f, \"now\": %.1f, \"now_over_old\": %.3f},\n", push_old, push_new,
              push_new / push_old);
  std::printf("  \"state_hash_ns\": %.1f,\n  \"state_hash_per_tick_ns\": %.2f,\n  \"servo_step_ns\": %.1f,\n", hash_ns,
              hash_ns / static_cast<double>(servo::kServoHashEvery), step_ns);
  std::printf("  \"rt_cost_of_recording_share_of_tick\": %.5f,\n",
              ((push_new - push_old) + hash_ns / static_cast<double>(servo::kServoHashEvery)) / 1e6);
  std::printf("  \"scripted_session\": {\"seconds\": %.0f, \"write_s\": %.3f, \"mb_per_minute\": %.2f}", static_cast<double>(ticks) * 1e-3,
              write_s, synth_mb_min);

  if (!recording_path.empty()) {
    auto rec = record::read_recording(recording_path);
    if (!rec.ok()) {
      std::fprintf(stderr, "lancet-bench-record: %s\n", rec.error().message.c_str());
      return 1;
    }
    const record::Recording& r = rec.value();
    const double duration = static_cast<double>(r.samples.back().t_ns - r.samples.front().t_ns) * 1e-9;
    t0 = Clock::now();
    auto rp = record::Replay::create(r);
    if (!rp.ok()) {
      std::fprintf(stderr, "lancet-bench-record: %s\n", rp.error().message.c_str());
      return 1;
    }
    const double setup_s = seconds_since(t0);
    t0 = Clock::now();
    auto check = rp.value()->run();
    const double replay_s = seconds_since(t0);
    if (!check.ok()) {
      std::fprintf(stderr, "lancet-bench-record: %s\n", check.error().message.c_str());
      return 1;
    }
    t0 = Clock::now();
    auto sc = scenario::parse_scenario(r.scenario_toml, r.scenario_file);
    const score::Metrics m = score::compute_metrics(r, sc.ok() ? &sc.value() : nullptr);
    const std::string html = score::report_html({{recording_path, &r, m}});
    const double report_s = seconds_since(t0);
    std::printf(",\n  \"recording\": {\"file\": \"%s\", \"seconds\": %.2f, \"ticks\": %zu, \"frames\": %zu, \"mb_per_minute\": %.2f,\n",
                recording_path.c_str(), duration, r.samples.size(), r.frames.size(),
                static_cast<double>(std::filesystem::file_size(recording_path)) / 1e6 / (duration / 60.0));
    std::printf("    \"replay_setup_s\": %.3f, \"replay_s\": %.3f, \"replay_x_real_time\": %.1f, \"replay_x_real_time_with_setup\": %.1f, "
                "\"bit_exact\": %s,\n",
                setup_s, replay_s, duration / replay_s, duration / (replay_s + setup_s), check.value().exact() ? "true" : "false");
    const record::ReplayTiming& tm = rp.value()->timing();
    std::printf("    \"replay_split_s\": {\"servo\": %.3f, \"scene\": %.3f, \"patch\": %.3f, \"blood\": %.3f, \"hash\": %.3f},\n",
                tm.servo, tm.scene, tm.patch, tm.blood, tm.hash);
    std::printf("    \"report_s\": %.4f, \"report_html_bytes\": %zu}", report_s, html.size());
  }
  std::printf(",\n  \"sink\": %llu\n}\n", static_cast<unsigned long long>(sink & 1));
  return 0;
}
