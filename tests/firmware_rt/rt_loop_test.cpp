// The servo loop: its accounting (ticks, overruns, misses, the watchdog, what a tick sees) on a
// simulated clock, exactly; on the real clock, a smoke test per wake strategy (it ticks, every
// deadline is accounted, it never wakes early), no allocation, no page faults, and what the
// real-time setup reports when it is refused. How well the host keeps time is a benchmark's
// business (lancetctl jitter, docs/PERFORMANCE.md), never a bound here.

#include "rt/rt_loop.hpp"

#include <gtest/gtest.h>
#include <sched.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cstdio>
#include <functional>
#include <memory>
#include <string>
#include <thread>
#include <utility>

#include "app/rt_servo.hpp"
#include "malloc_guard.hpp"
#include "rt/rt_setup.hpp"

namespace lancet::rt {
namespace {

// Simulated time for RtLoop::run: a sleep jumps to its target (plus the lateness `late` says for
// that wake-up, as a preempted thread would wake), a spin to its target, and a tick "computes" by
// advancing the clock itself. Exact whatever the host does.
struct SimClock {
  std::int64_t now = 5'000'000'000;  // not 0: the loop must not treat 0 as "no time yet"
  std::function<std::int64_t(std::int64_t target)> late;  // ns late for the sleep to `target` (empty: on time)
  std::int64_t last_sleep_target = 0, last_spin_target = 0;
  std::uint64_t sleeps = 0, spins = 0;

  [[nodiscard]] std::int64_t now_ns() const noexcept { return now; }
  void sleep_until(std::int64_t t) noexcept {
    ++sleeps;
    last_sleep_target = t;
    now = std::max(now, t) + (late ? late(t) : 0);
  }
  void spin_until(std::int64_t t) noexcept {
    ++spins;
    last_spin_target = t;
    now = std::max(now, t);
  }
  void compute(std::int64_t ns) noexcept { now += ns; }
};

template <class Tick>
void run_simulated(RtLoop& loop, SimClock& clock, Tick&& tick) {
  std::atomic<bool> stop{false};
  loop.run(tick, stop, clock);
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

TEST(RtLoop, AccountsForEveryDeadlineOfFiveSecondsEvenWhenTheLastTickIsLate) {
  LoopParams p;
  p.duration_ns = 5'000'000'000;
  RtLoop loop(p);
  SimClock clock;
  const std::int64_t start = clock.now;
  // A host that wakes us up to 0.9 ms late, and now and then a tick that takes 2.5 periods (it
  // swallows two deadlines); the last tick takes 10 periods, past the end of the duration.
  clock.late = [](std::int64_t t) { return (t / 1000 * 7919) % 900'000; };
  std::int64_t first = 0, last = 0;
  std::uint64_t off_grid = 0;
  run_simulated(loop, clock, [&](const TickContext& c) {
    if (first == 0) first = c.deadline_ns;
    last = c.deadline_ns;
    if ((c.deadline_ns - start) % p.period_ns != 0) ++off_grid;
    const std::int64_t end = start + p.duration_ns;
    if (c.tick % 97 == 0 && c.deadline_ns < end - 10'000'000) clock.compute(2'500'000);
    if (c.deadline_ns == end) clock.compute(10'000'000);
  });
  const LoopStats& s = loop.stats();
  // Every deadline in (start, start + 5 s] is either ticked or counted as skipped: no drift, no
  // silent loss, and none counted past the end.
  EXPECT_EQ(s.ticks + s.overruns, 5000u) << "ticks " << s.ticks << ", overruns " << s.overruns;
  EXPECT_GE(s.overruns, 2u * ((s.ticks - 10) / 97)) << "each slow tick swallows two deadlines";
  EXPECT_EQ(first, start + p.period_ns);
  EXPECT_EQ(last, start + p.duration_ns) << "the last deadline of the duration was ticked";
  EXPECT_EQ(off_grid, 0u) << "deadlines must stay on the 1 ms grid";
  EXPECT_EQ(s.wake_latency.count(), s.ticks);
  EXPECT_EQ(s.compute.count(), s.ticks);
  EXPECT_EQ(s.period_error.count(), s.ticks - 1);
  EXPECT_GE(s.missed, s.overruns);
  EXPECT_EQ(loop.stats().live.ticks, s.ticks) << "the final refresh publishes the end figures";
  EXPECT_EQ(loop.stats().live.overruns, s.overruns);
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
  // A live loop publishes them: they add up to the wake-ups counted by the last refresh, and the
  // wake-ups fall in the bins of their lateness (every 4th 150 us late, the others 1 us).
  LoopParams p;
  p.duration_ns = 400'000'000;
  RtLoop loop(p);
  SimClock clock;
  std::uint64_t n_sleeps = 0;
  clock.late = [&](std::int64_t) { return ++n_sleeps % 4 == 0 ? 150'000 : 1'000; };
  std::uint64_t live_sum = 0, live_ticks = 0, mismatched = 0;
  run_simulated(loop, clock, [&](const TickContext& c) {
    live_sum = 0;
    for (std::uint64_t n : c.live.wake_histogram) live_sum += n;
    live_ticks = c.live.ticks;
    if (live_sum != live_ticks) ++mismatched;
  });
  EXPECT_GT(live_ticks, 0u) << "the live figures are refreshed while the loop runs";
  EXPECT_EQ(mismatched, 0u) << "one wake-up per tick, all in some bin";
  const LoopLive& end = loop.stats().live;
  ASSERT_EQ(end.ticks, 400u);
  std::array<std::uint64_t, kWakeBins> end_expected{};
  for (std::size_t b = 0; b < kWakeBins; ++b) {
    const bool has_1us = 1 >= kWakeBinLowerUs[b] && (b + 1 == kWakeBins || 1 < kWakeBinLowerUs[b + 1]);
    const bool has_150us = 150 >= kWakeBinLowerUs[b] && (b + 1 == kWakeBins || 150 < kWakeBinLowerUs[b + 1]);
    end_expected[b] = (has_1us ? 300u : 0u) + (has_150us ? 100u : 0u);
  }
  EXPECT_EQ(end.wake_histogram, end_expected);
}

TEST(RtLoop, AnInjectedSlowTickIsAnOverrunAndTripsTheWatchdog) {
  LoopParams p;
  p.duration_ns = 200'000'000;
  p.watchdog.tick_budget_ns = 1'000'000;  // 1 ms budget
  RtLoop loop(p);
  SimClock clock;
  std::uint64_t zero_force_ticks = 0, first_zero_force_tick = 0;
  run_simulated(loop, clock, [&](const TickContext& c) {
    if (c.watchdog.tripped()) {  // what the servo does: zero force
      ++zero_force_ticks;
      if (first_zero_force_tick == 0) first_zero_force_tick = c.tick;
    }
    if (c.tick == 50) clock.compute(3'500'000);  // one tick takes 3.5 periods
  });
  const LoopStats& s = loop.stats();
  // Tick 50 ends 3.5 ms after its deadline: the deadlines at +1, +2 and +3 ms are skipped (no
  // catch-up burst), and tick 51 runs at +4 ms.
  EXPECT_EQ(s.overruns, 3u);
  EXPECT_EQ(s.missed, 4u) << "the late tick and the three deadlines it swallowed";
  EXPECT_EQ(s.ticks, 197u);
  EXPECT_EQ(s.ticks + s.overruns, 200u);
  EXPECT_TRUE(loop.watchdog().tripped());
  EXPECT_EQ(loop.watchdog().reason(), Watchdog::Reason::kTickOverBudget);
  EXPECT_EQ(loop.watchdog().trips(), 1u);
  EXPECT_EQ(s.longest_stall_ns, 4'000'000);
  EXPECT_EQ(s.compute.max_ns(), 3'500'000);
  EXPECT_EQ(first_zero_force_tick, 51u) << "the tick after the slow one sees the fault";
  EXPECT_EQ(zero_force_ticks, 197u - 50u) << "every tick after the trip sees the fault until a re-arm";
}

TEST(RtLoop, ConsecutiveMissesTripTheWatchdog) {
  LoopParams p;
  p.duration_ns = 100'000'000;
  p.watchdog.max_consecutive_misses = 2;
  // One missed deadline is not two in a row.
  {
    RtLoop loop(p);
    SimClock clock;
    run_simulated(loop, clock, [&](const TickContext& c) {
      if (c.tick == 20) clock.compute(1'500'000);
    });
    EXPECT_EQ(loop.stats().missed, 2u) << "the slow tick and the deadline it swallowed";
    EXPECT_FALSE(loop.watchdog().tripped());
  }
  // Two slow ticks in a row: the second trips it, and the next tick sees it tripped.
  RtLoop loop(p);
  SimClock clock;
  std::uint64_t first_tripped_tick = 0;
  run_simulated(loop, clock, [&](const TickContext& c) {
    if (first_tripped_tick == 0 && c.watchdog.tripped()) first_tripped_tick = c.tick;
    if (c.tick == 20 || c.tick == 21) clock.compute(1'500'000);
  });
  EXPECT_TRUE(loop.watchdog().tripped());
  EXPECT_EQ(loop.watchdog().reason(), Watchdog::Reason::kConsecutiveMisses);
  EXPECT_EQ(first_tripped_tick, 22u);
  EXPECT_EQ(loop.stats().ticks + loop.stats().overruns, 100u);
}

TEST(RtLoop, SpinStrategySleepsToHalfAPeriodBeforeTheDeadlineAtMostThenSpinsToIt) {
  LoopParams p;
  p.duration_ns = 300'000'000;
  p.strategy = WakeStrategy::kSleepThenSpin;
  p.spin_margin_ns = 5'000'000;  // asks for more than a period: clamped to half of it
  RtLoop loop(p);
  SimClock clock;
  std::uint64_t wrong_sleep = 0, wrong_spin = 0, early = 0;
  run_simulated(loop, clock, [&](const TickContext& c) {
    if (clock.last_sleep_target != c.deadline_ns - p.period_ns / 2) ++wrong_sleep;
    if (clock.last_spin_target != c.deadline_ns) ++wrong_spin;
    if (c.woke_ns < c.deadline_ns) ++early;
  });
  EXPECT_EQ(loop.stats().ticks, 300u);
  EXPECT_EQ(clock.spins, 300u);
  EXPECT_EQ(wrong_sleep, 0u) << "the thread sleeps half the period and never spins a whole one";
  EXPECT_EQ(wrong_spin, 0u);
  EXPECT_EQ(early, 0u);
  // A margin within half a period is taken as asked; kSleep never spins.
  p.spin_margin_ns = 200'000;
  RtLoop margin_loop(p);
  SimClock margin_clock;
  std::uint64_t wrong_margin = 0;
  run_simulated(margin_loop, margin_clock, [&](const TickContext& c) {
    if (margin_clock.last_sleep_target != c.deadline_ns - 200'000) ++wrong_margin;
  });
  EXPECT_EQ(wrong_margin, 0u);
  p.strategy = WakeStrategy::kSleep;
  RtLoop sleep_loop(p);
  SimClock sleep_clock;
  run_simulated(sleep_loop, sleep_clock, [](const TickContext&) {});
  EXPECT_EQ(sleep_clock.spins, 0u);
  EXPECT_EQ(sleep_clock.sleeps, 300u);
}

// The real clock and scheduler, for each wake strategy: the loop ticks, accounts for every
// deadline, keeps them on the grid and never wakes before one. How many it ticks in time is the
// host's business: only a loop that never ticks fails.
TEST(RtLoop, OnTheRealClockEveryDeadlineIsATickOrAnOverrunAndNoneWakesEarly) {
  for (const WakeStrategy strategy : {WakeStrategy::kSleep, WakeStrategy::kSleepThenSpin}) {
    SCOPED_TRACE(strategy == WakeStrategy::kSleep ? "sleep" : "sleep then spin");
    LoopParams p;
    p.duration_ns = 300'000'000;
    p.strategy = strategy;
    RtLoop loop(p);
    std::int64_t first = 0, last = 0, min_latency = INT64_MAX;
    run_on_rt_thread(loop, [&](const TickContext& c) {
      if (first == 0) first = c.deadline_ns;
      last = c.deadline_ns;
      min_latency = std::min(min_latency, c.woke_ns - c.deadline_ns);
    });
    const LoopStats& s = loop.stats();
    EXPECT_GT(s.ticks, 0u);
    EXPECT_EQ(s.ticks + s.overruns, 300u) << "ticks " << s.ticks << ", overruns " << s.overruns;
    EXPECT_EQ((last - first) % p.period_ns, 0) << "deadlines must stay on the 1 ms grid";
    EXPECT_GE(min_latency, 0) << "neither sleeping nor spinning may wake before the deadline";
    EXPECT_EQ(s.wake_latency.count(), s.ticks);
    EXPECT_EQ(s.live.ticks, s.ticks);
  }
}

TEST(RtLoop, TenThousandServoTicksAllocateNothingAndFaultNoPage) {
  // The real tick (servo + contact + samples, two hands) on a fast loop: 10 000 ticks at 10 kHz.
  LoopParams p;
  p.period_ns = 100'000;
  p.duration_ns = 1'000'000'000;
  p.warmup_ticks = 100;
  p.max_windows = 16;
  auto shared = std::make_unique<SharedState>();
  app::RtModel model;
  model.hands = 2;
  model.period_ns = p.period_ns;
  app::RtServo servo(model, *shared, monotonic_ns());
  auto patch = std::make_unique<TissuePatch>();
  patch->n_triangles = 2;
  patch->triangles[0] = {{{-0.1f, -0.1f, 0}, {0.1f, -0.1f, 0}, {0.1f, 0.1f, 0}}, 1, 0, 0};
  patch->triangles[1] = {{{-0.1f, -0.1f, 0}, {0.1f, 0.1f, 0}, {-0.1f, 0.1f, 0}}, 1, 0, 1};
  patch->t_ns = monotonic_ns();  // a patch must be stamped (and not from the future) to be taken
  shared->patch[0].publish(*patch);
  patch->hand = Hand::kLeft;
  shared->patch[1].publish(*patch);
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
  EXPECT_EQ(loop.stats().ticks + loop.stats().overruns, 10'000u) << "every deadline ticked or counted";
  EXPECT_EQ(allocations, 0u);
  if (!report.memory_locked) {
    std::printf("page faults not checked: mlockall was refused (run as root, as CI does)\n");
  } else if (!test::kAddressSanitizer) {  // ASan's shadow memory faults in lazily
    EXPECT_EQ(loop.stats().minor_faults, 0) << "page faults inside the loop after warm-up";
    EXPECT_EQ(loop.stats().major_faults, 0);
  }
  EXPECT_GT(servo.hand(Hand::kRight).servo.contact_ticks, 0u);
  EXPECT_EQ(servo.hand(Hand::kLeft).patch_version, 1u) << "the left hand stepped against its own patch too";
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

// The servo's CPU is the servo's: a thread that keeps off it (lancet-rt's supervisor, the jitter
// rig's viz stand-ins) loses that CPU, keeps the others, passes the mask on to the threads it
// starts, and does not bind the servo's thread, which is pinned there by start_rt_thread.
TEST(RtSetup, KeepOffCpuLeavesTheServoCpuToTheServo) {
  std::thread([] {
    cpu_set_t before;
    ASSERT_EQ(pthread_getaffinity_np(pthread_self(), sizeof before, &before), 0);
    if (CPU_COUNT(&before) < 2) GTEST_SKIP() << "one CPU allowed: nothing to keep off";
    int servo = -1;
    for (int c = 0; c < CPU_SETSIZE; ++c)
      if (CPU_ISSET(c, &before)) servo = c;
    EXPECT_FALSE(keep_off_cpu(-1));
    ASSERT_TRUE(keep_off_cpu(servo));
    cpu_set_t after;
    ASSERT_EQ(pthread_getaffinity_np(pthread_self(), sizeof after, &after), 0);
    EXPECT_FALSE(CPU_ISSET(servo, &after));
    EXPECT_EQ(CPU_COUNT(&after), CPU_COUNT(&before) - 1) << "every other CPU kept";
    EXPECT_FALSE(keep_off_cpu(servo)) << "already off it";
    std::thread([servo] {
      cpu_set_t inherited;
      ASSERT_EQ(pthread_getaffinity_np(pthread_self(), sizeof inherited, &inherited), 0);
      EXPECT_FALSE(CPU_ISSET(servo, &inherited)) << "a thread started afterwards inherits the mask";
    }).join();
    RtSetupOptions o;
    o.cpu = servo;
    RtSetupReport r;
    int ran_on = -2;
    RtThread t = start_rt_thread(o, r, [&] { ran_on = sched_getcpu(); });
    t.join();
    EXPECT_TRUE(r.affinity);
    EXPECT_EQ(ran_on, servo) << "the servo's thread runs on the servo's CPU all the same";
  }).join();
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
