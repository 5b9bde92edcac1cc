// lancet-bench-haptics: the cost of one haptic tick (proxy + friction + stage machine + safety)
// against TissuePatches of 64, 256 and 1024 triangles, with the tool sliding in contact (probe)
// and cutting (scalpel). Prints one JSON object: p50, p90, p99, max in ns per tick.
//   lancet-bench-haptics [--ticks N]

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "haptics/haptic_step.hpp"
#include "lancet/shared_model/units.hpp"

namespace {

using namespace lancet;

// A flat sheet of n triangles (nx × ny cells × 2) over 4 cm × 4 cm.
std::unique_ptr<TissuePatch> sheet(int n) {
  auto p = std::make_unique<TissuePatch>();
  const int cells = n / 2;
  int nx = static_cast<int>(std::sqrt(cells));
  while (cells % nx != 0) --nx;
  const int ny = cells / nx;
  const auto z = [](float, float) { return 0.0f; };  // flat: the scalpel stays in its cut
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < nx; ++i) {
      const float x0 = -0.02f + 0.04f * static_cast<float>(i) / static_cast<float>(nx);
      const float x1 = -0.02f + 0.04f * static_cast<float>(i + 1) / static_cast<float>(nx);
      const float y0 = -0.02f + 0.04f * static_cast<float>(j) / static_cast<float>(ny);
      const float y1 = -0.02f + 0.04f * static_cast<float>(j + 1) / static_cast<float>(ny);
      const Vec3f a{x0, y0, z(x0, y0)}, b{x1, y0, z(x1, y0)}, c{x1, y1, z(x1, y1)}, d{x0, y1, z(x0, y1)};
      p->triangles[p->n_triangles++] = {{a, b, c}, 1, 0};
      p->triangles[p->n_triangles++] = {{a, c, d}, 1, 0};
    }
  return p;
}

struct Stats {
  double p50, p90, p99, max;
};

Stats measure(int triangles, ToolMode mode, int ticks) {
  const auto patch = sheet(triangles);
  const haptics::HapticModel model = haptics::HapticModel::defaults();
  auto data = std::make_unique<haptics::HapticData>();
  haptics::HapticInput in;
  in.patch = patch.get();
  in.mode = mode;
  haptics::HapticOutput out;
  std::vector<double> ns(static_cast<std::size_t>(ticks));
  for (int i = -1000; i < ticks; ++i) {  // 1000 warm-up ticks
    const double t = i * 0.001;
    // Probe: 2 mm into the sheet, sliding. Scalpel: 5 mm in, past the yield force: cutting.
    // During warm-up the tool comes down from 5 mm above (a proxy that starts under the one-sided
    // sheet would rightly stay free).
    const double depth = mode == ToolMode::kScalpel ? -0.005 : -0.002;
    const double z = i < -500 ? 0.005 + (depth - 0.005) * (i + 1000) / 500.0 : depth;
    in.device = Vec3{0.012 * std::sin(t * 1.3), 0.012 * std::cos(t * 0.7), z};
    in.velocity = Vec3{0.012 * 1.3 * std::cos(t * 1.3), -0.012 * 0.7 * std::sin(t * 0.7), 0};
    const std::int64_t t0 = monotonic_ns();
    haptics::haptic_step(model, *data, in, out);
    const std::int64_t t1 = monotonic_ns();
    if (i >= 0) ns[static_cast<std::size_t>(i)] = static_cast<double>(t1 - t0);
  }
  if (mode == ToolMode::kScalpel && data->stage != Stage::kCutting) std::fprintf(stderr, "warning: the scalpel is not cutting\n");
  std::sort(ns.begin(), ns.end());
  const auto q = [&](double p) { return ns[std::min(ns.size() - 1, static_cast<std::size_t>(p * static_cast<double>(ns.size())))]; };
  return {q(0.5), q(0.9), q(0.99), ns.back()};
}

}  // namespace

int main(int argc, char** argv) {
  int ticks = 200'000;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--ticks") == 0 && i + 1 < argc) {
      ticks = std::max(1000, std::atoi(argv[++i]));
    } else {
      std::fprintf(stderr, "usage: lancet-bench-haptics [--ticks N]\n");
      return 2;
    }
  }
  std::printf("{\n  \"ticks\": %d,\n  \"results\": [\n", ticks);
  // Which stage the scalpel run ends in is part of the result: it must be cutting.
  bool first = true;
  for (ToolMode mode : {ToolMode::kProbe, ToolMode::kScalpel}) {
    for (int n : {64, 256, 1024}) {
      const Stats s = measure(n, mode, ticks);
      std::printf("%s    {\"triangles\": %d, \"mode\": \"%s\", \"p50_ns\": %.0f, \"p90_ns\": %.0f, \"p99_ns\": %.0f, \"max_ns\": %.0f}",
                  first ? "" : ",\n", n, mode == ToolMode::kProbe ? "probe (sliding in contact)" : "scalpel (cutting)", s.p50,
                  s.p90, s.p99, s.max);
      first = false;
    }
  }
  std::printf("\n  ]\n}\n");
  return 0;
}
