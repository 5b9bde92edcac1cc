// lancet-rt: the 1 kHz servo process. Creates the shared-memory segment, runs one servo loop for
// one or two hands (--hands), each with a simulated stylus or an arm from hw_configs (--config for
// the right hand, --left-config for the left), and pushes one ToolSample per tick and hand to
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
#include <array>
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
#include <vector>

#include "app/device_factory.hpp"
#include "device/canopen_arm.hpp"
#include "app/supervisor.hpp"
#include "app/rt_servo.hpp"
#include "app/rt_cli.hpp"
#include "config/text_file.hpp"
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
  bool clean = true;                            ///< the servo thread stopped and the arms were deactivated
  std::size_t hands = 1;
  std::array<std::string, lancet::kHandCount> arm_name;  ///< by Hand
  const lancet::rt::RtSetupReport* setup = nullptr;     ///< the real-time setup, as it went
};

/// The real-time setup as a JSON object: what took effect and each degradation's line.
std::string realtime_json(const lancet::rt::RtSetupReport& r) {
  const auto flag = [](bool b) { return std::string(b ? "true" : "false"); };
  std::string degraded;
  for (const auto& line : r.degraded) degraded += (degraded.empty() ? "" : ", ") + str(line);
  return "{\"preempt_rt\": " + flag(r.preempt_rt) + ", \"fifo\": " + flag(r.fifo) + ", \"affinity\": " + flag(r.affinity) +
         ", \"cpu_isolated\": " + flag(r.cpu_isolated) + ", \"memory_locked\": " + flag(r.memory_locked) +
         ", \"dma_latency_held\": " + flag(r.dma_latency_held) + ", \"malloc_tuned\": " + flag(r.malloc_tuned) +
         ",\n    \"kernel\": " + str(r.kernel) + ", \"isolated_cpus\": " + str(r.isolated_cpus) +
         ",\n    \"degraded\": [" + degraded + "]}";
}

/// A hand's arm as a JSON object.
std::string arm_json(const std::string& name, const lancet::HandStatus& st, const char* indent) {
  const lancet::BusCounters& b = st.bus;
  return "{\"name\": " + str(name) + ", \"state\": " + str(lancet::device::to_string(st.device_state)) + ", \"fault_cause\": " +
         str(st.device_state == lancet::device::Lifecycle::kFault ? lancet::device::to_string(st.device_fault_cause) : "") +
         ", \"fault\": " + str(st.fault_text) + ", \"fault_node\": " + std::to_string(st.fault_node) +
         ", \"fault_code\": " + std::to_string(st.fault_code) + ", \"last_error\": " + str(st.error_text) +
         ", \"link_lost\": " + (st.link_lost != 0 ? "true" : "false") + ", \"error_ticks\": " + num(st.device_errors) +
         ", \"rearm_failures\": " + num(st.rearm_failures) + ", \"last_rearm\": " + str(st.rearm_text) + ",\n" + indent +
         "\"bus\": {\"reads\": " + num(b.reads) + ", \"writes\": " + num(b.writes) + ", \"ok\": " + num(b.ok) +
         ", \"timeouts\": " + num(b.timeouts) + ", \"crc_errors\": " + num(b.crc_errors) +
         ", \"protocol_errors\": " + num(b.protocol_errors) + ", \"disconnects\": " + num(b.disconnects) +
         ", \"device_faults\": " + num(b.device_faults) + ", \"glitches\": " + num(b.glitches) +
         ", \"stale_replies\": " + num(b.stale_replies) + ", \"faults\": " + num(b.faults) +
         ", \"reconnects\": " + num(b.reconnects) + ", \"max_io_us\": " + num(static_cast<double>(b.max_io_ns) / 1e3) + "}}";
}

bool write_stats(const std::string& path, const StatsInput& in) {
  const lancet::RtStatus& st = in.status;
  std::string j = "{\n";
  auto field = [&j](const char* key, const std::string& value) { j += std::string("  \"") + key + "\": " + value + ",\n"; };
  field("ended_by", str(in.ended_by));
  field("clean_exit", in.clean ? "true" : "false");
  if (in.setup != nullptr) field("realtime", realtime_json(*in.setup));
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
    // The top-level figures that scripts and tests have always read cover every hand: counts are
    // sums over the hands, max_force_n the largest of any hand (per hand: "hands" below).
    const lancet::app::RtData& d = *in.data;
    std::uint64_t patches = 0, contact = 0, nan_guards = 0, clamps = 0, commands = 0;
    double max_force = 0;
    for (std::size_t h = 0; h < in.hands; ++h) {
      const lancet::app::HandData& hd = d.hand[h];
      patches += hd.patches_received, contact += hd.servo.contact_ticks, nan_guards += hd.servo.haptic.safety.nan_guards;
      clamps += hd.servo.haptic.safety.clamps, commands += hd.servo.commands_applied;
      max_force = std::max(max_force, hd.servo.max_force_seen);
    }
    field("patches_received", num(patches));
    field("contact_ticks", num(contact));
    field("max_force_n", num(max_force, 6));
    field("nan_guards", num(nan_guards));
    field("clamps", num(clamps));
    field("commands_applied", num(commands));
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
  // "arm": the right hand's arm, as before there were two (each hand's is in "hands").
  if (st.hand[0].has_arm != 0) field("arm", arm_json(in.arm_name[0], st.hand[0], "          "));
  field("hand_count", num(static_cast<std::uint64_t>(in.hands)));
  // Each hand on its own, right first.
  j += "  \"hands\": [";
  for (std::size_t k = 0; k < in.hands; ++k) {
    const lancet::HandStatus& hs = st.hand[k];
    j += k == 0 ? "\n" : ",\n";
    j += "    {\"hand\": " + str(lancet::hand_name(static_cast<lancet::Hand>(k)));
    if (in.data != nullptr) {
      const lancet::app::HandData& hd = in.data->hand[k];
      j += ", \"contact_ticks\": " + num(hd.servo.contact_ticks) + ", \"max_force_n\": " + num(hd.servo.max_force_seen, 6) +
           ", \"clamps\": " + num(hd.servo.haptic.safety.clamps) + ", \"nan_guards\": " + num(hd.servo.haptic.safety.nan_guards) +
           ", \"commands_applied\": " + num(hd.servo.commands_applied) + ", \"patches_received\": " + num(hd.patches_received);
    }
    j += ", \"device_errors\": " + num(hs.device_errors);
    if (hs.has_arm != 0) j += ",\n      \"arm\": " + arm_json(in.arm_name[k], hs, "        ");
    j += "}";
  }
  j += "\n  ],\n";
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

/// Everything lancet-rt's command line sets.
struct Args {
  std::size_t hands = 2;
  std::string shm = lancet::kDefaultShmName;
  double duration = 0;
  bool quiet = false;
  lancet::app::RtCliOptions rt;
  std::string stats_path;
  lancet::app::RtModel model;
  lancet::servo::ServoModel servo;  ///< every hand's servo model before its arm shapes it
  double script_depth = 0.004;      ///< m
  double stiffness = 0;
  double timeout_ms = 150, fade_ms = 100, stale_patch_ms = 100;
  bool script_waits = false;
  double stall_timeout_ms = 1000, first_read_timeout_ms = 2000, shutdown_grace_ms = 2000;
  double inject_stall_s = 0;
  std::string trajectory_path;
  std::array<std::string, lancet::kHandCount> config_path;  ///< by Hand; "" for the built-in stylus
};

void add_options(CLI::App& cli, Args& a) {
  cli.add_option("--shm", a.shm, "shared-memory segment name")->capture_default_str();
  cli.add_option("--duration", a.duration, "seconds to run; 0 runs until SIGINT/SIGTERM")->check(CLI::NonNegativeNumber);
  lancet::app::add_rt_options(cli, a.rt);
  cli.add_flag("-q,--quiet", a.quiet, "no once-a-second status line");
  cli.add_option("--stiffness", a.stiffness, "contact stiffness of every material (N/m); default: per material")
      ->check(CLI::Range(1.0, 5000.0));
  cli.add_option("--hands", a.hands, "hands the loop drives: 1 (right) or 2 (right and left; each with its own device)")
      ->check(CLI::Range(1, 2))->capture_default_str();
  cli.add_option("--max-force", a.servo.haptic.safety.max_force, "force clamp (N)")->check(CLI::Range(0.0, 40.0))->capture_default_str();
  cli.add_option("--viz-timeout-ms", a.timeout_ms, "viz heartbeat age after which the force fades")->check(CLI::Range(1.0, 10000.0))->capture_default_str();
  cli.add_option("--fade-ms", a.fade_ms, "time for the force to fade from full to zero")->check(CLI::Range(0.0, 10000.0))->capture_default_str();
  cli.add_option("--stale-patch-ms", a.stale_patch_ms, "tissue patch age after which the force fades (the viz stopped publishing)")
      ->check(CLI::Range(1.0, 10000.0))->capture_default_str();
  cli.add_flag("--script-waits-for-tissue", a.script_waits,
               "the scripted hand (or --trajectory) holds its starting point until the first tissue patch arrives, so a "
               "viz that takes long to build its tissue misses none of the script");
  cli.add_option("--depth-mm", a.script_depth, "how deep below the surface the script presses (mm)")
      ->transform([](std::string s) { return std::to_string(std::stod(s) * 1e-3); })->check(CLI::Range(0.0, 0.05));
  cli.add_option("--stats", a.stats_path, "write a JSON summary here on exit (also after a signal or a stall)");
  cli.add_option("--stall-timeout-ms", a.stall_timeout_ms,
                 "end lancet-rt when the servo tick has not advanced for this long (the arm's own watchdog then takes its "
                 "torque off)")
      ->check(CLI::Range(50.0, 60000.0))->capture_default_str();
  cli.add_option("--first-read-timeout-ms", a.first_read_timeout_ms,
                 "with --config: wait this long for the arm's first good read before enabling it")
      ->check(CLI::Range(1.0, 60000.0))->capture_default_str();
  cli.add_option("--shutdown-grace-ms", a.shutdown_grace_ms,
                 "after a signal, a stall or --duration, wait this long for the servo thread to stop before leaving "
                 "without it")
      ->check(CLI::Range(10.0, 60000.0))->capture_default_str();
  cli.add_option("--inject-stall-s", a.inject_stall_s,
                 "testing: block the servo thread for good this many seconds after start (exercises the stall path)")
      ->check(CLI::PositiveNumber)->group("Testing");
  cli.add_option("--trajectory", a.trajectory_path,
                 "replay this recorded hand trajectory (CSV: t_s, x_mm, y_mm, z_mm[, tool[, hand]]) instead of the built-in "
                 "scripts; the optional tool cell (probe, scalpel, retractor, drill) picks the tool from that time on, the hand "
                 "cell (right or left; default right) whose row it is; a hand without rows follows its built-in script");
  cli.add_option("--config", a.config_path[0],
                 "drive the right hand's arm described by this hw_configs TOML file instead of its built-in stylus");
  cli.add_option("--left-config", a.config_path[1],
                 "drive the left hand's arm described by this hw_configs TOML file instead of its built-in stylus (needs --hands 2)");
}

/// The configured arm: its config and device, configured and answering.
struct Arm {
  std::optional<lancet::arm::ArmConfig> config;
  std::unique_ptr<lancet::device::Device> device;
};

/// Prints why and returns false.
bool fail(const std::string& message) {
  std::fprintf(stderr, "lancet-rt: %s\n", message.c_str());
  return false;
}

/// Loads hand h's arm config (--config, --left-config); nothing touches a bus yet.
bool load_arm(const Args& a, std::size_t h, Arm& arm) {
  auto cfg = lancet::arm::load_arm_config(a.config_path[h]);
  if (!cfg.ok()) return fail(cfg.error().message);
  arm.config = std::move(cfg).value();
  return true;
}

/// True when both hands' arms are CANopen on the same interface (one bus, one SYNC producer).
bool share_a_can_bus(const std::array<Arm, lancet::kHandCount>& arms) {
  const auto& r = arms[0].config, &l = arms[1].config;
  return r && l && r->canopen && l->canopen && r->canopen->interface_name == l->canopen->interface_name;
}

/// Two CANopen arms on one interface are one network: exactly one SYNC producer, and it is the
/// right hand's (read first in the tick, so the left hand's drives answer the SYNC of the same
/// tick); no node id (drive or master) used twice; one SYNC period. Each problem as a sentence
/// naming both files and the fields; none when the arms do not share a bus.
std::vector<std::string> shared_bus_problems(const Args& a, const std::array<Arm, lancet::kHandCount>& arms) {
  std::vector<std::string> out;
  if (!share_a_can_bus(arms)) return out;
  const lancet::arm::CanopenBusConfig& r = *arms[0].config->canopen;
  const lancet::arm::CanopenBusConfig& l = *arms[1].config->canopen;
  const char* rp = a.config_path[0].c_str();
  const char* lp = a.config_path[1].c_str();
  const char* bus = r.interface_name.c_str();
  auto yes_no = [](bool b) { return b ? "true" : "false"; };
  if (!r.sync_producer || l.sync_producer) {
    out.push_back(lancet::text::format(
        "both arms are on CAN interface %s, which takes exactly one SYNC producer (CiA 301), the right hand's arm (read first "
        "in the tick): expected bus.canopen.sync_producer = true in %s (--config, right) and false in %s (--left-config, left), "
        "found %s and %s",
        bus, rp, lp, yes_no(r.sync_producer), yes_no(l.sync_producer)));
  }
  // Every node id on the bus belongs to one device: the drives' and the two masters' own.
  struct Id {
    int id;
    std::string field;
  };
  auto ids_of = [](const lancet::arm::CanopenBusConfig& c) {
    std::vector<Id> v;
    for (std::size_t j = 0; j < c.node_ids.size(); ++j) v.push_back({c.node_ids[j], "bus.canopen.node_ids[" + std::to_string(j) + "]"});
    v.push_back({c.master_node_id, "bus.canopen.master_node_id"});
    return v;
  };
  for (const Id& x : ids_of(r)) {
    for (const Id& y : ids_of(l)) {
      if (x.id != y.id) continue;
      out.push_back(lancet::text::format("both arms are on CAN interface %s and use node id %d: %s in %s (right) and %s in %s (left); "
                                         "expected node ids and master node ids that no other device on the bus uses",
                                         bus, x.id, x.field.c_str(), rp, y.field.c_str(), lp));
    }
  }
  const double r_us = r.sync_period * 1e6, l_us = l.sync_period * 1e6;
  if (std::llround(r_us) != std::llround(l_us)) {
    out.push_back(lancet::text::format("both arms are on CAN interface %s, one SYNC for both: expected the same bus.canopen.sync_period_us, "
                                       "found %.0f in %s (right) and %.0f in %s (left)",
                                       bus, r_us, rp, l_us, lp));
  }
  return out;
}

/// Keeps the SYNC-producing arm's SYNC (and its heartbeat) going once a SYNC period on a thread
/// of its own while the arm that shares its bus sets up or shuts down (which waits for SYNCs and
/// the TPDOs answering them). It judges nothing (CanopenArm::keep_sync): the producer's TPDOs late
/// while the other arm's set-up keeps the CPU busy are no fault of the producer. Start-up and
/// shut-down only, before and after the servo thread owns the devices.
class SyncKeeper {
 public:
  SyncKeeper(lancet::device::Device* producer, std::int64_t period_ns) {
    auto* arm = dynamic_cast<lancet::device::CanopenArm*>(producer);
    if (arm == nullptr) return;
    thread_ = std::thread([this, arm, period_ns] {
      auto next = std::chrono::steady_clock::now();
      while (!stop_.load(std::memory_order_relaxed)) {
        arm->keep_sync();
        next += std::chrono::nanoseconds(period_ns);
        std::this_thread::sleep_until(next);
      }
    });
  }
  SyncKeeper(const SyncKeeper&) = delete;
  SyncKeeper& operator=(const SyncKeeper&) = delete;
  ~SyncKeeper() {
    stop_.store(true, std::memory_order_relaxed);
    if (thread_.joinable()) thread_.join();
  }

 private:
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

/// Builds hand h's kinematics (into the hand's servo model) and device from its loaded config,
/// configures it and waits for a good read (activate comes just before the loop starts); fits the
/// hand's servo model to it.
bool open_arm(Args& a, std::size_t h, Arm& arm) {
  const std::string& config_path = a.config_path[h];
  if (arm.config->canopen) {
    // The drives were told the cycle (0x1006, 0x60C2) from the config; a servo on another period
    // would send SYNC at a rate they do not expect.
    const auto sync_ns = static_cast<std::int64_t>(std::llround(arm.config->canopen->sync_period * 1e9));
    if (std::llabs(sync_ns - a.rt.loop().period_ns) > 500) {
      const double period_us = static_cast<double>(a.rt.loop().period_ns) * 1e-3, sync_us = static_cast<double>(sync_ns) * 1e-3;
      return fail(lancet::text::format("--period-us %.0f differs from sync_period_us %.0f in [bus.canopen] of %s: the drives "
                                       "expect a SYNC every %.0f us (0x1006); give lancet-rt --period-us %.0f or change the config",
                                       period_us, sync_us, config_path.c_str(), sync_us, sync_us));
    }
  }
  const std::string cal_path = lancet::arm::calibration_path(config_path);
  auto cal = lancet::arm::apply_calibration_file(*arm.config, cal_path);
  if (!cal.ok()) return fail(cal.error().message);
  if (cal.value()) std::fprintf(stderr, "lancet-rt: calibration %s applied\n", cal_path.c_str());
  auto kin = lancet::arm::make_kinematics(*arm.config);
  if (!kin.ok()) return fail(kin.error().message);
  lancet::servo::ServoModel& m = a.model.hand[h].servo;
  m.kinematics = kin.value();
  auto dev = lancet::app::make_device(*arm.config);
  if (!dev.ok()) return fail(dev.error().message);
  arm.device = std::move(dev.value().device);
  install_signal_handlers();
  if (const lancet::Result<void> o = arm.device->configure(); !o.ok()) return fail(o.error().message);
  // No fault before the first good read: wait for it with the arm still disabled (errors while
  // inactive never trip the fault policy).
  if (const std::string why = await_first_read(*arm.device, a.first_read_timeout_ms * 1e-3); !why.empty()) {
    return fail(lancet::text::format("%s did not answer within %.0f ms of configuration (--first-read-timeout-ms): %s",
                                     arm.device->name().c_str(), a.first_read_timeout_ms, why.c_str()));
  }
  const auto& ws = arm.config->safety;
  m.device_origin = 0.5 * (ws.workspace_min + ws.workspace_max);
  for (std::size_t j = 0; j < ws.max_joint_torque.size() && j < m.max_joint_torque.size(); ++j)
    m.max_joint_torque[j] = ws.max_joint_torque[j];
  m.haptic.safety.max_force = std::min(m.haptic.safety.max_force, ws.max_force);
  return true;
}

/// The options that shape the servo models (every hand's alike, before an arm fits its own) and
/// the loop.
lancet::rt::LoopParams apply_model_options(Args& a) {
  lancet::rt::LoopParams loop_params = a.rt.loop();
  loop_params.duration_ns = lancet::seconds_to_ns(a.duration);
  lancet::servo::ServoModel& m = a.servo;
  m.period_ns = loop_params.period_ns;
  a.model.period_ns = loop_params.period_ns;
  a.model.hands = a.hands;
  if (a.stiffness > 0) {
    for (auto& mat : m.haptic.materials) mat.stiffness = a.stiffness;
  }
  m.fade.timeout_ns = static_cast<std::int64_t>(a.timeout_ms * 1e6);
  m.fade.fade_ns = static_cast<std::int64_t>(a.fade_ms * 1e6);
  m.fade.stale_after_ns = static_cast<std::int64_t>(a.stale_patch_ms * 1e6);
  a.model.script_waits_for_tissue = a.script_waits;
  for (lancet::app::HandModel& hm : a.model.hand) {
    hm.servo = m;
    hm.script_depth = a.script_depth;
  }
  return loop_params;
}

/// Hand h's arm's files as they were read (config, then calibration), for whoever records the
/// session.
void publish_arm_config(lancet::SharedState& shared, std::size_t h, const std::string& config_path) {
  constexpr std::size_t kMaxFile = 1 << 20;
  const auto read = [](const std::string& path) {
    auto r = lancet::config::read_text_file(path, kMaxFile, "an arm config");
    return r.ok() ? r.value() : std::string();
  };
  std::string text = read(config_path);
  const std::string cal = lancet::arm::calibration_path(config_path);
  if (std::filesystem::exists(cal)) text += "\n# --- calibration: " + cal + " ---\n" + read(cal);
  auto blob = std::make_unique<lancet::ArmConfigText>();
  blob->truncated = text.size() > lancet::kArmConfigCapacity ? 1u : 0u;
  blob->size = static_cast<std::uint32_t>(std::min<std::size_t>(text.size(), lancet::kArmConfigCapacity));
  std::memcpy(blob->text, text.data(), blob->size);
  shared.arm_config[h].write(*blob);
}

void print_status_line(const lancet::RtStatus& st) {
  std::string hands;
  for (std::size_t h = 0; h < st.hands && h < lancet::kHandCount; ++h) {
    const lancet::HandStatus& hs = st.hand[h];
    hands += lancet::text::format("  %s %.2f N %s%s v%llu%s%s", lancet::hand_name(static_cast<lancet::Hand>(h)), lancet::norm(hs.force),
                                  lancet::tool_name(hs.mode), hs.contact ? " contact" : "",
                                  static_cast<unsigned long long>(hs.patch_version), hs.has_arm ? " arm " : "",
                                  hs.has_arm ? lancet::app::describe_arm(hs).c_str() : "");
  }
  std::fprintf(stderr,
               "lancet-rt: tick %llu%s  viz %s  wake p99 %.0f us max %.0f us  missed %llu  dropped %llu%s\n",
               static_cast<unsigned long long>(st.tick), hands.c_str(), st.viz_alive ? "alive" : "absent",
               static_cast<double>(st.wake_p99_ns) / 1e3, static_cast<double>(st.wake_max_ns) / 1e3,
               static_cast<unsigned long long>(st.missed), static_cast<unsigned long long>(st.samples_dropped),
               st.watchdog_tripped ? "  WATCHDOG TRIPPED: force held at zero until re-armed" : "");
}

/// How the supervised run ended.
struct Ending {
  std::string by = "duration";  ///< duration, SIGTERM, SIGINT, SIGHUP, stall
  bool stalled = false;
};

/// The main thread while the servo runs: device re-arms and reconnects, what changed (said the
/// moment it is seen), a servo tick that stops advancing, signals, and the status line once a
/// second. It reads only the servo's private status, never the segment. Returns when the loop is
/// done, or when a stop was asked and the grace time has passed without it.
Ending supervise(const Args& a, lancet::app::RtServo& servo, const std::array<std::string, lancet::kHandCount>& arm_name,
                 const lancet::rt::LoopParams& loop_params, const std::atomic<bool>& loop_done) {
  lancet::app::SupervisorParams sp;
  sp.shm_name = a.shm;
  sp.arm_name = arm_name;
  sp.stall_timeout_ns = static_cast<std::int64_t>(a.stall_timeout_ms * 1e6);
  const std::int64_t started_ns = lancet::monotonic_ns();
  lancet::app::RtSupervisor supervisor(servo, sp, started_ns);
  Ending end;
  std::int64_t next_line_ns = started_ns + 1'000'000'000;
  std::int64_t stop_asked_ns = 0;
  for (;;) {
    const std::int64_t now = lancet::monotonic_ns();
    for (const auto& line : supervisor.poll(now)) std::fprintf(stderr, "lancet-rt: %s\n", line.c_str());
    if (loop_done.load(std::memory_order_acquire)) break;
    if (supervisor.stalled() && !end.stalled) {
      end.stalled = true;
      end.by = "stall";
      g_stop.store(true);
    }
    if (g_stop.load(std::memory_order_relaxed) && stop_asked_ns == 0) stop_asked_ns = now;
    // --duration is the loop's own end; should the loop not get there, it is enforced here too.
    if (a.duration > 0 && stop_asked_ns == 0 && now - started_ns > lancet::seconds_to_ns(a.duration) + loop_params.period_ns * 100) {
      stop_asked_ns = now;
      g_stop.store(true);
    }
    if (stop_asked_ns != 0 && now - stop_asked_ns > static_cast<std::int64_t>(a.shutdown_grace_ms * 1e6)) break;
    if (!a.quiet && now >= next_line_ns && supervisor.has_status()) {
      next_line_ns += 1'000'000'000;
      print_status_line(supervisor.last());
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  if (const int sig = g_signal.load(std::memory_order_relaxed); sig != 0 && !end.stalled) end.by = signal_name(sig);
  return end;
}

/// The servo thread is stuck (in a tick, in the device): leave without it. The segment goes, the
/// stats come from its last published status, and the arm's own watchdog (drive side) takes the
/// torque off, since nobody writes to it any more.
[[noreturn]] void leave_without_servo(const Args& a, lancet::app::RtServo& servo, StatsInput& stats, lancet::SharedChannel& channel) {
  std::fprintf(stderr, "lancet-rt: the servo thread did not stop within %.0f ms: leaving without it (exit 4)\n",
               a.shutdown_grace_ms);
  stats.clean = false;
  stats.has_status = servo.read_status(stats.status) == lancet::ReadStatus::kOk;
  if (!a.stats_path.empty() && !write_stats(a.stats_path, stats))
    std::fprintf(stderr, "lancet-rt: cannot write stats to %s\n", a.stats_path.c_str());
  channel.segment().unlink_name();
  std::fflush(stderr);
  std::_Exit(4);
}

double max_force_seen(const lancet::app::RtServo& servo) {
  double f = 0;
  for (std::size_t h = 0; h < servo.hands(); ++h) f = std::max(f, servo.data().hand[h].servo.max_force_seen);
  return f;
}

void print_stop_line(const std::string& ended_by, const lancet::rt::LoopStats& ls, const lancet::SharedState& shared,
                     const lancet::app::RtServo& servo) {
  std::fprintf(stderr,
               "lancet-rt: stopped (%s) after %llu ticks: %llu missed deadlines, wake-up p50 %.1f us p99 %.1f us max %.1f us, "
               "%llu samples dropped, max force %.2f N\n",
               ended_by.c_str(), static_cast<unsigned long long>(ls.ticks), static_cast<unsigned long long>(ls.missed),
               static_cast<double>(ls.wake_latency.percentile_ns(50)) / 1e3,
               static_cast<double>(ls.wake_latency.percentile_ns(99)) / 1e3,
               static_cast<double>(ls.wake_latency.max_ns()) / 1e3,
               static_cast<unsigned long long>(shared.samples.overflow_count()), max_force_seen(servo));
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App cli{"lancet-rt: 1 kHz haptic servo process (built-in simulated stylus, or an arm from hw_configs)"};
  Args a;
  add_options(cli, a);
  CLI11_PARSE(cli, argc, argv);
  // At once: a signal during start-up (loading the arm, waiting for its first read) ends the run,
  // also when lancet-rt was started in the background, where the shell left SIGINT ignored.
  install_signal_handlers();

  if (a.hands < 2 && !a.config_path[1].empty()) {
    fail("--left-config needs --hands 2");
    return 2;
  }
  const lancet::rt::LoopParams loop_params = apply_model_options(a);
  std::optional<lancet::device::HandTrajectories> trajectory;
  if (!a.trajectory_path.empty()) {
    auto tr = lancet::device::load_trajectory_csv(a.trajectory_path);
    if (!tr.ok()) {
      fail(tr.error().message);
      return 2;
    }
    trajectory = std::move(tr).value();
    for (std::size_t h = 0; h < lancet::kHandCount; ++h) {
      const lancet::device::Trajectory& t = (*trajectory)[h];
      if (t.t.empty()) continue;
      const char* hand = lancet::hand_name(static_cast<lancet::Hand>(h));
      if (h >= a.hands) {
        std::fprintf(stderr, "lancet-rt: %s: the %s hand's rows are not used (--hands %zu)\n", a.trajectory_path.c_str(), hand, a.hands);
        continue;
      }
      a.model.hand[h].trajectory = &t;
      std::fprintf(stderr, "lancet-rt: %s hand: replaying %zu trajectory points over %.2f s\n", hand, t.t.size(), t.duration());
    }
  }
  std::array<Arm, lancet::kHandCount> arms;
  for (std::size_t h = 0; h < a.hands; ++h) {
    if (!a.config_path[h].empty() && !load_arm(a, h, arms[h])) return 2;
  }
  // Before any bus traffic: two arms on one CAN bus must agree on who sends SYNC and on ids.
  if (const std::vector<std::string> problems = shared_bus_problems(a, arms); !problems.empty()) {
    for (const std::string& p : problems) fail(p);
    return 2;
  }
  const bool one_can_bus = share_a_can_bus(arms);
  for (std::size_t h = 0; h < a.hands; ++h) {
    if (!a.config_path[h].empty() && !open_arm(a, h, arms[h])) return 2;
  }

  lancet::ShmSegment::CreateOptions seg_opts;
  seg_opts.creator_name = "lancet-rt";
  auto channel = lancet::SharedChannel::create(a.shm, seg_opts);
  if (!channel) {
    fail(channel.error().message);
    return 2;
  }
  for (const auto& note : channel.value().segment().notes()) std::fprintf(stderr, "lancet-rt: %s\n", note.c_str());
  lancet::SharedState& shared = channel.value().state();

  install_signal_handlers();

  // Real time: process-wide setup first, then the loop on its own SCHED_FIFO thread.
  const lancet::rt::RtSetupOptions setup_opts = a.rt.setup();
  lancet::rt::RtSetupReport setup;
  lancet::rt::RtEnvironment environment(setup_opts, setup);
  // This thread (the supervisor) and every thread started from here on but the servo's (the
  // devices', the patch intake's) stay off the servo's CPU: the servo wakes to an idle CPU, as
  // cyclictest does.
  if (setup_opts.enable && lancet::rt::keep_off_cpu(setup_opts.cpu))
    setup.applied.push_back("other threads kept off CPU " + std::to_string(setup_opts.cpu));
  // Enable the arm as late as possible: a drive-side watchdog counts from the end of activate(),
  // so the servo's first tick follows within a period or two.
  std::array<lancet::device::Device*, lancet::kHandCount> devices{};
  std::array<std::string, lancet::kHandCount> arm_name;
  for (std::size_t h = 0; h < a.hands; ++h) {
    Arm& arm = arms[h];
    if (!arm.device) continue;
    // The left arm on the right's bus sets up on the right's SYNCs.
    const SyncKeeper keeper(h == 1 && one_can_bus ? arms[0].device.get() : nullptr, a.model.period_ns);
    if (const lancet::Result<void> o = arm.device->activate(); !o.ok()) {
      fail(o.error().message);
      return 2;
    }
    std::fprintf(stderr, "lancet-rt: %s hand: arm '%s' (%s, %d joints) is %s\n", lancet::hand_name(static_cast<lancet::Hand>(h)),
                 arm.config->name.c_str(), arm.device->name().c_str(), arm.device->joint_count(),
                 lancet::device::to_string(arm.device->state()));
    devices[h] = arm.device.get();
    arm_name[h] = arm.device->name();
  }
  lancet::app::RtServo servo(a.model, shared, lancet::monotonic_ns(), devices);  // after mlockall: locked too
  for (std::size_t h = 0; h < a.hands; ++h) {
    if (!a.config_path[h].empty()) publish_arm_config(shared, h, a.config_path[h]);
  }
  // New patches are copied, checked and get their tree on a helper thread, below the servo's
  // priority and off its CPU, so no tick pays for one.
  const std::string intake_line = servo.start_patch_intake(setup_opts.enable, std::max(1, setup_opts.priority - 10), setup_opts.cpu);
  lancet::rt::RtLoop loop(loop_params);
  std::atomic<bool> loop_done{false};
  lancet::rt::RtThread thread = lancet::rt::start_rt_thread(setup_opts, setup, [&] {
    servo.set_fifo(lancet::rt::current_thread_is_fifo());
    const std::int64_t stall_at = a.inject_stall_s > 0 ? lancet::monotonic_ns() + lancet::seconds_to_ns(a.inject_stall_s) : 0;
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
  std::fprintf(stderr, "lancet-rt: running %zu hand%s at %.0f Hz on segment %s (pid %d), strategy %s\n", a.hands,
               a.hands == 1 ? "" : "s", 1e9 / static_cast<double>(a.model.period_ns), a.shm.c_str(), static_cast<int>(getpid()),
               a.rt.strategy.c_str());

  const Ending end = supervise(a, servo, arm_name, loop_params, loop_done);
  StatsInput stats;
  stats.setup = &setup;
  stats.hands = a.hands;
  stats.arm_name = arm_name;
  stats.ended_by = end.by;
  if (!loop_done.load(std::memory_order_acquire)) leave_without_servo(a, servo, stats, channel.value());
  thread.join();
  g_stop.store(true);
  for (std::size_t h = 0; h < a.hands; ++h) {
    if (!arms[h].device) continue;
    std::fprintf(stderr, "lancet-rt: %s arm: %s: %s\n", lancet::hand_name(static_cast<lancet::Hand>(h)), arm_name[h].c_str(),
                 lancet::app::describe_bus(servo.data().status.hand[h].bus).c_str());
  }
  // The left arm first: on the right's bus it shuts its drives down on the right's SYNCs.
  for (std::size_t h = a.hands; h-- > 0;) {
    if (!arms[h].device) continue;
    const SyncKeeper keeper(h == 1 && one_can_bus ? arms[0].device.get() : nullptr, a.model.period_ns);
    (void)arms[h].device->deactivate();
  }
  shared.rt_heartbeat.stop();

  print_stop_line(end.by, loop.stats(), shared, servo);
  stats.loop = &loop.stats();
  stats.watchdog_trips = loop.watchdog().trips();
  stats.data = &servo.data();
  stats.has_status = servo.read_status(stats.status) == lancet::ReadStatus::kOk;
  if (!a.stats_path.empty() && !write_stats(a.stats_path, stats)) {
    std::fprintf(stderr, "lancet-rt: cannot write stats to %s\n", a.stats_path.c_str());
    return 1;
  }
  return end.stalled ? 3 : 0;
}
