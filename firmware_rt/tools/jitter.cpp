#include "tools/jitter.hpp"

#include <unistd.h>

#include <filesystem>
#include <thread>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <memory>
#include <sstream>

#include "app/rt_servo.hpp"
#include "rt/rt_loop.hpp"
#include "tools/cyclictest_runner.hpp"
#include "recording/hdf5_io.hpp"
#include "text/text.hpp"

namespace lancet::tools {
namespace {

// A 1024-triangle tessellated plane at z = 0 (32 × 16 cells over 4 cm × 4 cm): the largest patch
// the servo handles, so every tick pays the full contact search.
void fill_workload_patch(TissuePatch& p) {
  constexpr int nx = 32, ny = 16;
  constexpr float w = 0.04f, h = 0.04f;
  std::uint32_t n = 0;
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      const float x0 = -w / 2 + w * static_cast<float>(i) / nx, x1 = -w / 2 + w * static_cast<float>(i + 1) / nx;
      const float y0 = -h / 2 + h * static_cast<float>(j) / ny, y1 = -h / 2 + h * static_cast<float>(j + 1) / ny;
      p.triangles[n] = {{{x0, y0, 0}, {x1, y0, 0}, {x1, y1, 0}}, 1, 0, n};
      ++n;
      p.triangles[n] = {{{x0, y0, 0}, {x1, y1, 0}, {x0, y1, 0}}, 1, 0, n};
      ++n;
    }
  }
  p.n_triangles = n;
}

// Adds b's samples to a (both histograms with whole-microsecond bucket edges).
void merge_into(rt::Distribution& a, const rt::Distribution& b) {
  std::vector<std::pair<double, std::uint64_t>> merged;
  auto i = a.buckets.cbegin();
  auto j = b.buckets.cbegin();
  while (i != a.buckets.cend() || j != b.buckets.cend()) {
    if (j == b.buckets.cend() || (i != a.buckets.cend() && i->first < j->first)) {
      merged.push_back(*i++);
    } else if (i == a.buckets.cend() || j->first < i->first) {
      merged.push_back(*j++);
    } else {
      merged.emplace_back(i->first, i->second + j->second);
      ++i, ++j;
    }
  }
  const double total = static_cast<double>(a.count + b.count);
  if (total > 0) {
    a.avg_us = (a.avg_us * static_cast<double>(a.count) + b.avg_us * static_cast<double>(b.count)) / total;
  }
  a.min_us = a.count ? std::min(a.min_us, b.min_us) : b.min_us;
  a.max_us = std::max(a.max_us, b.max_us);
  a.count += b.count;
  a.overflows += b.overflows;
  a.overflow_above_us = b.overflow_above_us;
  a.buckets = std::move(merged);
}


std::string percentile_name(double p) {
  std::ostringstream s;
  s << "p" << p;
  return s.str();
}

void json_distribution(std::ostringstream& o, const rt::Distribution& d) {
  o << "{\"count\": " << d.count << ", \"min_us\": " << text::json_number(d.min_us, 1) << ", \"avg_us\": " << text::json_number(d.avg_us, 1)
    << ", \"max_us\": " << text::json_number(d.max_us, 1);
  for (double p : rt::kReportPercentiles) o << ", \"" << percentile_name(p) << "_us\": " << text::json_number(d.percentile_us(p), 1);
  o << ", \"overflows\": " << d.overflows << "}";
}

// A round's loop figures, added to the whole run's.
void add_round(JitterResult& r, const rt::RtLoop& loop) {
  const rt::LoopStats& s = loop.stats();
  r.wake.merge(s.wake_latency);
  r.compute.merge(s.compute);
  r.period_error.merge(s.period_error);
  r.ticks += s.ticks;
  r.overruns += s.overruns;
  r.missed += s.missed;
  r.watchdog_trips += loop.watchdog().trips();
  r.longest_stall_ns = std::max(r.longest_stall_ns, s.longest_stall_ns);
  r.minor_faults += s.minor_faults;
  r.major_faults += s.major_faults;
  r.window_max_us.insert(r.window_max_us.end(), s.window_max_us.begin(), s.window_max_us.end());
}

// An "on" round's recording, finished: its counts and size into the result; removed when it was
// only made to be measured.
void finish_recording(JitterResult& r, std::unique_ptr<record::Recorder> recorder, const std::string& path, bool remove) {
  r.recorded_samples += recorder->samples();
  r.recorded_lost += recorder->samples_lost();
  if (const auto done = recorder->finish(); !done.ok() && r.record_error.empty()) r.record_error = done.error().message;
  std::error_code ec;
  r.record_bytes += std::filesystem::file_size(path, ec);
  recorder.reset();
  if (remove) std::filesystem::remove(path, ec);
}

// The bounds asked for (--max-p99-us, --max-us, --max-missed), each with its verdict.
void add_bounds(JitterResult& r, const JitterOptions& o) {
  const double p99 = static_cast<double>(r.wake.percentile_ns(99)) / 1e3;
  const double mx = static_cast<double>(r.wake.max_ns()) / 1e3;
  if (o.max_p99_us) r.bounds.push_back({"wake-up p99 (us)", *o.max_p99_us, p99, p99 <= *o.max_p99_us});
  if (o.max_us) r.bounds.push_back({"wake-up max (us)", *o.max_us, mx, mx <= *o.max_us});
  if (o.max_missed) {
    r.bounds.push_back({"missed deadlines", static_cast<double>(*o.max_missed), static_cast<double>(r.missed),
                        r.missed <= *o.max_missed});
  }
}

}  // namespace

bool JitterResult::pass() const {
  return std::all_of(bounds.begin(), bounds.end(), [](const Bound& b) { return b.pass; });
}

JitterResult run_jitter(const JitterOptions& o) {
  JitterResult r;
  const rt::RtSetupOptions setup_opts = o.rt.setup();
  r.cpu = setup_opts.cpu;
  rt::RtEnvironment environment(setup_opts, r.setup);

  // The workload: the servo with two simulated hands as lancet-rt runs by default, each with its
  // own patch (the right hand pressing into it), viz "alive".
  auto shared = std::make_unique<SharedState>();
  auto patch = std::make_unique<TissuePatch>();
  fill_workload_patch(*patch);
  const auto publish_patches = [&shared, &patch] {
    for (std::size_t h = 0; h < kHandCount; ++h) {
      patch->hand = static_cast<Hand>(h);
      shared->patch[h].publish_prefix(*patch, tissue_patch_bytes(*patch));
    }
  };
  publish_patches();
  app::RtModel model;
  model.hands = kHandCount;
  model.period_ns = o.rt.loop().period_ns;
  app::RtServo servo(model, *shared, monotonic_ns());
  // As in lancet-rt: patches arrive through the intake's helper thread, off the servo's CPU.
  (void)servo.start_patch_intake(setup_opts.enable, std::max(1, setup_opts.priority - 10), setup_opts.cpu);

  const int rounds = o.compare_recording ? std::max(2, o.rounds + o.rounds % 2) : std::max(1, o.rounds);
  const std::string record_path =
      o.record_path.empty() ? (std::filesystem::temp_directory_path() / ("lancet-jitter-" + std::to_string(getpid()) + ".h5")).string()
                            : o.record_path;
  if (o.compare_recording) r.recording_off.emplace(), r.recording_on.emplace();
  // cyclictest runs whole seconds (-D): when comparing, both sides run rounds of that length.
  const double round_s = o.compare_cyclictest ? std::max(1.0, std::ceil(o.duration_s / rounds)) : o.duration_s / rounds;
  rt::Distribution cyc;
  cyc.name = "cyclictest";
  bool cyc_ok = o.compare_cyclictest;
  for (int round = 0; round < rounds; ++round) {
    rt::LoopParams lp = o.rt.loop();
    lp.duration_ns = seconds_to_ns(round_s);
    lp.max_windows = static_cast<std::size_t>(round_s / 0.1) + 2;
    rt::RtLoop loop(lp);
    std::atomic<bool> stop{false};
    ToolSample drained{};
    // The recording comparison: a consumer thread drains the ring as the viz would (every 16 ms),
    // and in odd rounds records what it drains.
    const bool recording = o.compare_recording && round % 2 == 1;
    std::unique_ptr<record::Recorder> recorder;
    if (recording) {
      record::Recording meta;
      meta.lancet_version = "lancetctl jitter";
      meta.layout_hash = kSharedLayoutHash;
      meta.protocol = kProtocolVersion;
      meta.period_ns = o.rt.loop().period_ns;
      meta.hands = static_cast<std::uint32_t>(model.hands);
      auto made = record::Recorder::create(record_path, meta);
      if (made.ok()) {
        recorder = std::move(made).value();
      } else if (r.record_error.empty()) {
        r.record_error = made.error().message;
      }
    }
    std::atomic<bool> consumer_stop{false};
    // The viz's patches: a fresh one about every 16 ms (60 Hz), from a thread of its own as the
    // viz publishes from its process.
    std::thread publisher;
    if (o.servo_workload) {
      publisher = std::thread([&] {
        if (setup_opts.enable) (void)rt::keep_off_cpu(setup_opts.cpu);  // as the viz: never on the servo's CPU
        while (!consumer_stop.load(std::memory_order_relaxed)) {
          std::this_thread::sleep_for(std::chrono::milliseconds(16));
          patch->t_ns = monotonic_ns();
          ++patch->seq;
          publish_patches();
        }
      });
    }
    std::thread consumer;
    if (o.compare_recording) {
      consumer = std::thread([&] {
        if (setup_opts.enable) (void)rt::keep_off_cpu(setup_opts.cpu);
        std::vector<ToolSample> batch(4096);
        while (!consumer_stop.load(std::memory_order_relaxed)) {
          std::this_thread::sleep_for(std::chrono::milliseconds(16));
          std::size_t n = 0;
          while ((n = shared->samples.try_pop_n(batch.data(), batch.size())) > 0) {
            if (recorder) recorder->add_samples(std::span<const ToolSample>(batch.data(), n));
          }
        }
      });
    }
    rt::RtSetupReport later_rounds;  // the first round's report is the one shown
    rt::RtThread t = rt::start_rt_thread(setup_opts, round == 0 ? r.setup : later_rounds, [&] {
      servo.set_fifo(rt::current_thread_is_fifo());
      loop.run(
          [&](const rt::TickContext& c) {
            if (!o.servo_workload) return;
            shared->viz_heartbeat.beat(c.woke_ns, 0);
            servo.tick(c);
            if (!o.compare_recording) {
              while (shared->samples.try_pop(drained)) {
              }
            }
          },
          stop);
    });
    t.join();
    consumer_stop.store(true);
    if (consumer.joinable()) consumer.join();
    if (publisher.joinable()) publisher.join();
    if (o.compare_recording) {
      // What the round pushed and the consumer had not drained yet: the round's own ticks, recorded
      // (an "on" round) or dropped, never left for the next round.
      std::vector<ToolSample> rest(4096);
      std::size_t n = 0;
      while ((n = shared->samples.try_pop_n(rest.data(), rest.size())) > 0) {
        if (recorder) recorder->add_samples(std::span<const ToolSample>(rest.data(), n));
      }
    }
    if (recorder) finish_recording(r, std::move(recorder), record_path, o.record_path.empty());
    if (o.compare_recording) (recording ? *r.recording_on : *r.recording_off).merge(loop.stats().wake_latency);
    add_round(r, loop);

    if (cyc_ok) {
      CyclictestOptions co;
      co.interval_us = static_cast<int>(std::lround(o.rt.period_us));
      co.priority = o.rt.priority;
      co.cpu = setup_opts.cpu;
      co.duration_s = round_s;
      co.executable = o.cyclictest;
      auto d = run_cyclictest(co);
      if (d) {
        merge_into(cyc, d.value());
      } else {
        r.cyclictest_error = d.error().message;
        cyc_ok = false;
      }
    }
  }
  if (cyc_ok) r.cyclictest = std::move(cyc);

  add_bounds(r, o);
  return r;
}

std::string format_jitter_text(const JitterOptions& o, const JitterResult& r) {
  std::ostringstream s;
  const rt::Distribution ours = rt::to_distribution(r.wake, "lancet");
  s << "# lancetctl jitter: " << o.duration_s << " s in " << std::max(1, o.rounds) << " round(s), interval "
    << o.rt.period_us << " us, strategy " << o.rt.strategy
    << (o.rt.strategy == "spin" ? " (margin " + text::format("%.1f", o.rt.spin_margin_us) + " us)" : std::string()) << ", priority "
    << o.rt.priority << (r.setup.fifo ? " SCHED_FIFO" : " (not SCHED_FIFO)") << ", cpu " << r.cpu << ", workload "
    << (o.servo_workload ? "servo (1024-triangle patch)" : "none") << "\n";
  s << "# kernel " << r.setup.kernel << (r.setup.preempt_rt ? " (PREEMPT_RT)" : " (not PREEMPT_RT)") << "\n";
  for (const auto& l : r.setup.applied) s << "# ok: " << l << "\n";
  for (const auto& l : r.setup.degraded) s << "# degraded: " << l << "\n";
  // cyclictest's own summary line, for people who read those (Act: the worst of the last 100 ms).
  char line[256];
  std::snprintf(line, sizeof line, "T: 0 (%7d) P:%2d I:%.0f C:%8llu Min:%7.0f Act:%5.0f Avg:%5.0f Max:%8.0f  lancet\n",
                static_cast<int>(getpid()), o.rt.priority, o.rt.period_us, static_cast<unsigned long long>(ours.count),
                ours.min_us, r.window_max_us.empty() ? ours.max_us : r.window_max_us.back(), ours.avg_us, ours.max_us);
  s << line;
  const rt::Distribution* c = r.cyclictest ? &*r.cyclictest : nullptr;
  if (c != nullptr) {
    std::snprintf(line, sizeof line, "T: 0 (cyclict) P:%2d I:%.0f C:%8llu Min:%7.0f Act:%5s Avg:%5.0f Max:%8.0f  cyclictest\n",
                  o.rt.priority, o.rt.period_us, static_cast<unsigned long long>(c->count), c->min_us, "-", c->avg_us,
                  c->max_us);
    s << line;
  }
  s << "\nwake-up latency (us)        lancet" << (c ? "   cyclictest   lancet/cyclictest" : "") << "\n";
  const auto row = [&](const std::string& name, double a, double b) {
    std::snprintf(line, sizeof line, "  %-10s %19.1f", name.c_str(), a);
    s << line;
    if (c != nullptr) {
      std::snprintf(line, sizeof line, " %12.1f %19.2f", b, b > 0 ? a / b : 0.0);
      s << line;
    }
    s << "\n";
  };
  row("min", ours.min_us, c ? c->min_us : 0);
  row("avg", ours.avg_us, c ? c->avg_us : 0);
  for (double p : rt::kReportPercentiles) row(percentile_name(p), ours.percentile_us(p), c ? c->percentile_us(p) : 0);
  row("max", ours.max_us, c ? c->max_us : 0);
  if (!r.cyclictest_error.empty()) s << "cyclictest: " << r.cyclictest_error << "\n";
  if (r.recording_off && r.recording_on) {
    const rt::Distribution off = rt::to_distribution(*r.recording_off, "off"), on = rt::to_distribution(*r.recording_on, "on");
    s << "\nwake-up latency (us)  recording off   recording on   on/off\n";
    const auto rrow = [&](const std::string& name, double a, double b) {
      std::snprintf(line, sizeof line, "  %-10s %15.1f %14.1f %8.2f\n", name.c_str(), a, b, a > 0 ? b / a : 0.0);
      s << line;
    };
    rrow("avg", off.avg_us, on.avg_us);
    for (double p : rt::kReportPercentiles) rrow(percentile_name(p), off.percentile_us(p), on.percentile_us(p));
    rrow("max", off.max_us, on.max_us);
    std::snprintf(line, sizeof line, "  recorded %llu samples (%llu lost) into %.1f MB of HDF5%s%s\n",
                  static_cast<unsigned long long>(r.recorded_samples), static_cast<unsigned long long>(r.recorded_lost),
                  static_cast<double>(r.record_bytes) / 1e6, r.record_error.empty() ? "" : "; ", r.record_error.c_str());
    s << line;
  }
  std::snprintf(line, sizeof line,
                "\nlancet loop: %llu ticks, %llu missed deadlines (%llu skipped), longest stall %.1f us,\n"
                "  compute p50 %.1f us p99 %.1f us max %.1f us, period error p99 %.1f us,\n"
                "  page faults after warm-up %ld, watchdog trips %llu\n",
                static_cast<unsigned long long>(r.ticks), static_cast<unsigned long long>(r.missed),
                static_cast<unsigned long long>(r.overruns), static_cast<double>(r.longest_stall_ns) / 1e3,
                static_cast<double>(r.compute.percentile_ns(50)) / 1e3, static_cast<double>(r.compute.percentile_ns(99)) / 1e3,
                static_cast<double>(r.compute.max_ns()) / 1e3, static_cast<double>(r.period_error.percentile_ns(99)) / 1e3,
                r.minor_faults + r.major_faults, static_cast<unsigned long long>(r.watchdog_trips));
  s << line;
  for (const auto& b : r.bounds) {
    std::snprintf(line, sizeof line, "bound: %-20s <= %10.1f : %10.1f  %s\n", b.what.c_str(), b.limit, b.value,
                  b.pass ? "PASS" : "FAIL");
    s << line;
  }
  if (!r.bounds.empty()) s << "result: " << (r.pass() ? "PASS" : "FAIL") << "\n";
  return s.str();
}

std::string format_jitter_json(const JitterOptions& o, const JitterResult& r) {
  std::ostringstream s;
  const rt::Distribution ours = rt::to_distribution(r.wake, "lancet");
  const auto boolean = [](bool b) { return b ? "true" : "false"; };
  s << "{\n  \"config\": {\"duration_s\": " << o.duration_s << ", \"rounds\": " << std::max(1, o.rounds)
    << ", \"interval_us\": " << o.rt.period_us << ", \"strategy\": \"" << o.rt.strategy
    << "\", \"workload\": \"" << (o.servo_workload ? "servo" : "none") << "\", \"spin_margin_us\": " << o.rt.spin_margin_us << ", \"priority\": " << o.rt.priority << ", \"cpu\": " << r.cpu
    << "},\n";
  s << "  \"setup\": {\"fifo\": " << boolean(r.setup.fifo) << ", \"memory_locked\": " << boolean(r.setup.memory_locked)
    << ", \"dma_latency_held\": " << boolean(r.setup.dma_latency_held) << ", \"preempt_rt\": " << boolean(r.setup.preempt_rt)
    << ", \"cpu_isolated\": " << boolean(r.setup.cpu_isolated) << ", \"kernel\": " << text::json_string(r.setup.kernel)
    << ", \"degraded\": [";
  for (std::size_t i = 0; i < r.setup.degraded.size(); ++i) {
    s << (i ? ", " : "") << text::json_string(r.setup.degraded[i]);
  }
  s << "]},\n  \"lancet\": {\"wake_latency\": ";
  json_distribution(s, ours);
  s << ",\n    \"compute\": ";
  json_distribution(s, rt::to_distribution(r.compute, "compute"));
  s << ",\n    \"period_error\": ";
  json_distribution(s, rt::to_distribution(r.period_error, "period_error"));
  s << ",\n    \"ticks\": " << r.ticks << ", \"missed\": " << r.missed << ", \"overruns\": " << r.overruns
    << ", \"longest_stall_us\": " << text::json_number(static_cast<double>(r.longest_stall_ns) / 1e3, 1)
    << ", \"page_faults\": " << (r.minor_faults + r.major_faults) << ", \"watchdog_trips\": " << r.watchdog_trips << "},\n";
  s << "  \"cyclictest\": ";
  if (r.cyclictest) {
    json_distribution(s, *r.cyclictest);
    s << ",\n  \"ratio\": {";
    bool first = true;
    for (double p : rt::kReportPercentiles) {
      const double b = r.cyclictest->percentile_us(p);
      s << (first ? "" : ", ") << "\"" << percentile_name(p) << "\": " << (b > 0 ? ours.percentile_us(p) / b : 0.0);
      first = false;
    }
    s << "}";
  } else {
    s << "null";
    if (!r.cyclictest_error.empty()) s << ",\n  \"cyclictest_error\": " << text::json_string(r.cyclictest_error);
  }
  if (r.recording_off && r.recording_on) {
    s << ",\n  \"recording\": {\"off\": ";
    json_distribution(s, rt::to_distribution(*r.recording_off, "off"));
    s << ", \"on\": ";
    json_distribution(s, rt::to_distribution(*r.recording_on, "on"));
    s << ", \"samples\": " << r.recorded_samples << ", \"lost\": " << r.recorded_lost << ", \"bytes\": " << r.record_bytes
      << ", \"error\": " << text::json_string(r.record_error) << "}";
  }
  s << ",\n  \"bounds\": [";
  for (std::size_t i = 0; i < r.bounds.size(); ++i) {
    const auto& b = r.bounds[i];
    s << (i ? ", " : "") << "{\"what\": \"" << b.what << "\", \"limit\": " << b.limit << ", \"value\": " << b.value
      << ", \"pass\": " << boolean(b.pass) << "}";
  }
  s << "],\n  \"pass\": " << boolean(r.pass()) << "\n}\n";
  return s.str();
}

}  // namespace lancet::tools
