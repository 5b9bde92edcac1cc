#include "app/viz_session.hpp"

#include "lancet/shared_model/validate.hpp"

#include <algorithm>
#include <cassert>

#include <unistd.h>

#include <utility>

namespace lancet::viz {

VizSession::VizSession(VizSessionParams params)
    : params_(std::move(params)), batch_(512) {
  for (auto& p : patch_) p = std::make_unique<TissuePatch>();
  message_ = "waiting for lancet-rt on " + params_.shm_name;
}

void VizSession::try_attach(std::int64_t now_ns) {
  if (now_ns < next_attempt_ns_) return;
  next_attempt_ns_ = now_ns + params_.retry_ns;
  auto ch = SharedChannel::open(params_.shm_name);
  if (!ch) {
    const Error& e = ch.error();
    // A mismatched peer is a build problem the user must fix: say exactly that.
    if (link_ == Link::kWaiting || e.code == ErrorCode::kMismatch) message_ = e.message;
    return;
  }
  channel_.emplace(std::move(ch).value());
  SharedState& s = channel_->state();
  total_received_ += stats_.received;
  stats_.restart();
  // Samples queued before we attached are history; start from the live edge.
  bool reset = false;
  stats_.discarded = s.samples.discard_all(&reset);
  samples_applied_ = 0;  // this lancet-rt's ticks start again
  hand_seq_.fill(0);
  if (reset) ++stats_.ring_resets;
  link_ = Link::kConnected;
  ++connections_;
  message_ = "connected to lancet-rt (pid " + std::to_string(channel_->segment().creator_pid()) + ") on " +
             params_.shm_name;
}

void VizSession::detach(const std::string& why) {
  if (channel_) channel_->state().viz_heartbeat.stop();
  channel_.reset();
  link_ = Link::kLost;
  ++rt_losses_;
  rt_status_.reset();
  message_ = why;
}

std::span<const ToolSample> VizSession::drain(std::int64_t now_ns) {
  ++frame_;
  drained_.clear();
  if (!channel_) try_attach(now_ns);
  if (!channel_) return {};
  SharedState& s = channel_->state();

  // Is lancet-rt still there? A clean exit stops its heartbeat at once; a crash leaves it stale.
  if (!s.rt_heartbeat.fresh(now_ns, params_.rt_timeout_ns)) {
    const bool alive = channel_->segment().creator_alive();
    // last_ns() == 0 with beats counted is a clean exit; with none counted, rt has not ticked yet.
    if (!alive || (s.rt_heartbeat.last_ns() == 0 && s.rt_heartbeat.count() > 0)) {
      detach("lancet-rt is not running (pid " + std::to_string(channel_->segment().creator_pid()) +
             " exited): haptics stopped, waiting for it to restart");
      return {};
    }
    if (s.rt_heartbeat.count() > 0) {
      message_ = "lancet-rt (pid " + std::to_string(channel_->segment().creator_pid()) +
                 ") is not answering: its loop is stalled";
    }
  } else if (link_ == Link::kConnected && message_.find("not answering") != std::string::npos) {
    message_ = "connected to lancet-rt (pid " + std::to_string(channel_->segment().creator_pid()) + ")";
  }

  // Drain the ToolSamples since the last frame: at most one ring's worth, whatever the ring's
  // indices say, and only samples that pass the checks.
  for (std::size_t popped = 0; popped < kSampleRingCapacity;) {
    bool reset = false;
    const std::size_t n = s.samples.try_pop_n(batch_.data(), batch_.size(), &reset);
    if (reset) {
      ++stats_.ring_resets;
      stats_.last_reject = "samples ring: indices impossible, reset";
    }
    if (n == 0) break;
    popped += n;
    std::size_t kept = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const char* why = wire::check(batch_[i]);
      // Each hand's ticks come in order, a ring's worth at most ahead of its last: a sample a
      // little behind (a stale slot) or far ahead (no overflow is that long) is garbage in the
      // segment; applying it would replay old events or make every later tick look old. A sample
      // far *behind* says the last one taken was the garbage: it is taken, and the count starts
      // from it.
      const std::size_t h = why == nullptr ? hand_index(batch_[i].hand) : 0;
      const std::uint64_t seq = batch_[i].seq, last = hand_seq_[h];
      const bool stale = seq <= last && last - seq <= kSampleRingCapacity;
      if (why == nullptr && last != 0 && (stale || (seq > last && seq - last > kSampleRingCapacity)))
        why = "sample.seq: not after the last one, or further ahead than the ring holds";
      if (why != nullptr) {
        ++stats_.rejected;
        stats_.last_reject = why;
        continue;
      }
      hand_seq_[h] = seq;
      samples_applied_ = seq;
      latest_by_hand_[h] = batch_[i];
      batch_[kept++] = batch_[i];
    }
    if (kept > 0) {
      stats_.ingest(batch_.data(), kept);
      latest_ = batch_[kept - 1];
      drained_.insert(drained_.end(), batch_.begin(), batch_.begin() + static_cast<std::ptrdiff_t>(kept));
    }
    if (n < batch_.size()) break;
  }

  RtStatus st{};
  if (s.rt_status.try_read(st) == ReadStatus::kOk) {
    if (const char* why = wire::check(st)) {
      ++stats_.status_rejected;
      stats_.last_reject = why;
    } else {
      rt_status_ = st;
    }
  }
  return drained_;
}

void VizSession::publish(const std::array<const TissuePatch*, kHandCount>& patches, std::int64_t now_ns) {
  if (!channel_) return;
  SharedState& s = channel_->state();
  for (std::size_t h = 0; h < kHandCount; ++h) {
    const TissuePatch* patch = patches[h];
    if (patch == nullptr) continue;
    assert(patch == patch_[h].get() && "VizSession::publish: a hand's patch is the one filled in patch_buffer(hand)");
    s.patch[h].publish_prefix(*patch, tissue_patch_bytes(*patch));
    patch_version_[h] = s.patch[h].version();
    ++patches_published_;
  }
  s.viz_heartbeat.beat(now_ns, static_cast<std::int32_t>(getpid()));
}

bool VizSession::read_servo_model(Hand h, ServoModelBlob& out) {
  if (!channel_ || hand_index(h) >= kHandCount) return false;
  return channel_->state().servo_model[hand_index(h)].try_read(out, 100) == ReadStatus::kOk;
}

std::string VizSession::read_arm_config(Hand h) {
  if (!channel_ || hand_index(h) >= kHandCount) return {};
  auto blob = std::make_unique<ArmConfigText>();
  if (channel_->state().arm_config[hand_index(h)].try_read(*blob, 100) != ReadStatus::kOk) return {};
  // What the peer wrote is input: its size is bounded, its bytes made printable.
  std::string text(blob->text, std::min<std::size_t>(blob->size, kArmConfigCapacity));
  for (char& c : text) {
    const auto u = static_cast<unsigned char>(c);
    if (!(u == '\n' || u == '\t' || (u >= 0x20 && u < 0x7f))) c = '?';
  }
  if (blob->truncated != 0) text += "\n# (truncated: the file is longer than " + std::to_string(kArmConfigCapacity) + " bytes)\n";
  return text;
}

void VizSession::set_stylus_target(Hand hand, bool active, Vec3 position, std::int64_t now_ns) {
  if (!channel_ || hand_index(hand) >= kHandCount) return;
  StylusTarget t{};
  t.seq = ++target_seq_[hand_index(hand)];
  t.t_ns = now_ns;
  t.target = Pose{position, Quat{}};
  t.active = active ? 1u : 0u;
  t.hand = hand;
  channel_->state().stylus_target[hand_index(hand)].write(t);
}

bool VizSession::send(Command c, std::int64_t now_ns) {
  if (!channel_) return false;
  c.seq = ++command_seq_;
  c.t_ns = std::max(now_ns, last_command_t_ns_ + 1);  // lancet-rt takes only newer commands
  last_command_t_ns_ = c.t_ns;
  wire::seal(c);
  return channel_->state().commands.try_push(c);
}

bool VizSession::send_each_hand(CommandKind kind, std::size_t hands, std::int64_t now_ns) {
  if (!channel_ || hands == 0 || hands > kHandCount) return false;
  std::array<Command, kHandCount> cs{};
  for (std::size_t h = 0; h < hands; ++h) {
    Command& c = cs[h];
    c.kind = kind;
    c.hand = static_cast<Hand>(h);
    c.seq = command_seq_ + 1 + h;
    c.t_ns = std::max(now_ns, last_command_t_ns_ + 1) + static_cast<std::int64_t>(h);  // each newer than the one before
    wire::seal(c);
  }
  if (!channel_->state().commands.try_push_n(cs.data(), hands)) return false;
  command_seq_ += hands;
  last_command_t_ns_ = cs[hands - 1].t_ns;
  return true;
}

}  // namespace lancet::viz
