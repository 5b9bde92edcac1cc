#include "score/task_monitor.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <system_error>
#include <utility>

namespace lancet::score {

TaskMonitor::TaskMonitor(const scenario::Scenario& s, const TissueScene& scene) : s_(&s) {
  if (s.task == scenario::TaskKind::kDrill) drill_bone_ = window_bone_now(scene);
  for (const auto& st : s.avoid) label_voxels_.push_back(st.kind == scenario::ShapeKind::kLabel ? label_count(scene, st.label) : 0);
  damaged_.assign(s.avoid.size(), false);
  (void)update(scene, {});
}

std::size_t TaskMonitor::window_bone_now(const TissueScene& scene) const {
  const scenario::DrillTask& w = s_->drill;
  const Vec3 sp = scene.volume().spacing;
  const double h = std::min({sp.x, sp.y, sp.z});
  std::size_t n = 0;
  for (double z = 0; z <= w.depth + 1e-9; z += h)
    for (double y = -w.radius; y <= w.radius + 1e-9; y += h)
      for (double x = -w.radius; x <= w.radius + 1e-9; x += h) {
        if (x * x + y * y > w.radius * w.radius) continue;
        const std::uint8_t l = scene.label_at(w.centre + Vec3{x, y, -z});
        n += l == volume::kCorticalBone || l == volume::kMarrow;
      }
  return n;
}

std::size_t TaskMonitor::label_count(const TissueScene& scene, std::uint8_t label) const {
  const auto labels = scene.labels();
  return static_cast<std::size_t>(std::count(labels.begin(), labels.end(), label));
}

const TaskStatus& TaskMonitor::update(const TissueScene& scene, std::span<const ToolSample> samples) {
  const scenario::Scenario& s = *s_;
  TaskStatus& st = status_;
  char buf[200];
  bool drilled = false;
  // Structures reached: by the drill (its removals as they come) ...
  for (const ToolSample& t : samples) {
    if ((t.events & event::kDrillRemove) == 0) continue;
    drilled = true;
    for (std::size_t i = 0; i < s.avoid.size(); ++i)
      if (s.avoid[i].kind != scenario::ShapeKind::kLabel && scenario::touches(s.avoid[i], t.payload.position, t.payload.magnitude))
        damaged_[i] = true;
  }
  // ... and by a cut reaching down to the cut depth under its path: the points added since the
  // last update (paths only grow; a point once checked stays checked).
  const auto cuts = scene.cut_paths();
  const double depth = scene.description().cut_depth;
  cut_points_checked_.resize(cuts.size(), 0);
  for (std::size_t c = 0; c < cuts.size(); ++c)
    for (std::size_t n = std::exchange(cut_points_checked_[c], cuts[c].size()); n < cuts[c].size(); ++n)
      for (double z = 0; z <= depth + 1e-9; z += 0.0005) {
        const Vec3& p = cuts[c][n];
        const Vec3 q = p - Vec3{0, 0, z};
        for (std::size_t i = 0; i < s.avoid.size(); ++i) {
          if (damaged_[i]) continue;
          const scenario::Structure& a = s.avoid[i];
          damaged_[i] = a.kind == scenario::ShapeKind::kLabel ? scene.label_at(q) == a.label : scenario::touches(a, q, 0);
        }
      }
  if (drilled)
    for (std::size_t i = 0; i < s.avoid.size(); ++i)
      if (s.avoid[i].kind == scenario::ShapeKind::kLabel && !damaged_[i])
        damaged_[i] = label_count(scene, s.avoid[i].label) < label_voxels_[i];
  st.damaged.clear();
  st.damaged_flags = damaged_;
  for (std::size_t i = 0; i < s.avoid.size(); ++i)
    if (damaged_[i]) st.damaged.push_back(s.avoid[i].name);

  if (s.task == scenario::TaskKind::kIncision) {
    const auto p = scenario::incision_progress(s.incision, cuts);
    st.progress = p.covered;
    st.max_deviation = p.max_deviation;
    st.outside = p.outside;
    std::snprintf(buf, sizeof buf, "task: incision along the line: %.0f%% cut, off the line by up to %.1f mm (tolerance %.1f mm)",
                  100 * p.covered, p.max_deviation * 1e3, s.incision.tolerance * 1e3);
  } else {
    if (drilled || drill_bone_ == 0) {
      const std::size_t now = drill_bone_ > 0 ? window_bone_now(scene) : 0;
      st.progress = drill_bone_ > 0 ? 1.0 - static_cast<double>(now) / static_cast<double>(drill_bone_) : 0.0;
      // The window is sampled on a grid of the finest spacing: each sample stands for h³.
      const Vec3 sp = scene.volume().spacing;
      const double h = std::min({sp.x, sp.y, sp.z});
      st.window_removed = static_cast<double>(drill_bone_ - std::min(now, drill_bone_)) * h * h * h;
    }
    std::snprintf(buf, sizeof buf, "task: drill the window (%.0f mm across, %.0f mm deep): %.0f%% of its bone removed",
                  2e3 * s.drill.radius, 1e3 * s.drill.depth, 100 * st.progress);
  }
  st.line = buf;
  for (const auto& name : st.damaged) st.line += "; DAMAGED: " + name;
  return st;
}

}  // namespace lancet::score
