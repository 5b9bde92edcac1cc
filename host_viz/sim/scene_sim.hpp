#pragma once
// SceneSim: what lancet-viz simulates — the tissue scene, its blood and the task's monitor — built
// the same way live and in a replay, and stepped the same way by the one frame function
// (sim/viz_frame.hpp): the frame's samples (apply), the patch around the newest tool position
// and the blood's preparation beside it (export_patches_and_prepare_blood), the blood stepped by the
// frame's time (step_blood). Its hash() covers the drawn surface, the blood on it and the task's
// figures, so a replay can check it frame by frame.
// No OpenGL: tested headless.

#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "blood/bleeding.hpp"
#include "blood/worker_pool.hpp"
#include "score/task_monitor.hpp"
#include "sim/blood_behind.hpp"
#include "tissue/scenario_scene.hpp"
#include "tissue/tissue_scene.hpp"
#include "lancet/shared_model/result.hpp"
#include "recording/recording.hpp"

namespace lancet::sim {

/// How the visualizer's simulation is set up (lancet-viz's command line; a recording keeps it).
struct SceneSetup {
  std::string tissue = "block";   ///< without a scenario: "block" or "phantom"
  std::string scenario_toml;      ///< with a scenario: its text ...
  std::string scenario_file;      ///< ... and where it came from (relative tissue paths resolve against it)
  std::string volume_path;        ///< --volume ("" when none)
  double patch_radius = 0.04;     ///< m (lancet-viz's --patch-radius-mm; a recording keeps its own)
};

class SceneSim {
 public:
  /// Builds the scene (loading the CT a file scenario names). Errors say what the scenario or the
  /// volume got wrong.
  [[nodiscard]] static Result<std::unique_ptr<SceneSim>> create(const SceneSetup& setup);

  /// One frame's samples, in order (one batch a frame: the batch's end matters to the scene).
  void apply(std::span<const ToolSample> samples);
  /// The patch around `at` (m); returns its triangle count. Leaves the header (seq, t_ns,
  /// samples_applied) to the caller.
  std::size_t export_patch(Vec3 at, TissuePatch& patch);
  /// What a frame reads from the scene once it has applied its samples: each hand's patch where
  /// patches[h] is not null, around centres[h] (m), as TissueScene::export_patch makes it (at [h]
  /// its triangle count; the header, seq, t_ns and samples_applied, is the caller's), and
  /// the blood's preparation for blood_dt s (Bleeding::prepare; step_blood then steps it). They
  /// only read the scene, so they run at once on two threads (each patch with its own scratch),
  /// and each comes out as it would alone.
  std::array<std::size_t, kHandCount> export_patches_and_prepare_blood(const std::array<TissuePatch*, kHandCount>& patches,
                                                                       const std::array<Vec3, kHandCount>& centres, double blood_dt);
  /// Steps the blood that export_patches_and_prepare_blood prepared (nothing without blood, and
  /// nothing with the blood behind, whose thread steps it).
  void step_blood();
  /// On: from the next frame, the blood is prepared and stepped behind the caller, on a thread of
  /// its own (sim/blood_behind.hpp): export_patches_and_prepare_blood hands it the frame's blood
  /// time, the next apply() (or scene() for changing) waits until it is prepared, and whatever
  /// reads the blood (hash, figures, take_events, bleeding()) until it is stepped. The same blood,
  /// bit for bit. For a replay, which looks at the blood only at hashes; off (the default, and
  /// what the live viz runs, which draws the blood every frame): waits for it and steps as before.
  void set_blood_behind(bool on);
  /// Seconds spent waiting for the blood behind so far: before changing the scene, and before
  /// reading the blood.
  [[nodiscard]] double blood_waited_for_scene_s() const noexcept { return waited_prepared_s_; }
  [[nodiscard]] double blood_waited_for_blood_s() const noexcept { return waited_stepped_s_; }
  /// The task's and the blood's figures after this frame, into f (the rest of f is the caller's).
  void figures(record::FrameRecord& f) const;
  /// The tissue's events since the last call, appended to `out` (blood sources that began, vessels
  /// that stopped, structures reached, bone drilled), stamped with `frame` and `t_ns`.
  void take_events(std::uint64_t frame, std::int64_t t_ns, std::vector<record::SceneEvent>& out);
  /// A hash of the drawn surface, the blood on it and the task's figures (never 0).
  [[nodiscard]] std::uint64_t hash() const;

  [[nodiscard]] tissue::TissueScene& scene() noexcept { return wait_blood_prepared(), *scene_; }
  [[nodiscard]] const tissue::TissueScene& scene() const noexcept { return *scene_; }
  [[nodiscard]] blood::Bleeding* bleeding() noexcept { return wait_blood_stepped(), bleeding_.get(); }
  [[nodiscard]] const blood::Bleeding* bleeding() const noexcept { return wait_blood_stepped(), bleeding_.get(); }
  [[nodiscard]] score::TaskMonitor* task() noexcept { return task_ ? &*task_ : nullptr; }
  [[nodiscard]] const score::TaskMonitor* task() const noexcept { return task_ ? &*task_ : nullptr; }
  [[nodiscard]] const scenario::Scenario* scenario() const noexcept { return scenario_ ? &*scenario_ : nullptr; }
  [[nodiscard]] const SceneSetup& setup() const noexcept { return setup_; }

 private:
  SceneSim() = default;
  SceneSetup setup_;
  std::optional<scenario::Scenario> scenario_;
  std::unique_ptr<tissue::TissueScene> scene_;
  std::unique_ptr<blood::Bleeding> bleeding_;
  std::optional<score::TaskMonitor> task_;
  std::array<tissue::PatchExportScratch, kHandCount> patch_scratch_;  // by hand
  std::unique_ptr<blood::WorkerPool> pool_;  // the patches and the blood's preparation
  std::unique_ptr<BloodBehind> behind_;       // with set_blood_behind(true); before bleeding_ dies
  mutable double waited_prepared_s_ = 0, waited_stepped_s_ = 0;
  void wait_blood_prepared() const noexcept;
  void wait_blood_stepped() const noexcept;
  // What take_events has reported.
  std::size_t sources_seen_ = 0;
  std::vector<bool> stopped_seen_, damaged_seen_;
  std::uint64_t voxels_seen_ = 0;
  Vec3 last_removal_{};
};

}  // namespace lancet::sim
