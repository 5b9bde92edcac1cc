#include "app/recorder_control.hpp"

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <filesystem>

#include "servo/servo_step.hpp"

namespace lancet::viz {

RecorderControl::RecorderControl(std::string record_path, sim::SceneSetup setup, std::string scenario_name,
                                 std::string lancet_version)
    : record_path_(std::move(record_path)),
      setup_(std::move(setup)),
      scenario_name_(std::move(scenario_name)),
      lancet_version_(std::move(lancet_version)) {
  if (!record_path_.empty()) arm(record_path_);
}

RecorderControl::~RecorderControl() { stop(); }

void RecorderControl::arm(std::string path) {
  path_ = std::move(path);
  state_ = State::kArmed;
}

void RecorderControl::stop() {
  if (recorder_) {
    const auto done = recorder_->finish();
    std::printf("lancet-viz: recorded %llu servo ticks (%llu lost in %llu gaps) and %llu frames to %s%s%s\n",
                static_cast<unsigned long long>(recorder_->samples()), static_cast<unsigned long long>(recorder_->samples_lost()),
                static_cast<unsigned long long>(recorder_->gaps()), static_cast<unsigned long long>(recorder_->frames()),
                recorder_->path().c_str(), done.ok() ? "" : ": ", done.ok() ? "" : done.error().message.c_str());
    std::fflush(stdout);
    message_ = "recorded " + recorder_->path();
    const std::string path = recorder_->path();
    recorder_.reset();
    if (done.ok() && on_recorded_) on_recorded_(path);
  }
  state_ = State::kOff;
}

std::span<const ToolSample> RecorderControl::admit(std::span<const ToolSample> batch, VizSession& session) {
  std::span<const ToolSample> use = batch;
  // Armed, the fresh scene waits for the session: what the servo sends before its reset (in the
  // frame that connects, before the reset goes out) is not applied to it.
  if (state_ == State::kArmed) use = {};
  if (state_ == State::kWaitingReset) {
    // Until the servo has applied the reset, what it sends belongs to no session.
    const auto reset = std::find_if(use.begin(), use.end(), [](const ToolSample& t) { return t.reset_mode != kNoReset; });
    use = use.subspan(static_cast<std::size_t>(reset - use.begin()));
    if (!use.empty()) begin(use, session);
    if (state_ == State::kArmed) use = {};  // the reset is asked for again
  }
  if (state_ == State::kOn) recorder_->add_samples(use);
  if (!use.empty()) last_seq_ = use.back().seq;
  frame_ticks_ = state_ == State::kOn ? use.size() : 0;
  return use;
}

void RecorderControl::begin(std::span<const ToolSample> from_reset, VizSession& session) {
  // Each hand's reset tick's patch and every newer one this viz published: what the recorded ticks
  // use before the first recorded frame publishes. A hand whose reset sample has not arrived yet
  // (the ring had only the other's when drained) reset in the same tick: the patch its newest
  // sample used is no newer than that tick's.
  const std::size_t hands = session.hands();
  std::array<std::uint64_t, kHandCount> reset_patch{};
  for (std::size_t h = 0; h < hands; ++h) {
    const auto hand = static_cast<Hand>(h);
    const auto own = std::find_if(from_reset.begin(), from_reset.end(), [&](const ToolSample& t) { return t.hand == hand; });
    reset_patch[h] = own != from_reset.end() ? own->patch_version : session.latest(hand).patch_version;
    const auto& kept = armed_patches_[h];
    const bool have = reset_patch[h] == 0 || std::any_of(kept.begin(), kept.end(), [&](const auto& a) { return a.first == reset_patch[h]; });
    if (!have) {
      // (Only if the reset took longer than kArmedPatches frames to come back.) Ask again.
      std::fprintf(stderr, "lancet-viz: the %s hand's reset used patch %llu, no longer kept: sending the reset again\n",
                   hand_name(hand), static_cast<unsigned long long>(reset_patch[h]));
      state_ = State::kArmed;
      return;
    }
  }
  record::Recording meta;
  meta.lancet_version = lancet_version_;
  meta.layout_hash = kSharedLayoutHash;
  meta.protocol = kProtocolVersion;
  char when[32];
  const std::time_t wall = std::time(nullptr);
  std::strftime(when, sizeof when, "%Y-%m-%dT%H:%M:%SZ", std::gmtime(&wall));
  meta.created = when;
  meta.scenario_name = scenario_name_;
  meta.scenario_toml = setup_.scenario_toml;
  meta.scenario_file = setup_.scenario_file;
  meta.tissue = setup_.tissue;
  meta.volume_path = setup_.volume_path;
  meta.patch_radius = setup_.patch_radius;
  meta.servo_hash_every = static_cast<std::uint32_t>(servo::kServoHashEvery);
  meta.scene_hash_every = record::kSceneHashEvery;
  meta.hands = static_cast<std::uint32_t>(hands);
  for (std::size_t h = 0; h < hands; ++h) (void)session.read_servo_model(static_cast<Hand>(h), meta.servo_model[h]);
  meta.arm_config = session.read_arm_config(Hand::kRight);
  if (hands > 1) meta.left_arm_config = session.read_arm_config(Hand::kLeft);
  meta.period_ns = session.rt_status() ? session.rt_status()->period_ns : 1'000'000;
  for (std::size_t h = 0; h < hands; ++h) {
    for (const auto& [version, kept] : armed_patches_[h]) {
      if (reset_patch[h] == 0 || version < reset_patch[h]) continue;
      meta.first_patch_versions.push_back(version);
      meta.first_patches.push_back(*kept);
    }
  }
  auto made = record::Recorder::create(path_, meta);
  if (!made.ok()) {
    std::fprintf(stderr, "lancet-viz: %s\n", made.error().message.c_str());
    message_ = made.error().message;
    state_ = State::kOff;
    return;
  }
  recorder_ = std::move(made).value();
  state_ = State::kOn;
  frames_ = 0;
  message_.clear();
  std::printf("lancet-viz: recording to %s from servo tick %llu\n", path_.c_str(),
              static_cast<unsigned long long>(from_reset.front().seq));
}

void RecorderControl::keep_published(const VizSession& session, const std::array<bool, kHandCount>& published) {
  for (std::size_t h = 0; h < kHandCount; ++h) {
    auto& kept_h = armed_patches_[h];
    if ((state_ == State::kArmed || state_ == State::kWaitingReset) && published[h]) {
      const auto hand = static_cast<Hand>(h);
      std::unique_ptr<TissuePatch> kept;
      if (kept_h.size() >= kArmedPatches) {
        kept = std::move(kept_h.front().second);
        kept_h.pop_front();
      } else {
        kept = std::make_unique<TissuePatch>();
      }
      std::memcpy(static_cast<void*>(kept.get()), &session.patch(hand), tissue_patch_bytes(session.patch(hand)));
      kept_h.emplace_back(session.patch_version(hand), std::move(kept));
    }
    if (state_ == State::kOff || state_ == State::kOn) kept_h.clear();
  }
}

bool RecorderControl::servo_uses_ours(const VizSession& session) const {
  for (std::size_t h = 0; h < session.hands(); ++h) {
    const auto hand = static_cast<Hand>(h);
    const auto& kept = armed_patches_[h];
    if (!session.has_sample(hand) || kept.empty() || session.latest(hand).patch_version < kept.front().first) return false;
  }
  return true;
}

void RecorderControl::after_frame(VizSession& session, sim::SceneSim& sim, const sim::FrameResult& frame, std::int64_t now_ns) {
  keep_published(session, frame.patch);
  // The session's start: the servo's reset, for every hand at once, once each hand uses a patch
  // this viz published (the reset keeps the tool in hand).
  if (session.link() == Link::kConnected && state_ == State::kArmed && servo_uses_ours(session)) {
    if (session.send_each_hand(CommandKind::kReset, session.hands(), now_ns)) state_ = State::kWaitingReset;
  }
  if (state_ != State::kOn) return;
  record::FrameRecord f;
  f.frame = frames_;
  f.t_ns = now_ns;
  f.last_seq = last_seq_;
  f.ticks = frame_ticks_;
  frame_ticks_ = 0;
  // Each hand's patch published this frame: its version, header and centre (the right hand's in
  // patch_*, the left's in left_patch_*).
  const auto published = [&](Hand hand, std::uint64_t& version, std::uint64_t& seq, std::int64_t& t_ns, std::uint64_t& applied,
                              Vec3& centre) {
    if (!frame.patch[hand_index(hand)]) return;
    const TissuePatch& p = session.patch(hand);
    version = session.patch_version(hand);
    seq = p.seq, t_ns = p.t_ns, applied = p.samples_applied;
    centre = session.latest(hand).tool.position;
  };
  published(Hand::kRight, f.patch_version, f.patch_seq, f.patch_t_ns, f.patch_samples_applied, f.patch_centre);
  published(Hand::kLeft, f.left_patch_version, f.left_patch_seq, f.left_patch_t_ns, f.left_patch_samples_applied, f.left_patch_centre);
  f.blood_dt = frame.blood_dt;
  sim.figures(f);
  if (frames_ % record::kSceneHashEvery == 0) f.scene_hash = sim.hash();
  recorder_->add_frame(f);
  events_.clear();
  sim.take_events(frames_, now_ns, events_);
  for (const auto& e : events_) recorder_->add_event(e);
  ++frames_;
}

std::string RecorderControl::after_rt_loss(const VizSession& session) {
  if (session.rt_losses() == rt_losses_seen_) return {};
  rt_losses_seen_ = session.rt_losses();
  if (state_ == State::kOff) return {};
  // Its servo's state went with it, so the attempt (and its recording) ends here.
  const bool was_recording = state_ == State::kOn;
  stop();
  if (was_recording) std::printf("lancet-viz: lancet-rt went away: the recording ends there\n");
  std::string next;
  if (!record_path_.empty()) {
    const std::filesystem::path base(record_path_);
    next = (base.parent_path() / (base.stem().string() + "-" + std::to_string(++parts_) + base.extension().string())).string();
    std::printf("lancet-viz: the next attempt will be recorded to %s once lancet-rt is back\n", next.c_str());
  }
  std::fflush(stdout);
  return next;
}

std::string RecorderControl::panel_line() const {
  if (state_ == State::kOn) {
    char buf[200];
    std::snprintf(buf, sizeof buf, "REC %s: %llu ticks, %llu lost", path_.c_str(),
                  static_cast<unsigned long long>(recorder_->samples()), static_cast<unsigned long long>(recorder_->samples_lost()));
    return buf;
  }
  if (state_ != State::kOff) return "recording: waiting for lancet-rt's reset";
  return message_;
}

}  // namespace lancet::viz
