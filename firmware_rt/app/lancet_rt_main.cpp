// lancet-rt: the 1 kHz servo process. Creates the shared-memory segment, runs the servo loop
// with the simulated stylus or an arm from hw_configs, and pushes one ToolSample per tick to
// lancet-viz. The main thread supervises (re-arms, reconnects, announcements, stalls).
//
// It always ends within a bounded time, with its stats written and its segment removed: at
// --duration, on SIGINT / SIGTERM / SIGHUP, or when the servo tick stops advancing
// (--stall-timeout-ms). Exit codes: 0 ended normally, 1 stats could not be written, 2 bad
// arguments or the arm could not be brought up, 3 ended because the servo stalled, 4 the servo
// thread never came back (left without it, --shutdown-grace-ms).

#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <thread>

#include "app/device_factory.hpp"
#include "app/supervisor.hpp"
#include "app/rt_servo.hpp"
#include "app/rt_cli.hpp"
#include "rt/rt_loop.hpp"
#include "rt/rt_setup.hpp"
#include "text/text.hpp"

namespace {

using lancet::app::copy_text;

std::atomic<bool> g_stop{false};
std::atomic<int> g_signal{0};
static_assert(std::atomic<bool>::is_always_lock_free, "the stop flag is set from a signal handler");
static_assert(std::atomic<int>::is_always_lock_free, "the signal number is set from a signal handler");

extern "C" void on_signal(int sig) {
  g_signal.store(sig, std::memory_order_relaxed);
  g_stop.store(true, std::memory_order_relaxed);
}

/// SIGINT, SIGTERM and SIGHUP end lancet-rt: without SA_RESTART, so a blocking call in the main
/// thread returns at once.
// A whole file's text ("" when it cannot be read).
std::string read_text_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return in ? text.str() : std::string();
}

void install_signal_handlers() {
  struct sigaction sa {};
  sa.sa_handler = on_signal;
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = 0;
  for (int sig : {SIGINT, SIGTERM, SIGHUP}) sigaction(sig, &sa, nullptr);
}

/// A JSON number, or null for what JSON cannot hold.
std::string num(double v, int decimals = 1) { return lancet::text::json_number(v, decimals); }
std::string num(std::uint64_t v) { return std::to_string(v); }
std::string num(std::int64_t v) { return std::to_string(v); }
std::string str(const std::string& v) { return lancet::text::json_string(v); }

struct StatsInput {
  const lancet::rt::LoopStats* loop = nullptr;  ///< null when the servo thread never came back
  std::uint64_t watchdog_trips = 0;
  const lancet::app::RtData* data = nullptr;    ///< null likewise
  lancet::RtStatus status{};                    ///< the servo's last published status
  bool has_status = false;
  std::string ended_by;                         ///< duration, SIGTERM, SIGINT, SIGHUP, stall
  bool clean = true;                            ///< the servo thread stopped and the arm was deactivated
  std::string arm_name;
};

bool write_stats(const std::string& path, const StatsInput& in) {
  const lancet::RtStatus& st = in.status;
  std::string j = "{\n";
  auto field = [&j](const char* key, const std::string& value) { j += std::string("  \"") + key + "\": " + value + ",\n"; };
  field("ended_by", str(in.ended_by));
  field("clean_exit", in.clean ? "true" : "false");
  if (in.loop != nullptr) {
    const lancet::rt::LoopStats& ls = *in.loop;
    field("ticks", num(ls.ticks));
    field("overruns", num(ls.overruns));
    field("missed", num(ls.missed));
    field("wake_p50_us", num(static_cast<double>(ls.wake_latency.percentile_ns(50)) / 1e3));
    field("wake_p99_us", num(static_cast<double>(ls.wake_latency.percentile_ns(99)) / 1e3));
    field("wake_max_us", num(static_cast<double>(ls.wake_latency.max_ns()) / 1e3));
    field("compute_p99_us", num(static_cast<double>(ls.compute.percentile_ns(99)) / 1e3));
    field("longest_stall_us", num(static_cast<double>(ls.longest_stall_ns) / 1e3));
    field("watchdog_trips", num(in.watchdog_trips));
  } else {
    field("ticks", num(st.tick));
    field("missed", num(st.missed));
  }
  field("samples_pushed", num(st.samples_pushed));
  field("samples_dropped", num(st.samples_dropped));
  if (in.data != nullptr) {
    const lancet::app::RtData& d = *in.data;
    field("patches_received", num(d.patches_received));
    field("contact_ticks", num(d.servo.contact_ticks));
    field("max_force_n", num(d.servo.max_force_seen, 6));
    field("nan_guards", num(d.servo.haptic.safety.nan_guards));
    field("clamps", num(d.servo.haptic.safety.clamps));
    field("commands_applied", num(d.servo.commands_applied));
    field("viz_lost_at_beat_ns", num(d.viz_lost_at_beat_ns));
    field("force_zero_ns", num(d.force_zero_ns));
  }
  const lancet::SegmentHealth& h = st.health;
  j += "  \"segment\": {\"ring_resets\": " + num(h.ring_resets) + ", \"commands_rejected\": " + num(h.commands_rejected) +
       ", \"commands_deferred\": " + num(h.commands_deferred) + ", \"patches_rejected\": " + num(h.patches_rejected) +
       ", \"patches_unreadable\": " + num(h.patches_unreadable) + ", \"targets_rejected\": " + num(h.targets_rejected) +
       ", \"sample_ring_resets\": " + num(h.sample_ring_resets) + "},\n";
  field("rearms", num(st.rearms));
  field("operator_requests", num(st.operator_requests));
  if (st.has_arm != 0) {
    const lancet::BusCounters& b = st.bus;
    j += "  \"arm\": {\"name\": " + str(in.arm_name) + ", \"state\": " +
         str(lancet::device::to_string(st.device_state)) + ", \"fault_cause\": " +
         str(st.device_state == lancet::device::Lifecycle::kFault
                 ? lancet::device::to_string(st.device_fault_cause)
                 : "") +
         ", \"fault\": " + str(st.fault_text) + ", \"fault_node\": " + std::to_string(st.fault_node) +
         ", \"fault_code\": " + std::to_string(st.fault_code) + ", \"last_error\": " + str(st.error_text) +
         ", \"link_lost\": " + (st.link_lost != 0 ? "true" : "false") + ", \"error_ticks\": " + num(st.device_errors) +
         ", \"rearm_failures\": " + num(st.rearm_failures) + ", \"last_rearm\": " + str(st.rearm_text) +
         ",\n          \"bus\": {\"reads\": " + num(b.reads) + ", \"writes\": " + num(b.writes) + ", \"ok\": " + num(b.ok) +
         ", \"timeouts\": " + num(b.timeouts) + ", \"crc_errors\": " + num(b.crc_errors) +
         ", \"protocol_errors\": " + num(b.protocol_errors) + ", \"disconnects\": " + num(b.disconnects) +
         ", \"device_faults\": " + num(b.device_faults) + ", \"glitches\": " + num(b.glitches) +
         ", \"stale_replies\": " + num(b.stale_replies) + ", \"faults\": " + num(b.faults) +
         ", \"reconnects\": " + num(b.reconnects) + ", \"max_io_us\": " + num(static_cast<double>(b.max_io_ns) / 1e3) +
         "}},\n";
  }
  j += "  \"has_status\": " + std::string(in.has_status ? "true" : "false") + "\n}\n";
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (f == nullptr) return false;
  const bool wrote = std::fputs(j.c_str(), f) >= 0;
  return std::fclose(f) == 0 && wrote;
}

const char* signal_name(int sig) {
  switch (sig) {
    case SIGINT: return "SIGINT";
    case SIGTERM: return "SIGTERM";
    case SIGHUP: return "SIGHUP";
    default: return "signal";
  }
}

/// Reads the arm until one read succeeds (the arm inactive: errors here never fault it), or the
/// timeout. Returns an empty string when it answered, else why not.
std::string await_first_read(lancet::device::Device& arm, double timeout_s) {
  lancet::device::JointState js;
  const std::int64_t deadline = lancet::monotonic_ns() + static_cast<std::int64_t>(timeout_s * 1e9);
  lancet::device::IoStatus last = lancet::device::IoStatus::kOk;
  for (;;) {
    last = arm.read(js);
    if (last == lancet::device::IoStatus::kOk) return {};
    if (g_stop.load(std::memory_order_relaxed)) return "interrupted by a signal";
    if (lancet::monotonic_ns() >= deadline) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  const auto& e = arm.last_error();
  return std::string(lancet::device::to_string(last)) + (e.status != lancet::device::IoStatus::kOk ? std::string(": ") + e.c_str() : "");
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
  cli.add_option("--max-force", model.servo.haptic.safety.max_force, "force clamp (N)")->check(CLI::Range(0.0, 40.0))->capture_default_str();
  cli.add_option("--viz-timeout-ms", timeout_ms, "viz heartbeat age after which the force fades")->check(CLI::Range(1.0, 10000.0))->capture_default_str();
  cli.add_option("--fade-ms", fade_ms, "time for the force to fade from full to zero")->check(CLI::Range(0.0, 10000.0))->capture_default_str();
  double stale_patch_ms = 100;
  cli.add_option("--stale-patch-ms", stale_patch_ms, "tissue patch age after which the force fades (the viz stopped publishing)")
      ->check(CLI::Range(1.0, 10000.0))->capture_default_str();
  bool script_waits = false;
  cli.add_flag("--script-waits-for-tissue", script_waits,
               "the scripted hand (or --trajectory) holds its starting point until the first tissue patch arrives, so a "
               "viz that takes long to build its tissue misses none of the script");
  cli.add_option("--depth-mm", model.script_depth, "how deep below the surface the script presses (mm)")
      ->transform([](std::string s) { return std::to_string(std::stod(s) * 1e-3); })->check(CLI::Range(0.0, 0.05));
  cli.add_option("--stats", stats_path, "write a JSON summary here on exit (also after a signal or a stall)");
  double stall_timeout_ms = 1000, first_read_timeout_ms = 2000, shutdown_grace_ms = 2000;
  cli.add_option("--stall-timeout-ms", stall_timeout_ms,
                 "end lancet-rt when the servo tick has not advanced for this long (the arm's own watchdog then takes its "
                 "torque off)")
      ->check(CLI::Range(50.0, 60000.0))->capture_default_str();
  cli.add_option("--first-read-timeout-ms", first_read_timeout_ms,
                 "with --config: wait this long for the arm's first good read before enabling it")
      ->check(CLI::Range(1.0, 60000.0))->capture_default_str();
  cli.add_option("--shutdown-grace-ms", shutdown_grace_ms,
                 "after a signal, a stall or --duration, wait this long for the servo thread to stop before leaving "
                 "without it")
      ->check(CLI::Range(10.0, 60000.0))->capture_default_str();
  double inject_stall_s = 0;
  cli.add_option("--inject-stall-s", inject_stall_s,
                 "testing: block the servo thread for good this many seconds after start (exercises the stall path)")
      ->check(CLI::PositiveNumber)->group("Testing");
  std::string config_path, trajectory_path;
  cli.add_option("--trajectory", trajectory_path,
                 "replay this recorded hand trajectory (CSV: t_s, x_mm, y_mm, z_mm[, tool]) instead of the built-in script; the "
                 "optional tool cell (probe, scalpel, retractor, drill) picks the tool from that time on");
  cli.add_option("--config", config_path,
                 "drive the arm described by this hw_configs TOML file (backend sim; the others as they land) instead of the "
                 "built-in stylus");
  CLI11_PARSE(cli, argc, argv);
  // At once: a signal during start-up (loading the arm, waiting for its first read) ends the run,
  // also when lancet-rt was started in the background, where the shell left SIGINT ignored.
  install_signal_handlers();

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
  // The arm, when one is configured: load, build its kinematics and device, configure, wait for a
  // good read (activate comes just before the loop starts).
  std::optional<lancet::arm::ArmConfig> arm_config;
  std::optional<lancet::arm::Kinematics> kinematics;
  std::unique_ptr<lancet::device::Device> arm;
  if (!config_path.empty()) {
    auto cfg = lancet::arm::load_arm_config(config_path);
    if (!cfg.ok()) {
      std::fprintf(stderr, "lancet-rt: %s\n", cfg.error().message.c_str());
      return 2;
    }
    arm_config = std::move(cfg).value();
    if (arm_config->canopen) {
      // The drives were told the cycle (0x1006, 0x60C2) from the config; a servo on another period
      // would send SYNC at a rate they do not expect.
      const auto sync_ns = static_cast<std::int64_t>(std::llround(arm_config->canopen->sync_period * 1e9));
      if (std::llabs(sync_ns - rt_opts.loop().period_ns) > 500) {
        std::fprintf(stderr,
                     "lancet-rt: --period-us %.0f differs from sync_period_us %.0f in [bus.canopen] of %s: the drives expect "
                     "a SYNC every %.0f us (0x1006); give lancet-rt --period-us %.0f or change the config\n",
                     static_cast<double>(rt_opts.loop().period_ns) * 1e-3, static_cast<double>(sync_ns) * 1e-3,
                     config_path.c_str(), static_cast<double>(sync_ns) * 1e-3, static_cast<double>(sync_ns) * 1e-3);
        return 2;
      }
    }
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
    install_signal_handlers();
    if (const lancet::Result<void> o = arm->configure(); !o.ok()) {
      std::fprintf(stderr, "lancet-rt: %s\n", o.error().message.c_str());
      return 2;
    }
    // No fault before the first good read: wait for it with the arm still disabled (errors while
    // inactive never trip the fault policy).
    if (const std::string why = await_first_read(*arm, first_read_timeout_ms * 1e-3); !why.empty()) {
      std::fprintf(stderr, "lancet-rt: %s did not answer within %.0f ms of configuration (--first-read-timeout-ms): %s\n",
                   arm->name().c_str(), first_read_timeout_ms, why.c_str());
      return 2;
    }
    model.servo.kinematics = *kinematics;
    const auto& ws = arm_config->safety;
    model.servo.device_origin = 0.5 * (ws.workspace_min + ws.workspace_max);
    for (std::size_t j = 0; j < ws.max_joint_torque.size() && j < model.servo.max_joint_torque.size(); ++j)
      model.servo.max_joint_torque[j] = ws.max_joint_torque[j];
    model.servo.haptic.safety.max_force = std::min(model.servo.haptic.safety.max_force, ws.max_force);
  }

  lancet::rt::LoopParams loop_params = rt_opts.loop();
  loop_params.duration_ns = lancet::seconds_to_ns(duration);
  model.servo.period_ns = loop_params.period_ns;
  if (stiffness > 0) {
    for (auto& mat : model.servo.haptic.materials) mat.stiffness = stiffness;
  }
  model.servo.fade.timeout_ns = static_cast<std::int64_t>(timeout_ms * 1e6);
  model.servo.fade.fade_ns = static_cast<std::int64_t>(fade_ms * 1e6);
  model.servo.fade.stale_after_ns = static_cast<std::int64_t>(stale_patch_ms * 1e6);
  model.script_waits_for_tissue = script_waits;

  lancet::ShmSegment::CreateOptions seg_opts;
  seg_opts.creator_name = "lancet-rt";
  auto channel = lancet::SharedChannel::create(shm, seg_opts);
  if (!channel) {
    std::fprintf(stderr, "lancet-rt: %s\n", channel.error().message.c_str());
    return 2;
  }
  for (const auto& note : channel.value().segment().notes()) std::fprintf(stderr, "lancet-rt: %s\n", note.c_str());
  lancet::SharedState& shared = channel.value().state();

  install_signal_handlers();

  // Real time: process-wide setup first, then the loop on its own SCHED_FIFO thread.
  const lancet::rt::RtSetupOptions setup_opts = rt_opts.setup();
  lancet::rt::RtSetupReport setup;
  lancet::rt::RtEnvironment environment(setup_opts, setup);
  // Enable the arm as late as possible: a drive-side watchdog counts from the end of activate(),
  // so the servo's first tick follows within a period or two.
  if (arm) {
    if (const lancet::Result<void> o = arm->activate(); !o.ok()) {
      std::fprintf(stderr, "lancet-rt: %s\n", o.error().message.c_str());
      return 2;
    }
    std::fprintf(stderr, "lancet-rt: arm '%s' (%s, %d joints) is %s\n", arm_config->name.c_str(), arm->name().c_str(),
                 arm->joint_count(), lancet::device::to_string(arm->state()));
  }
  lancet::app::RtServo servo(model, shared, lancet::monotonic_ns(), arm.get());  // after mlockall: locked too
  if (!config_path.empty()) {
    // The arm's files as they were read, for whoever records the session.
    std::string text = read_text_file(config_path);
    const std::string cal = lancet::arm::calibration_path(config_path);
    if (std::filesystem::exists(cal)) text += "\n# --- calibration: " + cal + " ---\n" + read_text_file(cal);
    auto blob = std::make_unique<lancet::ArmConfigText>();
    blob->truncated = text.size() > lancet::kArmConfigCapacity ? 1u : 0u;
    blob->size = static_cast<std::uint32_t>(std::min<std::size_t>(text.size(), lancet::kArmConfigCapacity));
    std::memcpy(blob->text, text.data(), blob->size);
    shared.arm_config.write(*blob);
  }
  // New patches are copied, checked and get their tree on a helper thread, below the servo's
  // priority and off its CPU, so no tick pays for one.
  const std::string intake_line = servo.start_patch_intake(setup_opts.enable, std::max(1, setup_opts.priority - 10), setup_opts.cpu);
  lancet::rt::RtLoop loop(loop_params);
  std::atomic<bool> loop_done{false};
  lancet::rt::RtThread thread = lancet::rt::start_rt_thread(setup_opts, setup, [&] {
    servo.set_fifo(lancet::rt::current_thread_is_fifo());
    const std::int64_t stall_at = inject_stall_s > 0 ? lancet::monotonic_ns() + lancet::seconds_to_ns(inject_stall_s) : 0;
    loop.run(
        [&servo, stall_at](const lancet::rt::TickContext& ctx) {
          if (stall_at != 0 && ctx.woke_ns >= stall_at) {
            for (;;) pause();  // a tick that never returns: what a hung bus call or a bug looks like
          }
          servo.tick(ctx);
        },
        g_stop);
    loop_done.store(true, std::memory_order_release);
  });
  for (const auto& line : setup.applied) std::fprintf(stderr, "lancet-rt: %s\n", line.c_str());
  for (const auto& line : setup.degraded) std::fprintf(stderr, "lancet-rt: degraded: %s\n", line.c_str());
  std::fprintf(stderr, "lancet-rt: %s\n", intake_line.c_str());
  std::fprintf(stderr, "lancet-rt: running at %.0f Hz on segment %s (pid %d), strategy %s\n",
               1e9 / static_cast<double>(model.servo.period_ns), shm.c_str(), static_cast<int>(getpid()), rt_opts.strategy.c_str());

  // This thread supervises: device re-arms and reconnects, what changed (said the moment it is
  // seen), a servo tick that stops advancing, signals, and the status line once a second. It
  // reads only the servo's private status, never the segment.
  lancet::app::SupervisorParams sp;
  sp.shm_name = shm;
  sp.arm_name = arm ? arm->name() : "";
  sp.stall_timeout_ns = static_cast<std::int64_t>(stall_timeout_ms * 1e6);
  const std::int64_t started_ns = lancet::monotonic_ns();
  lancet::app::RtSupervisor supervisor(servo, sp, started_ns);
  std::string ended_by = "duration";
  std::int64_t next_line_ns = started_ns + 1'000'000'000;
  std::int64_t stop_asked_ns = 0;
  bool stalled = false;
  for (;;) {
    const std::int64_t now = lancet::monotonic_ns();
    for (const auto& line : supervisor.poll(now)) std::fprintf(stderr, "lancet-rt: %s\n", line.c_str());
    if (loop_done.load(std::memory_order_acquire)) break;
    if (supervisor.stalled() && !stalled) {
      stalled = true;
      ended_by = "stall";
      g_stop.store(true);
    }
    if (g_stop.load(std::memory_order_relaxed) && stop_asked_ns == 0) stop_asked_ns = now;
    // --duration is the loop's own end; should the loop not get there, it is enforced here too.
    if (duration > 0 && stop_asked_ns == 0 && now - started_ns > lancet::seconds_to_ns(duration) + loop_params.period_ns * 100) {
      stop_asked_ns = now;
      g_stop.store(true);
    }
    if (stop_asked_ns != 0 && now - stop_asked_ns > static_cast<std::int64_t>(shutdown_grace_ms * 1e6)) break;
    if (!quiet && now >= next_line_ns && supervisor.has_status()) {
      next_line_ns += 1'000'000'000;
      const lancet::RtStatus& st = supervisor.last();
      std::fprintf(stderr,
                   "lancet-rt: tick %llu  force %.2f N  scale %.2f  viz %s  patch v%llu  wake p99 %.0f us max %.0f us  "
                   "missed %llu  dropped %llu%s%s%s\n",
                   static_cast<unsigned long long>(st.tick), lancet::norm(st.force), st.force_scale,
                   st.viz_alive ? "alive" : "absent", static_cast<unsigned long long>(st.patch_version),
                   static_cast<double>(st.wake_p99_ns) / 1e3, static_cast<double>(st.wake_max_ns) / 1e3,
                   static_cast<unsigned long long>(st.missed), static_cast<unsigned long long>(st.samples_dropped),
                   st.has_arm ? "  arm " : "", st.has_arm ? lancet::app::describe_arm(st).c_str() : "",
                   st.watchdog_tripped ? "  WATCHDOG TRIPPED: force held at zero until re-armed" : "");
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }

  if (const int sig = g_signal.load(std::memory_order_relaxed); sig != 0 && !stalled) ended_by = signal_name(sig);
  StatsInput stats;
  stats.arm_name = arm ? arm->name() : "";
  stats.ended_by = ended_by;
  if (!loop_done.load(std::memory_order_acquire)) {
    // The servo thread is stuck (in a tick, in the device): leave without it. The segment goes,
    // the stats come from its last published status, and the arm's own watchdog (drive side)
    // takes the torque off, since nobody writes to it any more.
    std::fprintf(stderr, "lancet-rt: the servo thread did not stop within %.0f ms: leaving without it (exit 4)\n",
                 shutdown_grace_ms);
    stats.clean = false;
    stats.has_status = servo.read_status(stats.status) == lancet::ReadStatus::kOk;
    if (!stats_path.empty() && !write_stats(stats_path, stats))
      std::fprintf(stderr, "lancet-rt: cannot write stats to %s\n", stats_path.c_str());
    channel.value().segment().unlink_name();
    std::fflush(stderr);
    std::_Exit(4);
  }
  thread.join();
  g_stop.store(true);
  if (arm) {
    std::fprintf(stderr, "lancet-rt: %s: %s\n", arm->name().c_str(),
                 lancet::app::describe_bus(servo.data().status.bus).c_str());
    (void)arm->deactivate();
  }
  shared.rt_heartbeat.stop();

  const auto& ls = loop.stats();
  std::fprintf(stderr,
               "lancet-rt: stopped (%s) after %llu ticks: %llu missed deadlines, wake-up p50 %.1f us p99 %.1f us max %.1f us, "
               "%llu samples dropped, max force %.2f N\n",
               ended_by.c_str(), static_cast<unsigned long long>(ls.ticks), static_cast<unsigned long long>(ls.missed),
               static_cast<double>(ls.wake_latency.percentile_ns(50)) / 1e3,
               static_cast<double>(ls.wake_latency.percentile_ns(99)) / 1e3,
               static_cast<double>(ls.wake_latency.max_ns()) / 1e3,
               static_cast<unsigned long long>(shared.samples.overflow_count()), servo.data().servo.max_force_seen);
  stats.loop = &ls;
  stats.watchdog_trips = loop.watchdog().trips();
  stats.data = &servo.data();
  stats.has_status = servo.read_status(stats.status) == lancet::ReadStatus::kOk;
  if (!stats_path.empty() && !write_stats(stats_path, stats)) {
    std::fprintf(stderr, "lancet-rt: cannot write stats to %s\n", stats_path.c_str());
    return 1;
  }
  return stalled ? 3 : 0;
}
