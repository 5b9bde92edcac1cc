#pragma once
// The scenario's task measured on the scene while the trainee works: how much of the incision
// line has been cut, how much of the drill window removed, and which structures not to damage
// have been reached. What a whole recording scores is score/metrics.hpp's.

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "lancet/shared_model/messages.hpp"
#include "scenarios/scenario.hpp"
#include "tissue/tissue_scene.hpp"

namespace lancet::score {

using tissue::TissueScene;

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

}  // namespace lancet::score
