#pragma once
// A recorded hand trajectory for the simulated arm or stylus: where the hand pulls the stylus
// over time, replayed instead of the built-in script (test rigs, repeatable demos).
// File: CSV lines `t_s, x_mm, y_mm, z_mm[, tool[, hand]]` (tissue frame), '#' comments, an
// optional header line of names. The optional fifth cell picks the tool from that time on (probe,
// scalpel, retractor or drill; empty: no change), so a scripted hand can press with the scalpel,
// lift and pull with the retractor. The optional sixth cell says whose row it is (right or left;
// empty or absent: right): each hand has its own trajectory, its times strictly increasing from
// >= 0, its own tool changes. Loading allocates; at() does not.

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "lancet/shared_model/geometry.hpp"
#include "lancet/shared_model/messages.hpp"
#include "lancet/shared_model/result.hpp"

namespace lancet::device {

struct Trajectory {
  struct ToolChange {
    double t;             ///< s
    ToolMode mode;
  };
  std::vector<double> t;  ///< s
  std::vector<Vec3> p;    ///< m
  std::vector<ToolChange> tools;  ///< in time order
  /// Linear interpolation at time s; the first point before it, the last after. RT-safe.
  [[nodiscard]] Vec3 at(double s) const noexcept;
  [[nodiscard]] double duration() const noexcept { return t.empty() ? 0.0 : t.back(); }
};

/// Each hand's trajectory, by Hand; a hand without rows has an empty one (t empty).
using HandTrajectories = std::array<Trajectory, kHandCount>;

/// Errors name the file, the line and what was expected (e.g. "trajectory.csv:7: x_mm: expected
/// a number, found 'abc'"). A file without any point is an error; one hand without points is not.
[[nodiscard]] Result<HandTrajectories> load_trajectory_csv(const std::string& path);

}  // namespace lancet::device
