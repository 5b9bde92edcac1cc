// lancetctl: bring-up and test-rig command line for Lancet.
//   lancetctl jitter      run the servo loop (and cyclictest) and report wake-up latency
//   lancetctl host-check  audit this host for 1 kHz work (kernel, CPU isolation, limits, the bus's IRQs)

#include <CLI/CLI.hpp>

#include "tools/bringup.hpp"
#include "tools/host_check.hpp"
#include "tools/validate_cmd.hpp"
#include <cstdio>
#include <fstream>
#include <stdexcept>

#include "tools/jitter.hpp"
#include "tools/jitter_plot.hpp"

namespace {

bool write_file(const std::string& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
  return static_cast<bool>(out);
}

int run_jitter_command(const lancet::tools::JitterOptions& o) {
  lancet::tools::JitterResult r;
  try {
    r = lancet::tools::run_jitter(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "lancetctl jitter: %s\n", e.what());
    return 2;
  }
  std::fputs(lancet::tools::format_jitter_text(o, r).c_str(), stdout);
  if (!o.json_path.empty() && !write_file(o.json_path, lancet::tools::format_jitter_json(o, r))) {
    std::fprintf(stderr, "lancetctl jitter: cannot write %s\n", o.json_path.c_str());
    return 2;
  }
  if (!o.plot_path.empty()) {
    std::vector<lancet::rt::Distribution> dists{lancet::rt::to_distribution(r.wake, "lancet")};
    if (r.cyclictest) dists.push_back(*r.cyclictest);
    std::string error;
    const std::vector<lancet::tools::TimeSeries> series{{"lancet", 0.1, r.window_max_us}};
    if (!lancet::tools::write_jitter_svg(o.plot_path, dists, series, "lancetctl jitter: wake-up latency", &error)) {
      std::fprintf(stderr, "lancetctl jitter: cannot write %s: %s\n", o.plot_path.c_str(), error.c_str());
      return 2;
    }
  }
  if (o.compare_cyclictest && !r.cyclictest) {
    std::fprintf(stderr, "lancetctl jitter: the cyclictest comparison failed (see above)\n");
    return 2;
  }
  return r.pass() ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App cli{"lancetctl: Lancet bring-up and test-rig tool"};
  cli.require_subcommand(1);

  lancet::tools::JitterOptions jo;
  CLI::App* jitter = cli.add_subcommand(
      "jitter",
      "run the real servo loop (simulated arm, full haptic workload) and report its wake-up latency; exit 0 when "
      "every given bound holds, 1 when one fails, 2 on errors");
  jitter->add_option("--duration", jo.duration_s, "seconds of measurement in all")->check(CLI::Range(0.1, 86400.0))->capture_default_str();
  lancet::app::add_rt_options(*jitter, jo.rt);
  jitter->add_flag("--compare-cyclictest", jo.compare_cyclictest,
                   "also run cyclictest (rt-tests) with the same interval, priority and CPU, alternating with our loop");
  jitter->add_flag("--compare-recording", jo.compare_recording,
                   "alternate rounds without and with a session recording (HDF5, as lancet-viz --record writes it) and "
                   "report both wake-up distributions");
  jitter->add_option("--record-file", jo.record_path, "with --compare-recording: keep the recording here");
  jitter->add_option("--rounds", jo.rounds, "alternations of our loop and cyclictest")->check(CLI::Range(1, 100))->capture_default_str();
  jitter->add_option("--cyclictest", jo.cyclictest, "cyclictest executable")->capture_default_str();
  jitter->add_option("--max-p99-us", jo.max_p99_us, "fail when the wake-up latency p99 exceeds this (us)")->check(CLI::PositiveNumber);
  jitter->add_option("--max-us", jo.max_us, "fail when the worst wake-up latency exceeds this (us)")->check(CLI::PositiveNumber);
  jitter->add_option("--max-missed", jo.max_missed, "fail when more deadlines than this were missed");
  std::string workload = "servo";
  jitter->add_option("--workload", workload, "what each tick does: servo (the real haptic tick) or none (the bare loop)")
      ->check(CLI::IsMember({"servo", "none"}))->capture_default_str();
  jitter->add_option("--json", jo.json_path, "write the results as JSON here");
  jitter->add_option("--plot", jo.plot_path, "write an SVG plot (histograms and latency over time) here");

  std::string config_path;
  CLI::App* validate = cli.add_subcommand(
      "validate", "check an arm configuration (hw_configs/*.toml): print every error with file:line:column and the field; "
                  "exit 0 when valid, 1 when not, 2 when unreadable");
  validate->add_option("config", config_path, "the arm's TOML file")->required();

  // Bring-up: list, probe, monitor, calibrate (home), jog.
  cli.add_subcommand("list", "USB devices, CAN interfaces and serial ports on this machine");
  CLI::App* probe = cli.add_subcommand("probe", "configure the arm from its config and read it once (exit 1 if it does not answer)");
  probe->add_option("config", config_path, "the arm's TOML file")->required();
  double mon_duration = 0, mon_rate = 10;
  CLI::App* monitor = cli.add_subcommand("monitor", "read the arm continuously: joints, tool pose, buttons, bus statistics (never moves it)");
  std::string mon_shm;
  monitor->add_option("config", config_path, "the arm's TOML file (not with --rt)");
  monitor->add_option("--rt", mon_shm, "instead: follow a running lancet-rt on this segment (e.g. /lancet): tool, force, arm state")
      ->expected(0, 1)->default_str("/lancet");
  monitor->add_option("--duration", mon_duration, "seconds; 0 runs until interrupted")->check(CLI::NonNegativeNumber)->capture_default_str();
  monitor->add_option("--rate", mon_rate, "lines per second")->check(CLI::Range(0.1, 1000.0))->capture_default_str();
  bool mon_json = false;
  monitor->add_flag("--json", mon_json, "with --rt: one JSON object a line (every field of lancet-rt's status), for rigs and scripts");
  std::vector<double> home;
  bool write_cal = false;
  CLI::App* calibrate = cli.add_subcommand(
      "calibrate", "with the arm held in its home pose: encoder offsets that make the joints read that pose, saved next to the config "
                   "(a Novint Falcon homes on its switches instead: this guides the homing and shows which motors are done)");
  calibrate->alias("home");
  calibrate->add_option("config", config_path, "the arm's TOML file")->required();
  calibrate->add_option("--home", home, "joint values of the home pose (deg; mm for prismatic joints); default all zero")->delimiter(',');
  calibrate->add_flag("--write", write_cal, "write <config>.calibration.toml (default: a dry run that prints the offsets)");
  int jog_joint = 0;
  double jog_torque = 0, jog_seconds = 0.5;
  bool jog_yes = false;
  CLI::App* jog = cli.add_subcommand("jog", "a small torque on one joint for a moment (at most 10% of its limit, 2 s), after confirmation");
  jog->add_option("config", config_path, "the arm's TOML file")->required();
  jog->add_option("--joint", jog_joint, "joint index")->required();
  jog->add_option("--torque", jog_torque, "N·m (N for prismatic joints)")->required();
  jog->add_option("--seconds", jog_seconds, "how long")->capture_default_str();
  jog->add_flag("--yes", jog_yes, "confirm: the workspace is clear and the stylus is held");

  std::string rearm_shm = "/lancet";
  bool rearm_yes = false;
  double rearm_timeout = 5;
  CLI::App* rearm = cli.add_subcommand(
      "rearm", "re-arm a running lancet-rt's faulted arms and tripped watchdog: shows the fault, asks, then waits for the outcome "
               "(exit 0 re-armed or nothing to do, 1 refused/failed/no answer)");
  rearm->add_option("--rt", rearm_shm, "lancet-rt's shared-memory segment")->capture_default_str();
  rearm->add_flag("--yes", rearm_yes, "do not ask: the workspace is clear and the stylus is held");
  rearm->add_option("--timeout", rearm_timeout, "seconds to wait for the outcome")->check(CLI::Range(0.1, 120.0))->capture_default_str();
  std::string rearm_hand = "both";
  rearm->add_option("--hand", rearm_hand, "the hand whose arm to re-arm: right, left or both (every hand lancet-rt drives)")
      ->check(CLI::IsMember({"right", "left", "both"}))->capture_default_str();

  lancet::tools::HostCheckOptions ho;
  CLI::App* host_check = cli.add_subcommand(
      "host-check",
      "audit this host for 1 kHz servo work: one line per check (pass / warn / fail / skip) with what was found and the "
      "fix; exit 0 when no check fails, 1 when one does, 2 on a bad config. fail: what breaks the 1 kHz promise (not "
      "PREEMPT_RT, RT throttling starving the servo, RLIMIT_MEMLOCK too low without CAP_IPC_LOCK, RLIMIT_RTPRIO 0 without "
      "CAP_SYS_NICE, the servo CPU offline); warn: what degrades the latency tail (CPU not isolated, SMT sibling busy, "
      "governor, C-states, THP always, swap, timer_migration, clocksource not tsc, irqbalance, the bus IRQ's CPU and "
      "thread priority); skip: not applicable. Run it as the user that runs lancet-rt");
  host_check->add_option("--config", ho.config_path, "the arm's TOML file: also check its bus (CAN interface, USB device, "
                                                     "the NIC to the Modbus TCP drive box): IRQ affinity and thread priority");
  host_check->add_option("--cpu", ho.cpu, "the servo CPU (default: lancet-rt's, the last online CPU)")->check(CLI::Range(0, 4095));
  host_check->add_option("--priority", ho.priority, "the servo's SCHED_FIFO priority (lancet-rt --priority)")
      ->check(CLI::Range(1, 98))->capture_default_str();
  host_check->add_flag("--json", ho.json, "print the report as one JSON object (checks and a summary)");
  host_check->add_option("--root", ho.root, "read /proc and /sys under this folder (tests)")->group("");

  CLI11_PARSE(cli, argc, argv);
  if (host_check->parsed()) return lancet::tools::run_host_check_command(ho, stdout, stderr);
  if (rearm->parsed()) return lancet::tools::run_rearm_rt(rearm_shm, rearm_yes, rearm_timeout, stdin, stdout, rearm_hand);
  jo.servo_workload = workload == "servo";
  if (cli.got_subcommand("list")) return lancet::tools::run_list(stdout);
  if (probe->parsed()) return lancet::tools::run_probe(config_path, stdout);
  if (monitor->parsed()) {
    if (monitor->count("--rt") > 0) return lancet::tools::run_monitor_rt(mon_shm.empty() ? "/lancet" : mon_shm, mon_duration, mon_rate, stdout, mon_json);
    if (config_path.empty()) {
      std::fprintf(stderr, "lancetctl monitor: give the arm's config, or --rt to follow a running lancet-rt\n");
      return 2;
    }
    return lancet::tools::run_monitor(config_path, mon_duration, mon_rate, stdout);
  }
  if (calibrate->parsed()) return lancet::tools::run_calibrate(config_path, home, write_cal, stdout);
  if (jog->parsed()) return lancet::tools::run_jog(config_path, jog_joint, jog_torque, jog_seconds, jog_yes, stdout);
  if (jitter->parsed()) return run_jitter_command(jo);
  if (validate->parsed()) return lancet::tools::run_validate(config_path, stdout);
  return 2;
}
