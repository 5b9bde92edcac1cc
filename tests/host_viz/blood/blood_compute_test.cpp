// The bleeding automaton's GPU twin (blood::BloodCompute, headless EGL, llvmpipe) against the CPU
// reference (blood::Automaton) on a tilted, wavy 64 × 48 grid with two sources, a swab and a
// poured pool, both started from the same state: after 100 steps every cell's volume agrees
// within 1e-5 of the largest, none is negative, the GPU's mass and ledger match the CPU's, the
// same tiles were worked on each step and the idle ones really were skipped; and with skipping
// off, every tile is worked on and the results still agree, also after the tissue tilts.

#include "blood/blood_compute.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <vector>

#include "blood_support.hpp"
#include "../render/headless_gl.hpp"

namespace lancet::render {
namespace {

using blood::BloodCompute;
using blood::test::kDown;

constexpr float kH = 0.0007f;  // 0.7 mm between cells

using BloodComputeTest = test::HeadlessGl<64, 64>;

/// The largest |a − b| over the largest |a| (0 when a is all zeros), and the largest |a − b|.
struct Diff {
  double abs = 0, rel = 0;
};
Diff compare(const std::vector<float>& a, const std::vector<float>& b) {
  Diff d;
  double scale = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    d.abs = std::max(d.abs, std::abs(static_cast<double>(a[i]) - static_cast<double>(b[i])));
    scale = std::max(scale, std::abs(static_cast<double>(a[i])));
  }
  d.rel = scale > 0 ? d.abs / scale : d.abs;
  return d;
}

/// The scene: downhill towards +x and −y, with ripples; a film of 20 µm.
struct Scene {
  blood::test::Grid g = blood::test::grid(64, 48, kH, [](float x, float y) {
    return -0.3f * x + 0.05f * y + 2e-4f * std::sin(x / 0.003f) * std::cos(y / 0.004f);
  });
  blood::Network net = blood::mesh_network(g.xyz, g.tri, kDown, 2e-5f);
  std::vector<float> sources, sinks;
  Scene() : sources(net.cells(), 0.0f), sinks(net.cells(), 0.0f) {
    sources[g.at(8, 30)] = 2e-8f;  // 0.02 mL/s
    sources[g.at(30, 26)] = 1e-8f;
    for (int i = 46; i < 51; ++i)
      for (int j = 6; j < 14; ++j) sinks[g.at(i, j)] = 3.0f;
    sinks[g.at(45, 10)] = 600.0f;  // k·Δt > 1: the swab takes all
  }
  /// Pours the pool (3 × 3 cells, 2 mm deep) on the CPU.
  void pour(blood::Automaton& a) const {
    for (int i = 39; i < 42; ++i)
      for (int j = 10; j < 13; ++j) a.place(g.at(i, j), 2e-3f * net.area[g.at(i, j)]);
  }
};

TEST_F(BloodComputeTest, MatchesTheCpuReferenceAfterAHundredStepsAndSkipsTheSameIdleTiles) {
  const Scene sc;
  blood::Automaton cpu(sc.net, blood::Params{});
  ASSERT_EQ(sc.net.tiles(), 12u);
  sc.pour(cpu);
  cpu.set_sources(sc.sources);
  cpu.set_sinks(sc.sinks);
  // A few CPU steps first, so that the GPU starts from fluxes, tracer and a time that are not zero.
  for (int s = 0; s < 10; ++s) cpu.step();
  // Blood held by its film (not mobile) far from the rest, in the last tile: that tile stays
  // idle, and its tracer shows whether it was skipped: the flux pass of a tile it works on sets
  // the cell's concentration born / V (here the time it was placed), a skipped tile keeps 0.
  const std::uint32_t held = sc.g.at(60, 45);
  const std::size_t far_tile = held / blood::kTile;
  cpu.place(held, 0.5f * sc.net.film[held]);
  ASSERT_GT(cpu.state().born[held], 0.0f);

  BloodCompute gpu(sc.net, blood::Params{});
  gpu.upload_state(cpu.state());
  gpu.set_sources(sc.sources);
  gpu.set_sinks(sc.sinks);
  const blood::Ledger start = cpu.ledger();
  std::size_t fewest_active = sc.net.tiles(), steps_mismatched = 0;
  for (int s = 0; s < 100; ++s) {
    cpu.step();
    gpu.step();
    const std::vector<std::uint8_t> active = gpu.tile_active();
    const std::vector<std::uint8_t> expected(cpu.tile_active().begin(), cpu.tile_active().end());
    steps_mismatched += active != expected;
    fewest_active = std::min<std::size_t>(fewest_active, static_cast<std::size_t>(std::count(active.begin(), active.end(), 1)));
    EXPECT_EQ(active[far_tile], 0) << "step " << s;
  }
  const blood::State g = gpu.download();
  const blood::State& c = cpu.state();
  ASSERT_EQ(g.volume.size(), c.volume.size());
  const Diff dv = compare(c.volume, g.volume), db = compare(c.born, g.born), df = compare(c.flux, g.flux),
             dc = compare(c.conc, g.conc);
  std::printf("[ info     ] after 100 steps, GPU vs CPU: volume max |d| %.3e m³ (%.3e of the largest %.3e), born %.3e, "
              "flux %.3e, conc %.3e (relative); %zu to %zu of %zu tiles active\n",
              dv.abs, dv.rel, static_cast<double>(*std::max_element(c.volume.begin(), c.volume.end())), db.rel, df.rel, dc.rel,
              fewest_active, cpu.active_tiles(), sc.net.tiles());
  // The acceptance: depths agree within 1e-5 (the same float operations in the same order, and
  // on llvmpipe the same results to the bit).
  EXPECT_LE(dv.rel, 1e-5);
  EXPECT_LE(db.rel, 1e-5);
  EXPECT_LE(df.rel, 1e-5);
  EXPECT_LE(dc.rel, 1e-5);
  EXPECT_GE(*std::min_element(g.volume.begin(), g.volume.end()), 0.0f);
  EXPECT_DOUBLE_EQ(g.time, c.time);

  // The mass: the GPU's per-tile sums against the CPU ledger; sources and sinks since the upload.
  const blood::Ledger gl = gpu.ledger(), &cl = cpu.ledger();
  const double scale = cl.expected();
  std::printf("[ info     ] mass: GPU %.9e m³, CPU %.9e m³ (relative %.2e); sources %.6e / %.6e, sinks %.6e / %.6e\n", gl.now,
              cl.now, std::abs(gl.now - cl.now) / scale, gl.sources, cl.sources - start.sources, gl.sinks, cl.sinks - start.sinks);
  EXPECT_NEAR(gl.now, cl.now, 1e-5 * scale);
  EXPECT_NEAR(gpu.total_volume(), cl.now, 1e-5 * scale);
  EXPECT_NEAR(gl.sources, cl.sources - start.sources, 1e-5 * scale);
  EXPECT_NEAR(gl.sinks, cl.sinks - start.sinks, 1e-5 * scale);
  EXPECT_LE(gl.relative_error(), 1e-5) << "GPU mass = initial + sources − sinks";
  EXPECT_GT(gl.sinks, 0.0) << "the swab took blood";
  EXPECT_GT(gl.sources, 0.0);

  // The same tiles each step, some of them idle, and the idle one really skipped: its held blood
  // is still there, its concentration never set, no flux out of its cells.
  EXPECT_EQ(steps_mismatched, 0u) << "steps whose active tiles differ";
  EXPECT_LT(fewest_active, sc.net.tiles());
  EXPECT_GT(g.volume[held], 0.0f);
  EXPECT_EQ(g.conc[held], 0.0f) << "the idle tile's flux pass ran";
  EXPECT_EQ(c.conc[held], 0.0f);
  for (std::uint32_t i = static_cast<std::uint32_t>(far_tile * blood::kTile); i < sc.net.cells(); ++i)
    for (std::uint32_t k = sc.net.first[i]; k < sc.net.first[i + 1]; ++k) ASSERT_EQ(g.flux[k], 0.0f) << "cell " << i;
}

TEST_F(BloodComputeTest, WithoutSkippingEveryTileIsSteppedAndTheResultsStillAgreeAfterTheTissueTilts) {
  const Scene sc;
  blood::Params p;
  p.skip_idle_tiles = false;
  blood::Automaton cpu(sc.net, p);
  sc.pour(cpu);
  cpu.set_sources(sc.sources);
  BloodCompute gpu(sc.net, p);
  gpu.upload_state(cpu.state());
  gpu.set_sources(sc.sources);
  for (int s = 0; s < 40; ++s) {
    if (s == 20) {  // the tissue tilts the other way: the blood turns round on both
      std::vector<float> e(sc.net.elevation);
      for (std::size_t i = 0; i < e.size(); ++i) e[i] += 0.6f * sc.g.xyz[3 * i];
      std::vector<float> area(sc.net.area);
      for (float& a : area) a *= 1.25f;  // and opens: the same blood stands lower
      cpu.set_geometry(e, area);
      gpu.set_geometry(e, area);
    }
    cpu.step();
    gpu.step();
  }
  const std::vector<std::uint8_t> active = gpu.tile_active();
  EXPECT_EQ(static_cast<std::size_t>(std::count(active.begin(), active.end(), 1)), sc.net.tiles());
  const blood::State g = gpu.download();
  EXPECT_LE(compare(cpu.state().volume, g.volume).rel, 1e-5);
  EXPECT_LE(compare(cpu.state().conc, g.conc).rel, 1e-5);
  // No sinks: the swab pass still runs (for the sources) and takes nothing.
  EXPECT_EQ(gpu.ledger().sinks, 0.0);
  EXPECT_NEAR(gpu.ledger().now, cpu.ledger().now, 1e-5 * cpu.ledger().now);
}

}  // namespace
}  // namespace lancet::render
