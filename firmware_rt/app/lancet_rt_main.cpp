// lancet-rt: the 1 kHz servo process. Creates the shared-memory segment, runs the servo loop
// with the simulated stylus, and pushes one ToolSample per tick to lancet-viz.

#include <unistd.h>

#include <CLI/CLI.hpp>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <thread>

#include <memory>
#include <optional>

#include "app/device_factory.hpp"
#include "app/rt_servo.hpp"
#include "app/rt_cli.hpp"
#include "rt/rt_loop.hpp"
#include "rt/rt_setup.hpp"

namespace {

std::atomic<bool> g_stop{false};
static_assert(std::atomic<bool>::is_always_lock_free, "the stop flag is set from a signal handler");

extern "C" void on_signal(int) { g_stop.store(true, std::memory_order_relaxed); }

bool write_stats(const std::string& path, const lancet::app::RtServo& servo, const lancet::rt::RtLoop& loop,
                 const lancet::SharedState& shared) {
  const lancet::app::RtData& d = servo.data();
  const lancet::rt::LoopStats& ls = loop.stats();
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (f == nullptr) return false;
  std::fprintf(f,
               "{\n  \"ticks\": %llu,\n  \"overruns\": %llu,\n  \"missed\": %llu,\n"
               "  \"wake_p50_us\": %.1f,\n  \"wake_p99_us\": %.1f,\n  \"wake_max_us\": %.1f,\n"
               "  \"compute_p99_us\": %.1f,\n  \"longest_stall_us\": %.1f,\n  \"watchdog_trips\": %llu,\n"
               "  \"samples_pushed\": %llu,\n  \"samples_dropped\": %llu,\n  \"patches_received\": %llu,\n"
               "  \"contact_ticks\": %llu,\n  \"max_force_n\": %.6f,\n  \"nan_guards\": %llu,\n  \"clamps\": %llu,\n"
               "  \"commands_applied\": %llu,\n  \"viz_lost_at_beat_ns\": %lld,\n  \"force_zero_ns\": %lld\n}\n",
               static_cast<unsigned long long>(ls.ticks), static_cast<unsigned long long>(ls.overruns),
               static_cast<unsigned long long>(ls.missed), static_cast<double>(ls.wake_latency.percentile_ns(50)) / 1e3,
               static_cast<double>(ls.wake_latency.percentile_ns(99)) / 1e3,
               static_cast<double>(ls.wake_latency.max_ns()) / 1e3, static_cast<double>(ls.compute.percentile_ns(99)) / 1e3,
               static_cast<double>(ls.longest_stall_ns) / 1e3, static_cast<unsigned long long>(loop.watchdog().trips()),
               static_cast<unsigned long long>(shared.samples.pushed_count()),
               static_cast<unsigned long long>(shared.samples.overflow_count()),
               static_cast<unsigned long long>(d.patches_received), static_cast<unsigned long long>(d.contact_ticks),
               d.max_force_seen, static_cast<unsigned long long>(d.haptic.safety.nan_guards),
               static_cast<unsigned long long>(d.haptic.safety.clamps), static_cast<unsigned long long>(d.commands_applied),
               static_cast<long long>(d.viz_lost_at_beat_ns), static_cast<long long>(d.force_zero_ns));
  return std::fclose(f) == 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App cli{"lancet-rt: 1 kHz haptic servo process (built-in simulated stylus, or an arm from hw_configs)"};
  std::string shm = lancet::kDefaultShmName;
  double duration = 0;
  bool quiet = false;
  lancet::app::RtCliOptions rt_opts;
  std::string stats_path;
  lancet::app::RtModel model;
  double timeout_ms = 150, fade_ms = 100;
  cli.add_option("--shm", shm, "shared-memory segment name")->capture_default_str();
  cli.add_option("--duration", duration, "seconds to run; 0 runs until SIGINT/SIGTERM")->check(CLI::NonNegativeNumber);
  lancet::app::add_rt_options(cli, rt_opts);
  cli.add_flag("-q,--quiet", quiet, "no once-a-second status line");
  double stiffness = 0;
  cli.add_option("--stiffness", stiffness, "contact stiffness of every material (N/m); default: per material")
      ->check(CLI::Range(1.0, 5000.0));
  cli.add_option("--max-force", model.haptic.safety.max_force, "force clamp (N)")->check(CLI::Range(0.0, 40.0))->capture_default_str();
  cli.add_option("--viz-timeout-ms", timeout_ms, "viz heartbeat age after which the force fades")->check(CLI::Range(1.0, 10000.0))->capture_default_str();
  cli.add_option("--fade-ms", fade_ms, "time for the force to fade from full to zero")->check(CLI::Range(0.0, 10000.0))->capture_default_str();
  cli.add_option("--depth-mm", model.script_depth, "how deep below the surface the script presses (mm)")
      ->transform([](std::string s) { return std::to_string(std::stod(s) * 1e-3); })->check(CLI::Range(0.0, 0.05));
  cli.add_option("--stats", stats_path, "write a JSON summary here on exit");
  std::string config_path, trajectory_path;
  cli.add_option("--trajectory", trajectory_path,
                 "replay this recorded hand trajectory (CSV: t_s, x_mm, y_mm, z_mm) instead of the built-in script");
  cli.add_option("--config", config_path,
                 "drive the arm described by this hw_configs TOML file (backend sim; the others as they land) instead of the "
                 "built-in stylus");
  CLI11_PARSE(cli, argc, argv);

  std::optional<lancet::device::Trajectory> trajectory;
  if (!trajectory_path.empty()) {
    auto tr = lancet::device::load_trajectory_csv(trajectory_path);
    if (!tr.ok()) {
      std::fprintf(stderr, "lancet-rt: %s\n", tr.error().message.c_str());
      return 2;
    }
    trajectory = std::move(tr).value();
    model.trajectory = &*trajectory;
    std::fprintf(stderr, "lancet-rt: replaying %zu trajectory points over %.2f s\n", trajectory->t.size(), trajectory->duration());
  }
  // The arm, when one is configured: load, build its kinematics and device, configure, activate.
  std::optional<lancet::arm::ArmConfig> arm_config;
  std::optional<lancet::arm::Kinematics> kinematics;
  std::unique_ptr<lancet::device::Device> arm;
  lancet::device::ArmPhysics* hand = nullptr;
  if (!config_path.empty()) {
    auto cfg = lancet::arm::load_arm_config(config_path);
    if (!cfg.ok()) {
      std::fprintf(stderr, "lancet-rt: %s\n", cfg.error().message.c_str());
      return 2;
    }
    arm_config = std::move(cfg).value();
    auto cal = lancet::arm::apply_calibration_file(*arm_config, lancet::arm::calibration_path(config_path));
    if (!cal.ok()) {
      std::fprintf(stderr, "lancet-rt: %s\n", cal.error().message.c_str());
      return 2;
    }
    if (cal.value()) std::fprintf(stderr, "lancet-rt: calibration %s applied\n", lancet::arm::calibration_path(config_path).c_str());
    auto kin = lancet::arm::make_kinematics(*arm_config);
    if (!kin.ok()) {
      std::fprintf(stderr, "lancet-rt: %s\n", kin.error().message.c_str());
      return 2;
    }
    kinematics = kin.value();
    auto dev = lancet::app::make_device(*arm_config);
    if (!dev.ok()) {
      std::fprintf(stderr, "lancet-rt: %s\n", dev.error().message.c_str());
      return 2;
    }
    arm = std::move(dev.value().device);
    hand = dev.value().hand;
    for (const bool configure : {true, false}) {
      const lancet::device::Outcome o = configure ? arm->configure() : arm->activate();
      if (!o.ok()) {
        std::fprintf(stderr, "lancet-rt: %s\n", o.error->message.c_str());
        return 2;
      }
    }
    model.kinematics = &*kinematics;
    const auto& ws = arm_config->safety;
    model.device_origin = 0.5 * (ws.workspace_min + ws.workspace_max);
    for (std::size_t j = 0; j < ws.max_joint_torque.size() && j < model.max_joint_torque.size(); ++j)
      model.max_joint_torque[j] = ws.max_joint_torque[j];
    model.haptic.safety.max_force = std::min(model.haptic.safety.max_force, ws.max_force);
    std::fprintf(stderr, "lancet-rt: arm '%s' (%s, %d joints) is %s\n", arm_config->name.c_str(), arm->name().c_str(),
                 arm->joint_count(), lancet::device::to_string(arm->state()));
  }

  lancet::rt::LoopParams loop_params = rt_opts.loop();
  loop_params.duration_ns = lancet::seconds_to_ns(duration);
  model.period_ns = loop_params.period_ns;
  if (stiffness > 0) {
    for (auto& mat : model.haptic.materials) mat.stiffness = stiffness;
  }
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

  // Status printing happens here, off the servo thread, from the RtStatus seqlock.
  std::thread reporter;
  if (!quiet) {
    reporter = std::thread([&shared] {
      lancet::RtStatus st{};
      while (!g_stop.load(std::memory_order_relaxed)) {
        for (int i = 0; i < 10 && !g_stop.load(std::memory_order_relaxed); ++i) {
          std::this_thread::sleep_for(std::chrono::milliseconds(100));
        }
        if (shared.rt_status.try_read(st) != lancet::ReadStatus::kOk) continue;
        std::fprintf(stderr,
                     "lancet-rt: tick %llu  force %.2f N  scale %.2f  viz %s  patch v%llu  wake p99 %.0f us max %.0f us  "
                     "missed %llu  dropped %llu%s\n",
                     static_cast<unsigned long long>(st.tick), lancet::norm(st.force), st.force_scale,
                     st.viz_alive ? "alive" : "absent", static_cast<unsigned long long>(st.patch_version),
                     static_cast<double>(st.wake_p99_ns) / 1e3, static_cast<double>(st.wake_max_ns) / 1e3,
                     static_cast<unsigned long long>(st.missed), static_cast<unsigned long long>(st.samples_dropped),
                     st.watchdog_tripped ? "  WATCHDOG TRIPPED: force held at zero until re-armed" : "");
      }
    });
  }

  // Real time: process-wide setup first, then the loop on its own SCHED_FIFO thread.
  const lancet::rt::RtSetupOptions setup_opts = rt_opts.setup();
  lancet::rt::RtSetupReport setup;
  lancet::rt::RtEnvironment environment(setup_opts, setup);
  lancet::app::RtServo servo(model, shared, lancet::monotonic_ns(), arm.get(), hand);  // after mlockall: locked too
  // Re-arming a faulted arm reconnects its bus: done here, off the servo thread, when asked.
  std::thread supervisor;
  if (arm) {
    supervisor = std::thread([&servo, &arm] {
      while (!g_stop.load(std::memory_order_relaxed)) {
        if (servo.supervise())
          std::fprintf(stderr, "lancet-rt: %s re-armed: %s\n", arm->name().c_str(), lancet::device::to_string(arm->state()));
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
      }
    });
  }
  lancet::rt::RtLoop loop(loop_params);
  lancet::rt::RtThread thread = lancet::rt::start_rt_thread(setup_opts, setup, [&] {
    servo.set_fifo(lancet::rt::current_thread_is_fifo());
    loop.run([&servo](const lancet::rt::TickContext& ctx) { servo.tick(ctx); }, g_stop);
  });
  for (const auto& line : setup.applied) std::fprintf(stderr, "lancet-rt: %s\n", line.c_str());
  for (const auto& line : setup.degraded) std::fprintf(stderr, "lancet-rt: degraded: %s\n", line.c_str());
  std::fprintf(stderr, "lancet-rt: running at %.0f Hz on segment %s (pid %d), strategy %s\n",
               1e9 / static_cast<double>(model.period_ns), shm.c_str(), static_cast<int>(getpid()), rt_opts.strategy.c_str());
  thread.join();
  g_stop.store(true);
  if (reporter.joinable()) reporter.join();
  if (supervisor.joinable()) supervisor.join();
  if (arm) {
    const auto& c = arm->counters();
    std::fprintf(stderr,
                 "lancet-rt: %s: %llu reads, %llu writes, %llu timeouts, %llu crc, %llu protocol, %llu disconnects, %llu faults, "
                 "slowest I/O %.0f us\n",
                 arm->name().c_str(), static_cast<unsigned long long>(c.reads), static_cast<unsigned long long>(c.writes),
                 static_cast<unsigned long long>(c.timeouts), static_cast<unsigned long long>(c.crc_errors),
                 static_cast<unsigned long long>(c.protocol_errors), static_cast<unsigned long long>(c.disconnects),
                 static_cast<unsigned long long>(c.faults), static_cast<double>(c.max_io_ns) / 1e3);
    (void)arm->deactivate();
  }
  shared.rt_heartbeat.stop();

  const auto& ls = loop.stats();
  std::fprintf(stderr,
               "lancet-rt: stopped after %llu ticks: %llu missed deadlines, wake-up p50 %.1f us p99 %.1f us max %.1f us, "
               "%llu samples dropped, max force %.2f N\n",
               static_cast<unsigned long long>(ls.ticks), static_cast<unsigned long long>(ls.missed),
               static_cast<double>(ls.wake_latency.percentile_ns(50)) / 1e3,
               static_cast<double>(ls.wake_latency.percentile_ns(99)) / 1e3,
               static_cast<double>(ls.wake_latency.max_ns()) / 1e3,
               static_cast<unsigned long long>(shared.samples.overflow_count()), servo.data().max_force_seen);
  if (!stats_path.empty() && !write_stats(stats_path, servo, loop, shared)) {
    std::fprintf(stderr, "lancet-rt: cannot write stats to %s\n", stats_path.c_str());
    return 1;
  }
  return 0;
}
