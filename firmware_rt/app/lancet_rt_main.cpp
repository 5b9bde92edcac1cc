// lancet-rt: the 1 kHz servo process. Creates the shared-memory segment, runs the servo loop
// with the simulated stylus, and pushes one ToolSample per tick to lancet-viz.

#include <unistd.h>

#include <CLI/CLI.hpp>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <thread>

#include "app/rt_servo.hpp"
#include "rt/periodic_timer.hpp"
#include "rt/rt_setup.hpp"

namespace {

std::atomic<bool> g_stop{false};
static_assert(std::atomic<bool>::is_always_lock_free, "the stop flag is set from a signal handler");

extern "C" void on_signal(int) { g_stop.store(true, std::memory_order_relaxed); }

bool write_stats(const std::string& path, const lancet::app::RtServo& servo, const lancet::SharedState& shared) {
  const lancet::app::RtData& d = servo.data();
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (f == nullptr) return false;
  std::fprintf(f,
               "{\n  \"ticks\": %llu,\n  \"overruns\": %llu,\n  \"max_wake_latency_us\": %.1f,\n"
               "  \"samples_pushed\": %llu,\n  \"samples_dropped\": %llu,\n  \"patches_received\": %llu,\n"
               "  \"contact_ticks\": %llu,\n  \"max_force_n\": %.6f,\n  \"nan_guards\": %llu,\n  \"clamps\": %llu,\n"
               "  \"commands_applied\": %llu,\n  \"viz_lost_at_beat_ns\": %lld,\n  \"force_zero_ns\": %lld\n}\n",
               static_cast<unsigned long long>(d.tick), static_cast<unsigned long long>(d.overruns),
               static_cast<double>(d.max_wake_latency_ns) / 1e3,
               static_cast<unsigned long long>(shared.samples.pushed_count()),
               static_cast<unsigned long long>(shared.samples.overflow_count()),
               static_cast<unsigned long long>(d.patches_received), static_cast<unsigned long long>(d.contact_ticks),
               d.max_force_seen, static_cast<unsigned long long>(d.nan_guards),
               static_cast<unsigned long long>(d.clamps), static_cast<unsigned long long>(d.commands_applied),
               static_cast<long long>(d.viz_lost_at_beat_ns), static_cast<long long>(d.force_zero_ns));
  return std::fclose(f) == 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App cli{"lancet-rt: 1 kHz haptic servo process (simulated stylus)"};
  std::string shm = lancet::kDefaultShmName;
  double duration = 0;
  double period_us = 1000;
  bool no_rt = false;
  bool quiet = false;
  int priority = 80;
  std::string stats_path;
  lancet::app::RtModel model;
  double timeout_ms = 150, fade_ms = 100;
  cli.add_option("--shm", shm, "shared-memory segment name")->capture_default_str();
  cli.add_option("--duration", duration, "seconds to run; 0 runs until SIGINT/SIGTERM")->check(CLI::NonNegativeNumber);
  cli.add_option("--period-us", period_us, "servo period in microseconds")->check(CLI::Range(100.0, 100000.0))->capture_default_str();
  cli.add_option("--priority", priority, "SCHED_FIFO priority")->check(CLI::Range(1, 98))->capture_default_str();
  cli.add_flag("--no-rt", no_rt, "do not try mlockall/SCHED_FIFO");
  cli.add_flag("-q,--quiet", quiet, "no once-a-second status line");
  cli.add_option("--stiffness", model.contact.stiffness, "contact stiffness (N/m)")->check(CLI::Range(0.0, 5000.0))->capture_default_str();
  cli.add_option("--max-force", model.max_force, "force clamp (N)")->check(CLI::Range(0.0, 40.0))->capture_default_str();
  cli.add_option("--viz-timeout-ms", timeout_ms, "viz heartbeat age after which the force fades")->check(CLI::Range(1.0, 10000.0))->capture_default_str();
  cli.add_option("--fade-ms", fade_ms, "time for the force to fade from full to zero")->check(CLI::Range(0.0, 10000.0))->capture_default_str();
  cli.add_option("--depth-mm", model.script_depth, "how deep below the surface the script presses (mm)")
      ->transform([](std::string s) { return std::to_string(std::stod(s) * 1e-3); })->check(CLI::Range(0.0, 0.05));
  cli.add_option("--stats", stats_path, "write a JSON summary here on exit");
  CLI11_PARSE(cli, argc, argv);

  model.period_ns = static_cast<std::int64_t>(period_us * 1e3);
  model.fade.timeout_ns = static_cast<std::int64_t>(timeout_ms * 1e6);
  model.fade.fade_ns = static_cast<std::int64_t>(fade_ms * 1e6);

  lancet::ShmSegment::CreateOptions seg_opts;
  seg_opts.creator_name = "lancet-rt";
  auto channel = lancet::SharedChannel::create(shm, seg_opts);
  if (!channel) {
    std::fprintf(stderr, "lancet-rt: %s\n", channel.error().message.c_str());
    return 2;
  }
  for (const auto& note : channel.value().segment().notes()) std::fprintf(stderr, "lancet-rt: %s\n", note.c_str());
  lancet::SharedState& shared = channel.value().state();

  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);

  // Status printing happens here, off the servo thread, from the RtStatus seqlock. It starts
  // before the real-time setup so that it does not inherit SCHED_FIFO.
  std::thread reporter;
  if (!quiet) {
    reporter = std::thread([&shared] {
      lancet::RtStatus st{};
      while (!g_stop.load(std::memory_order_relaxed)) {
        for (int i = 0; i < 10 && !g_stop.load(std::memory_order_relaxed); ++i) {
          std::this_thread::sleep_for(std::chrono::milliseconds(100));
        }
        if (shared.rt_status.try_read(st) != lancet::ReadStatus::kOk) continue;
        std::fprintf(stderr, "lancet-rt: tick %llu  force %.2f N  scale %.2f  viz %s  patch v%llu  overruns %llu  dropped %llu\n",
                     static_cast<unsigned long long>(st.tick), lancet::norm(st.force), st.force_scale,
                     st.viz_alive ? "alive" : "absent", static_cast<unsigned long long>(st.patch_version),
                     static_cast<unsigned long long>(st.overruns), static_cast<unsigned long long>(st.samples_dropped));
      }
    });
  }

  const auto setup = lancet::rt::apply_rt_setup({!no_rt, priority});
  for (const auto& line : setup.degraded) std::fprintf(stderr, "lancet-rt: degraded: %s\n", line.c_str());
  const std::int64_t start = lancet::monotonic_ns();
  lancet::app::RtServo servo(model, shared, start);  // allocated after mlockall: locked too
  lancet::rt::PeriodicTimer timer(model.period_ns, start);
  const std::int64_t end = duration > 0 ? start + lancet::seconds_to_ns(duration) : INT64_MAX;
  std::fprintf(stderr, "lancet-rt: running at %.0f Hz on segment %s (pid %d)%s\n", 1e9 / static_cast<double>(model.period_ns),
               shm.c_str(), static_cast<int>(getpid()), setup.fifo ? ", SCHED_FIFO" : "");

  while (!g_stop.load(std::memory_order_relaxed)) {
    const lancet::rt::Wake w = timer.wait();
    if (w.deadline_ns >= end) break;
    servo.tick(w.deadline_ns, w.woke_ns, timer.overruns());
  }
  g_stop.store(true);
  if (reporter.joinable()) reporter.join();
  shared.rt_heartbeat.stop();

  const auto& d = servo.data();
  std::fprintf(stderr, "lancet-rt: stopped after %llu ticks, %llu overruns, %llu samples dropped, max force %.2f N\n",
               static_cast<unsigned long long>(d.tick), static_cast<unsigned long long>(d.overruns),
               static_cast<unsigned long long>(shared.samples.overflow_count()), d.max_force_seen);
  if (!stats_path.empty() && !write_stats(stats_path, servo, shared)) {
    std::fprintf(stderr, "lancet-rt: cannot write stats to %s\n", stats_path.c_str());
    return 1;
  }
  return 0;
}
