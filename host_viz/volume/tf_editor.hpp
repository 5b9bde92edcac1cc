#pragma once
// The transfer function as a user edits it: control points (value, colour, opacity) over a
// histogram of the volume, as in 3D Slicer's Volume Rendering module and ParaView's colour map
// editor. The editor starts from a preset (after window/level) and keeps its points sorted by
// value; the UI (render/overlay) maps its canvas to [0, 1]² — x the value over [lo, hi], y the
// opacity — and forwards the pointer: press on a point and drag it (its value stays between its
// neighbours'; the two end points pin the table's range and move only up and down), double-click
// empty canvas to add a point (coloured as the table is there), right-click a point to remove it
// (not an end point). No OpenGL here.

#include <cstdint>
#include <vector>

#include "volume/raycast.hpp"
#include "volume/volume.hpp"

namespace lancet::volume {

/// Voxel counts over [lo, hi] in equal bins (values outside clamp into the end bins).
struct Histogram {
  float lo = 0, hi = 1;
  std::vector<std::uint64_t> counts;
  /// Bar heights for drawing, 0..1: log(1 + count) / log(1 + largest count) (CT histograms
  /// span orders of magnitude: air and soft tissue would flatten everything else).
  [[nodiscard]] std::vector<float> log_heights() const;
};
[[nodiscard]] Histogram histogram(const Volume& v, float lo, float hi, int bins);

class TfEditor {
 public:
  TfEditor() = default;
  /// From a table's points (sorted here; at least two: fewer gets the range's two ends, clear).
  explicit TfEditor(TfSpec spec);

  [[nodiscard]] const std::vector<TfPoint>& points() const noexcept { return spec_.points; }
  [[nodiscard]] float lo() const noexcept { return spec_.lo; }
  [[nodiscard]] float hi() const noexcept { return spec_.hi; }
  /// The table the points make.
  [[nodiscard]] TransferFunction table() const;

  /// Canvas coordinates of a point ([0, 1]²) and back.
  [[nodiscard]] float x_of(float value) const noexcept { return (value - spec_.lo) / (spec_.hi - spec_.lo); }
  [[nodiscard]] float value_at(float x) const noexcept { return spec_.lo + x * (spec_.hi - spec_.lo); }
  /// The point nearest (x, y) within an ellipse of radii (rx, ry); -1 when none.
  [[nodiscard]] int pick(float x, float y, float rx, float ry) const noexcept;

  /// Pointer down at (x, y): selects the point there (true) or nothing (false).
  bool press(float x, float y, float rx, float ry) noexcept;
  /// Moves the selected point to (x, y) as far as its neighbours allow; false when none is held.
  bool drag_to(float x, float y) noexcept;
  void release() noexcept { held_ = false; }
  /// Adds a point at (x, y) coloured as the table is at that value, and selects it; its index,
  /// or -1 where it would sit on an existing point's value or outside (lo, hi).
  int add(float x, float y);
  /// Removes point i (not the first or the last); false when it may not.
  bool remove(int i);
  void set_colour(int i, float r, float g, float b) noexcept;
  [[nodiscard]] int selected() const noexcept { return selected_; }

 private:
  TfSpec spec_{{{-1000, 0, 0, 0, 0}, {3000, 1, 1, 1, 1}}, -1000, 3000, false};
  int selected_ = -1;
  bool held_ = false;
};

}  // namespace lancet::volume
