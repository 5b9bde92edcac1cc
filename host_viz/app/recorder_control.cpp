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
    recorder_.reset();
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
  // The reset tick's patch and every newer one this viz published: what the recorded ticks use
  // before the first recorded frame publishes.
  const std::uint64_t reset_patch = from_reset.front().patch_version;
  const bool have_patches = reset_patch == 0 || std::any_of(armed_patches_.begin(), armed_patches_.end(),
                                                            [&](const auto& a) { return a.first == reset_patch; });
  if (!have_patches) {
    // (Only if the reset took longer than kArmedPatches frames to come back.) Ask again.
    std::fprintf(stderr, "lancet-viz: the servo's reset used patch %llu, no longer kept: sending the reset again\n",
                 static_cast<unsigned long long>(reset_patch));
    state_ = State::kArmed;
    return;
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
  (void)session.read_servo_model(meta.servo_model);
  meta.arm_config = session.read_arm_config();
  meta.period_ns = session.rt_status() ? session.rt_status()->period_ns : 1'000'000;
  for (const auto& [version, kept] : armed_patches_) {
    if (reset_patch == 0 || version < reset_patch) continue;
    meta.first_patch_versions.push_back(version);
    meta.first_patches.push_back(*kept);
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

void RecorderControl::keep_published(const VizSession& session, bool published) {
  if ((state_ == State::kArmed || state_ == State::kWaitingReset) && published) {
    std::unique_ptr<TissuePatch> kept;
    if (armed_patches_.size() >= kArmedPatches) {
      kept = std::move(armed_patches_.front().second);
      armed_patches_.pop_front();
    } else {
      kept = std::make_unique<TissuePatch>();
    }
    std::memcpy(static_cast<void*>(kept.get()), &session.patch(), tissue_patch_bytes(session.patch()));
    armed_patches_.emplace_back(session.patch_version(), std::move(kept));
  }
  if (state_ == State::kOff || state_ == State::kOn) armed_patches_.clear();
}

void RecorderControl::after_frame(VizSession& session, sim::SceneSim& sim, const sim::FrameResult& frame, std::int64_t now_ns) {
  keep_published(session, frame.patch);
  // The session's start: the servo's reset, once the servo uses a patch this viz published (the
  // reset keeps the tool in hand).
  const bool servo_uses_ours = session.has_sample() && !armed_patches_.empty() &&
                               session.latest().patch_version >= armed_patches_.front().first;
  if (session.link() == Link::kConnected && state_ == State::kArmed && servo_uses_ours) {
    Command c{};
    c.kind = CommandKind::kReset;
    if (session.send(c, now_ns)) state_ = State::kWaitingReset;
  }
  if (state_ != State::kOn) return;
  record::FrameRecord f;
  f.frame = frames_;
  f.t_ns = now_ns;
  f.last_seq = last_seq_;
  f.ticks = frame_ticks_;
  frame_ticks_ = 0;
  if (frame.patch) {
    const TissuePatch& p = session.patch();
    f.patch_version = session.patch_version();
    f.patch_seq = p.seq;
    f.patch_t_ns = p.t_ns;
    f.patch_samples_applied = p.samples_applied;
    f.patch_centre = session.latest().tool.position;
  }
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
