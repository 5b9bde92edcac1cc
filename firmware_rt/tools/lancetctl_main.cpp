// lancetctl: bring-up and test-rig command line for Lancet.
//   lancetctl jitter   run the servo loop (and cyclictest) and report wake-up latency

#include <CLI/CLI.hpp>

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

  CLI11_PARSE(cli, argc, argv);
  jo.servo_workload = workload == "servo";
  if (jitter->parsed()) return run_jitter_command(jo);
  if (validate->parsed()) return lancet::tools::run_validate(config_path, stdout);
  return 2;
}
