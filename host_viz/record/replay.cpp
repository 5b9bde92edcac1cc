#include "record/replay.hpp"

#include <algorithm>
#include <bit>
#include <chrono>
#include <cstdio>
#include <cstring>

#include "lancet/shared_model/shared_state.hpp"

namespace lancet::record {

namespace {

bool same_output(const ToolSample& a, const ToolSample& b) {
  return a.seq == b.seq && a.force == b.force && a.proxy == b.proxy && a.tool == b.tool && a.stage == b.stage &&
         a.events == b.events && a.mode == b.mode && a.payload.position == b.payload.position &&
         std::bit_cast<std::uint64_t>(a.payload.magnitude) == std::bit_cast<std::uint64_t>(b.payload.magnitude) &&
         std::memcmp(a.tau, b.tau, sizeof a.tau) == 0;
}

}  // namespace

namespace {

// Shared layouts of earlier protocols whose recorded messages (ToolSample, TissuePatch, the servo
// model blob) are laid out as this build's: their recordings, made before files carried
// recorded_layout_hash, still replay. Protocol 10 changed only what is not recorded.
constexpr std::uint64_t kEarlierLayoutsRecordingAsThisOne[] = {
    0xdfc3b587a1660cf6ull,  // protocol 9
};
// Recorded layouts of earlier builds whose bytes are this build's: protocol 10's ToolSample and
// TissuePatch had reserved bytes where the hand is now, always 0: the right hand.
constexpr std::uint64_t kEarlierRecordedLayouts[] = {
    0x937ea367a07bda5eull,  // protocol 10 (one hand)
};

bool replayable_layout(const Recording& rec) {
  if (rec.recorded_layout_hash != 0) {
    if (rec.recorded_layout_hash == kRecordedLayoutHash) return true;
    for (const std::uint64_t h : kEarlierRecordedLayouts)
      if (rec.recorded_layout_hash == h) return true;
    return false;
  }
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
  if (rec.hands < 1 || rec.hands > kHandCount) return Error{ErrorCode::kInvalid, "the recording's hands: not 1 or 2"};
  std::unique_ptr<Replay> r(new Replay());
  r->rec_ = &rec;
  for (std::size_t h = 0; h < rec.hands; ++h) {
    auto model = servo::model_from_blob(rec.servo_model[h]);
    if (!model.ok())
      return Error{model.error().code, std::string("the recording's ") + hand_name(static_cast<Hand>(h)) + " hand's " + model.error().message};
    r->model_[h] = model.value();
  }
  sim::SceneSetup setup;
  setup.tissue = rec.tissue;
  setup.scenario_toml = rec.scenario_toml;
  setup.scenario_file = rec.scenario_file;
  setup.volume_path = rec.volume_path;
  setup.patch_radius = rec.patch_radius;
  auto sim = sim::SceneSim::create(setup);
  if (!sim.ok()) return Error{sim.error().code, "the recording's scene: " + sim.error().message};
  r->sim_ = std::move(sim).value();
  // The session began with each hand's servo's reset: a fresh state, with the tool it kept, at the
  // tick before its first.
  for (std::size_t h = 0; h < rec.hands; ++h) {
    const auto hand = static_cast<Hand>(h);
    const auto first = std::find_if(rec.samples.begin(), rec.samples.end(), [&](const ToolSample& s) { return s.hand == hand; });
    if (first == rec.samples.end())
      return Error{ErrorCode::kInvalid, std::string("the recording has no tick of the ") + hand_name(hand) + " hand"};
    if (first->reset_mode == kNoReset || first->reset_mode >= kToolCount)
      return Error{ErrorCode::kInvalid, std::string("the recording's first tick of the ") + hand_name(hand) + " hand (" +
                                            std::to_string(first->seq) + ") is not its servo's reset: it cannot be replayed from a known state"};
    r->data_[h].tick = first->seq - 1;
    r->data_[h].mode = static_cast<ToolMode>(first->reset_mode);
  }
  for (const ToolSample& s : rec.samples)
    if (hand_index(s.hand) >= rec.hands)
      return Error{ErrorCode::kInvalid, "tick " + std::to_string(s.seq) + " is the " + hand_name(s.hand) + " hand's, in a recording of " +
                                            std::to_string(rec.hands) + " hand(s)"};
  for (std::size_t i = 0; i < rec.first_patch_versions.size() && i < rec.first_patches.size(); ++i) {
    const std::size_t h = hand_index(rec.first_patches[i].hand);
    if (h >= rec.hands) return Error{ErrorCode::kInvalid, "the recording's first patch " + std::to_string(i) + " is for a hand it does not have"};
    r->patches_[h].emplace_back(rec.first_patch_versions[i], std::make_unique<TissuePatch>(rec.first_patches[i]));
  }
  r->replayed_.reserve(rec.samples.size());
  return r;
}

const TissuePatch* Replay::find_patch(Hand hand, std::uint64_t version) const {
  for (const auto& [v, p] : patches_[hand_index(hand)])
    if (v == version) return p.get();
  return nullptr;
}

const TissuePatch* Replay::patch(Hand h) const noexcept {
  const auto& ps = patches_[hand_index(h)];
  return ps.empty() ? nullptr : ps.back().second.get();
}

double Replay::time_s() const noexcept {
  return has_latest_ ? static_cast<double>(latest_.t_ns - rec_->samples.front().t_ns) * 1e-9 : 0.0;
}

double Replay::duration_s() const noexcept {
  return static_cast<double>(rec_->samples.back().t_ns - rec_->samples.front().t_ns) * 1e-9;
}

Result<sim::FrameBatch> Replay::drain() {
  const FrameRecord& f = rec_->frames[next_frame_];
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  // The servo ticks the frame had applied, through the same step with the recorded inputs.
  batch_.clear();
  // The frame's ticks: as many as it applied (format 2), or (format 1) those up to its last_seq.
  const bool by_count = rec_->format_version >= 2;
  const std::size_t frame_end = by_count ? std::min(rec_->samples.size(), next_sample_ + static_cast<std::size_t>(std::min<std::uint64_t>(f.ticks, rec_->samples.size())))
                                         : rec_->samples.size();
  while (next_sample_ < frame_end && (by_count || rec_->samples[next_sample_].seq <= f.last_seq)) {
    const ToolSample& s = rec_->samples[next_sample_++];
    const std::size_t h = hand_index(s.hand);  // checked by create()
    // A gap (the viz stalled longer than the sample ring holds): the servo's state after it
    // depends on ticks nobody kept, so from here the servo is not re-stepped; the scene goes on
    // with the recorded ticks, exactly what the live scene was given, and is still checked.
    if (check_.gap_seq == 0 && has_hand_[h] && s.seq != latest_by_hand_[h].seq + 1) {
      check_.gap_seq = s.seq;
      check_.ticks_lost = s.seq > latest_by_hand_[h].seq ? s.seq - latest_by_hand_[h].seq - 1 : 0;
    }
    latest_by_hand_[h] = s;
    has_hand_[h] = true;
    if (check_.gap_seq != 0) {
      ++check_.ticks_unchecked;
      batch_.push_back(s);
      replayed_.push_back(s);
      latest_ = s;
      continue;
    }
    servo::ServoInput in = servo::input_from_sample(s);
    if (s.patch_version != 0) {
      in.patch = find_patch(s.hand, s.patch_version);
      if (in.patch == nullptr)
        return Error{ErrorCode::kInvalid, "tick " + std::to_string(s.seq) + " of the " + hand_name(s.hand) + " hand used patch version " +
                                              std::to_string(s.patch_version) + ", which no recorded frame published"};
    }
    servo::servo_step(model_[h], data_[h], in, out_);
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
  if (!batch_.empty()) {
    latest_ = batch_.back();
    has_latest_ = true;
  }
  timing_.servo += std::chrono::duration<double>(Clock::now() - t0).count();
  // The frame as recorded: its ticks, its blood time, and the patch it published (if it did),
  // around the newest tool, with the recorded header.
  sim::FrameBatch b;
  b.samples = batch_;
  b.blood_dt = f.blood_dt;
  const sim::PatchHeader headers[kHandCount] = {{f.patch_seq, f.patch_t_ns, f.patch_samples_applied},
                                                {f.left_patch_seq, f.left_patch_t_ns, f.left_patch_samples_applied}};
  for (std::size_t h = 0; h < kHandCount; ++h) {
    if (frame_patch_version(f, h) == 0) continue;
    filling_[h] = std::make_unique<TissuePatch>();
    b.patches[h] = {filling_[h].get(), has_hand_[h] ? latest_by_hand_[h].tool.position : Vec3{}, headers[h]};
  }
  return b;
}

std::uint64_t Replay::frame_patch_version(const FrameRecord& f, std::size_t hand) noexcept {
  return hand == 0 ? f.patch_version : f.left_patch_version;
}

void Replay::publish(const std::array<const TissuePatch*, kHandCount>& patches) {
  const FrameRecord& f = rec_->frames[next_frame_];
  for (std::size_t h = 0; h < kHandCount; ++h) {
    auto& kept = patches_[h];
    if (patches[h] != nullptr) kept.emplace_back(frame_patch_version(f, h), std::move(filling_[h]));
    // The patches a later tick of this hand may still use: the servo takes newer versions only, so
    // none older than the hand's next recorded tick's (however many frames a stalled servo let
    // pass meanwhile).
    std::uint64_t needed = ~std::uint64_t{0};
    for (std::size_t i = next_sample_; i < rec_->samples.size() && i < next_sample_ + 2 * kHandCount; ++i) {
      if (hand_index(rec_->samples[i].hand) == h) {
        needed = rec_->samples[i].patch_version;
        break;
      }
    }
    while (kept.size() > 1 && kept.front().first < needed) kept.pop_front();
  }
}

Result<bool> Replay::step_frame() {
  if (done()) return false;
  const FrameRecord& f = rec_->frames[next_frame_];
  // The visualizer's frame, as the live viz ran it: the ticks, the scene, the patch, the blood.
  const double for_scene = sim_->blood_waited_for_scene_s();
  auto stepped = sim::run_frame(*sim_, *this);
  if (!stepped.ok()) return stepped.error();
  // With the blood behind (run()), a frame waits for the blood only where it was late: before its
  // scene changes (inside the scene's time), and before a hash.
  const double late = sim_->blood_waited_for_scene_s() - for_scene;
  timing_.scene += stepped.value().scene_s - late;
  timing_.blood += stepped.value().blood_s + late;
  timing_.patch += stepped.value().patch_s;
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  const double for_blood = sim_->blood_waited_for_blood_s();
  if (f.scene_hash != 0) {
    ++check_.scene_hashes;
    if (sim_->hash() != f.scene_hash) {
      ++check_.scene_hash_mismatches;
      if (check_.first_bad_frame == 0) check_.first_bad_frame = f.frame + 1;
    }
  }
  const double hash_late = sim_->blood_waited_for_blood_s() - for_blood;
  timing_.hash += std::chrono::duration<double>(Clock::now() - t0).count() - hash_late;
  timing_.blood += hash_late;
  ++check_.frames;
  ++next_frame_;
  return true;
}

Result<ReplayCheck> Replay::run() {
  // No one looks at the blood between frames here: it is prepared and stepped on a thread of its
  // own, beside the frame's patches and the next frame's ticks (SceneSim::set_blood_behind).
  sim_->set_blood_behind(true);
  for (;;) {
    auto r = step_frame();
    if (!r.ok() || !r.value()) {
      sim_->set_blood_behind(false);
      if (!r.ok()) return r.error();
      return check_;
    }
  }
}

}  // namespace lancet::record
