#pragma once
// Replay: a recorded session re-fed through the same servo step (firmware_rt/servo) and the same
// visualizer frame (sim::run_frame, which the live viz runs too), frame by frame, checking that it
// comes out the same. A replay is that frame's FrameIo: its samples are the recorded frame's ticks
// re-stepped through the servo, its patch is kept for the later ticks that used it, and its blood
// time is the recorded one.
//
// Replay checks, as it goes: every replayed ToolSample against the recorded one (force, proxy,
// stage, events, and the servo's state hash every kServoHashEvery ticks), and the scene's hash
// wherever the recording has one. Bit-exact: the same build replays its recordings with zero
// mismatches; a recording from another shared layout is refused (both hashes named). After a gap
// in the recorded ticks (a viz that stalled longer than the sample ring holds) the servo cannot be
// re-stepped: the recorded ticks then drive the scene, whose hashes are still checked
// (ReplayCheck::gap_seq says where). A recording cut short (Recording::cut_short) replays up to
// where its file ends.

#include <array>
#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "lancet/shared_model/result.hpp"
#include "recording/recording.hpp"
#include "servo/servo_step.hpp"
#include "sim/scene_sim.hpp"
#include "sim/viz_frame.hpp"

namespace lancet::record {

/// What the replay found so far.
struct ReplayCheck {
  std::uint64_t ticks = 0, frames = 0;
  std::uint64_t servo_hashes = 0, servo_hash_mismatches = 0;
  std::uint64_t sample_mismatches = 0;  ///< force, proxy, stage or events not bit-identical
  std::uint64_t scene_hashes = 0, scene_hash_mismatches = 0;
  std::uint64_t first_bad_seq = 0;      ///< 0: none
  std::uint64_t first_bad_frame = 0;    ///< frame + 1 (0: none)
  /// The first tick after a gap in the recording (0: none): the servo is re-stepped and checked up
  /// to it; after it the recorded ticks drive the scene, which is still checked.
  std::uint64_t gap_seq = 0;
  std::uint64_t ticks_lost = 0;         ///< missing at that gap
  std::uint64_t ticks_unchecked = 0;    ///< recorded ticks from the gap on (not re-stepped)
  [[nodiscard]] bool exact() const noexcept {
    return servo_hash_mismatches == 0 && sample_mismatches == 0 && scene_hash_mismatches == 0;
  }
};

/// Where a replay's time went (s), for the benchmark.
struct ReplayTiming {
  double servo = 0, scene = 0, patch = 0, blood = 0, hash = 0;
};

class Replay final : private sim::FrameIo {
 public:
  /// Refuses a recording of another shared layout or servo model layout (naming both), one with
  /// no ticks or frames, or one whose scene cannot be built.
  [[nodiscard]] static Result<std::unique_ptr<Replay>> create(const Recording& recording);

  /// Replays the next recorded frame: its servo ticks, the scene's batch, the patch, the blood,
  /// and the checks. False at the end. An error (a patch version the recording does not have)
  /// stops the replay.
  [[nodiscard]] Result<bool> step_frame();
  /// Replays every remaining frame.
  [[nodiscard]] Result<ReplayCheck> run();

  [[nodiscard]] const ReplayCheck& check() const noexcept { return check_; }
  [[nodiscard]] const ReplayTiming& timing() const noexcept { return timing_; }
  [[nodiscard]] std::size_t frame() const noexcept { return next_frame_; }   ///< frames replayed
  [[nodiscard]] std::size_t frames() const noexcept { return rec_->frames.size(); }
  [[nodiscard]] bool done() const noexcept { return next_frame_ >= rec_->frames.size(); }
  /// Seconds since the first recorded tick, of the newest tick replayed.
  [[nodiscard]] double time_s() const noexcept;
  [[nodiscard]] double duration_s() const noexcept;
  [[nodiscard]] const ToolSample* latest() const noexcept { return has_latest_ ? &latest_ : nullptr; }
  /// The patch published for hand h by the newest replayed frame that published one (null before the first).
  [[nodiscard]] const TissuePatch* patch(Hand h = Hand::kRight) const noexcept;
  /// The newest replayed tick of hand h (null before its first).
  [[nodiscard]] const ToolSample* latest(Hand h) const noexcept { return has_hand_[hand_index(h)] ? &latest_by_hand_[hand_index(h)] : nullptr; }
  [[nodiscard]] sim::SceneSim& sim() noexcept { return *sim_; }
  [[nodiscard]] const Recording& recording() const noexcept { return *rec_; }
  /// The replayed samples so far (live metrics and replayed metrics must agree on them).
  [[nodiscard]] const std::vector<ToolSample>& replayed() const noexcept { return replayed_; }

 private:
  Replay() = default;
  const Recording* rec_ = nullptr;
  std::unique_ptr<sim::SceneSim> sim_;
  // By hand.
  std::array<servo::ServoModel, kHandCount> model_{};
  std::array<servo::ServoData, kHandCount> data_{};
  servo::ServoOutput out_{};
  std::size_t next_sample_ = 0, next_frame_ = 0;
  // By hand, by version: the patches later ticks may use.
  std::array<std::deque<std::pair<std::uint64_t, std::unique_ptr<TissuePatch>>>, kHandCount> patches_;
  std::array<std::unique_ptr<TissuePatch>, kHandCount> filling_;  // the frame's patches, between drain() and publish()
  std::vector<ToolSample> batch_, replayed_;
  ToolSample latest_{};
  bool has_latest_ = false;
  std::array<ToolSample, kHandCount> latest_by_hand_{};  // the newest recorded tick of each hand
  std::array<bool, kHandCount> has_hand_{};
  ReplayCheck check_{};
  ReplayTiming timing_{};
  const TissuePatch* find_patch(Hand hand, std::uint64_t version) const;
  static std::uint64_t frame_patch_version(const FrameRecord& f, std::size_t hand) noexcept;
  // The recorded frame next_frame_ as the frame function's two ends.
  Result<sim::FrameBatch> drain() override;
  void publish(const std::array<const TissuePatch*, kHandCount>& patches) override;
};

}  // namespace lancet::record
