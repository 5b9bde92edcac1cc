#pragma once
// VizSession: lancet-viz's side of the shared-memory link, with no OpenGL in it (tested headless).
// Each frame begins with drain(): attach to lancet-rt's segment if not attached (retrying twice a
// second), notice when lancet-rt goes away (and keep running), return every ToolSample since the
// last frame (checked, each hand's in order); and ends with publish(): each hand's TissuePatch
// filled in patch_buffer(hand) around that hand's newest tool position, and the viz heartbeat. It knows nothing of the tissue: the frame
// function (sim/viz_frame.hpp) applies the samples to the scene and fills the patch in between.

#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "app/sample_stats.hpp"
#include "lancet/shared_model/shared_state.hpp"

namespace lancet::viz {

enum class Link {
  kWaiting,    ///< never attached yet
  kConnected,  ///< attached and lancet-rt's heartbeat is fresh
  kLost,       ///< was attached; lancet-rt exited or stopped answering
};

struct VizSessionParams {
  std::string shm_name = kDefaultShmName;
  std::int64_t retry_ns = 500'000'000;       ///< attach retry interval
  std::int64_t rt_timeout_ns = 1'000'000'000;  ///< rt heartbeat age that counts as lost
};

class VizSession {
 public:
  explicit VizSession(VizSessionParams params);

  /// The frame's start at now_ns (CLOCK_MONOTONIC): attaches or notices lancet-rt leaving, then
  /// returns the samples since the last frame, checked and in order (at most a ring's worth; empty
  /// when not attached). Valid until the next drain(). Not real-time; allocates only while its
  /// buffers grow.
  [[nodiscard]] std::span<const ToolSample> drain(std::int64_t now_ns);
  /// The frame's end: publishes each hand's patch (patches[h] is patch_buffer(h), filled, with
  /// its header; null: none this frame for that hand) to that hand's buffer, and beats the viz
  /// heartbeat. Nothing when not attached.
  void publish(const std::array<const TissuePatch*, kHandCount>& patches, std::int64_t now_ns);
  /// Where a hand's patch is filled before publish().
  [[nodiscard]] TissuePatch& patch_buffer(Hand h) noexcept { return *patch_[hand_index(h)]; }
  /// Attached to a lancet-rt segment (drain() found it, and it has not gone away).
  [[nodiscard]] bool attached() const noexcept { return channel_.has_value(); }
  /// Frames drained so far (what a patch's seq names).
  [[nodiscard]] std::uint64_t frames() const noexcept { return frame_; }
  /// seq of the newest sample drain() returned since attaching (a patch's samples_applied).
  [[nodiscard]] std::uint64_t samples_applied() const noexcept { return samples_applied_; }
  /// seq of hand h's newest sample drain() returned since attaching (its patch's samples_applied).
  [[nodiscard]] std::uint64_t samples_applied(Hand h) const noexcept { return hand_seq_[hand_index(h)]; }
  /// How many hands lancet-rt drives (its status says; 1 until it has said).
  [[nodiscard]] std::size_t hands() const noexcept { return rt_status_ ? rt_status_->hands : 1; }

  /// Sets (active=true) or releases the stylus target sent to a hand's simulated arm.
  void set_stylus_target(Hand hand, bool active, Vec3 position, std::int64_t now_ns);

  /// Queues a command for lancet-rt (for c.hand); false when not attached or its ring is full.
  bool send(Command c, std::int64_t now_ns);
  /// Queues a command of `kind` for each of the first `hands` hands, all at once: lancet-rt applies
  /// them in one tick (the resets that start a two-handed recording). False when not attached or
  /// the ring has no room for all.
  bool send_each_hand(CommandKind kind, std::size_t hands, std::int64_t now_ns);

  [[nodiscard]] Link link() const noexcept { return link_; }
  /// One line for the user: what the link is doing and what to do about it.
  [[nodiscard]] const std::string& link_message() const noexcept { return message_; }
  [[nodiscard]] const SampleStats& stats() const noexcept { return stats_; }
  /// Stats of the whole run (all connections), for the exit summary.
  [[nodiscard]] std::uint64_t samples_total() const noexcept { return total_received_ + stats_.received; }
  [[nodiscard]] bool has_sample() const noexcept { return stats_.received > 0; }
  /// Whether a sample of hand h has arrived since attaching.
  [[nodiscard]] bool has_sample(Hand h) const noexcept { return stats_.hand_last_seq[hand_index(h)] != 0; }
  /// The newest sample drained (of either hand).
  [[nodiscard]] const ToolSample& latest() const noexcept { return latest_; }
  /// The newest sample of hand h.
  [[nodiscard]] const ToolSample& latest(Hand h) const noexcept { return latest_by_hand_[hand_index(h)]; }
  [[nodiscard]] const TissuePatch& patch(Hand h = Hand::kRight) const noexcept { return *patch_[hand_index(h)]; }
  [[nodiscard]] std::uint64_t patches_published() const noexcept { return patches_published_; }
  /// The version hand h's last patch was published as (what its ToolSample::patch_version names).
  [[nodiscard]] std::uint64_t patch_version(Hand h = Hand::kRight) const noexcept { return patch_version_[hand_index(h)]; }
  /// A hand's servo model (lancet-rt publishes it once at its start); false when not attached or unreadable.
  [[nodiscard]] bool read_servo_model(Hand h, ServoModelBlob& out);
  /// The text of a hand's arm configuration ("" for the built-in stylus, or when not attached):
  /// at most kArmConfigCapacity bytes, bytes other than printable ASCII, tab and newline replaced by '?'.
  [[nodiscard]] std::string read_arm_config(Hand h = Hand::kRight);
  [[nodiscard]] const std::optional<RtStatus>& rt_status() const noexcept { return rt_status_; }
  [[nodiscard]] std::uint32_t connections() const noexcept { return connections_; }
  [[nodiscard]] std::uint32_t rt_losses() const noexcept { return rt_losses_; }

 private:
  void try_attach(std::int64_t now_ns);
  void detach(const std::string& why);

  VizSessionParams params_;
  std::optional<SharedChannel> channel_;
  Link link_ = Link::kWaiting;
  std::string message_;
  std::int64_t next_attempt_ns_ = 0;
  std::uint64_t frame_ = 0;
  SampleStats stats_{};
  std::uint64_t total_received_ = 0;
  ToolSample latest_{};
  std::array<ToolSample, kHandCount> latest_by_hand_{};
  std::vector<ToolSample> batch_;    ///< one pop from the ring
  std::vector<ToolSample> drained_;  ///< the frame's checked samples (what drain() returns)
  std::array<std::unique_ptr<TissuePatch>, kHandCount> patch_;
  std::uint64_t patches_published_ = 0;
  std::array<std::uint64_t, kHandCount> patch_version_{};
  std::optional<RtStatus> rt_status_;
  std::uint64_t command_seq_ = 0;
  std::int64_t last_command_t_ns_ = 0;
  std::array<std::uint64_t, kHandCount> target_seq_{};
  std::uint32_t connections_ = 0;
  std::uint32_t rt_losses_ = 0;
  std::uint64_t samples_applied_ = 0;  ///< seq of the newest sample returned since attaching
  std::array<std::uint64_t, kHandCount> hand_seq_{};  ///< by hand: seq of its newest sample taken since attaching
};

}  // namespace lancet::viz
