#pragma once
// From a training scenario (host_viz/scenarios) to what the visualizer runs: the scene's
// description (loading the CT a file scenario names, or the one given on the command line), and
// the task's progress measured on the scene — how much of the incision line has been cut, how
// much of the drill window removed, and which structures not to damage have been reached.

#include <string>
#include <vector>

#include "hybrid/tissue_scene.hpp"
#include "lancet/shared_model/result.hpp"
#include "scenarios/scenario.hpp"
#include "volume/volume.hpp"

namespace lancet::hybrid {

/// Loads a CT: a DICOM series (a directory), MetaImage (.mhd, .mha) or NRRD (.nrrd, .nhdr).
/// Errors name the path and what is wrong with it.
[[nodiscard]] Result<volume::Volume> load_ct(const std::string& path);

/// The scene a scenario describes. volume_override (the command line's --volume) replaces the
/// file's path and is required when a file scenario names none; it is refused for a phantom or
/// block scenario (it would be silently ignored).
[[nodiscard]] Result<SceneDescription> scene_description(const scenario::Scenario& s, const std::string& volume_override = {});

/// How the trainee is doing on the scenario's task.
struct TaskStatus {
  double progress = 0;        ///< 0..1: the incision line covered, or the drill window's bone removed
  double max_deviation = 0;   ///< m, incision: the cuts' farthest point from the line
  double outside = 0;         ///< incision: fraction of the cut length off the line
  double window_removed = 0;  ///< m³, drill: the bone removed from the drill window so far
  std::vector<std::string> damaged;  ///< names of the structures reached (by a cut's depth or the drill)
  std::vector<bool> damaged_flags;   ///< per scenario avoid entry: reached
  std::string line;           ///< one line for the screen
};

/// Measures the task on the scene. Labelled structures are reached when a voxel of that label was
/// drilled away (the scene's volume no longer has it where it had it) or lies under a cut within
/// the cut depth; shapes when a drill removal or a cut point within the cut depth touches them.
class TaskMonitor {
 public:
  TaskMonitor(const scenario::Scenario& s, const TissueScene& scene);
  /// Re-measures (cheap: the cut paths and the drill removals seen so far).
  const TaskStatus& update(const TissueScene& scene, std::span<const ToolSample> samples);
  [[nodiscard]] const TaskStatus& status() const noexcept { return status_; }

 private:
  const scenario::Scenario* s_;
  std::size_t drill_bone_ = 0;      ///< bone voxels in the drill window at the start
  std::vector<std::size_t> label_voxels_;  ///< per avoid entry with a label: its voxels at the start
  std::vector<bool> damaged_;
  std::vector<std::size_t> cut_points_checked_;  ///< per cut: path points already checked for structures
  TaskStatus status_;
  std::size_t window_bone_now(const TissueScene& scene) const;
  std::size_t label_count(const TissueScene& scene, std::uint8_t label) const;
};

}  // namespace lancet::hybrid
