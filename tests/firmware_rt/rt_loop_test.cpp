// The servo loop on a real clock: rate, overruns, watchdog, no allocation, no page faults, and
// what the real-time setup reports when it is refused. These run serially (timing matters).

#include "rt/rt_loop.hpp"

#include <gtest/gtest.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cstdio>
#include <memory>
#include <string>
#include <thread>

#include "app/rt_servo.hpp"
#include "malloc_guard.hpp"
#include "rt/rt_setup.hpp"

namespace lancet::rt {
namespace {

void busy_wait(std::int64_t ns) {
  const std::int64_t until = monotonic_ns() + ns;
  while (monotonic_ns() < until) {
  }
}

// Runs the loop on a SCHED_FIFO thread when permitted (as CI does), else an ordinary one.
void run_on_rt_thread(RtLoop& loop, const std::function<void(const TickContext&)>& tick) {
  std::atomic<bool> stop{false};
  RtSetupOptions o;
  o.cpu = -1;
  RtSetupReport report;
  RtThread t = start_rt_thread(o, report, [&] { loop.run(tick, stop); });
  t.join();
}

TEST(RtLoop, AccountsForEveryDeadlineOfFiveSecondsAtOneKilohertz) {
  LoopParams p;
  p.duration_ns = 5'000'000'000;
  RtLoop loop(p);
  std::int64_t first = 0, last = 0;
  run_on_rt_thread(loop, [&](const TickContext& c) {
    if (first == 0) first = c.deadline_ns;
    last = c.deadline_ns;
  });
  const LoopStats& s = loop.stats();
  // 5000 deadlines in 5 s: every one is either ticked or counted as skipped (no drift, no
  // silent loss). How many the host lets us tick is its business, not the loop's: a shared CI
  // VM preempts us for tens of milliseconds at a time, so only a gross shortfall fails.
  EXPECT_NEAR(static_cast<double>(s.ticks + s.overruns), 5000.0, 2.0)
      << "ticks " << s.ticks << ", overruns " << s.overruns;
  EXPECT_GE(s.ticks, 4750u) << "overruns " << s.overruns << ", wake p99 "
                            << s.wake_latency.percentile_ns(99) << " ns";
  EXPECT_EQ((last - first) % p.period_ns, 0) << "deadlines must stay on the 1 ms grid";
  EXPECT_EQ(s.wake_latency.count(), s.ticks);
  EXPECT_EQ(s.compute.count(), s.ticks);
}

TEST(RtLoop, TheWakeUpHistogramsCoarseBinsHoldEveryWakeUpInTheRightBin) {
  LatencyHistogram h;
  // On each side of some edges, and beyond the last one.
  for (std::int64_t ns : {0ll, 1'999ll, 2'000ll, 4'999ll, 99'999ll, 100'000ll, 999'999ll, 1'000'000ll, 1'999'999ll, 2'000'000ll,
                          5'000'000'000ll})
    h.record(ns);
  const auto bins = wake_bins(h);
  const std::array<std::uint64_t, kWakeBins> expected = {2, 2, 0, 0, 0, 0, 0, 1, 1, 0, 0, 0, 0, 1, 2, 2};
  EXPECT_EQ(bins, expected);
  // A live loop publishes them: they add up to the wake-ups counted by the last refresh.
  LoopParams p;
  p.duration_ns = 400'000'000;
  RtLoop loop(p);
  std::uint64_t live_sum = 0, live_ticks = 0;
  run_on_rt_thread(loop, [&](const TickContext& c) {
    live_sum = 0;
    for (std::uint64_t n : c.live.wake_histogram) live_sum += n;
    live_ticks = c.live.ticks;
  });
  EXPECT_GT(live_ticks, 0u);
  EXPECT_EQ(live_sum, live_ticks) << "one wake-up per tick, all in some bin";
}

TEST(RtLoop, AnInjectedSlowTickIsAnOverrunAndTripsTheWatchdog) {
  LoopParams p;
  p.duration_ns = 200'000'000;
  p.watchdog.tick_budget_ns = 1'000'000;  // 1 ms budget
  RtLoop loop(p);
  std::uint64_t zero_force_ticks = 0;
  std::atomic<bool> stop{false};
  loop.run(
      [&](const TickContext& c) {
        if (c.watchdog.tripped()) ++zero_force_ticks;  // what the servo does: zero force
        if (c.tick == 50) busy_wait(3'500'000);        // one tick takes 3.5 periods
      },
      stop);
  const LoopStats& s = loop.stats();
  EXPECT_GE(s.overruns, 3u);
  EXPECT_GE(s.missed, 4u);  // the late tick and the three deadlines it swallowed
  EXPECT_TRUE(loop.watchdog().tripped());
  EXPECT_EQ(loop.watchdog().reason(), Watchdog::Reason::kTickOverBudget);
  EXPECT_GE(s.longest_stall_ns, 3'500'000);
  EXPECT_GT(zero_force_ticks, 50u) << "every tick after the trip sees the fault until a re-arm";
  // No catch-up burst: the loop did not run 200 ticks in 200 ms.
  EXPECT_LE(s.ticks + s.overruns, 201u);
}

TEST(RtLoop, ConsecutiveMissesTripTheWatchdog) {
  LoopParams p;
  p.duration_ns = 100'000'000;
  p.watchdog.max_consecutive_misses = 2;
  RtLoop loop(p);
  std::atomic<bool> stop{false};
  loop.run([&](const TickContext& c) {
    if (c.tick == 20 || c.tick == 21) busy_wait(1'500'000);
  }, stop);
  EXPECT_TRUE(loop.watchdog().tripped());
  EXPECT_EQ(loop.watchdog().reason(), Watchdog::Reason::kConsecutiveMisses);
}

TEST(RtLoop, SpinStrategyWakesAtTheDeadlineAndNeverSpinsAWholePeriod) {
  LoopParams p;
  p.duration_ns = 300'000'000;
  p.strategy = WakeStrategy::kSleepThenSpin;
  p.spin_margin_ns = 5'000'000;  // asks for more than a period: clamped to half of it
  RtLoop loop(p);
  std::int64_t min_latency = INT64_MAX;
  std::atomic<bool> stop{false};
  loop.run([&](const TickContext& c) { min_latency = std::min(min_latency, c.woke_ns - c.deadline_ns); }, stop);
  EXPECT_GE(min_latency, 0) << "spinning must not wake before the deadline";
  // Half the period is slept: compute + spin leaves the thread idle for at least ~0.5 ms a tick,
  // so the loop keeps up.
  EXPECT_GE(loop.stats().ticks, 250u);
}

TEST(RtLoop, TenThousandServoTicksAllocateNothingAndFaultNoPage) {
  // The real tick (servo + contact + samples) on a fast loop: 10 000 ticks at 10 kHz.
  LoopParams p;
  p.period_ns = 100'000;
  p.duration_ns = 1'000'000'000;
  p.warmup_ticks = 100;
  p.max_windows = 16;
  auto shared = std::make_unique<SharedState>();
  app::RtModel model;
  model.servo.period_ns = p.period_ns;
  app::RtServo servo(model, *shared, monotonic_ns());
  auto patch = std::make_unique<TissuePatch>();
  patch->n_triangles = 2;
  patch->triangles[0] = {{{-0.1f, -0.1f, 0}, {0.1f, -0.1f, 0}, {0.1f, 0.1f, 0}}, 1, 0, 0};
  patch->triangles[1] = {{{-0.1f, -0.1f, 0}, {0.1f, 0.1f, 0}, {-0.1f, 0.1f, 0}}, 1, 0, 1};
  patch->t_ns = monotonic_ns();  // a patch must be stamped (and not from the future) to be taken
  shared->patch.write(*patch);
  RtLoop loop(p);
  std::size_t allocations = 1;
  // Set up as lancet-rt does: mlockall (which maps every page, code included, before the loop;
  // without it the first call of a function after warm-up faults its code page in) and a thread
  // with a prefaulted stack.
  RtSetupOptions o;
  o.cpu = -1;
  o.hold_dma_latency = false;
  RtSetupReport report;
  RtEnvironment environment(o, report);
  RtThread t = start_rt_thread(o, report, [&] {
    std::atomic<bool> stop{false};
    ToolSample drained{};
    test::MallocGuard guard;
    loop.run(
        [&](const TickContext& c) {
          shared->viz_heartbeat.beat(c.woke_ns, 1);
          servo.tick(c);
          while (shared->samples.try_pop(drained)) {
          }
        },
        stop);
    allocations = guard.count();
  });
  t.join();
  EXPECT_GE(loop.stats().ticks + loop.stats().overruns, 9'000u);
  EXPECT_EQ(allocations, 0u);
  if (!report.memory_locked) {
    std::printf("page faults not checked: mlockall was refused (run as root, as CI does)\n");
  } else if (!test::kAddressSanitizer) {  // ASan's shadow memory faults in lazily
    EXPECT_EQ(loop.stats().minor_faults, 0) << "page faults inside the loop after warm-up";
    EXPECT_EQ(loop.stats().major_faults, 0);
  }
  EXPECT_GT(servo.data().servo.contact_ticks, 0u);
}

// In a child that has dropped its privileges: what does the setup report?
TEST(RtSetup, RefusedStepsAreReportedWithARemedy) {
  int fds[2];
  ASSERT_EQ(pipe(fds), 0);
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    close(fds[0]);
    rlimit zero{0, 0};
    setrlimit(RLIMIT_RTPRIO, &zero);
    setrlimit(RLIMIT_MEMLOCK, &zero);
    if (getuid() == 0) {
      // nobody: no CAP_SYS_NICE, no CAP_IPC_LOCK, no /dev/cpu_dma_latency.
      if (setgid(65534) != 0 || setuid(65534) != 0) _exit(3);
    }
    std::string out;
    {
      RtSetupOptions o;
      o.cpu = -1;
      RtSetupReport r;
      RtEnvironment env(o, r);
      RtThread t = start_rt_thread(o, r, [] {});
      t.join();
      out += r.fifo ? "FIFO-GRANTED\n" : "";
      for (const auto& l : r.degraded) out += l + "\n";
    }
    const ssize_t n = write(fds[1], out.data(), out.size());
    _exit(n == static_cast<ssize_t>(out.size()) ? 0 : 4);
  }
  close(fds[1]);
  std::string text;
  char buf[4096];
  ssize_t n;
  while ((n = read(fds[0], buf, sizeof buf)) > 0) text.append(buf, static_cast<std::size_t>(n));
  close(fds[0]);
  int status = 0;
  waitpid(child, &status, 0);
  ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << "child status " << status;
  EXPECT_EQ(text.find("FIFO-GRANTED"), std::string::npos) << text;
  EXPECT_NE(text.find("SCHED_FIFO priority 80 refused"), std::string::npos) << text;
  EXPECT_NE(text.find("CAP_SYS_NICE"), std::string::npos) << text;
  if (!test::kAddressSanitizer) {  // ASan intercepts mlockall and always reports success
    EXPECT_NE(text.find("mlockall refused"), std::string::npos) << text;
    EXPECT_NE(text.find("ulimit -l"), std::string::npos) << text;
  }
}

TEST(RtSetup, ParsesCpuLists) {
  EXPECT_EQ(parse_cpu_list("1,3-5"), (std::vector<int>{1, 3, 4, 5}));
  EXPECT_EQ(parse_cpu_list(""), std::vector<int>{});
  EXPECT_EQ(parse_cpu_list("2"), std::vector<int>{2});
  EXPECT_EQ(parse_cpu_list("5-3"), std::vector<int>{});
  EXPECT_EQ(parse_cpu_list("x"), std::vector<int>{});
}

}  // namespace
}  // namespace lancet::rt
