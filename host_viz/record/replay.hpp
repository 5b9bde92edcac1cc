#pragma once
// Replay: a recorded session re-fed through the same servo step (firmware_rt/servo) and the same
// visualizer simulation, frame by frame, checking that it comes out the same.
//
// SceneSim is what lancet-viz simulates each frame — the tissue scene, its blood and the task's
// monitor — built the same way live and in a replay, and stepped the same way: one batch of
// samples a frame (apply), the patch around the newest tool position (export_patch), the blood
// advanced by the frame's time (advance_blood). Its hash() covers the drawn surface, the blood on
// it and the task's figures.
//
// Replay checks, as it goes: every replayed ToolSample against the recorded one (force, proxy,
// stage, events, and the servo's state hash every kServoHashEvery ticks), and the scene's hash
// wherever the recording has one. Bit-exact: the same build replays its recordings with zero
// mismatches; a recording from another shared layout is refused (both hashes named). After a gap
// in the recorded ticks (a viz that stalled longer than the sample ring holds) the servo cannot be
// re-stepped: the recorded ticks then drive the scene, whose hashes are still checked
// (ReplayCheck::gap_seq says where). A recording cut short (Recording::cut_short) replays up to
// where its file ends.

#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "hybrid/bleeding.hpp"
#include "hybrid/scenario_scene.hpp"
#include "hybrid/tissue_scene.hpp"
#include "lancet/shared_model/result.hpp"
#include "record/recording.hpp"
#include "servo/servo_step.hpp"

namespace lancet::record {

/// How the visualizer's simulation is set up (lancet-viz's command line; a recording keeps it).
struct SceneSetup {
  std::string tissue = "block";   ///< without a scenario: "block" or "phantom"
  std::string scenario_toml;      ///< with a scenario: its text ...
  std::string scenario_file;      ///< ... and where it came from (relative tissue paths resolve against it)
  std::string volume_path;        ///< --volume ("" when none)
  double patch_radius = 0.03;     ///< m
};

/// The scene hash is taken every this many frames.
inline constexpr std::uint32_t kSceneHashEvery = 30;

class SceneSim {
 public:
  /// Builds the scene (loading the CT a file scenario names). Errors say what the scenario or the
  /// volume got wrong.
  [[nodiscard]] static Result<std::unique_ptr<SceneSim>> create(const SceneSetup& setup);

  /// One frame's samples, in order (one batch a frame: the batch's end matters to the scene).
  void apply(std::span<const ToolSample> samples);
  /// The patch around `at` (m); returns its triangle count.
  std::size_t export_patch(Vec3 at, TissuePatch& patch);
  /// Simulates the blood for dt seconds.
  void advance_blood(double dt);
  /// The task's and the blood's figures after this frame, into f (the rest of f is the caller's).
  void figures(FrameRecord& f) const;
  /// The tissue's events since the last call, appended to `out` (blood sources that began, vessels
  /// that stopped, structures reached, bone drilled), stamped with `frame` and `t_ns`.
  void take_events(std::uint64_t frame, std::int64_t t_ns, std::vector<SceneEvent>& out);
  /// A hash of the drawn surface, the blood on it and the task's figures (never 0).
  [[nodiscard]] std::uint64_t hash() const;

  [[nodiscard]] hybrid::TissueScene& scene() noexcept { return *scene_; }
  [[nodiscard]] hybrid::Bleeding* bleeding() noexcept { return bleeding_.get(); }
  [[nodiscard]] hybrid::TaskMonitor* task() noexcept { return task_ ? &*task_ : nullptr; }
  [[nodiscard]] const scenario::Scenario* scenario() const noexcept { return scenario_ ? &*scenario_ : nullptr; }
  [[nodiscard]] const SceneSetup& setup() const noexcept { return setup_; }

 private:
  SceneSim() = default;
  SceneSetup setup_;
  std::optional<scenario::Scenario> scenario_;
  std::unique_ptr<hybrid::TissueScene> scene_;
  std::unique_ptr<hybrid::Bleeding> bleeding_;
  std::optional<hybrid::TaskMonitor> task_;
  // What take_events has reported.
  std::size_t sources_seen_ = 0;
  std::vector<bool> stopped_seen_, damaged_seen_;
  std::uint64_t voxels_seen_ = 0;
  Vec3 last_removal_{};
};

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

class Replay {
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
  /// The patch published by the newest replayed frame (null before the first).
  [[nodiscard]] const TissuePatch* patch() const noexcept;
  [[nodiscard]] SceneSim& sim() noexcept { return *sim_; }
  [[nodiscard]] const Recording& recording() const noexcept { return *rec_; }
  /// The replayed samples so far (live metrics and replayed metrics must agree on them).
  [[nodiscard]] const std::vector<ToolSample>& replayed() const noexcept { return replayed_; }

 private:
  Replay() = default;
  const Recording* rec_ = nullptr;
  std::unique_ptr<SceneSim> sim_;
  servo::ServoModel model_{};
  servo::ServoData data_{};
  servo::ServoOutput out_{};
  std::size_t next_sample_ = 0, next_frame_ = 0;
  std::deque<std::pair<std::uint64_t, std::unique_ptr<TissuePatch>>> patches_;  // by version: those later ticks may use
  std::vector<ToolSample> batch_, replayed_;
  ToolSample latest_{};
  bool has_latest_ = false;
  ReplayCheck check_{};
  ReplayTiming timing_{};
  const TissuePatch* find_patch(std::uint64_t version) const;
};

}  // namespace lancet::record
