// lancet-bench-chainmail: Enhanced ChainMail throughput (host_viz/volume/chainmail.hpp) on two
// workloads, against the target of 5e7 elements/s (the thesis measured 7.3e5/s, section 3.3.2.5).
// Prints one JSON object on stdout.
//
//   lancet-bench-chainmail [--quick] [--reps N]
//
// groove: a 256 × 256 × 128 lattice at 0.5 mm of layered tissue (air above, then skin, fat and an
//   anisotropic muscle), a bent 80 mm cut 18.5 mm deep opened into an 8 mm groove by a retractor
//   holding the top faces 20 mm in from either end; one step.
// push: a 256³ block of one material (no material array); the middle element of the top layer
//   pushed 5 mm (10 spacings) down; one step.
// Each is timed cold (a fresh object: bricks are allocated as the region grows) and warm (the same
// step again after reset(), which keeps the bricks: no allocation), warm as the median of several
// repetitions. "processed" = coordinates moved (each once, whatever the queue's work), as
// ChainMailStepResult counts them; both workloads move elements along one axis, so that is
// elements. --quick: half the lattice and one repetition. --reps N: N warm repetitions (default 5;
// more for a profile).
// yardstick: the same push region visited by the simplest possible propagation on this machine, a
// first-in-first-out flood over a dense array of doubles (no priority, no bricks, no materials, one
// bound per neighbour); its rate is a ceiling for any ChainMail here, measured in the same run.

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "volume/chainmail.hpp"

namespace {

using namespace lancet;
using namespace lancet::volume;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

struct Run {
  ChainMailStepResult step;
  double cold_s = 0, warm_s = 0;
  std::uint64_t materialised = 0;
  std::size_t bytes = 0;
  double setup_s = 0;  // cut (groove) or nothing (push)
};

// Layered tissue: air above 90 % of the height, then 4 layers of skin, 16 of fat, muscle below.
std::vector<std::uint8_t> tissue(int nx, int ny, int nz, int& surface_k) {
  std::vector<std::uint8_t> ids(static_cast<std::size_t>(nx) * static_cast<std::size_t>(ny) * static_cast<std::size_t>(nz));
  surface_k = nz * 9 / 10;
  for (int k = 0; k < nz; ++k) {
    const std::uint8_t m = k > surface_k ? 0 : (k > surface_k - 4 ? 1 : (k > surface_k - 20 ? 2 : 3));
    std::fill_n(ids.begin() + static_cast<std::ptrdiff_t>(static_cast<std::size_t>(k) * static_cast<std::size_t>(nx) * static_cast<std::size_t>(ny)),
                static_cast<std::ptrdiff_t>(static_cast<std::size_t>(nx) * static_cast<std::size_t>(ny)), m);
  }
  return ids;
}

Run groove(bool quick, int reps, std::array<int, 3>& dims_out, double& length_out) {
  const int scale = quick ? 2 : 1;
  const std::array<int, 3> dims{256 / scale, 256 / scale, 128 / scale};
  dims_out = dims;
  const double s = 0.5e-3 * scale;
  const Vec3 sp{s, s, s};
  int surface_k = 0;
  const std::vector<std::uint8_t> ids = tissue(dims[0], dims[1], dims[2], surface_k);
  const std::vector<ChainMailMaterial> mats{
      ChainMailMaterial::air(), ChainMailMaterial::relative(sp, 0.2, 0.3, 0.3), ChainMailMaterial::relative(sp, 0.4, 0.4, 0.4),
      // Muscle, fibres along x: stiffer along the fibres than across them.
      ChainMailMaterial{true, {{{0.9 * s, 1.1 * s, 0.25 * s}, {0.7 * s, 1.3 * s, 0.3 * s}, {0.7 * s, 1.3 * s, 0.3 * s}}}}};
  const ChainMailLattice lat{dims, sp, {}};
  // A bent polyline across the middle, 80 mm long in all; cut from the lattice top to 37 layers
  // below it (the tissue starts under the air).
  const double cx = 0.5 * dims[0] * s, cy = 0.5 * dims[1] * s;
  const std::vector<Vec3> line{{cx - 0.040 + 0.0003, cy - 0.004 + 0.0002, 0}, {cx + 0.0001, cy + 0.003, 0}, {cx + 0.0395, cy - 0.002, 0}};
  const double depth = (dims[2] - 1 - surface_k + 37 / scale) * s;
  const double width = 8e-3;

  Run run;
  {
    ChainMail cm(lat, mats, ids);
    auto t0 = Clock::now();
    const ChainMailCut cut = cm.cut(line, depth);
    run.setup_s = seconds_since(t0);
    length_out = cut.length;
    const ChainMailRetractor retractor{0.020, cut.length - 0.020, 0};
    t0 = Clock::now();
    run.step = cm.open_groove(cut, width, retractor);
    run.cold_s = seconds_since(t0);
    run.materialised = cm.materialised_elements();
    run.bytes = cm.bytes_used();
    std::vector<double> warm;
    for (int r = 0; r < reps; ++r) {
      cm.reset();
      const ChainMailCut again = cm.cut(line, depth);
      t0 = Clock::now();
      const ChainMailStepResult w = cm.open_groove(again, width, retractor);
      warm.push_back(seconds_since(t0));
      if (w.processed != run.step.processed) std::fprintf(stderr, "warning: the warm groove differs from the cold one\n");
    }
    run.warm_s = median(warm);
  }
  return run;
}

Run push(bool quick, int reps, int& n_out, double& push_out) {
  const int n = quick ? 128 : 256;
  n_out = n;
  const double s = 0.5e-3;
  const double P = (quick ? 5 : 10) * s;
  push_out = P;
  const std::vector<ChainMailMaterial> mats{ChainMailMaterial::relative({s, s, s}, 0.1, 0.1, 0.1)};
  ChainMail cm({{n, n, n}, {s, s, s}, {}}, mats);
  const ChainMail::Index e{n / 2, n / 2, n - 1};
  const Vec3 target = cm.rest_position(e) + Vec3{0, 0, -P};
  Run run;
  auto t0 = Clock::now();
  run.step = cm.move(e, target);
  run.cold_s = seconds_since(t0);
  run.materialised = cm.materialised_elements();
  run.bytes = cm.bytes_used();
  std::vector<double> warm;
  for (int r = 0; r < reps; ++r) {
    cm.reset();
    t0 = Clock::now();
    const ChainMailStepResult w = cm.move(e, target);
    warm.push_back(seconds_since(t0));
    if (w.processed != run.step.processed) std::fprintf(stderr, "warning: the warm push differs from the cold one\n");
  }
  run.warm_s = median(warm);
  return run;
}

// The yardstick: a FIFO flood from the same element over a dense n³ array; each neighbour must be
// within `allowance` of an element's value. Returns elements/s (median) and the element count.
double yardstick(int n, double push, double allowance, int reps, std::size_t& count) {
  const std::size_t total = static_cast<std::size_t>(n) * static_cast<std::size_t>(n) * static_cast<std::size_t>(n);
  std::vector<double> u(total, 0.0);
  std::vector<std::uint32_t> seen(total, 0), queue;
  queue.reserve(1 << 20);
  std::vector<double> rates;
  for (int r = 1; r <= reps; ++r) {
    std::fill(u.begin(), u.end(), 0.0);
    queue.clear();
    const std::size_t start = static_cast<std::size_t>(n / 2) + static_cast<std::size_t>(n) * (static_cast<std::size_t>(n / 2) + static_cast<std::size_t>(n) * static_cast<std::size_t>(n - 1));
    u[start] = push;
    seen[start] = static_cast<std::uint32_t>(r);
    queue.push_back(static_cast<std::uint32_t>(start));
    const auto t0 = Clock::now();
    for (std::size_t head = 0; head < queue.size(); ++head) {
      const std::size_t e = queue[head];
      const std::size_t i = e % static_cast<std::size_t>(n), j = (e / static_cast<std::size_t>(n)) % static_cast<std::size_t>(n),
                        k = e / (static_cast<std::size_t>(n) * static_cast<std::size_t>(n));
      const std::size_t row = static_cast<std::size_t>(n), slab = row * row;
      const std::size_t nb[6] = {i + 1 < row ? e + 1 : total, i > 0 ? e - 1 : total, j + 1 < row ? e + row : total,
                                 j > 0 ? e - row : total,  k + 1 < row ? e + slab : total, k > 0 ? e - slab : total};
      const double need = u[e] - allowance;
      for (const std::size_t x : nb) {
        if (x == total || seen[x] == static_cast<std::uint32_t>(r) || !(need > 1e-15)) continue;
        u[x] = need;
        seen[x] = static_cast<std::uint32_t>(r);
        queue.push_back(static_cast<std::uint32_t>(x));
      }
    }
    rates.push_back(static_cast<double>(queue.size()) / seconds_since(t0));
    count = queue.size();
  }
  return median(rates);
}

void print_run(const char* name, const Run& r, bool last) {
  const double p = static_cast<double>(r.step.processed);
  std::printf("  \"%s_processed\": %llu,\n  \"%s_moved\": %llu,\n  \"%s_conflicts\": %llu,\n", name,
              static_cast<unsigned long long>(r.step.processed), name, static_cast<unsigned long long>(r.step.moved), name,
              static_cast<unsigned long long>(r.step.conflicts));
  std::printf("  \"%s_cold_s\": %.6f,\n  \"%s_warm_s\": %.6f,\n", name, r.cold_s, name, r.warm_s);
  std::printf("  \"%s_cold_elements_per_s\": %.4g,\n  \"%s_warm_elements_per_s\": %.4g,\n", name, p / r.cold_s, name, p / r.warm_s);
  std::printf("  \"%s_materialised_elements\": %llu,\n  \"%s_bytes_used\": %zu%s\n", name,
              static_cast<unsigned long long>(r.materialised), name, r.bytes, last ? "" : ",");
}

}  // namespace

int main(int argc, char** argv) {
  bool quick = false;
  int reps_override = 0;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--quick") == 0) {
      quick = true;
    } else if (std::strcmp(argv[i], "--reps") == 0 && i + 1 < argc) {
      reps_override = std::atoi(argv[++i]);
    } else {
      std::fprintf(stderr, "usage: lancet-bench-chainmail [--quick] [--reps N]\n");
      return 2;
    }
  }
  const int reps = reps_override > 0 ? reps_override : (quick ? 1 : 5);
  std::array<int, 3> gdims{};
  double length = 0;
  const Run g = groove(quick, reps, gdims, length);
  int pn = 0;
  double p = 0;
  const Run q = push(quick, reps, pn, p);
  const double target = 5e7;
  const double g_rate = static_cast<double>(g.step.processed) / g.warm_s, p_rate = static_cast<double>(q.step.processed) / q.warm_s;
  std::printf("{\n  \"quick\": %s,\n  \"target_elements_per_s\": %.3g,\n  \"thesis_elements_per_s\": 7.3156e5,\n", quick ? "true" : "false", target);
  std::printf("  \"groove_lattice\": [%d, %d, %d],\n  \"groove_cut_length_m\": %.4f,\n  \"groove_width_m\": 0.008,\n  \"groove_cut_s\": %.6f,\n",
              gdims[0], gdims[1], gdims[2], length, g.setup_s);
  print_run("groove", g, false);
  std::printf("  \"push_lattice\": [%d, %d, %d],\n  \"push_m\": %.4f,\n", pn, pn, pn, p);
  print_run("push", q, false);
  std::size_t flood = 0;
  const double floor_rate = yardstick(pn, p, 0.1 * 0.5e-3, reps, flood);
  std::printf("  \"yardstick_fifo_flood_elements\": %zu,\n  \"yardstick_fifo_flood_elements_per_s\": %.4g,\n", flood, floor_rate);
  std::printf("  \"groove_warm_fraction_of_yardstick\": %.3f,\n", g_rate / floor_rate);
  std::printf("  \"push_warm_fraction_of_yardstick\": %.3f,\n", p_rate / floor_rate);
  std::printf("  \"meets_target_warm\": %s\n}\n", g_rate >= target && p_rate >= target ? "true" : "false");
  return 0;
}
