#include "sim/scene_sim.hpp"

#include <algorithm>
#include <atomic>
#include <cstdio>

#include "lancet/shared_model/word_hasher.hpp"

namespace lancet::sim {

namespace {
// mm³ of one voxel of the scene's volume.
double voxel_mm3(const tissue::TissueScene& scene) {
  const Vec3 sp = scene.volume().spacing;
  return sp.x * sp.y * sp.z * 1e9;
}
}  // namespace

Result<std::unique_ptr<SceneSim>> SceneSim::create(const SceneSetup& setup) {
  std::unique_ptr<SceneSim> sim(new SceneSim());
  sim->setup_ = setup;
  tissue::SceneDescription desc;
  if (!setup.scenario_toml.empty()) {
    auto parsed = scenario::parse_scenario(setup.scenario_toml, setup.scenario_file);
    if (!parsed.ok()) return parsed.error();
    sim->scenario_ = std::move(parsed).value();
    auto d = tissue::scene_description(*sim->scenario_, setup.volume_path);
    if (!d.ok()) return d.error();
    desc = std::move(d).value();
  } else if (setup.tissue == "block" || setup.tissue == "phantom") {
    desc.source = setup.tissue == "block" ? tissue::SceneSource::kBlock : tissue::SceneSource::kPhantom;
  } else {
    return Error{ErrorCode::kInvalid, "tissue: expected block or phantom, found \"" + setup.tissue + "\""};
  }
  desc.patch.radius = setup.patch_radius;
  auto made = tissue::TissueScene::create(std::move(desc));
  if (!made.ok()) return made.error();
  sim->scene_ = std::move(made).value();
  if (sim->scene_->description().surface == tissue::SceneSurface::kSkin)
    sim->bleeding_ = std::make_unique<blood::Bleeding>(*sim->scene_);
  if (sim->scenario_) sim->task_.emplace(*sim->scenario_, *sim->scene_);
  return sim;
}

void SceneSim::apply(std::span<const ToolSample> samples) {
  wait_blood_prepared();  // the blood behind reads the scene until then
  if (samples.empty()) return;
  for (const ToolSample& t : samples)
    if ((t.events & event::kDrillRemove) != 0) last_removal_ = t.payload.position;
  (void)scene_->apply(samples);
  if (task_) (void)task_->update(*scene_, samples);
  if (bleeding_) bleeding_->observe(samples);
}

std::size_t SceneSim::export_patch(Vec3 at, TissuePatch& patch) { return scene_->export_patch(at, patch); }

std::array<std::size_t, kHandCount> SceneSim::export_patches_and_prepare_blood(const std::array<TissuePatch*, kHandCount>& patches,
                                                                               const std::array<Vec3, kHandCount>& centres,
                                                                               double blood_dt) {
  std::array<std::size_t, kHandCount> found{};
  const tissue::TissueScene& scene = *scene_;
  // Up to three tasks that only read the scene: a patch per hand (with the hand's own scratch) and
  // the blood's preparation.
  std::array<std::size_t, kHandCount + 1> tasks{};
  std::size_t n = 0;
  for (std::size_t h = 0; h < kHandCount; ++h)
    if (patches[h] != nullptr) tasks[n++] = h;
  if (behind_)
    behind_->post(blood_dt);  // prepared and stepped on its own thread, beside the patches
  else if (bleeding_)
    tasks[n++] = kHandCount;
  const auto run = [&](std::size_t task) {
    if (task == kHandCount) {
      bleeding_->prepare(scene, blood_dt);
      return;
    }
    found[task] = scene.export_patch(centres[task], patch_scratch_[task], *patches[task]);
  };
  if (n <= 1) {
    for (std::size_t i = 0; i < n; ++i) run(tasks[i]);
    return found;
  }
  if (!pool_) pool_ = std::make_unique<blood::WorkerPool>(2);
  std::atomic<std::size_t> next{0};
  auto job = [&](int) {
    for (std::size_t i = next.fetch_add(1); i < n; i = next.fetch_add(1)) run(tasks[i]);
  };
  pool_->run(job);
  return found;
}

void SceneSim::step_blood() {
  if (bleeding_ && !behind_) bleeding_->step();
}

void SceneSim::set_blood_behind(bool on) {
  if (on && bleeding_ && !behind_) behind_ = std::make_unique<BloodBehind>(*bleeding_, *scene_);
  if (!on && behind_) {
    wait_blood_stepped();
    behind_.reset();
  }
}

void SceneSim::wait_blood_prepared() const noexcept {
  if (behind_) waited_prepared_s_ += behind_->wait_prepared();
}

void SceneSim::wait_blood_stepped() const noexcept {
  if (behind_) waited_stepped_s_ += behind_->wait_stepped();
}

void SceneSim::figures(record::FrameRecord& f) const {
  wait_blood_stepped();
  if (task_) {
    const score::TaskStatus& t = task_->status();
    f.task_progress = t.progress;
    f.max_deviation = t.max_deviation;
    f.outside = t.outside;
    f.damaged = 0;
    for (std::size_t i = 0; i < t.damaged_flags.size() && i < 32; ++i)
      if (t.damaged_flags[i]) f.damaged |= 1u << i;
    f.drilled_mm3 = static_cast<double>(scene_->events().voxels_drilled) * voxel_mm3(*scene_);
    f.drilled_outside_mm3 = std::max(0.0, f.drilled_mm3 - t.window_removed * 1e9);
  }
  if (bleeding_) {
    const blood::BloodFigures b = bleeding_->figures();
    f.blood_lost_ml = b.lost_ml;
    f.blood_on_tissue_ml = b.on_tissue_ml;
    f.blood_swabbed_ml = b.swabbed_ml;
  }
}

void SceneSim::take_events(std::uint64_t frame, std::int64_t t_ns, std::vector<record::SceneEvent>& out) {
  wait_blood_stepped();
  const auto make = [&](std::uint32_t kind, std::uint32_t index, Vec3 at, double value, const std::string& name) {
    record::SceneEvent e;
    e.frame = frame, e.t_ns = t_ns, e.kind = kind, e.index = index, e.position = at, e.value = value;
    std::snprintf(e.name, sizeof e.name, "%s", name.c_str());
    out.push_back(e);
  };
  if (bleeding_) {
    const auto& sources = bleeding_->sources();
    for (std::size_t i = sources_seen_; i < sources.size(); ++i)
      make(record::SceneEvent::kBloodSource, static_cast<std::uint32_t>(i), sources[i].position, sources[i].rate_ml_s, sources[i].name);
    sources_seen_ = std::max(sources_seen_, sources.size());
    stopped_seen_.resize(sources.size(), false);
    for (std::size_t i = 0; i < sources.size(); ++i) {
      if (sources[i].stopped && !stopped_seen_[i]) make(record::SceneEvent::kBleedingStopped, static_cast<std::uint32_t>(i), sources[i].position, 0, sources[i].name);
      stopped_seen_[i] = sources[i].stopped;
    }
  }
  if (task_ && scenario_) {
    const std::vector<bool>& d = task_->status().damaged_flags;
    damaged_seen_.resize(d.size(), false);
    for (std::size_t i = 0; i < d.size(); ++i) {
      if (d[i] && !damaged_seen_[i]) make(record::SceneEvent::kStructureReached, static_cast<std::uint32_t>(i), {}, 0, scenario_->avoid[i].name);
      damaged_seen_[i] = d[i];
    }
  }
  const std::uint64_t voxels = scene_->events().voxels_drilled;
  if (voxels > voxels_seen_) {
    make(record::SceneEvent::kBoneDrilled, 0, last_removal_, static_cast<double>(voxels - voxels_seen_) * voxel_mm3(*scene_), "bone");
    voxels_seen_ = voxels;
  }
}

std::uint64_t SceneSim::hash() const {
  wait_blood_stepped();
  WordHasher h(0x243f6a8885a308d3ull);
  surface::TriangleMesh mesh;
  scene_->draw_mesh(mesh);
  h.word(mesh.vertices.size()), h.word(mesh.triangles.size());
  for (const Vec3f& v : mesh.vertices) h.f(v.x), h.f(v.y), h.f(v.z);
  for (const auto& t : mesh.triangles) h.word(static_cast<std::uint64_t>(t[0]) << 32 | t[1]), h.word(t[2]);
  if (bleeding_) {
    std::vector<float> depth, age;
    bleeding_->vertex_blood(mesh, depth, age);
    for (const float d : depth) h.f(d);
    const blood::BloodFigures b = bleeding_->figures();
    h.f(b.lost_ml), h.f(b.on_tissue_ml), h.f(b.swabbed_ml);
  }
  const tissue::SceneEvents& e = scene_->events();
  h.word(e.samples), h.word(e.ruptures), h.word(e.cut_steps), h.word(e.grabs), h.word(e.voxels_drilled);
  if (task_) h.f(task_->status().progress), h.f(task_->status().max_deviation);
  return h.value();
}

}  // namespace lancet::sim
