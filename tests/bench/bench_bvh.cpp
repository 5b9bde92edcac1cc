// lancet-bench-bvh: the cost of the surface BVH (host_viz/surface/bvh.hpp) on wavy grids 20 cm
// across of about 10k, 100k and 1M triangles: build, full refit, local refit of 98 faces (a 7 × 7
// cell patch pushed by the tool), faces_within(r = 10 mm) and with r shrunk so the answer holds
// about as many faces at every size, closest_point from within 0.5 mm and 5 mm of the sheet, and
// first_hit of a 6 cm segment through it. Each query runs over random positions (cold caches) and
// along a tool path advancing 0.1 mm a query (how the simulator asks). Queries and local refits
// should stay nearly flat across sizes (log n); faces_within(10 mm) grows with its answer (the grid
// gets finer). Prints one JSON object; per-call median and 99th percentile in ns, build and full
// refit the best of a few runs.
//   lancet-bench-bvh [--queries N]

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <vector>

#include "lancet/shared_model/units.hpp"
#include "surface/bvh.hpp"

namespace {

using namespace lancet;
using surface::MeshView;
using surface::TriangleBvh;

constexpr float kHalf = 0.1f;  // m: the grid spans [-kHalf, kHalf]²

float height(float x, float y) { return 0.01f * std::sin(x / 0.03f) * std::cos(y / 0.02f); }

struct Grid {
  int n = 0;  // cells per side
  std::vector<float> xyz;
  std::vector<std::array<std::uint32_t, 3>> faces;
  [[nodiscard]] MeshView view() const { return {xyz.data(), xyz.size() / 3, faces}; }
  [[nodiscard]] std::uint32_t id(int x, int y) const { return static_cast<std::uint32_t>(y * (n + 1) + x); }
  [[nodiscard]] float coord(int i) const { return -kHalf + 2 * kHalf * static_cast<float>(i) / static_cast<float>(n); }
};

Grid grid(int n) {
  Grid g;
  g.n = n;
  for (int y = 0; y <= n; ++y)
    for (int x = 0; x <= n; ++x) g.xyz.insert(g.xyz.end(), {g.coord(x), g.coord(y), height(g.coord(x), g.coord(y))});
  for (int y = 0; y < n; ++y)
    for (int x = 0; x < n; ++x) {
      g.faces.push_back({g.id(x, y), g.id(x + 1, y), g.id(x + 1, y + 1)});
      g.faces.push_back({g.id(x, y), g.id(x + 1, y + 1), g.id(x, y + 1)});
    }
  return g;
}

struct Stats {
  double p50 = 0, p99 = 0;
};
Stats stats(std::vector<double>& ns) {
  std::sort(ns.begin(), ns.end());
  const auto q = [&](double p) { return ns[std::min(ns.size() - 1, static_cast<std::size_t>(p * static_cast<double>(ns.size())))]; };
  return {q(0.5), q(0.99)};
}

template <class F>
double best_of(int runs, F&& f) {
  double best = 1e300;
  for (int i = 0; i < runs; ++i) {
    const std::int64_t t0 = monotonic_ns();
    f();
    best = std::min(best, static_cast<double>(monotonic_ns() - t0));
  }
  return best;
}

// Times each call of f(i) for i in [0, n).
template <class F>
Stats per_call(int n, F&& f) {
  std::vector<double> ns(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) {
    const std::int64_t t0 = monotonic_ns();
    f(i);
    ns[static_cast<std::size_t>(i)] = static_cast<double>(monotonic_ns() - t0);
  }
  return stats(ns);
}

volatile double g_sink = 0;  // keeps results alive

void run(int n_cells, int queries, bool first) {
  Grid g = grid(n_cells);
  const MeshView m = g.view();
  const std::size_t n_faces = g.faces.size();
  TriangleBvh bvh;
  // The whole tree at once (lazy = false), then the build that SurfaceModel uses: on a large mesh
  // only the top down to the blocks, whose nodes the queries make as they reach them.
  const double build_eager_ns = best_of(n_faces > 500'000 ? 2 : 3, [&] { bvh.build(m, true, false); });
  const double build_ns = best_of(n_faces > 500'000 ? 2 : 3, [&] { bvh.build(m); });
  if (!bvh.check(m)) std::fprintf(stderr, "error: check() failed after build\n");

  // Full refit after every vertex moved.
  for (std::size_t i = 2; i < g.xyz.size(); i += 3) g.xyz[i] += 1e-4f * std::sin(static_cast<float>(i));
  const double refit_ns = best_of(3, [&] { bvh.refit(m); });

  std::mt19937 rng(12345);
  std::uniform_real_distribution<float> u(-0.09f, 0.09f), unit(0.0f, 1.0f);


  // Two kinds of query sequence: random positions (cold caches: every query a new part of the
  // tree) and a tool path, a Lissajous curve over the sheet advancing 0.1 mm per query (a haptic
  // tick at 10 cm/s), which is how the simulator asks.
  const auto path_xy = [](int i) {
    const float s = 1e-4f * static_cast<float>(i) / 0.08f;  // radians along the curve, ≈ 0.1 mm a step
    return std::array<float, 2>{0.08f * std::sin(1.3f * s), 0.08f * std::sin(0.7f * s + 0.5f)};
  };
  std::vector<std::array<float, 2>> random_xy(static_cast<std::size_t>(queries)), tool_xy(random_xy.size());
  std::vector<float> offsets(random_xy.size());
  for (std::size_t i = 0; i < random_xy.size(); ++i) {
    random_xy[i] = {u(rng), u(rng)};
    tool_xy[i] = path_xy(static_cast<int>(i));
    offsets[i] = unit(rng) - 0.5f;  // in (−0.5, 0.5)
  }
  const std::array<const std::vector<std::array<float, 2>>*, 2> sequences{&random_xy, &tool_xy};

  // Local refit: a 7 × 7 cell patch (98 faces) under the point, whose 6 × 6 inner vertices the
  // tool pushes (moving the vertices is not timed).
  std::array<Stats, 2> local_refit;
  std::vector<std::uint32_t> patch;
  patch.reserve(98);
  for (std::size_t k = 0; k < 2; ++k) {
    std::vector<double> ns;
    ns.reserve(static_cast<std::size_t>(queries));
    for (int q = 0; q < queries; ++q) {
      const auto xy = (*sequences[k])[static_cast<std::size_t>(q)];
      const auto cell_of = [&](float c) {
        return std::clamp(static_cast<int>((c + kHalf) / (2 * kHalf) * static_cast<float>(n_cells)) - 3, 0, n_cells - 7);
      };
      const int x0 = cell_of(xy[0]), y0 = cell_of(xy[1]);
      const float depth = 0.002f * offsets[static_cast<std::size_t>(q)];
      patch.clear();
      for (int y = y0; y < y0 + 7; ++y)
        for (int x = x0; x < x0 + 7; ++x) {
          const auto cell = static_cast<std::uint32_t>(2 * (y * n_cells + x));
          patch.push_back(cell);
          patch.push_back(cell + 1);
        }
      for (int y = y0 + 1; y < y0 + 7; ++y)
        for (int x = x0 + 1; x < x0 + 7; ++x) {
          const float dx = static_cast<float>(x - x0) - 3.5f, dy = static_cast<float>(y - y0) - 3.5f;
          g.xyz[3 * g.id(x, y) + 2] += depth * std::exp(-(dx * dx + dy * dy) / 4.0f);
        }
      const std::int64_t t0 = monotonic_ns();
      bvh.refit_faces(m, patch);
      ns.push_back(static_cast<double>(monotonic_ns() - t0));
    }
    local_refit[k] = stats(ns);
  }
  if (!bvh.check(m)) std::fprintf(stderr, "error: check() failed after local refits\n");

  // The point of sequence k, query i, `off` metres off the sheet (times a random factor in ±0.5).
  const auto point = [&](std::size_t k, int i, float off) {
    const auto xy = (*sequences[k])[static_cast<std::size_t>(i)];
    return Vec3f{xy[0], xy[1], height(xy[0], xy[1]) + off * offsets[static_cast<std::size_t>(i)]};
  };
  std::vector<std::uint32_t> within;
  within.reserve(n_faces);
  // r for about as many faces as 10 mm finds on the 10k grid.
  const float r_const = 0.01f * 71.0f / static_cast<float>(n_cells);
  std::array<Stats, 2> within_10mm, within_const, closest_near, closest_far, first_hit;
  std::array<double, 2> found_10mm{}, found_const{};
  int misses = 0;
  for (std::size_t k = 0; k < 2; ++k) {
    within_10mm[k] = per_call(queries, [&](int i) {
      bvh.faces_within(m, point(k, i, 0.0f), 0.01f, within);
      found_10mm[k] += static_cast<double>(within.size());
    });
    within_const[k] = per_call(queries, [&](int i) {
      bvh.faces_within(m, point(k, i, 0.0f), r_const, within);
      found_const[k] += static_cast<double>(within.size());
    });
    closest_near[k] = per_call(queries, [&](int i) {
      const auto h = bvh.closest_point(m, point(k, i, 0.001f));
      g_sink = g_sink + (h ? h->distance : 0.0f);
    });
    closest_far[k] = per_call(queries, [&](int i) {
      const auto h = bvh.closest_point(m, point(k, i, 0.01f));
      g_sink = g_sink + (h ? h->distance : 0.0f);
    });
    first_hit[k] = per_call(queries, [&](int i) {
      const Vec3f p = point(k, i, 0.0f);
      misses += !bvh.first_hit(m, {p.x, p.y, 0.03f}, {p.x + 0.002f, p.y - 0.001f, -0.03f}).has_value();
    });
  }
  if (misses != 0) std::fprintf(stderr, "warning: %d segments missed the sheet\n", misses);

  // "name": {random and path percentiles[, extra]}
  const auto print = [](const char* name, const std::array<Stats, 2>& s, const char* extra, bool last = false) {
    std::printf("     \"%s\": {\"random_p50_ns\": %.0f, \"random_p99_ns\": %.0f, \"path_p50_ns\": %.0f, \"path_p99_ns\": %.0f%s}%s\n",
                name, s[0].p50, s[0].p99, s[1].p50, s[1].p99, extra, last ? "}" : ",");
  };
  const double q = queries;
  char extra[96];
  std::printf("%s{\"triangles\": %zu, \"nodes\": %zu, \"depth\": %zu, \"bvh_bytes\": %zu, \"build_ms\": %.1f, \"build_eager_ms\": %.1f, "
              "\"blocks\": %zu, \"refit_all_us\": %.1f,\n",
              first ? "    " : "   ,", n_faces, bvh.node_count(), bvh.depth(), bvh.size_bytes(), build_ns * 1e-6, build_eager_ns * 1e-6,
              bvh.block_count(), refit_ns * 1e-3);
  print("refit_98_faces", local_refit, "");
  std::snprintf(extra, sizeof extra, ", \"mean_faces\": %.1f", found_10mm[0] / q);
  print("faces_within_10mm", within_10mm, extra);
  std::snprintf(extra, sizeof extra, ", \"r_mm\": %.3f, \"mean_faces\": %.1f", 1e3 * r_const, found_const[0] / q);
  print("faces_within_const_count", within_const, extra);
  print("closest_point_within_0.5mm", closest_near, "");
  print("closest_point_within_5mm", closest_far, "");
  print("first_hit_6cm_segment", first_hit, "", true);
}

}  // namespace

int main(int argc, char** argv) {
  int queries = 5000;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--queries") == 0 && i + 1 < argc) {
      queries = std::max(100, std::atoi(argv[++i]));
    } else {
      std::fprintf(stderr, "usage: lancet-bench-bvh [--queries N]\n");
      return 2;
    }
  }
  std::printf("{\n  \"mesh\": \"wavy grid 20 cm x 20 cm, amplitude 1 cm\",\n  \"queries\": %d,\n  \"results\": [\n", queries);
  bool first = true;
  for (int n_cells : {71, 224, 707}) {  // 10 082, 100 352 and 999 698 triangles
    run(n_cells, queries, first);
    first = false;
  }
  std::printf("  ]\n}\n");
  return 0;
}
