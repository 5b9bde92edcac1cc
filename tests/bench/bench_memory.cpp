// lancet-bench-memory: what lancet-viz's simulation and drawing hold, per training scenario. Each
// scenario runs in a process of its own (so that its peak is its own) through the stages the viz
// goes through, and after each stage the process's resident set (VmRSS), its peak so far (VmHWM)
// and the heap in use (glibc's mallinfo2: bytes handed out, arenas and mmapped blocks) are read:
//   start     nothing built yet (the libraries are loaded)
//   scene     sim::SceneSim::create: the tissue scene (volume, labels, surface, ChainMail ids), its
//             blood, the task's monitor, as lancet-viz builds them
//   worked    a scripted hand, as lancet-rt's samples would drive it, 16 samples a frame: an
//             incision (press, the cut along the task's line, the retractor's pull) or drilling
//             in the task's window (then the probe, so that the felt bone surface follows);
//             the patch exported and the blood advanced every frame, the mesh for drawing made
//             whenever it changed
//   gl_mesh   a headless GL context, the SceneRenderer and 20 frames (--quick: 5) of the mesh
//             view at 1280x720 with the patch's wireframe, each ended by Window::swap_and_poll as
//             lancet-viz ends its frames
//   gl_volume the composite view: TissueScene::render_volume() and the ray caster's texture, the
//             same number of frames
// Scenarios: skin_incision, bone_drilling (the built-in phantom) and ct_incision on VTK's headsq
// CT when ../shared/data/volumes holds it (or --volume PATH). Prints one JSON object.
// Numbers depend on the allocator and the GL driver (llvmpipe here): a benchmark, never a test.
// --scenario NAME runs that one alone, in this process (for heaptrack or massif).
//   lancet-bench-memory [--quick] [--volume PATH] [--scenario NAME]

#include <malloc.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "record/replay.hpp"
#include "render/scene_renderer.hpp"
#include "render/volume_raycaster.hpp"
#include "render/window.hpp"
#include "tissue/scripted_sample.hpp"
#include "volume/raycast.hpp"

#ifndef LANCET_SOURCE_DIR
#define LANCET_SOURCE_DIR "."
#endif

namespace {

using namespace lancet;

constexpr int kSamplesPerFrame = 16;
constexpr double kMiB = 1024.0 * 1024.0;

// VmRSS and VmHWM of this process (MiB).
void read_status(double& rss, double& hwm) {
  rss = hwm = -1;
  std::ifstream f("/proc/self/status");
  std::string line;
  while (std::getline(f, line)) {
    if (line.rfind("VmRSS:", 0) == 0) rss = std::stod(line.substr(6)) / 1024.0;
    if (line.rfind("VmHWM:", 0) == 0) hwm = std::stod(line.substr(6)) / 1024.0;
  }
}

struct Stages {
  std::string json;
  void mark(const char* stage) {
    double rss = 0, hwm = 0;
    read_status(rss, hwm);
    const struct mallinfo2 mi = mallinfo2();
    const double heap = static_cast<double>(mi.uordblks + mi.hblkhd) / kMiB;
    char buf[200];
    std::snprintf(buf, sizeof buf, "%s\n        {\"stage\": \"%s\", \"rss_mib\": %.1f, \"hwm_mib\": %.1f, \"heap_mib\": %.1f}",
                  json.empty() ? "" : ",", stage, rss, hwm, heap);
    json += buf;
    std::fprintf(stderr, "lancet-bench-memory:   %-9s rss %7.1f MiB, peak %7.1f MiB, heap %7.1f MiB\n", stage, rss, hwm, heap);
  }
};

std::string read_file(const std::string& path) {
  std::ifstream f(path);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

// One frame of the viz's simulation: the frame function (the batch applied, the blood advanced,
// the patch exported around the newest proxy position), the drawn mesh remade when it changed.
struct Driver final : sim::FrameIo {
  explicit Driver(sim::SceneSim& s) : sim(s) {}
  sim::SceneSim& sim;
  std::unique_ptr<TissuePatch> patch = std::make_unique<TissuePatch>();
  surface::TriangleMesh mesh;
  std::uint64_t shown = ~std::uint64_t{0};
  std::uint64_t seq = 0;
  std::int64_t now = 1'000'000'000;

  const std::vector<ToolSample>* batch_ = nullptr;

  Result<sim::FrameBatch> drain() override {
    sim::FrameBatch b;
    b.samples = *batch_;
    b.blood_dt = 1e-3 * kSamplesPerFrame;
    if (!batch_->empty()) b.patches[0] = {patch.get(), batch_->back().proxy.position, {}};
    return b;
  }
  void publish(const std::array<const TissuePatch*, kHandCount>&) override {}

  void frame(std::vector<ToolSample>& batch) {
    batch_ = &batch;
    (void)sim::run_frame(sim, *this);
    if (sim.scene().revision() != shown) {
      shown = sim.scene().revision();
      sim.scene().draw_mesh(mesh);
    }
    batch.clear();
  }
  ToolSample sample(ToolMode mode, Stage stage, Vec3 tool, Vec3 proxy) {
    now += 1'000'000;
    ToolSample t = tissue::scripted_sample(++seq, now, mode, stage, proxy, tool, 0);
    t.reset_mode = kNoReset;
    return t;
  }
};

// Press, cut along the task's line at 20 mm/s (a progress event every 0.5 mm), then pull the
// incision open to 8 mm with the retractor.
void incise(Driver& d, const scenario::IncisionTask& task, int pull_frames) {
  const tissue::TissueScene& scene = d.sim.scene();
  const Vec3 a = task.line.front(), b = task.line.back();
  const auto on_surface = [&](double x, double y) {
    const auto p = scene.surface_below(x, y);
    return p ? *p : Vec3{x, y, 0.0};
  };
  std::vector<ToolSample> batch;
  const Vec3 start = on_surface(a.x, a.y);
  for (int f = 0; f < 30; ++f) {
    for (int k = 0; k < kSamplesPerFrame; ++k) {
      const double depth = 0.003 * std::min(1.0, (f * kSamplesPerFrame + k) / 500.0);
      batch.push_back(d.sample(ToolMode::kScalpel, Stage::kDeform, start - Vec3{0, 0, depth}, start));
    }
    d.frame(batch);
  }
  const double length = std::hypot(b.x - a.x, b.y - a.y);
  const int ticks = static_cast<int>(length / 0.02 * 1000.0);  // at 20 mm/s
  for (int tick = 0; tick <= ticks; ++tick) {
    const double s = static_cast<double>(tick) / ticks;
    const Vec3 p = on_surface(a.x + s * (b.x - a.x), a.y + s * (b.y - a.y)) - Vec3{0, 0, 0.003};
    ToolSample t = d.sample(ToolMode::kScalpel, tick == 0 ? Stage::kRupture : Stage::kCutting, p, p);
    if (tick == 0) {
      t.events = event::kRupture;
      t.payload.position = p + Vec3{0, 0, 0.003};
    } else if (tick % 25 == 0) {
      t.events = event::kCutProgress;
      t.payload.position = p;
    }
    batch.push_back(t);
    if (batch.size() == kSamplesPerFrame) d.frame(batch);
  }
  d.frame(batch);
  const Vec3 mid = on_surface(0.5 * (a.x + b.x), 0.5 * (a.y + b.y));
  for (int f = 0; f < pull_frames; ++f) {
    for (int k = 0; k < kSamplesPerFrame; ++k) {
      ToolSample t = d.sample(ToolMode::kRetractor, Stage::kPulling, mid, mid);
      if (d.seq % 25 == 0) {
        t.events = event::kPull;
        t.payload.magnitude = std::min(0.008, 0.0002 * f);
      }
      batch.push_back(t);
    }
    d.frame(batch);
  }
}

// The drill in the window for `frames` frames: a 2 mm burr removing bone every tick, circling at
// half the window's radius as it goes down by the task's depth; then the probe for half a second.
void drill(Driver& d, const scenario::DrillTask& task, int frames) {
  std::vector<ToolSample> batch;
  const int ticks = frames * kSamplesPerFrame;
  for (int tick = 0; tick < ticks; ++tick) {
    const double turn = 6.0 * 2.0 * M_PI * tick / ticks, r = 0.5 * task.radius;  // six turns inside the window
    const Vec3 p = task.centre + Vec3{r * std::cos(turn), r * std::sin(turn), -task.depth * tick / ticks};
    ToolSample t = d.sample(ToolMode::kDrill, Stage::kDrilling, p, p);
    t.events = event::kDrillRemove;
    t.payload.position = p;
    t.payload.magnitude = 0.002;
    batch.push_back(t);
    if (batch.size() == kSamplesPerFrame) d.frame(batch);
  }
  for (int f = 0; f < 32; ++f) {
    for (int k = 0; k < kSamplesPerFrame; ++k)
      batch.push_back(d.sample(ToolMode::kProbe, Stage::kFree, task.centre + Vec3{0, 0, 0.01}, task.centre + Vec3{0, 0, 0.01}));
    d.frame(batch);
  }
}

// The frames the viz draws: the mesh view, then the composite view (the volume ray cast beneath).
void draw(Driver& d, const scenario::Scenario& s, int frames, Stages& stages) {
  auto window = render::Window::create({1280, 720, false, "lancet-bench-memory"});
  if (!window) {
    std::fprintf(stderr, "lancet-bench-memory: no headless GL: %s\n", window.error().message.c_str());
    return;
  }
  render::SceneRenderer renderer(1280, 720);
  d.sim.scene().draw_mesh(d.mesh);
  renderer.set_mesh(d.mesh);
  render::SceneInput in;
  in.camera_yaw = static_cast<float>(s.camera.yaw);
  in.camera_pitch = static_cast<float>(s.camera.pitch);
  in.camera_distance = static_cast<float>(s.camera.distance);
  in.camera_target = s.camera.target;
  in.patches[0] = d.patch.get();
  for (int f = 0; f < frames; ++f) {
    renderer.render(in);
    window.value()->swap_and_poll();
  }
  stages.mark("gl_mesh");
  render::VolumeRaycaster raycaster;
  raycaster.set_volume(d.sim.scene().render_volume());
  raycaster.set_transfer_function(volume::tf_preset_spec(volume::kTfPresets[0]).table());
  in.volume = &raycaster;
  in.volume_to_world = d.sim.scene().volume_to_world();
  in.volume_params.step = 1.0f;
  for (int f = 0; f < frames; ++f) {
    renderer.render(in);
    window.value()->swap_and_poll();
  }
  stages.mark("gl_volume");
}

// One scenario, in this (child) process; prints its JSON object.
int run(const std::string& name, const std::string& volume_path, bool quick) {
  Stages stages;
  stages.mark("start");
  sim::SceneSetup setup;
  setup.scenario_file = std::string(LANCET_SOURCE_DIR) + "/host_viz/scenarios/" + name + ".toml";
  setup.scenario_toml = read_file(setup.scenario_file);
  setup.volume_path = volume_path;
  auto made = sim::SceneSim::create(setup);
  if (!made) {
    std::fprintf(stderr, "lancet-bench-memory: %s: %s\n", name.c_str(), made.error().message.c_str());
    return 1;
  }
  sim::SceneSim& sim = *made.value();
  const scenario::Scenario& s = *sim.scenario();
  stages.mark("scene");
  Driver d(sim);
  if (s.task == scenario::TaskKind::kIncision)
    incise(d, s.incision, quick ? 20 : 60);
  else
    drill(d, s.drill, quick ? 60 : 120);
  stages.mark("worked");
  draw(d, s, quick ? 5 : 20, stages);
  const volume::Volume& v = sim.scene().volume();
  std::printf("    {\"scenario\": \"%s\", \"voxels\": %zu, \"dims\": [%d, %d, %d], \"triangles\": %zu, \"vertices\": %zu,\n"
              "     \"drilled_voxels\": %llu, \"cuts\": %zu, \"stages\": [%s]}",
              name.c_str(), v.voxel_count(), v.dims[0], v.dims[1], v.dims[2], sim.scene().surface().n_faces(),
              static_cast<std::size_t>(sim.scene().surface().mesh().n_vertices()),
              static_cast<unsigned long long>(sim.scene().events().voxels_drilled), sim.scene().surface().cuts().size(),
              stages.json.c_str());
  std::fflush(stdout);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  bool quick = false;
  std::string only;
  std::string ct = std::string(LANCET_SOURCE_DIR) + "/../shared/data/volumes/head_ct_headsq/headsq_64x64x93_int16.mhd";
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--quick") == 0) {
      quick = true;
    } else if (std::strcmp(argv[i], "--volume") == 0 && i + 1 < argc) {
      ct = argv[++i];
    } else if (std::strcmp(argv[i], "--scenario") == 0 && i + 1 < argc) {
      only = argv[++i];
    } else {
      std::fprintf(stderr, "usage: lancet-bench-memory [--quick] [--volume PATH] [--scenario NAME]\n");
      return 2;
    }
  }
  if (!only.empty()) return run(only, only == "ct_incision" ? ct : "", quick);
  struct Case {
    std::string name, volume;
  };
  std::vector<Case> cases = {{"skin_incision", ""}, {"bone_drilling", ""}};
  if (std::ifstream(ct).good())
    cases.push_back({"ct_incision", ct});
  else
    std::fprintf(stderr, "lancet-bench-memory: no CT at %s: ct_incision skipped (--volume PATH)\n", ct.c_str());
  // Each scenario in a child process, its JSON object back through a pipe (a scenario that fails
  // leaves nothing in the output but its line on stderr).
  std::string objects;
  int failures = 0;
  for (const Case& c : cases) {
    std::fprintf(stderr, "lancet-bench-memory: %s\n", c.name.c_str());
    int fds[2];
    if (pipe(fds) != 0) return 1;
    std::fflush(stdout);
    const pid_t child = fork();
    if (child == 0) {
      close(fds[0]);
      dup2(fds[1], STDOUT_FILENO);
      _exit(run(c.name, c.volume, quick));
    }
    close(fds[1]);
    std::string out;
    char buf[4096];
    for (ssize_t n; (n = read(fds[0], buf, sizeof buf)) > 0;) out.append(buf, static_cast<std::size_t>(n));
    close(fds[0]);
    int status = 0;
    waitpid(child, &status, 0);
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0 || out.empty()) {
      ++failures;
      continue;
    }
    objects += (objects.empty() ? "" : ",\n") + out;
  }
  std::printf("{\n  \"samples_per_frame\": %d,\n  \"quick\": %s,\n  \"scenarios\": [\n%s\n", kSamplesPerFrame,
              quick ? "true" : "false", objects.c_str());
  std::printf("  ]\n}\n");
  return failures == 0 ? 0 : 1;
}
