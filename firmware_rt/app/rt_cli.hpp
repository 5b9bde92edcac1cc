#pragma once
// Command-line options shared by every program that runs the servo loop (lancet-rt, lancetctl
// jitter): period, wake strategy, priority, CPU, watchdog. Configure time only.

#include <unistd.h>

#include <CLI/CLI.hpp>
#include <string>

#include "rt/rt_loop.hpp"
#include "rt/rt_setup.hpp"

namespace lancet::app {

struct RtCliOptions {
  double period_us = 1000;
  std::string strategy = "sleep";
  double spin_margin_us = 200;
  int priority = 80;
  int cpu = -2;  ///< -2: default (the last online CPU); -1: no affinity
  bool no_rt = false;
  std::uint32_t watchdog_misses = 0;
  double watchdog_budget_us = 0;

  /// The real-time setup these options ask for.
  [[nodiscard]] rt::RtSetupOptions setup() const {
    rt::RtSetupOptions o;
    o.enable = !no_rt;
    o.priority = priority;
    o.cpu = cpu == -2 ? rt::default_rt_cpu() : cpu;
    return o;
  }
  /// The loop these options ask for (duration and windows are the caller's).
  [[nodiscard]] rt::LoopParams loop() const {
    rt::LoopParams p;
    p.period_ns = static_cast<std::int64_t>(period_us * 1e3);
    p.strategy = strategy == "spin" ? rt::WakeStrategy::kSleepThenSpin : rt::WakeStrategy::kSleep;
    p.spin_margin_ns = static_cast<std::int64_t>(spin_margin_us * 1e3);
    p.watchdog.max_consecutive_misses = watchdog_misses;
    p.watchdog.tick_budget_ns = static_cast<std::int64_t>(watchdog_budget_us * 1e3);
    return p;
  }
};

inline void add_rt_options(CLI::App& app, RtCliOptions& o) {
  app.add_option("--period-us", o.period_us, "servo period in microseconds")->check(CLI::Range(100.0, 100000.0))->capture_default_str();
  app.add_option("--strategy", o.strategy, "wake strategy: sleep, or spin (sleep to deadline - margin, then spin)")
      ->check(CLI::IsMember({"sleep", "spin"}))->capture_default_str();
  app.add_option("--spin-margin-us", o.spin_margin_us, "spin strategy: wake this early, then spin (at most half a period)")
      ->check(CLI::Range(1.0, 50000.0))->capture_default_str();
  app.add_option("--priority", o.priority, "SCHED_FIFO priority (1-98)")->check(CLI::Range(1, 98))->capture_default_str();
  app.add_option("--cpu", o.cpu, "pin the loop to this CPU; -1: no affinity (default: the last CPU)")->check(CLI::Range(-1, 4095));
  app.add_flag("--no-rt", o.no_rt, "skip the real-time setup (mlockall, SCHED_FIFO, affinity, cpu_dma_latency)");
  app.add_option("--watchdog-misses", o.watchdog_misses, "zero force after this many missed deadlines in a row (0: off)")
      ->capture_default_str();
  app.add_option("--watchdog-budget-us", o.watchdog_budget_us, "zero force after one tick computes longer than this (0: off)")
      ->check(CLI::NonNegativeNumber)->capture_default_str();
}

}  // namespace lancet::app
