#include "record/replay.hpp"

#include <bit>
#include <chrono>
#include <cstdio>
#include <cstring>

#include "lancet/shared_model/shared_state.hpp"
#include "lancet/shared_model/word_hasher.hpp"

namespace lancet::record {

namespace {


bool same_output(const ToolSample& a, const ToolSample& b) {
  return a.seq == b.seq && a.force == b.force && a.proxy == b.proxy && a.tool == b.tool && a.stage == b.stage &&
         a.events == b.events && a.mode == b.mode && a.payload.position == b.payload.position &&
         std::bit_cast<std::uint64_t>(a.payload.magnitude) == std::bit_cast<std::uint64_t>(b.payload.magnitude) &&
         std::memcmp(a.tau, b.tau, sizeof a.tau) == 0;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// SceneSim

namespace {
// mm³ of one voxel of the scene's volume.
double voxel_mm3(const hybrid::TissueScene& scene) {
  const Vec3 sp = scene.volume().spacing;
  return sp.x * sp.y * sp.z * 1e9;
}
}  // namespace

Result<std::unique_ptr<SceneSim>> SceneSim::create(const SceneSetup& setup) {
  std::unique_ptr<SceneSim> sim(new SceneSim());
  sim->setup_ = setup;
  hybrid::SceneDescription desc;
  if (!setup.scenario_toml.empty()) {
    auto parsed = scenario::parse_scenario(setup.scenario_toml, setup.scenario_file);
    if (!parsed.ok()) return parsed.error();
    sim->scenario_ = std::move(parsed).value();
    auto d = hybrid::scene_description(*sim->scenario_, setup.volume_path);
    if (!d.ok()) return d.error();
    desc = std::move(d).value();
  } else if (setup.tissue == "block" || setup.tissue == "phantom") {
    desc.source = setup.tissue == "block" ? hybrid::SceneSource::kBlock : hybrid::SceneSource::kPhantom;
  } else {
    return Error{ErrorCode::kInvalid, "tissue: expected block or phantom, found \"" + setup.tissue + "\""};
  }
  desc.patch.radius = setup.patch_radius;
  auto made = hybrid::TissueScene::create(std::move(desc));
  if (!made.ok()) return made.error();
  sim->scene_ = std::move(made).value();
  if (sim->scene_->description().surface == hybrid::SceneSurface::kSkin)
    sim->bleeding_ = std::make_unique<hybrid::Bleeding>(*sim->scene_);
  if (sim->scenario_) sim->task_.emplace(*sim->scenario_, *sim->scene_);
  return sim;
}

void SceneSim::apply(std::span<const ToolSample> samples) {
  if (samples.empty()) return;
  for (const ToolSample& t : samples)
    if ((t.events & event::kDrillRemove) != 0) last_removal_ = t.payload.position;
  (void)scene_->apply(samples);
  if (task_) (void)task_->update(*scene_, samples);
  if (bleeding_) bleeding_->observe(samples);
}

std::size_t SceneSim::export_patch(Vec3 at, TissuePatch& patch) { return scene_->export_patch(at, patch); }

void SceneSim::advance_blood(double dt) {
  if (bleeding_) bleeding_->advance(*scene_, dt);
}

void SceneSim::figures(FrameRecord& f) const {
  if (task_) {
    const hybrid::TaskStatus& t = task_->status();
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
    const hybrid::BloodFigures b = bleeding_->figures();
    f.blood_lost_ml = b.lost_ml;
    f.blood_on_tissue_ml = b.on_tissue_ml;
    f.blood_swabbed_ml = b.swabbed_ml;
  }
}

void SceneSim::take_events(std::uint64_t frame, std::int64_t t_ns, std::vector<SceneEvent>& out) {
  const auto make = [&](std::uint32_t kind, std::uint32_t index, Vec3 at, double value, const std::string& name) {
    SceneEvent e;
    e.frame = frame, e.t_ns = t_ns, e.kind = kind, e.index = index, e.position = at, e.value = value;
    std::snprintf(e.name, sizeof e.name, "%s", name.c_str());
    out.push_back(e);
  };
  if (bleeding_) {
    const auto& sources = bleeding_->sources();
    for (std::size_t i = sources_seen_; i < sources.size(); ++i)
      make(SceneEvent::kBloodSource, static_cast<std::uint32_t>(i), sources[i].position, sources[i].rate_ml_s, sources[i].name);
    sources_seen_ = std::max(sources_seen_, sources.size());
    stopped_seen_.resize(sources.size(), false);
    for (std::size_t i = 0; i < sources.size(); ++i) {
      if (sources[i].stopped && !stopped_seen_[i]) make(SceneEvent::kBleedingStopped, static_cast<std::uint32_t>(i), sources[i].position, 0, sources[i].name);
      stopped_seen_[i] = sources[i].stopped;
    }
  }
  if (task_ && scenario_) {
    const std::vector<bool>& d = task_->status().damaged_flags;
    damaged_seen_.resize(d.size(), false);
    for (std::size_t i = 0; i < d.size(); ++i) {
      if (d[i] && !damaged_seen_[i]) make(SceneEvent::kStructureReached, static_cast<std::uint32_t>(i), {}, 0, scenario_->avoid[i].name);
      damaged_seen_[i] = d[i];
    }
  }
  const std::uint64_t voxels = scene_->events().voxels_drilled;
  if (voxels > voxels_seen_) {
    make(SceneEvent::kBoneDrilled, 0, last_removal_, static_cast<double>(voxels - voxels_seen_) * voxel_mm3(*scene_), "bone");
    voxels_seen_ = voxels;
  }
}

std::uint64_t SceneSim::hash() const {
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
    const hybrid::BloodFigures b = bleeding_->figures();
    h.f(b.lost_ml), h.f(b.on_tissue_ml), h.f(b.swabbed_ml);
  }
  const hybrid::SceneEvents& e = scene_->events();
  h.word(e.samples), h.word(e.ruptures), h.word(e.cut_steps), h.word(e.grabs), h.word(e.voxels_drilled);
  if (task_) h.f(task_->status().progress), h.f(task_->status().max_deviation);
  return h.value();
}

// ---------------------------------------------------------------------------------------------
// Replay

namespace {

// Shared layouts of earlier protocols whose recorded messages (ToolSample, TissuePatch, the servo
// model blob) are laid out as this build's: their recordings, made before files carried
// recorded_layout_hash, still replay. Protocol 10 changed only what is not recorded.
constexpr std::uint64_t kEarlierLayoutsRecordingAsThisOne[] = {
    0xdfc3b587a1660cf6ull,  // protocol 9
};

bool replayable_layout(const Recording& rec) {
  if (rec.recorded_layout_hash != 0) return rec.recorded_layout_hash == kRecordedLayoutHash;
  if (rec.layout_hash == kSharedLayoutHash) return true;
  for (const std::uint64_t h : kEarlierLayoutsRecordingAsThisOne)
    if (rec.layout_hash == h) return true;
  return false;
}

}  // namespace

Result<std::unique_ptr<Replay>> Replay::create(const Recording& rec) {
  const auto hex = [](std::uint64_t v) {
    char b[24];
    std::snprintf(b, sizeof b, "%016llx", static_cast<unsigned long long>(v));
    return std::string(b);
  };
  if (!replayable_layout(rec))
    return Error{ErrorCode::kMismatch, "the recording was made with recorded-message layout " + hex(rec.recorded_layout_hash) +
                                           " (shared layout " + hex(rec.layout_hash) + ", protocol " + std::to_string(rec.protocol) +
                                           ", lancet " + rec.lancet_version + "); this build's is " + hex(kRecordedLayoutHash) +
                                           " (shared layout " + hex(kSharedLayoutHash) + ", protocol " +
                                           std::to_string(kProtocolVersion) + "): replay it with the build that recorded it"};
  if (rec.samples.empty() || rec.frames.empty()) return Error{ErrorCode::kInvalid, "the recording has no ticks or no frames"};
  for (const ToolSample& s : rec.samples)
    if ((s.inputs & input::kCommandsCut) != 0)
      return Error{ErrorCode::kInvalid, "tick " + std::to_string(s.seq) + " applied more commands than a sample records (" +
                                            std::to_string(kSampleCommands) + "): it cannot be replayed exactly"};
  auto model = servo::model_from_blob(rec.servo_model);
  if (!model.ok()) return Error{model.error().code, "the recording's " + model.error().message};
  std::unique_ptr<Replay> r(new Replay());
  r->rec_ = &rec;
  r->model_ = model.value();
  SceneSetup setup;
  setup.tissue = rec.tissue;
  setup.scenario_toml = rec.scenario_toml;
  setup.scenario_file = rec.scenario_file;
  setup.volume_path = rec.volume_path;
  setup.patch_radius = rec.patch_radius;
  auto sim = SceneSim::create(setup);
  if (!sim.ok()) return Error{sim.error().code, "the recording's scene: " + sim.error().message};
  r->sim_ = std::move(sim).value();
  // The session began with the servo's reset: a fresh state, with the tool it kept, at the tick
  // before the first.
  const ToolSample& first = rec.samples.front();
  if (first.reset_mode == kNoReset || first.reset_mode >= kToolCount)
    return Error{ErrorCode::kInvalid, "the recording's first tick (" + std::to_string(first.seq) +
                                          ") is not the servo's reset: it cannot be replayed from a known state"};
  r->data_.tick = first.seq - 1;
  r->data_.mode = static_cast<ToolMode>(first.reset_mode);
  for (std::size_t i = 0; i < rec.first_patch_versions.size() && i < rec.first_patches.size(); ++i)
    r->patches_.emplace_back(rec.first_patch_versions[i], std::make_unique<TissuePatch>(rec.first_patches[i]));
  r->replayed_.reserve(rec.samples.size());
  return r;
}

const TissuePatch* Replay::find_patch(std::uint64_t version) const {
  for (const auto& [v, p] : patches_)
    if (v == version) return p.get();
  return nullptr;
}

const TissuePatch* Replay::patch() const noexcept { return patches_.empty() ? nullptr : patches_.back().second.get(); }

double Replay::time_s() const noexcept {
  return has_latest_ ? static_cast<double>(latest_.t_ns - rec_->samples.front().t_ns) * 1e-9 : 0.0;
}

double Replay::duration_s() const noexcept {
  return static_cast<double>(rec_->samples.back().t_ns - rec_->samples.front().t_ns) * 1e-9;
}

Result<bool> Replay::step_frame() {
  if (done()) return false;
  const FrameRecord& f = rec_->frames[next_frame_];
  using Clock = std::chrono::steady_clock;
  const auto since = [](Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); };
  auto t0 = Clock::now();
  // The servo ticks the frame had applied, through the same step with the recorded inputs.
  batch_.clear();
  // The frame's ticks: as many as it applied (format 2), or (format 1) those up to its last_seq.
  const bool by_count = rec_->format_version >= 2;
  const std::size_t frame_end = by_count ? std::min(rec_->samples.size(), next_sample_ + static_cast<std::size_t>(std::min<std::uint64_t>(f.ticks, rec_->samples.size())))
                                         : rec_->samples.size();
  while (next_sample_ < frame_end && (by_count || rec_->samples[next_sample_].seq <= f.last_seq)) {
    const ToolSample& s = rec_->samples[next_sample_++];
    // A gap (the viz stalled longer than the sample ring holds): the servo's state after it
    // depends on ticks nobody kept, so from here the servo is not re-stepped; the scene goes on
    // with the recorded ticks, exactly what the live scene was given, and is still checked.
    if (check_.gap_seq == 0 && has_latest_ && s.seq != latest_.seq + 1) {
      check_.gap_seq = s.seq;
      check_.ticks_lost = s.seq > latest_.seq ? s.seq - latest_.seq - 1 : 0;
    }
    if (check_.gap_seq != 0) {
      ++check_.ticks_unchecked;
      batch_.push_back(s);
      replayed_.push_back(s);
      latest_ = s;
      continue;
    }
    servo::ServoInput in = servo::input_from_sample(s);
    if (s.patch_version != 0) {
      in.patch = find_patch(s.patch_version);
      if (in.patch == nullptr)
        return Error{ErrorCode::kInvalid, "tick " + std::to_string(s.seq) + " used patch version " + std::to_string(s.patch_version) +
                                              ", which no recorded frame published"};
    }
    servo::servo_step(model_, data_, in, out_);
    ToolSample& o = out_.sample;
    o.write_status = s.write_status;
    if (s.write_status != IoStatus::kOk) o.events |= event::kFault;
    ++check_.ticks;
    const bool hash_ok = o.state_hash == s.state_hash, output_ok = same_output(o, s);
    if (s.state_hash != 0) ++check_.servo_hashes;
    if (!hash_ok) ++check_.servo_hash_mismatches;
    if (!output_ok) ++check_.sample_mismatches;
    if ((!hash_ok || !output_ok) && check_.first_bad_seq == 0) check_.first_bad_seq = s.seq;
    batch_.push_back(o);
    replayed_.push_back(o);
    latest_ = s;
    has_latest_ = true;
  }
  timing_.servo += since(t0);
  // The visualizer's frame: the batch, then the patch around the newest tool, then the blood.
  t0 = Clock::now();
  sim_->apply(batch_);
  timing_.scene += since(t0);
  t0 = Clock::now();
  if (!batch_.empty()) {
    latest_ = batch_.back();
    has_latest_ = true;
  }
  if (f.patch_version != 0) {
    auto p = std::make_unique<TissuePatch>();
    p->n_triangles = 0;
    p->brick.valid = 0;
    (void)sim_->export_patch(has_latest_ ? latest_.tool.position : Vec3{}, *p);
    p->seq = f.patch_seq;
    p->t_ns = f.patch_t_ns;
    p->samples_applied = f.patch_samples_applied;
    patches_.emplace_back(f.patch_version, std::move(p));
  }
  // The patches a later tick may still use: the servo takes newer versions only, so none older
  // than the next recorded tick's (however many frames a stalled servo let pass meanwhile).
  const std::uint64_t needed = next_sample_ < rec_->samples.size() ? rec_->samples[next_sample_].patch_version : ~std::uint64_t{0};
  while (patches_.size() > 1 && patches_.front().first < needed) patches_.pop_front();
  timing_.patch += since(t0);
  t0 = Clock::now();
  sim_->advance_blood(f.blood_dt);
  timing_.blood += since(t0);
  t0 = Clock::now();
  if (f.scene_hash != 0) {
    ++check_.scene_hashes;
    if (sim_->hash() != f.scene_hash) {
      ++check_.scene_hash_mismatches;
      if (check_.first_bad_frame == 0) check_.first_bad_frame = f.frame + 1;
    }
  }
  timing_.hash += since(t0);
  ++check_.frames;
  ++next_frame_;
  return true;
}

Result<ReplayCheck> Replay::run() {
  for (;;) {
    auto r = step_frame();
    if (!r.ok()) return r.error();
    if (!r.value()) return check_;
  }
}

}  // namespace lancet::record
