// lancet-bench-blood: the bleeding automaton's GPU twin (blood::BloodCompute, GL compute shaders,
// headless through EGL: DISPLAY unset) on square grids fully wet (1 mm of blood on every cell,
// so every tile is worked on every step): cell-steps per second, N steps timed between two
// glFinish; and the CPU reference (blood::Automaton) on the same grid, 1 thread and all, for
// scale. Prints one JSON object.
//   lancet-bench-blood [--size N] [--seconds S]
// --size: one grid of N × N cells instead of 512² and 2048²; --seconds: the least time each figure
// is measured over (default 2).
//
// The memory-bandwidth bound, in the same run: the copy bandwidth (memcpy of 256 MB, read plus
// write counted) over the bytes one cell-step must move at least, counting each array the step's
// passes stream once per pass (neighbours' values of the same pass come from cache): plan reads
// volume, film, source, sink (16 B) and every outgoing flux; sources and sinks read source, sink
// (8 B); fluxes read volume, area, elevation, film, born and write conc (24 B), and per pipe read
// to, conductance and read and write the flux (16 B); volumes read and write volume and born and
// read conc (20 B), and per pipe read twin, the twin's flux and the own flux (12 B); the ledger
// reads volume (4 B). 72 B + 32 B per pipe.

#include <epoxy/gl.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "../host_viz/blood/blood_support.hpp"
#include "blood/automaton.hpp"
#include "blood/blood_compute.hpp"
#include "render/window.hpp"

namespace {

using namespace lancet;
using Clock = std::chrono::steady_clock;

/// Copy bandwidth (bytes moved per second, read plus write) of memcpy over 256 MB, best of 5.
double copy_bandwidth() {
  const std::size_t n = std::size_t{256} << 20;
  std::vector<char> a(n, 1), b(n, 2);
  double best = 0;
  for (int r = 0; r < 5; ++r) {
    const auto t0 = Clock::now();
    std::memcpy(b.data(), a.data(), n);
    const double dt = std::chrono::duration<double>(Clock::now() - t0).count();
    best = std::max(best, 2.0 * static_cast<double>(n) / dt);
    a[static_cast<std::size_t>(r)] = b[n - 1 - static_cast<std::size_t>(r)];  // keep the copies observable
  }
  return best;
}

/// Steps `step` in batches (`finish` after each) until `seconds` have passed: steps per second.
template <class Step, class Finish>
double steps_per_second(double seconds, int batch, Step&& step, Finish&& finish) {
  for (int s = 0; s < 2; ++s) step();  // warm up (the shaders' first dispatch, the caches)
  finish();
  long steps = 0;
  const auto t0 = Clock::now();
  double elapsed = 0;
  do {
    for (int s = 0; s < batch; ++s) step();
    finish();
    steps += batch;
    elapsed = std::chrono::duration<double>(Clock::now() - t0).count();
  } while (elapsed < seconds);
  return static_cast<double>(steps) / elapsed;
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<int> sizes = {512, 2048};
  double seconds = 2;
  for (int i = 1; i < argc; i += 2) {
    if (i + 1 >= argc) {
      std::fprintf(stderr, "lancet-bench-blood: %s needs a value\n", argv[i]);
      return 2;
    }
    if (std::strcmp(argv[i], "--size") == 0) {
      sizes = {std::max(16, std::atoi(argv[i + 1]))};
    } else if (std::strcmp(argv[i], "--seconds") == 0) {
      seconds = std::max(0.1, std::atof(argv[i + 1]));
    } else {
      std::fprintf(stderr, "lancet-bench-blood: unknown option %s (--size N, --seconds S)\n", argv[i]);
      return 2;
    }
  }
  unsetenv("DISPLAY");  // headless: EGL without a display
  auto window = render::Window::create({64, 64, false, "bench"});
  if (!window) {
    std::fprintf(stderr, "lancet-bench-blood: %s\n", window.error().message.c_str());
    return 1;
  }
  const int threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  const double bandwidth = copy_bandwidth();
  std::printf("{\n  \"gl\": \"%s\",\n  \"cpu_threads\": %d,\n  \"copy_bandwidth_gb_s\": %.2f,\n  \"grids\": [\n",
              window.value()->gl_description().c_str(), threads, bandwidth * 1e-9);
  for (std::size_t n = 0; n < sizes.size(); ++n) {
    const int size = sizes[n];
    constexpr float h = 0.0007f;
    // A gentle slope with ripples, 1 mm of blood everywhere: mobile on every cell.
    const auto g = blood::test::grid(size, size, h, [](float x, float y) {
      return -0.05f * x + 2e-4f * std::sin(x / 0.003f) * std::cos(y / 0.004f);
    });
    const blood::Network net = blood::mesh_network(g.xyz, g.tri, blood::test::kDown, 2e-5f);
    blood::Automaton cpu(net, blood::Params{});
    for (std::uint32_t i = 0; i < net.cells(); ++i) cpu.place(i, 1e-3f * net.area[i]);
    const double cells = static_cast<double>(net.cells());
    // Batches of about 1e7 cell-steps between two glFinish (the GPU queue stays full within one).
    const int batch = std::max(1, static_cast<int>(1e7 / cells));

    blood::BloodCompute gpu(net, blood::Params{});
    gpu.upload_state(cpu.state());
    const double gpu_rate = steps_per_second(seconds, batch, [&] { gpu.step(); }, [] { glFinish(); });
    const std::vector<std::uint8_t> active = gpu.tile_active();
    const auto gpu_active = static_cast<std::size_t>(std::count(active.begin(), active.end(), 1));

    const double cpu1_rate = steps_per_second(seconds, batch, [&] { cpu.step(1); }, [] {});
    const double cpun_rate = steps_per_second(seconds, batch, [&] { cpu.step(threads); }, [] {});
    const double bytes = 72.0 + 32.0 * static_cast<double>(net.pipes()) / cells;  // per cell-step, see the top
    const double bound = bandwidth / bytes;
    std::printf("    {\"cells\": %zu, \"grid\": \"%dx%d\", \"pipes\": %zu, \"tiles\": %zu, \"gpu_active_tiles\": %zu, "
                "\"gpu_cell_steps_per_s\": %.4g, \"gpu_ms_per_step\": %.3f, \"cpu_1_thread_cell_steps_per_s\": %.4g, "
                "\"cpu_%d_threads_cell_steps_per_s\": %.4g, \"bytes_per_cell_step\": %.0f, \"bandwidth_bound_cell_steps_per_s\": %.4g, "
                "\"cpu_%d_threads_over_bound\": %.2f}%s\n",
                net.cells(), size, size, net.pipes(), net.tiles(), gpu_active, gpu_rate * cells, 1e3 / gpu_rate, cpu1_rate * cells,
                threads, cpun_rate * cells, bytes, bound, threads, cpun_rate * cells / bound, n + 1 < sizes.size() ? "," : "");
  }
  std::printf("  ]\n}\n");
  return 0;
}
