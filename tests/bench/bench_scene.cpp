// lancet-bench-scene: one lancet-viz frame's scene update, as the viz runs it: the 16 ToolSamples
// of 16 ms at 1 kHz drained from the shared ring (checked), applied to the TissueScene (dent,
// rupture, the cut growing by progress events, the cut reaching into the volume when the blade
// leaves, the retractor's pull opening the incision and its ChainMail groove), the TissuePatch
// exported around the tool with the voxel brick and written to the segment; then, apart, the
// mesh for drawing (surface and groove walls) that follows a change of shape. On the phantom's skin and on a
// 1M-triangle sheet. The target: p99 < 4 ms for the update (docs/PERFORMANCE.md). Prints one JSON object.
//   lancet-bench-scene [--quick] [--patch-radius-mm R]
// R: the patch's radius (default the TissueScene's, 30 mm; lancet-viz's is 40 mm). With LANCET_BENCH_SCENE_PULLS
// set, each pull frame's µs go to stderr.

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "app/viz_session.hpp"
#include "tissue/tissue_scene.hpp"

namespace {

using namespace lancet;
using Clock = std::chrono::steady_clock;

double us_since(Clock::time_point t0) { return std::chrono::duration<double, std::micro>(Clock::now() - t0).count(); }

struct Pct {
  double p50 = 0, p99 = 0, max = 0;
};
Pct percentiles(std::vector<double> v) {
  if (v.empty()) return {};
  std::sort(v.begin(), v.end());
  const auto at = [&](double q) { return v[static_cast<std::size_t>(q * static_cast<double>(v.size() - 1))]; };
  return {at(0.5), at(0.99), v.back()};
}

struct Tissue {
  std::string name;
  std::unique_ptr<tissue::TissueScene> scene;
  std::function<double(double, double)> height;  ///< surface height at (x, y), m
};

Tissue phantom_tissue(double patch_radius) {
  Tissue t;
  t.name = "phantom skin";
  tissue::SceneDescription d;
  d.patch.radius = patch_radius;
  t.scene = std::move(tissue::TissueScene::create(std::move(d)).value());
  surface::TriangleMesh mesh;
  t.scene->surface().to_triangle_mesh(mesh);
  // The skin's top along x near y = 0 (where the tool works): the highest vertex in each 1 mm
  // slab of x within 2 mm of y = 0.
  auto top_by_x = std::make_shared<std::vector<double>>(400, -1.0);  // x from −0.2 m in 1 mm slabs
  for (const auto& v : mesh.vertices) {
    const auto slab = static_cast<long>(std::floor((v.x + 0.2) / 0.001));
    if (slab >= 0 && slab < 400 && std::abs(v.y) < 0.002) (*top_by_x)[static_cast<std::size_t>(slab)] =
        std::max((*top_by_x)[static_cast<std::size_t>(slab)], static_cast<double>(v.z));
  }
  t.height = [top_by_x](double x, double) {
    const auto slab = static_cast<long>(std::floor((x + 0.2) / 0.001));
    return slab >= 0 && slab < 400 ? (*top_by_x)[static_cast<std::size_t>(slab)] : -1.0;
  };
  return t;
}

Tissue sheet_tissue(double patch_radius) {
  Tissue t;
  t.name = "sheet 1M triangles";
  tissue::SceneDescription d;
  d.patch.radius = patch_radius;
  d.source = tissue::SceneSource::kBlock;
  d.block.cells = 707;  // 2 · 707² ≈ 1.0M triangles of 1 mm cells, 0.71 m across
  d.block.half_extent = 0.0005 * d.block.cells;
  const surface::TissueBlockParams p = d.block;
  t.scene = std::move(tissue::TissueScene::create(std::move(d)).value());
  t.height = [p](double x, double y) { return surface::tissue_block_height(p, x, y); };
  return t;
}

}  // namespace

int main(int argc, char** argv) {
  bool quick = false;
  double patch_radius = tissue::PatchExportParams{}.radius;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--quick") == 0) {
      quick = true;
    } else if (std::strcmp(argv[i], "--patch-radius-mm") == 0 && i + 1 < argc) {
      patch_radius = std::atof(argv[++i]) * 1e-3;
    } else {
      std::fprintf(stderr, "usage: lancet-bench-scene [--quick] [--patch-radius-mm R]\n");
      return 2;
    }
  }
  const int press_frames = quick ? 30 : 60, cut_frames = quick ? 60 : 150, pull_frames = quick ? 30 : 60;
  constexpr int kSamplesPerFrame = 16;
  std::printf("{\n  \"samples_per_frame\": %d,\n  \"frames\": {\"press\": %d, \"cut\": %d, \"pull\": %d},\n  \"tissues\": [\n",
              kSamplesPerFrame, press_frames, cut_frames, pull_frames);
  Tissue tissues[2] = {phantom_tissue(patch_radius), sheet_tissue(patch_radius)};
  for (int n = 0; n < 2; ++n) {
    Tissue& tissue = tissues[n];
    tissue::TissueScene& scene = *tissue.scene;
    const std::string shm = "/lancet-bench-scene-" + std::to_string(getpid());
    auto channel = SharedChannel::create(shm, {});
    if (!channel) {
      std::fprintf(stderr, "lancet-bench-scene: %s\n", channel.error().message.c_str());
      return 1;
    }
    SharedState& s = channel.value().state();
    viz::VizSessionParams vp;
    vp.shm_name = shm;
    viz::VizSession session(vp);
    const auto apply = [&](std::span<const ToolSample> batch) { (void)scene.apply(batch); };
    bool brick = false;
    std::vector<double> export_us;
    std::uint64_t patch_sum = 0, patch_max = 0;
    const auto fill = [&](Vec3 tool, TissuePatch& patch) {
      const std::int64_t t0 = monotonic_ns();
      (void)scene.export_patch(tool, patch);
      export_us.push_back(static_cast<double>(monotonic_ns() - t0) * 1e-3);
      brick = brick || patch.brick.valid != 0;
      patch_sum += patch.n_triangles;
      patch_max = std::max<std::uint64_t>(patch_max, patch.n_triangles);
    };
    // One frame of the link around the scene, as the live viz runs it (without the blood): the
    // samples drained and applied, the patch filled around the newest tool position, published.
    const auto link_frame = [&](std::int64_t t) {
      apply(session.drain(t));
      std::array<const TissuePatch*, kHandCount> out{};
      if (session.attached() && session.has_sample()) {
        TissuePatch* p = &session.patch_buffer(Hand::kRight);
        p->n_triangles = 0;
        p->brick.valid = 0;
        fill(session.latest().tool.position, *p);
        p->seq = session.frames(), p->t_ns = t, p->samples_applied = session.samples_applied();
        out[0] = p;
      }
      session.publish(out, t);
    };
    std::int64_t now = monotonic_ns();
    s.rt_heartbeat.beat(now, getpid());
    link_frame(now);  // attach
    const auto surface_z = [&](double x, double y) { return tissue.height(x, y); };
    std::uint64_t seq = 0;
    std::vector<double> press_us, cut_us, pull_us, draw_us;
    surface::TriangleMesh draw;
    std::uint64_t shown = scene.revision();
    const double x0 = -0.02, speed = 0.02;  // m, m/s along x
    const double z0 = surface_z(x0, 0.001);
    const int frames = press_frames + cut_frames + pull_frames;
    for (int f = 0; f < frames; ++f) {
      for (int k = 0; k < kSamplesPerFrame; ++k) {
        ToolSample t{};
        t.seq = ++seq;
        now += 1'000'000;
        t.t_ns = now;
        const double time = static_cast<double>(seq) * 1e-3;
        if (f < press_frames) {
          t.mode = ToolMode::kScalpel;
          t.stage = Stage::kDeform;
          t.proxy.position = {x0, 0.001, z0};
          t.tool.position = {x0, 0.001, z0 - 0.003 * std::min(1.0, time / 0.5)};
        } else if (f < press_frames + cut_frames) {
          const double x = x0 + speed * (time - press_frames * kSamplesPerFrame * 1e-3);
          t.mode = ToolMode::kScalpel;
          const bool first = f == press_frames && k == 0;
          t.stage = first ? Stage::kRupture : Stage::kCutting;
          t.proxy.position = {x, 0.001, surface_z(x, 0.001) - 0.003};
          t.tool.position = t.proxy.position;
          if (first) {
            t.events = event::kRupture;
            t.payload.position = {x, 0.001, surface_z(x, 0.001)};
          } else if (seq % 25 == 0) {  // 0.5 mm at 20 mm/s
            t.events = event::kCutProgress;
            t.payload.position = t.proxy.position;
          }
        } else {
          t.mode = ToolMode::kRetractor;
          t.stage = Stage::kPulling;
          t.proxy.position = {0.0, 0.004, z0};
          t.tool.position = t.proxy.position;
          // lancet-rt reports a pull every 0.5 mm of hand travel: here every 25 ticks (20 mm/s).
          if (seq % 25 == 0) {
            t.events = event::kPull;
            t.payload.magnitude = std::min(0.012, 0.0001 * (f - press_frames - cut_frames));
          }
        }
        (void)s.samples.try_push(t);
      }
      s.rt_heartbeat.beat(now, getpid());
      const auto t0 = Clock::now();
      link_frame(now);
      const double us = us_since(t0);
      (f < press_frames ? press_us : f < press_frames + cut_frames ? cut_us : pull_us).push_back(us);
      if (scene.revision() != shown) {
        shown = scene.revision();
        const auto t1 = Clock::now();
        scene.draw_mesh(draw);
        draw_us.push_back(us_since(t1));
      }
    }
    if (std::getenv("LANCET_BENCH_SCENE_PULLS") != nullptr)
      for (double u : pull_us) std::fprintf(stderr, "%.0f ", u);
    const auto pr = percentiles(press_us), cu = percentiles(cut_us), pu = percentiles(pull_us), dr = percentiles(draw_us);
    std::vector<double> all = press_us;
    all.insert(all.end(), cut_us.begin(), cut_us.end());
    all.insert(all.end(), pull_us.begin(), pull_us.end());
    const auto al = percentiles(all);
    const auto ex = percentiles(export_us);
    const auto grooves = scene.grooves();
    std::printf("    {\"tissue\": \"%s\", \"triangles\": %zu, \"brick\": %s, \"cuts\": %zu, \"groove_width_mm\": %.2f,"
                " \"groove_depth_mm\": %.2f, \"groove_conflicts\": %llu,\n"
                "     \"update_us\": {\"all\": {\"p50\": %.0f, \"p99\": %.0f, \"max\": %.0f}, \"press\": {\"p50\": %.0f, \"p99\": %.0f},"
                " \"cut\": {\"p50\": %.0f, \"p99\": %.0f}, \"pull\": {\"p50\": %.0f, \"p99\": %.0f, \"first\": %.0f, \"max_after_first\": %.0f}},\n"
                "     \"mesh_copy_for_drawing_us\": {\"p50\": %.0f, \"p99\": %.0f, \"count\": %zu},\n"
                "     \"patch\": {\"radius_mm\": %.0f, \"triangles_mean\": %.0f, \"triangles_max\": %llu, \"export_us_p50\": %.0f, \"export_us_p99\": %.0f}}%s\n",
                tissue.name.c_str(), scene.surface().n_faces(), brick ? "true" : "false", scene.surface().cuts().size(),
                grooves.empty() ? 0.0 : grooves[0].top_gap * 1e3, grooves.empty() ? 0.0 : grooves[0].depth * 1e3,
                grooves.empty() ? 0ull : static_cast<unsigned long long>(grooves[0].conflicts), al.p50,
                al.p99, al.max, pr.p50, pr.p99, cu.p50, cu.p99, pu.p50, pu.p99, pull_us.empty() ? 0.0 : pull_us.front(),
                pull_us.size() < 2 ? 0.0 : *std::max_element(pull_us.begin() + 1, pull_us.end()), dr.p50, dr.p99, draw_us.size(),
                patch_radius * 1e3, export_us.empty() ? 0.0 : static_cast<double>(patch_sum) / static_cast<double>(export_us.size()),
                static_cast<unsigned long long>(patch_max), ex.p50, ex.p99, n == 0 ? "," : "");
  }
  std::printf("  ]\n}\n");
  return 0;
}
