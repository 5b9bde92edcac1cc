// lancet-bench-patch: how a TissuePatch gets from the viz to the servo. Prints one JSON object on
// stdout (progress on stderr).
//
//   lancet-bench-patch [--quick] [--busy N]
//
// Arrival: lancet-rt's servo (RtServo at 1 kHz on its RtLoop, SCHED_FIFO when permitted) while a
// "viz" thread publishes patches of 1 024 and 16 384 triangles at 30 Hz, 60 Hz and flat out, with
// the patch intake on its helper thread (what lancet-rt does) and, for comparison in the same
// run, in the tick (what it did before). For each case:
//   - latency: from the end of a publish to the first tick that uses it, in ticks (p50, p99, max);
//   - the cost of a tick that starts using a new patch (µs, p50, p99, max) and of the other ticks.
// Goal: latency p99 <= 2 ticks and an arrival tick p99 <= 50 µs at 16 384 triangles.
// --busy N runs N busy loops for the whole benchmark (as a loaded machine would).
//
// Readers: one writer flat out at TissuePatch size, one reader hammering: the share of reads
// turned away (kBusy) by a Seqlock and by the TripleBuffer's claim, in the same run.

#include <pthread.h>
#include <sched.h>
#include <sys/utsname.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "app/rt_servo.hpp"
#include "lancet/shared_model/seqlock.hpp"
#include "lancet/shared_model/triple_buffer.hpp"
#include "patch_sheet.hpp"
#include "rt/rt_loop.hpp"
#include "rt/rt_setup.hpp"

namespace {

using namespace lancet;

struct Percentiles {
  double p50 = 0, p99 = 0, max = 0;
  std::size_t n = 0;
};

Percentiles percentiles(std::vector<double> v) {
  Percentiles p;
  p.n = v.size();
  if (v.empty()) return p;
  std::sort(v.begin(), v.end());
  const auto at = [&](double q) { return v[std::min(v.size() - 1, static_cast<std::size_t>(q * static_cast<double>(v.size())))]; };
  p.p50 = at(0.50), p.p99 = at(0.99), p.max = v.back();
  return p;
}

std::string json(const Percentiles& p) {
  char b[160];
  std::snprintf(b, sizeof b, "{\"n\": %zu, \"p50\": %.3f, \"p99\": %.3f, \"max\": %.3f}", p.n, p.p50, p.p99, p.max);
  return b;
}

std::unique_ptr<TissuePatch> make_patch(int triangles) {
  auto p = std::make_unique<TissuePatch>();
  p->n_triangles = 0;
  const int nx = triangles == 1024 ? 32 : 128, ny = triangles / (2 * nx);
  // Under the scripted stylus (it presses 4 mm below z = 0 around the origin).
  test::add_sheet(*p, nx, ny, -0.05f, -0.05f, 0.1f / static_cast<float>(nx), 0.1f / static_cast<float>(ny),
                  [](float x, float y) { return Vec3f{x, y, 0.001f * std::sin(100.0f * x) * std::cos(80.0f * y)}; });
  return p;
}

struct Case {
  int triangles;
  double hz;  // 0: flat out
  bool thread;
};

struct CaseResult {
  Percentiles latency_ticks, arrival_us, other_us;
  std::uint64_t published = 0, used = 0, ticks = 0;
};

constexpr std::size_t kStamps = 1u << 20;  // publish times by version (a ring; each slot says whose it is)

struct Stamp {
  std::atomic<std::uint64_t> version{0};
  std::atomic<std::int64_t> ns{0};
};

CaseResult run_case(const Case& c, double seconds, bool rt_ok) {
  CaseResult r;
  auto shared = std::make_unique<SharedState>();
  app::RtModel model;
  app::RtServo servo(model, *shared, monotonic_ns());
  const int cpus = static_cast<int>(sysconf(_SC_NPROCESSORS_ONLN));
  rt::RtSetupOptions so;
  so.enable = rt_ok;
  so.cpu = cpus - 1;
  so.hold_dma_latency = false;
  if (c.thread) (void)servo.start_patch_intake(rt_ok, so.priority - 10, so.cpu);

  auto published_ns = std::make_unique<std::array<Stamp, kStamps>>();
  const auto stamp = [&](std::uint64_t version, std::int64_t ns) {
    Stamp& st = (*published_ns)[version % kStamps];
    st.version.store(0, std::memory_order_relaxed);
    st.ns.store(ns, std::memory_order_relaxed);
    st.version.store(version, std::memory_order_release);
  };
  std::atomic<bool> stop{false};
  auto patch = make_patch(c.triangles);
  patch->t_ns = monotonic_ns();
  shared->patch[0].publish_prefix(*patch, tissue_patch_bytes(*patch));
  stamp(1, monotonic_ns());
  std::uint64_t published = 1;
  std::thread viz([&] {
    const std::int64_t gap = c.hz > 0 ? static_cast<std::int64_t>(1e9 / c.hz) : 0;
    std::int64_t next = monotonic_ns();
    while (!stop.load(std::memory_order_relaxed)) {
      if (gap > 0) {
        next += gap;
        const timespec ts{static_cast<time_t>(next / 1'000'000'000), static_cast<long>(next % 1'000'000'000)};
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr);
      }
      patch->t_ns = monotonic_ns();
      ++patch->seq;
      shared->patch[0].publish_prefix(*patch, tissue_patch_bytes(*patch));
      ++published;
      stamp(published, monotonic_ns());
    }
  });

  const std::size_t max_ticks = static_cast<std::size_t>(seconds * 1000) + 100;
  std::vector<double> latency, arrival, other;
  latency.reserve(max_ticks), arrival.reserve(max_ticks), other.reserve(max_ticks);
  rt::LoopParams lp;
  lp.duration_ns = static_cast<std::int64_t>(seconds * 1e9);
  rt::RtLoop loop(lp);
  std::uint64_t last_version = 0;
  rt::RtSetupReport report;
  rt::RtThread t = rt::start_rt_thread(so, report, [&] {
    loop.run(
        [&](const rt::TickContext& ctx) {
          shared->viz_heartbeat.beat(ctx.woke_ns, 0);
          const std::int64_t t0 = monotonic_ns();
          servo.tick(ctx);
          const double us = static_cast<double>(monotonic_ns() - t0) * 1e-3;
          const std::uint64_t v = servo.hand(Hand::kRight).patch_version;
          ToolSample s;
          while (shared->samples.try_pop(s)) {
          }
          if (v != last_version && v != 0) {
            last_version = v;
            const Stamp& st = (*published_ns)[v % kStamps];
            const std::int64_t pub = st.version.load(std::memory_order_acquire) == v ? st.ns.load(std::memory_order_relaxed) : 0;
            if (latency.size() < max_ticks && pub != 0) latency.push_back(static_cast<double>(ctx.woke_ns - pub) / static_cast<double>(lp.period_ns));
            if (arrival.size() < max_ticks) arrival.push_back(us);
          } else if (other.size() < max_ticks) {
            other.push_back(us);
          }
        },
        stop);
  });
  t.join();
  stop.store(true);
  viz.join();
  r.latency_ticks = percentiles(latency);
  r.arrival_us = percentiles(arrival);
  r.other_us = percentiles(other);
  r.published = published;
  r.used = arrival.size();
  r.ticks = loop.stats().ticks;
  return r;
}

struct Stamped {
  std::uint64_t w[sizeof(TissuePatch) / 8];
};

// One writer flat out, one reader hammering for `seconds`: the share of reads that came back kBusy.
template <class Buffer>
double busy_share(double seconds) {
  auto buf = std::make_unique<Buffer>();
  std::atomic<bool> stop{false};
  std::thread writer([&] {
    auto v = std::make_unique<Stamped>();
    std::uint64_t c = 0;
    while (!stop.load(std::memory_order_relaxed)) {
      std::fill(std::begin(v->w), std::end(v->w), ++c);
      if constexpr (requires { buf->publish(*v); }) {
        buf->publish(*v);
      } else {
        buf->write(*v);
      }
    }
  });
  auto out = std::make_unique<Stamped>();
  std::uint64_t ok = 0, busy = 0;
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (std::chrono::steady_clock::now() < end) {
    const ReadStatus s = buf->try_read(*out);
    ok += s == ReadStatus::kOk;
    busy += s == ReadStatus::kBusy;
  }
  stop.store(true);
  writer.join();
  return ok + busy > 0 ? static_cast<double>(busy) / static_cast<double>(ok + busy) : 0.0;
}

}  // namespace

int main(int argc, char** argv) {
  bool quick = false;
  int busy = 0;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--quick") {
      quick = true;
    } else if (a == "--busy" && i + 1 < argc) {
      busy = std::atoi(argv[++i]);
    } else {
      std::fprintf(stderr, "usage: lancet-bench-patch [--quick] [--busy N]\n");
      return 2;
    }
  }
  std::atomic<bool> busy_stop{false};
  std::vector<std::thread> burners;
  for (int i = 0; i < busy; ++i)
    burners.emplace_back([&] {
      while (!busy_stop.load(std::memory_order_relaxed)) {
      }
    });
  const bool rt_ok = geteuid() == 0;
  const double seconds = quick ? 1.5 : 5.0;
  utsname u{};
  uname(&u);
  std::printf("{\n  \"bench\": \"lancet-bench-patch\",\n  \"machine\": \"%s %s, %ld CPUs\",\n  \"busy_loops\": %d,\n  \"sched_fifo\": %s,\n",
              u.nodename, u.release, sysconf(_SC_NPROCESSORS_ONLN), busy, rt_ok ? "true" : "false");
  std::printf("  \"arrival\": [\n");
  bool first = true;
  for (const int tri : {1024, 16384}) {
    for (const double hz : {30.0, 60.0, 0.0}) {
      for (const bool thread : {true, false}) {
        std::fprintf(stderr, "lancet-bench-patch: %d triangles, %s, intake %s\n", tri, hz > 0 ? (std::to_string(static_cast<int>(hz)) + " Hz").c_str() : "flat out",
                     thread ? "thread" : "in the tick");
        const CaseResult r = run_case({tri, hz, thread}, seconds, rt_ok);
        std::printf("%s    {\"triangles\": %d, \"publish_hz\": %s, \"intake\": \"%s\", \"published\": %llu, \"used\": %llu, \"ticks\": %llu,\n"
                    "     \"latency_ticks\": %s,\n     \"arrival_tick_us\": %s,\n     \"other_tick_us\": %s}",
                    first ? "" : ",\n", tri, hz > 0 ? std::to_string(static_cast<int>(hz)).c_str() : "\"flat out\"",
                    thread ? "thread" : "tick", static_cast<unsigned long long>(r.published), static_cast<unsigned long long>(r.used),
                    static_cast<unsigned long long>(r.ticks), json(r.latency_ticks).c_str(), json(r.arrival_us).c_str(),
                    json(r.other_us).c_str());
        std::fflush(stdout);
        first = false;
      }
    }
  }
  std::printf("\n  ],\n");
  std::fprintf(stderr, "lancet-bench-patch: readers against a writer flat out\n");
  const double seq = busy_share<Seqlock<Stamped>>(quick ? 0.5 : 2.0);
  const double tri = busy_share<TripleBuffer<Stamped>>(quick ? 0.5 : 2.0);
  std::printf("  \"reader_turned_away\": {\"seqlock\": %.4f, \"triple_buffer\": %.4f}\n}\n", seq, tri);
  busy_stop.store(true);
  for (auto& b : burners) b.join();
  return 0;
}
