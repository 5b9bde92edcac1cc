// lancet-bench-surface: what one tool step costs on the surface model against mesh size: the
// progressive cut step, the TissuePatch export and the deformation update, on sheets of about
// 10k, 100k and 1M triangles. The sheets share one triangle size (about 1 mm edges) and grow in
// area, so a flat cost means the operations are local. Prints one JSON object.
//   lancet-bench-surface [--quick]

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <vector>

#include "tissue/patch_export.hpp"
#include "surface/triangle_mesh.hpp"
#include "surface/surface_model.hpp"

namespace {

using namespace lancet;
using Clock = std::chrono::steady_clock;

double us_since(Clock::time_point t0) { return std::chrono::duration<double, std::micro>(Clock::now() - t0).count(); }

struct Pct {
  double p50, p99, max;
};
Pct percentiles(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const auto at = [&](double q) { return v[static_cast<std::size_t>(q * static_cast<double>(v.size() - 1))]; };
  return {at(0.5), at(0.99), v.back()};
}

}  // namespace

int main(int argc, char** argv) {
  const bool quick = argc > 1 && std::strcmp(argv[1], "--quick") == 0;
  const int steps = quick ? 60 : 120;  // at most 6 cm: the smallest sheet is 7 cm across
  const double step_len = 0.0005;  // 0.5 mm of tool travel between samples (a frame at 3 cm/s)
  std::printf("{\n  \"step_m\": %.4f,\n  \"steps\": %d,\n  \"sizes\": [\n", step_len, steps);
  const int cells_list[3] = {71, 224, 707};
  for (int n = 0; n < 3; ++n) {
    const int cells = cells_list[n];
    surface::TissueBlockParams p;
    p.cells = cells;
    p.half_extent = 0.0005 * cells;  // 1 mm cells
    p.wave_amplitude = 0.002;
    p.wave_length = 0.02;
    const auto t_build = Clock::now();
    const auto mesh = surface::make_tissue_block(p);
    auto model = std::move(surface::SurfaceModel::create(mesh.vertices, mesh.triangles, mesh.material).value());
    const double build_ms = us_since(t_build) / 1e3;
    const auto h = [&](double x, double y) { return surface::tissue_block_height(p, x, y); };
    std::vector<double> cut_us, export_us, deform_us;
    std::size_t crossings = 0;
    auto patch = std::make_unique<TissuePatch>();
    tissue::PatchExportScratch scratch;
    tissue::PatchExportParams params;
    params.radius = 0.01;
    // A wavy cut through the middle, starting 3 cm left of centre.
    double x = -0.03, y = 0.0003;
    model->begin_cut({x, y, h(x, y)});
    for (int i = 0; i < steps; ++i) {
      x += step_len;
      y = 0.0003 + 0.004 * std::sin(x * 200);
      const Vec3 tool{x, y, h(x, y)};
      auto t0 = Clock::now();
      crossings += model->cut_to(tool).crossings;
      cut_us.push_back(us_since(t0));
      t0 = Clock::now();
      (void)tissue::export_patch(*model, tool, params, scratch, *patch);
      export_us.push_back(us_since(t0));
      // A dent beside the cut (the other hand's probe), then its return.
      t0 = Clock::now();
      model->update_contact(surface::Contact{Vec3{x, y + 0.01, h(x, y + 0.01)}, {0, 0, -1}, 0.002}, 0.016);
      deform_us.push_back(us_since(t0));
    }
    model->end_cut();
    const Pct c = percentiles(cut_us), e = percentiles(export_us), d = percentiles(deform_us);
    std::printf("    {\"triangles\": %zu, \"build_ms\": %.1f, \"crossings_per_step\": %.2f, \"patch_triangles\": %u,\n", model->n_faces(), build_ms,
                static_cast<double>(crossings) / steps, patch->n_triangles);
    std::printf("     \"cut_step_us\": {\"p50\": %.1f, \"p99\": %.1f, \"max\": %.1f},\n", c.p50, c.p99, c.max);
    std::printf("     \"patch_export_us\": {\"p50\": %.1f, \"p99\": %.1f, \"max\": %.1f},\n", e.p50, e.p99, e.max);
    std::printf("     \"deform_update_us\": {\"p50\": %.1f, \"p99\": %.1f, \"max\": %.1f}}%s\n", d.p50, d.p99, d.max, n < 2 ? "," : "");
  }
  std::printf("  ]\n}\n");
  return 0;
}
