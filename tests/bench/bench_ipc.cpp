// lancet-bench-ipc: what the shared_model transport costs, measured against a yardstick in the
// same run. Prints one JSON object on stdout (progress on stderr).
//
//   lancet-bench-ipc [--quick]
//
// Ring: lancet::SpscRing against BareRing, a minimal SPSC ring written below (two atomic
// indices side by side, no cache-line padding, no cached indices, a memcpy per slot). Same
// capacity (the real sample ring's), same messages (a 64-byte struct and the real ToolSample), both placed in a
// MAP_SHARED | MAP_ANONYMOUS mapping shared by fork()ed processes, as the real segment is. A
// third ring, the bare one with its slots cache-line aligned, shows how much of the difference
// is slot alignment alone.
//   - throughput: a child pushes N messages, the parent pops and checks them; messages/s;
//     median over repetitions that rotate the order of the rings so drift hits all alike;
//     ours is also run with try_pop_n batches of 256;
//   - round trip: the parent pushes on one ring, the child echoes on a second, the parent
//     times each round trip (p50 / p90 / p99 / p99.9 ns), again rotating per repetition;
//   - cost ratios ours / bare (time per message, time per round trip); the target is <= 1.2.
// Seqlock: write and read cost (ns/op) for a 512-byte payload and for TissuePatch (about 48 KB),
// single thread, and a reader's cost while another thread writes (flat out, and at 1 kHz).
//
// Both sides spin with a pause instruction and yield after a while, so that a run on a loaded
// 2-core machine still finishes; absolute numbers on such a machine drift several-fold between
// runs, which is why every figure that matters is a ratio measured in the same run.

#include <sched.h>
#include <sys/mman.h>
#include <sys/utsname.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <fstream>
#include <memory>
#include <new>
#include <string>
#include <thread>
#include <type_traits>
#include <vector>

#include "lancet/shared_model/messages.hpp"
#include "lancet/shared_model/seqlock.hpp"
#include "lancet/shared_model/shared_state.hpp"
#include "lancet/shared_model/spsc_ring.hpp"

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#endif

namespace {

using Clock = std::chrono::steady_clock;
constexpr std::size_t kCapacity = lancet::kSampleRingCapacity;  // the real sample ring

// ---------------------------------------------------------------------------------------------
// The yardstick: the smallest correct SPSC ring. Head and tail share a cache line (and the
// first slots), every push reads the consumer's index and every pop the producer's.
// AlignSlots = true is a second yardstick, not in the brief of the bare ring: the same ring with
// its slot array starting on a fresh cache line, so that a 64-byte message is not split over two
// lines. It separates what ours gains from aligned slots from what it gains from padding the
// indices apart and caching them.

template <class T, std::size_t N, bool AlignSlots = false>
struct BareRing {
  static_assert(std::is_trivially_copyable_v<T> && (N & (N - 1)) == 0);
  std::atomic<std::uint64_t> head{0};
  std::atomic<std::uint64_t> tail{0};
  alignas(AlignSlots ? 64 : alignof(T)) T slots[N]{};

  bool try_push(const T& v) noexcept {
    const std::uint64_t h = head.load(std::memory_order_relaxed);
    if (h - tail.load(std::memory_order_acquire) >= N) return false;
    std::memcpy(static_cast<void*>(&slots[h & (N - 1)]), &v, sizeof(T));
    head.store(h + 1, std::memory_order_release);
    return true;
  }
  bool try_pop(T& out) noexcept {
    const std::uint64_t t = tail.load(std::memory_order_relaxed);
    if (head.load(std::memory_order_acquire) == t) return false;
    std::memcpy(static_cast<void*>(&out), &slots[t & (N - 1)], sizeof(T));
    tail.store(t + 1, std::memory_order_release);
    return true;
  }
};

/// A 64-byte message: a sequence number and filler.
struct Msg64 {
  std::uint64_t seq;
  std::uint64_t fill[7];
};
static_assert(sizeof(Msg64) == 64);

void cpu_relax() noexcept {
#if defined(__x86_64__) || defined(__i386__)
  _mm_pause();
#endif
}

/// Spins on a condition with a pause; yields the CPU after a while so that a process whose
/// peer shares its core lets the peer run.
class Backoff {
 public:
  void wait() noexcept {
    if (++spins_ < 4096) {
      cpu_relax();
    } else {
      spins_ = 0;
      sched_yield();
    }
  }
  void reset() noexcept { spins_ = 0; }

 private:
  unsigned spins_ = 0;
};

template <class T>
void set_seq(T& m, std::uint64_t seq) noexcept {
  m.seq = seq;
}

// ---------------------------------------------------------------------------------------------
// Shared anonymous mapping and child processes.

/// A zeroed MAP_SHARED | MAP_ANONYMOUS region that fork()ed children share. Pages are touched
/// up front so neither side takes first-touch faults during a measurement.
class SharedRegion {
 public:
  explicit SharedRegion(std::size_t bytes) : bytes_(bytes) {
    void* p = mmap(nullptr, bytes, PROT_READ | PROT_WRITE, MAP_SHARED | MAP_ANONYMOUS, -1, 0);
    if (p == MAP_FAILED) {
      std::perror("mmap");
      std::exit(1);
    }
    base_ = static_cast<unsigned char*>(p);
    std::memset(base_, 0, bytes_);
  }
  ~SharedRegion() { munmap(base_, bytes_); }
  SharedRegion(const SharedRegion&) = delete;
  SharedRegion& operator=(const SharedRegion&) = delete;
  [[nodiscard]] unsigned char* at(std::size_t offset) const noexcept { return base_ + offset; }

 private:
  unsigned char* base_ = nullptr;
  std::size_t bytes_ = 0;
};

constexpr std::size_t round_up(std::size_t n, std::size_t a) { return (n + a - 1) / a * a; }

template <class Fn>
pid_t spawn(Fn fn) {
  std::fflush(nullptr);
  const pid_t pid = fork();
  if (pid < 0) {
    std::perror("fork");
    std::exit(1);
  }
  if (pid == 0) _exit(fn());
  return pid;
}

void reap(pid_t pid, const char* what) {
  int status = 0;
  while (waitpid(pid, &status, 0) < 0) {
  }
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    std::fprintf(stderr, "lancet-bench-ipc: %s child failed (status %d)\n", what, status);
    std::exit(1);
  }
}

/// Control words beside the rings.
struct Control {
  alignas(64) std::atomic<std::uint32_t> go{0};
};

// ---------------------------------------------------------------------------------------------
// Ring throughput: child produces, parent consumes and checks the sequence.

template <class Ring, class T>
double ring_throughput_once(SharedRegion& region, std::uint64_t n, bool batch) {
  constexpr std::size_t kWarm = 4 * kCapacity;
  auto* ctl = new (region.at(0)) Control{};
  auto* ring = new (region.at(round_up(sizeof(Control), 4096))) Ring{};

  const pid_t child = spawn([&] {
    T m{};
    Backoff b;
    // Warm-up: run the whole ring through a few times (caches, TLB, page tables of the child).
    for (std::uint64_t i = 0; i < kWarm; ++i) {
      set_seq(m, i);
      while (!ring->try_push(m)) b.wait();
      b.reset();
    }
    while (ctl->go.load(std::memory_order_acquire) == 0) b.wait();
    for (std::uint64_t i = 0; i < n; ++i) {
      set_seq(m, i);
      while (!ring->try_push(m)) b.wait();
      b.reset();
    }
    return 0;
  });

  T m{};
  Backoff b;
  for (std::uint64_t i = 0; i < kWarm; ++i) {
    while (!ring->try_pop(m)) b.wait();
    b.reset();
  }
  std::uint64_t bad = 0;
  ctl->go.store(1, std::memory_order_release);
  const auto t0 = Clock::now();
  if (!batch) {
    for (std::uint64_t i = 0; i < n; ++i) {
      while (!ring->try_pop(m)) b.wait();
      b.reset();
      bad += m.seq != i ? 1 : 0;
    }
  } else {
    // Batch pops: only lancet::SpscRing has them.
    if constexpr (requires(Ring& r, T* p) { r.try_pop_n(p, std::size_t{}); }) {
      static T buf[256];
      for (std::uint64_t i = 0; i < n;) {
        const std::size_t got = ring->try_pop_n(buf, 256);
        if (got == 0) {
          b.wait();
          continue;
        }
        b.reset();
        for (std::size_t k = 0; k < got; ++k, ++i) bad += buf[k].seq != i ? 1 : 0;
      }
    } else {
      std::fprintf(stderr, "lancet-bench-ipc: this ring has no batch pop\n");
      std::exit(1);
    }
  }
  const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  reap(child, "throughput producer");
  if (bad != 0) {
    std::fprintf(stderr, "lancet-bench-ipc: %llu messages out of sequence\n", static_cast<unsigned long long>(bad));
    std::exit(1);
  }
  return static_cast<double>(n) / seconds;
}

// ---------------------------------------------------------------------------------------------
// Ring round trip: parent pings on one ring, child echoes on another.

template <class Ring, class T>
void ring_rtt_once(SharedRegion& region, std::size_t rounds, std::vector<double>& out_ns) {
  constexpr std::uint64_t kStop = ~std::uint64_t{0};
  constexpr std::size_t kWarm = 2000;
  const std::size_t ring_bytes = round_up(sizeof(Ring), 4096);
  auto* ping = new (region.at(0)) Ring{};
  auto* pong = new (region.at(ring_bytes)) Ring{};

  const pid_t child = spawn([&] {
    T m{};
    Backoff b;
    for (;;) {
      while (!ping->try_pop(m)) b.wait();
      b.reset();
      if (m.seq == kStop) return 0;
      while (!pong->try_push(m)) b.wait();
      b.reset();
    }
  });

  T m{};
  T back{};
  Backoff b;
  out_ns.reserve(out_ns.size() + rounds);
  for (std::size_t i = 0; i < kWarm + rounds; ++i) {
    set_seq(m, i);
    const auto t0 = Clock::now();
    while (!ping->try_push(m)) b.wait();
    b.reset();
    while (!pong->try_pop(back)) b.wait();
    b.reset();
    const auto t1 = Clock::now();
    if (back.seq != i) {
      std::fprintf(stderr, "lancet-bench-ipc: round trip %zu echoed %llu\n", i,
                   static_cast<unsigned long long>(back.seq));
      std::exit(1);
    }
    if (i >= kWarm) out_ns.push_back(std::chrono::duration<double, std::nano>(t1 - t0).count());
  }
  set_seq(m, kStop);
  while (!ping->try_push(m)) b.wait();
  reap(child, "echo");
}

// ---------------------------------------------------------------------------------------------
// Statistics and JSON.

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/// Percentile q in [0, 1] of sorted v (nearest rank).
double percentile_sorted(const std::vector<double>& v, double q) {
  if (v.empty()) return 0.0;
  const auto idx = static_cast<std::size_t>(q * static_cast<double>(v.size() - 1) + 0.5);
  return v[std::min(idx, v.size() - 1)];
}

std::string json_list(const std::vector<double>& v, const char* fmt) {
  std::string s = "[";
  char buf[64];
  for (std::size_t i = 0; i < v.size(); ++i) {
    std::snprintf(buf, sizeof buf, fmt, v[i]);
    s += (i ? ", " : "") + std::string(buf);
  }
  return s + "]";
}

std::string json_escape(const std::string& in) {
  std::string s;
  for (char c : in) {
    if (c == '"' || c == '\\') s += '\\';
    if (static_cast<unsigned char>(c) >= 0x20) s += c;
  }
  return s;
}

std::string cpu_model() {
  std::ifstream in("/proc/cpuinfo");
  std::string line;
  std::string model = "unknown";
  std::string family;
  std::string number;
  while (std::getline(in, line)) {
    auto value = [&] {
      const auto colon = line.find(':');
      return colon == std::string::npos ? std::string() : line.substr(std::min(colon + 2, line.size()));
    };
    if (line.rfind("model name", 0) == 0 && model == "unknown") model = value();
    if (line.rfind("cpu family", 0) == 0 && family.empty()) family = value();
    if (line.rfind("model\t", 0) == 0 && number.empty()) number = value();
  }
  if (!family.empty()) model += " (family " + family + ", model " + number + ")";
  return model;
}

std::string compiler() {
#if defined(__clang__)
  return "clang " __clang_version__;
#elif defined(__GNUC__)
  return "gcc " __VERSION__;
#else
  return "unknown";
#endif
}

std::string utc_now() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

// ---------------------------------------------------------------------------------------------
// Ring benchmark for one message type.

struct RingPlan {
  std::uint64_t messages;  // per throughput repetition
  int throughput_reps;
  std::size_t round_trips;  // per implementation, split over rtt_reps
  int rtt_reps;
};

/// Runs the three rings in a rotating order per repetition, so that drift over the run (another
/// process, host noise, frequency) falls on all of them alike.
template <class Fn>
void rotate3(int rep, Fn fn) {
  for (int k = 0; k < 3; ++k) fn((rep + k) % 3);
}

std::string percentiles_json(const std::vector<double>& sorted) {
  char buf[256];
  std::snprintf(buf, sizeof buf, "{\"p50\": %.0f, \"p90\": %.0f, \"p99\": %.0f, \"p999\": %.0f, \"max\": %.0f}",
                percentile_sorted(sorted, 0.50), percentile_sorted(sorted, 0.90), percentile_sorted(sorted, 0.99),
                percentile_sorted(sorted, 0.999), sorted.empty() ? 0.0 : sorted.back());
  return buf;
}

std::string rate_json(const std::vector<double>& v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.4g", median(v));
  return std::string("{\"median\": ") + buf + ", \"all\": " + json_list(v, "%.4g") + "}";
}

template <class T>
std::string bench_ring(const char* name, const RingPlan& plan) {
  using Ours = lancet::SpscRing<T, kCapacity>;
  using Bare = BareRing<T, kCapacity>;
  using BareAligned = BareRing<T, kCapacity, true>;
  const std::size_t ring_max = std::max({sizeof(Ours), sizeof(Bare), sizeof(BareAligned)});
  SharedRegion region(round_up(sizeof(Control), 4096) + 2 * round_up(ring_max, 4096));

  // Throughput. Index 0: ours, 1: bare, 2: bare with aligned slots.
  std::vector<double> rate[3];
  std::vector<double> ours_batch;
  std::vector<double> pair_cost;  // ours / bare, time per message, within one repetition
  for (int rep = 0; rep < plan.throughput_reps; ++rep) {
    std::fprintf(stderr, "  %s throughput rep %d/%d\n", name, rep + 1, plan.throughput_reps);
    rotate3(rep, [&](int v) {
      const double r = v == 0   ? ring_throughput_once<Ours, T>(region, plan.messages, false)
                       : v == 1 ? ring_throughput_once<Bare, T>(region, plan.messages, false)
                                : ring_throughput_once<BareAligned, T>(region, plan.messages, false);
      rate[v].push_back(r);
    });
    pair_cost.push_back(rate[1].back() / rate[0].back());
    ours_batch.push_back(ring_throughput_once<Ours, T>(region, plan.messages, true));
  }

  // Round trips; samples pooled per ring over the repetitions.
  std::vector<double> rtt[3];
  std::vector<double> pair_p50;  // ours / bare p50 within one repetition
  const std::size_t per_rep = plan.round_trips / static_cast<std::size_t>(plan.rtt_reps);
  for (int rep = 0; rep < plan.rtt_reps; ++rep) {
    std::fprintf(stderr, "  %s round trips rep %d/%d\n", name, rep + 1, plan.rtt_reps);
    std::vector<double> one[3];
    rotate3(rep, [&](int v) {
      if (v == 0) ring_rtt_once<Ours, T>(region, per_rep, one[0]);
      if (v == 1) ring_rtt_once<Bare, T>(region, per_rep, one[1]);
      if (v == 2) ring_rtt_once<BareAligned, T>(region, per_rep, one[2]);
    });
    pair_p50.push_back(median(one[0]) / median(one[1]));
    for (int v = 0; v < 3; ++v) rtt[v].insert(rtt[v].end(), one[v].begin(), one[v].end());
  }
  for (auto& v : rtt) std::sort(v.begin(), v.end());
  auto rtt_ratio = [&](int against, double q) {
    return percentile_sorted(rtt[0], q) / percentile_sorted(rtt[against], q);
  };

  std::string s;
  char buf[1024];
  std::snprintf(buf, sizeof buf,
                "{\"message_bytes\": %zu, \"capacity\": %zu, "
                "\"ring_bytes\": {\"ours\": %zu, \"bare\": %zu, \"bare_aligned_slots\": %zu},\n",
                sizeof(T), kCapacity, sizeof(Ours), sizeof(Bare), sizeof(BareAligned));
  s += buf;
  std::snprintf(buf, sizeof buf,
                "      \"throughput\": {\"messages_per_rep\": %llu, \"reps\": %d, "
                "\"consumer\": \"try_pop, one message at a time\",\n",
                static_cast<unsigned long long>(plan.messages), plan.throughput_reps);
  s += buf;
  s += "        \"ours_msgs_per_s\": " + rate_json(rate[0]) + ",\n";
  s += "        \"bare_msgs_per_s\": " + rate_json(rate[1]) + ",\n";
  s += "        \"bare_aligned_slots_msgs_per_s\": " + rate_json(rate[2]) + ",\n";
  s += "        \"ours_try_pop_n_256_msgs_per_s\": " + rate_json(ours_batch) + ",\n";
  std::snprintf(buf, sizeof buf,
                "        \"cost_ratio_ours_over_bare\": {\"of_medians\": %.3f, \"median_of_paired_reps\": %.3f, "
                "\"paired_reps\": %s},\n"
                "        \"cost_ratio_ours_over_bare_aligned_slots\": {\"of_medians\": %.3f}},\n",
                median(rate[1]) / median(rate[0]), median(pair_cost), json_list(pair_cost, "%.3f").c_str(),
                median(rate[2]) / median(rate[0]));
  s += buf;
  std::snprintf(buf, sizeof buf, "      \"round_trip_ns\": {\"round_trips_each\": %zu, \"reps\": %d,\n",
                rtt[0].size(), plan.rtt_reps);
  s += buf;
  s += "        \"ours\": " + percentiles_json(rtt[0]) + ",\n";
  s += "        \"bare\": " + percentiles_json(rtt[1]) + ",\n";
  s += "        \"bare_aligned_slots\": " + percentiles_json(rtt[2]) + ",\n";
  std::snprintf(buf, sizeof buf,
                "        \"cost_ratio_ours_over_bare\": {\"p50\": %.3f, \"p90\": %.3f, \"p99\": %.3f, "
                "\"median_of_paired_rep_p50\": %.3f},\n"
                "        \"cost_ratio_ours_over_bare_aligned_slots\": {\"p50\": %.3f, \"p90\": %.3f, \"p99\": %.3f}}}",
                rtt_ratio(1, 0.50), rtt_ratio(1, 0.90), rtt_ratio(1, 0.99), median(pair_p50), rtt_ratio(2, 0.50),
                rtt_ratio(2, 0.90), rtt_ratio(2, 0.99));
  s += buf;
  return s;
}

// ---------------------------------------------------------------------------------------------
// Seqlock.

struct Payload512 {
  std::uint64_t w[64];
};

template <class T>
void touch(T& v, std::uint64_t i) noexcept {
  std::memcpy(static_cast<void*>(&v), &i, sizeof i);
}

/// ns per call of fn over `iters` calls, median of `reps` repetitions.
template <class Fn>
double ns_per_op(std::uint64_t iters, int reps, Fn fn) {
  std::vector<double> r;
  for (int k = 0; k < reps; ++k) {
    const auto t0 = Clock::now();
    for (std::uint64_t i = 0; i < iters; ++i) fn(i);
    r.push_back(std::chrono::duration<double, std::nano>(Clock::now() - t0).count() / static_cast<double>(iters));
  }
  return median(r);
}

struct ContendedRead {
  double ns_per_call = 0;
  double ns_per_ok = 0;
  double ok_share = 0;  // kOk among kOk + kBusy
  std::uint64_t calls = 0;
  std::uint64_t writes = 0;
};

/// A reader thread calls try_read for `duration` while a writer thread writes (flat out, or
/// once per `period` when period > 0).
template <class T>
ContendedRead seqlock_contended(std::chrono::milliseconds duration, std::chrono::microseconds period) {
  auto lock = std::make_unique<lancet::Seqlock<T>>();
  auto value = std::make_unique<T>();
  lock->write(*value);
  std::atomic<bool> stop{false};
  std::uint64_t writes = 0;
  std::thread writer([&] {
    auto v = std::make_unique<T>();
    auto next = Clock::now();
    while (!stop.load(std::memory_order_relaxed)) {
      touch(*v, ++writes);
      lock->write(*v);
      if (period.count() > 0) {
        next += period;
        std::this_thread::sleep_until(next);
      }
    }
  });
  std::uint64_t ok = 0;
  std::uint64_t busy = 0;
  std::uint64_t calls = 0;
  const auto t0 = Clock::now();
  const auto end = t0 + duration;
  while (true) {
    for (int k = 0; k < 64; ++k) {
      const lancet::ReadStatus s = lock->try_read(*value);
      ok += s == lancet::ReadStatus::kOk ? 1 : 0;
      busy += s == lancet::ReadStatus::kBusy ? 1 : 0;
    }
    calls += 64;
    if (Clock::now() >= end) break;
  }
  const double ns = std::chrono::duration<double, std::nano>(Clock::now() - t0).count();
  stop.store(true);
  writer.join();
  ContendedRead r;
  r.calls = calls;
  r.writes = writes;
  r.ns_per_call = ns / static_cast<double>(calls);
  r.ns_per_ok = ok ? ns / static_cast<double>(ok) : 0.0;
  r.ok_share = ok + busy ? static_cast<double>(ok) / static_cast<double>(ok + busy) : 0.0;
  return r;
}

template <class T>
std::string bench_seqlock(const char* name, std::uint64_t iters, int reps, std::chrono::milliseconds contended) {
  std::fprintf(stderr, "  seqlock %s\n", name);
  auto lock = std::make_unique<lancet::Seqlock<T>>();
  auto v = std::make_unique<T>();
  auto out = std::make_unique<T>();
  const double write_ns = ns_per_op(iters, reps, [&](std::uint64_t i) {
    touch(*v, i);
    lock->write(*v);
  });
  std::uint64_t sink = 0;
  const double read_ns = ns_per_op(iters, reps, [&](std::uint64_t) {
    sink += lock->try_read(*out) == lancet::ReadStatus::kOk ? 1 : 0;
  });
  if (sink == 0) std::fprintf(stderr, "lancet-bench-ipc: no read succeeded\n");
  const ContendedRead flat = seqlock_contended<T>(contended, std::chrono::microseconds(0));
  const ContendedRead khz = seqlock_contended<T>(contended, std::chrono::microseconds(1000));
  auto cr = [](const ContendedRead& r) {
    char buf[256];
    std::snprintf(buf, sizeof buf,
                  "{\"ns_per_try_read\": %.1f, \"ns_per_ok_read\": %.1f, \"ok_share\": %.4f, \"reads\": %llu, "
                  "\"writes\": %llu}",
                  r.ns_per_call, r.ns_per_ok, r.ok_share, static_cast<unsigned long long>(r.calls),
                  static_cast<unsigned long long>(r.writes));
    return std::string(buf);
  };
  char buf[1024];
  std::snprintf(buf, sizeof buf,
                "{\"payload_bytes\": %zu, \"write_ns\": %.1f, \"read_ns\": %.1f,\n"
                "      \"read_while_writer_flat_out\": %s,\n      \"read_while_writer_1khz\": %s}",
                sizeof(T), write_ns, read_ns, cr(flat).c_str(), cr(khz).c_str());
  return buf;
}

}  // namespace

int main(int argc, char** argv) {
  bool quick = false;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--quick") == 0) {
      quick = true;
    } else {
      std::fprintf(stderr, "usage: %s [--quick]\n  prints one JSON object with ring and seqlock costs\n", argv[0]);
      return 2;
    }
  }
  const RingPlan small = quick ? RingPlan{500'000, 3, 15'000, 3} : RingPlan{10'000'000, 7, 200'000, 10};
  const RingPlan large = quick ? RingPlan{200'000, 3, 15'000, 3} : RingPlan{2'000'000, 7, 200'000, 10};

  utsname un{};
  uname(&un);
  std::fprintf(stderr, "lancet-bench-ipc (%s)\n", quick ? "quick" : "full");
  const std::string date = utc_now();
  const std::string ring64 = bench_ring<Msg64>("msg64", small);
  const std::string ring_sample = bench_ring<lancet::ToolSample>("tool_sample", large);
  const std::string seq512 =
      bench_seqlock<Payload512>("512 B", quick ? 200'000 : 2'000'000, 5, std::chrono::milliseconds(quick ? 100 : 500));
  const std::string seq_patch = bench_seqlock<lancet::TissuePatch>("TissuePatch", quick ? 2'000 : 20'000, 5,
                                                                    std::chrono::milliseconds(quick ? 100 : 500));

  std::printf("{\n");
  std::printf("  \"benchmark\": \"lancet-bench-ipc\",\n  \"mode\": \"%s\",\n  \"date\": \"%s\",\n",
              quick ? "quick" : "full", date.c_str());
  std::printf("  \"machine\": {\"cpu_model\": \"%s\", \"nproc\": %ld, \"kernel\": \"%s\", \"compiler\": \"%s\"},\n",
              json_escape(cpu_model()).c_str(), sysconf(_SC_NPROCESSORS_ONLN), json_escape(un.release).c_str(),
              json_escape(compiler()).c_str());
  std::printf("  \"ring\": {\n    \"msg64\": %s,\n    \"tool_sample\": %s},\n", ring64.c_str(), ring_sample.c_str());
  std::printf("  \"seqlock\": {\n    \"payload_512\": %s,\n    \"tissue_patch\": %s}\n", seq512.c_str(),
              seq_patch.c_str());
  std::printf("}\n");
  return 0;
}
