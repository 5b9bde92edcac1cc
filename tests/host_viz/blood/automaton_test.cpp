// The bleeding automaton (CPU reference): the mass ledger over 10,000 steps with sources and
// sinks, depths never negative, a mesh's network one pipe each way per edge (and no longer),
// blood running down a tilted plane at the rate the pipe model predicts, a pool levelling out in a bowl, blood crossing a cut through the groove's cells
// without loss, results that do not depend on the threads or on skipping idle tiles, and a step
// that is the plain equations over every cell, bit for bit.

#include "blood/automaton.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <numeric>
#include <string>

#include "blood_support.hpp"

namespace lancet::blood {
namespace {

using test::grid;
using test::kDown;

constexpr float kH = 0.0007f;  // 0.7 mm between cells

TEST(BloodAutomaton, TheLedgerHoldsOverTenThousandStepsWithSourcesAndSinksAndNoDepthGoesNegative) {
  // A shallow bowl, 48 × 48 cells: sources on one side, a swab on the other.
  const auto g = grid(48, 48, kH, [](float x, float y) {
    const float cx = x - 24 * kH, cy = y - 24 * kH;
    return 8.0f * (cx * cx + cy * cy);
  });
  Automaton a(mesh_network(g.xyz, g.tri, kDown, 2e-5f), Params{});
  ASSERT_GT(a.network().tiles(), 4u);
  std::vector<float> src(a.network().cells(), 0.0f), sink(a.network().cells(), 0.0f);
  src[g.at(5, 24)] = 2e-8f;  // 0.02 mL/s
  src[g.at(6, 30)] = 1e-8f;
  for (int i = 28; i < 36; ++i)
    for (int j = 20; j < 28; ++j) sink[g.at(i, j)] = 3.0f;
  a.set_sources(src);
  a.set_sinks(sink);
  a.place(g.at(24, 40), 2e-8f);
  double worst = 0;
  float lowest = 0;
  for (int s = 0; s < 10000; ++s) {
    a.step();
    worst = std::max(worst, a.ledger().relative_error());
    for (float v : a.state().volume) lowest = std::min(lowest, v);
  }
  const Ledger& l = a.ledger();
  std::printf("[ info     ] after 10,000 steps: sources %.4g m³, sinks %.4g m³, worst relative ledger error %.3g\n", l.sources,
              l.sinks, worst);
  EXPECT_GT(l.sources, 5e-7) << "the sources bled 20 s";
  EXPECT_GT(l.sinks, 1e-8) << "blood reached the swab";
  EXPECT_LE(worst, 1e-5) << "mass = initial + sources - sinks, every step";
  EXPECT_GE(lowest, 0.0f);
  // And the check can fail: a lost flux shows at once.
  Ledger wrong = l;
  wrong.now *= 1.0001;
  EXPECT_GT(wrong.relative_error(), 1e-5);
}

// A mesh edge comes from both its faces: the network merges the two into one pipe each way and
// holds its pipe arrays at exactly that size (sized by the unmerged count, they were twice as long).
TEST(BloodAutomaton, AMeshNetworkHasOnePipeEachWayPerEdgeAndArraysOfThatSize) {
  const auto g = grid(20, 20, kH, [](float, float) { return 0.0f; });
  const Network n = mesh_network(g.xyz, g.tri, kDown, 2e-5f);
  const std::size_t edges = 19 * 20 * 2 + 19 * 19;  // rows, columns and one diagonal per square
  EXPECT_EQ(n.pipes(), 2 * edges);
  EXPECT_EQ(n.to.capacity(), n.pipes());
  EXPECT_EQ(n.conductance.capacity(), n.pipes());
  EXPECT_EQ(n.twin.capacity(), n.pipes());
  for (std::size_t k = 0; k < n.pipes(); ++k) ASSERT_EQ(n.twin[n.twin[k]], k);
}

TEST(BloodAutomaton, BloodRunsDownATiltedPlaneAtTheRateThePipeModelPredicts) {
  const float slope = 0.3f;
  const auto g = grid(64, 8, kH, [&](float x, float) { return -slope * x; });
  Params p;
  Automaton a(mesh_network(g.xyz, g.tri, kDown, 0.0f), p);
  const Network& n = a.network();
  // A uniform 1 mm film (mobile depth above ref_depth: m = 1).
  for (std::uint32_t i = 0; i < n.cells(); ++i) a.place(i, 1e-3f * n.area[i]);
  for (int s = 0; s < 400; ++s) a.step();
  // Through the section between columns 31 and 32: every pipe crossing it carries, at steady
  // state, the fixed point of 5.17, f = Δt·mobility·C·m·Δh / (1 − δ), with Δh the head
  // difference across it (nearly the elevation's: the film stays nearly uniform there).
  const float keep = std::pow(p.damping, p.dt);
  double measured = 0, predicted = 0;
  for (int j = 0; j < g.ny; ++j) {
    const std::uint32_t i = g.at(31, j);
    for (std::uint32_t k = n.first[i]; k < n.first[i + 1]; ++k) {
      const std::uint32_t to = n.to[k];
      if (static_cast<int>(to % static_cast<std::uint32_t>(g.nx)) != 32) continue;
      measured += a.state().flux[k] - a.state().flux[n.twin[k]];
      const double dh = (n.elevation[i] + a.depth(i)) - (n.elevation[to] + a.depth(to));
      predicted += std::max(0.0, p.dt * p.mobility * n.conductance[k] * dh / (1.0f - keep));
      EXPECT_NEAR(a.depth(to), 1e-3f, 1e-4f) << "the film is still about 1 mm deep here";
    }
  }
  ASSERT_GT(predicted, 0.0);
  EXPECT_NEAR(measured / predicted, 1.0, 0.01) << "measured " << measured << " m³/s, predicted " << predicted;
  // Downhill: the upper end has drained, the lower end holds more than it started with.
  EXPECT_LT(a.depth(g.at(0, 4)), 0.9e-3f);
  EXPECT_GT(a.depth(g.at(63, 4)), 1.1e-3f);
  EXPECT_LE(a.ledger().relative_error(), 1e-6);
}

TEST(BloodAutomaton, APoolInABowlLevelsOut) {
  const auto g = grid(40, 40, kH, [](float x, float y) {
    const float cx = x - 20 * kH, cy = y - 20 * kH;
    return 10.0f * (cx * cx + cy * cy);
  });
  Automaton a(mesh_network(g.xyz, g.tri, kDown, 1e-5f), Params{});
  a.place(g.at(14, 20), 3e-7f);  // 0.3 mL poured on the bowl's side
  for (int s = 0; s < 10000; ++s) a.step();
  // The surface of the pool (elevation + depth) is level where the pool is deep.
  const Network& n = a.network();
  double lo = 1e9, hi = -1e9, deepest = 0;
  int wet = 0;
  for (std::uint32_t i = 0; i < n.cells(); ++i) {
    const double d = a.depth(i);
    deepest = std::max(deepest, d);
    if (d < 1e-3) continue;
    ++wet;
    lo = std::min(lo, n.elevation[i] + d);
    hi = std::max(hi, n.elevation[i] + d);
  }
  ASSERT_GT(wet, 20) << "the pool covers the bottom";
  EXPECT_GT(deepest, 1e-3);
  EXPECT_LT(hi - lo, 0.02 * deepest) << "surface from " << lo << " to " << hi << " m";
  // The deepest point is the bowl's bottom, not where it was poured.
  EXPECT_GT(a.depth(g.at(20, 20)), a.depth(g.at(14, 20)));
}

TEST(BloodAutomaton, BloodCrossesACutThroughTheGrooveWithoutLoss) {
  // Two sheets of tissue down a slope, split by a cut along y between them: no pipe joins their
  // lips. The groove under the cut is a chain of cells 3 mm below the lips, joined to both.
  const float slope = 0.2f;
  const int nx = 20, ny = 10;
  const auto left = grid(nx, ny, kH, [&](float x, float) { return -slope * x; });
  NetworkBuilder b;
  const auto add_sheet = [&](float x0) {
    const auto first = static_cast<std::uint32_t>(b.cells());
    Network sheet = mesh_network(left.xyz, left.tri, kDown, 1e-5f);
    for (std::uint32_t i = 0; i < sheet.cells(); ++i) b.add_cell(sheet.area[i], sheet.elevation[i] - slope * x0, sheet.film[i]);
    for (std::uint32_t i = 0; i < sheet.cells(); ++i)
      for (std::uint32_t k = sheet.first[i]; k < sheet.first[i + 1]; ++k)
        if (i < sheet.to[k]) b.add_pipe(first + i, first + sheet.to[k], sheet.conductance[k] * kH, kH);
    return first;
  };
  const std::uint32_t l0 = add_sheet(0.0f), r0 = add_sheet(nx * kH);
  std::vector<std::uint32_t> groove;
  for (int j = 0; j < ny; ++j) {
    const std::uint32_t lip_l = l0 + left.at(nx - 1, j), lip_r = r0 + left.at(0, j);
    const float rim = -slope * (nx - 0.5f) * kH;
    groove.push_back(b.add_cell(kH * 0.002f, rim - 0.003f, 0.0f));
    b.add_pipe(groove.back(), lip_l, kH, 0.001f);
    b.add_pipe(groove.back(), lip_r, kH, 0.001f);
    if (j > 0) b.add_pipe(groove[static_cast<std::size_t>(j - 1)], groove.back(), 0.002f, kH);
  }
  Automaton a(b.build(), Params{});
  std::vector<float> src(a.network().cells(), 0.0f);
  src[l0 + left.at(2, 5)] = 5e-8f;  // upstream on the left sheet
  a.set_sources(src);
  double right_sheet = 0, in_groove = 0;
  for (int s = 0; s < 8000; ++s) a.step();
  for (int i = 0; i < nx * ny; ++i) right_sheet += a.state().volume[r0 + static_cast<std::uint32_t>(i)];
  for (auto c : groove) in_groove += a.state().volume[c];
  EXPECT_GT(in_groove, 0.5 * 0.003 * 0.002 * kH * ny) << "the groove filled (at least half)";
  EXPECT_GT(right_sheet, 0.05 * a.ledger().sources) << "blood overflowed the groove onto the far side";
  EXPECT_LE(a.ledger().relative_error(), 1e-5);
}

TEST(BloodAutomaton, ThreadsAndSkippedIdleTilesChangeNothing) {
  // One run per thread count (1 to 4, the pool made by the first step and reused), and one on a
  // thread that steps every tile; halfway, every run's network is rebuilt (the mesh changed) and
  // the two-thread run changes its count, as the viz's settings may.
  const auto g = grid(64, 40, kH, [](float x, float y) { return -0.2f * x + 0.05f * std::sin(400.0f * y); });
  constexpr int kRuns = 5;
  const int threads[kRuns] = {1, 2, 3, 4, 1};
  std::vector<Automaton> runs;
  const auto set_rates = [&](Automaton& a) {
    std::vector<float> src(a.network().cells(), 0.0f), sink(a.network().cells(), 0.0f);
    src[g.at(3, 20)] = 3e-8f;
    sink[g.at(4, 20)] = 2.0f;
    a.set_sources(src);
    a.set_sinks(sink);
  };
  for (int variant = 0; variant < kRuns; ++variant) {
    Params p;
    p.skip_idle_tiles = variant != kRuns - 1;
    runs.emplace_back(mesh_network(g.xyz, g.tri, kDown, 2e-5f), p);
    set_rates(runs.back());
  }
  for (int s = 0; s < 1500; ++s) {
    if (s == 750)
      for (auto& r : runs) r.reshape(mesh_network(g.xyz, g.tri, kDown, 2e-5f)), set_rates(r);
    for (int v = 0; v < kRuns; ++v) runs[static_cast<std::size_t>(v)].step(v == 1 && s >= 750 ? 3 : threads[v]);
  }
  EXPECT_LT(runs[0].active_tiles(), runs[0].network().tiles()) << "the blood has not reached every tile";
  EXPECT_GT(runs[0].ledger().sinks, 0.0);
  for (std::size_t v = 1; v < kRuns; ++v) {
    SCOPED_TRACE(v + 1 < kRuns ? std::to_string(threads[v]) + " threads" : std::string("every tile stepped"));
    EXPECT_EQ(runs[0].state().volume, runs[v].state().volume);
    EXPECT_EQ(runs[0].state().born, runs[v].state().born);
    EXPECT_EQ(runs[0].state().flux, runs[v].state().flux);
    EXPECT_EQ(runs[0].ledger().now, runs[v].ledger().now);
    EXPECT_EQ(runs[0].ledger().sources, runs[v].ledger().sources);
    EXPECT_EQ(runs[0].ledger().sinks, runs[v].ledger().sinks);
    if (v + 1 < kRuns) {
      EXPECT_EQ(runs[0].active_tiles(), runs[v].active_tiles());
    }
  }
}

// The automaton's step, written out plainly from the equations (ALGORITHMS.md, the virtual pipes):
// every cell every step, no tiles, nothing skipped. The automaton skips idle tiles, dry cells that
// send nothing, and cells with no flux in or out; none of that may change a bit.
struct PlainPipes {
  const Network& net;
  Params p;
  std::vector<float> volume, born, flux, conc, head;
  double time = 0;

  PlainPipes(const Network& n, Params params) : net(n), p(params) {
    volume.assign(n.cells(), 0.0f), born.assign(n.cells(), 0.0f), conc.assign(n.cells(), 0.0f);
    flux.assign(n.pipes(), 0.0f);
    head.resize(n.cells());
    for (std::size_t i = 0; i < n.cells(); ++i) head[i] = n.elevation[i] + volume[i] / n.area[i];
  }
  void place(std::uint32_t i, float v) {
    volume[i] += v, born[i] += v * static_cast<float>(time);
    head[i] = net.elevation[i] + volume[i] / net.area[i];
  }
  void step(const std::vector<float>& source, const std::vector<float>& sink) {
    const std::size_t n = net.cells();
    const float dt = p.dt, now = static_cast<float>(time);
    for (std::size_t i = 0; i < n; ++i) {
      if (source[i] > 0.0f) {
        const float v = source[i] * dt;
        volume[i] += v, born[i] += v * now;
      }
      if (sink[i] > 0.0f && volume[i] > 0.0f) {
        const float f = std::min(1.0f, sink[i] * dt), v = volume[i] * f;
        volume[i] -= v, born[i] -= born[i] * f;
      }
      head[i] = net.elevation[i] + volume[i] / net.area[i];
    }
    const float keep = std::pow(p.damping, dt);
    for (std::size_t i = 0; i < n; ++i) {
      const float mobile = std::max(0.0f, volume[i] - net.film[i]);
      const float d = mobile / net.area[i] / p.ref_depth, m = std::min(1.0f, d * d);
      float sum = 0.0f;
      for (std::uint32_t k = net.first[i]; k < net.first[i + 1]; ++k) {
        flux[k] = std::max(0.0f, keep * flux[k] + dt * (p.mobility * net.conductance[k]) * m * (head[i] - head[net.to[k]]));
        sum += flux[k];
      }
      if (sum * dt > mobile)
        for (std::uint32_t k = net.first[i]; k < net.first[i + 1]; ++k) flux[k] *= 0.999999f * mobile / (sum * dt);
      conc[i] = volume[i] > 0.0f ? born[i] / volume[i] : 0.0f;
    }
    for (std::size_t i = 0; i < n; ++i) {
      float in = 0.0f, out = 0.0f, born_in = 0.0f;
      for (std::uint32_t k = net.first[i]; k < net.first[i + 1]; ++k) {
        in += flux[net.twin[k]], born_in += flux[net.twin[k]] * conc[net.to[k]];
        out += flux[k];
      }
      if (in == 0.0f && out == 0.0f) continue;
      volume[i] = std::max(volume[i] + dt * in - dt * out, 0.0f);
      born[i] = std::max(born[i] + dt * born_in - dt * out * conc[i], 0.0f);
      head[i] = net.elevation[i] + volume[i] / net.area[i];
    }
    time += p.dt;
  }
};

TEST(BloodAutomaton, TheStepIsThePlainEquationsOverEveryCellBitForBit) {
  // A tilted, rippled sheet mostly dry: a source runs down it past a swab, and a pool placed
  // upslope spreads; 1,500 steps on one and on two threads.
  const auto g = grid(64, 40, kH, [](float x, float y) { return -0.2f * x + 0.05f * std::sin(400.0f * y); });
  const Network net = mesh_network(g.xyz, g.tri, kDown, 2e-5f);
  std::vector<float> src(net.cells(), 0.0f), sink(net.cells(), 0.0f);
  src[g.at(3, 20)] = 3e-8f;
  sink[g.at(30, 21)] = 2.0f;
  for (const int threads : {1, 2}) {
    SCOPED_TRACE(std::to_string(threads) + " thread(s)");
    Automaton a(net, Params{});
    PlainPipes plain(net, Params{});
    a.set_sources(src), a.set_sinks(sink);
    a.place(g.at(10, 8), 4e-8f), plain.place(g.at(10, 8), 4e-8f);
    std::size_t most_active = 0;
    for (int s = 0; s < 1500; ++s) {
      a.step(threads);
      plain.step(src, sink);
      most_active = std::max(most_active, a.active_tiles());
    }
    EXPECT_LT(most_active, a.network().tiles()) << "some tiles stayed idle";
    std::size_t wet = 0;
    for (float v : plain.volume) wet += v > 0.0f ? 1 : 0;
    EXPECT_GT(wet, 20u) << "the blood spread";
    EXPECT_LT(wet, net.cells() / 2) << "most of the sheet stayed dry";
    EXPECT_EQ(a.state().volume, plain.volume);
    EXPECT_EQ(a.state().born, plain.born);
    EXPECT_EQ(a.state().flux, plain.flux);
  }
}

}  // namespace
}  // namespace lancet::blood
