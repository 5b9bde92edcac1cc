#pragma once
// VolumeView: the CT as lancet-viz shows it beside or beneath the surfaces — the ray caster, made
// and uploaded when the volume is first shown, its drilled voxels sent as they change; the transfer
// function (a preset after window/level, then the user's edits in the panel's editor) and the
// volume's histogram under the editor.

#include <memory>

#include "app/viz_input.hpp"
#include "tissue/tissue_scene.hpp"
#include "render/scene_renderer.hpp"
#include "render/volume_raycaster.hpp"
#include "volume/tf_editor.hpp"

namespace lancet::viz {

class VolumeView {
 public:
  /// The frame's volume: the voxels changed since the last frame (`changed`, taken from the scene
  /// every frame) are sent; when ui shows the volume, `in` gets it (transfer function, clip plane,
  /// whether the surfaces are drawn too).
  void prepare(const Interaction& ui, tissue::TissueScene& scene, const volume::VoxelBox& changed, render::SceneInput& in);
  /// Forgets the volume (a fresh scene: it is made again when next shown).
  void reset() noexcept { raycaster_.reset(); }
  /// The panel's editor changed the table: upload it at the next prepare().
  void mark_edited() noexcept { edited_ = true; }
  /// Shown at least once: the panel offers the editor and the histogram.
  [[nodiscard]] bool shown() const noexcept { return raycaster_ != nullptr; }
  [[nodiscard]] volume::TfEditor* editor() noexcept { return &editor_; }
  [[nodiscard]] const volume::Histogram* histogram() const noexcept { return &histogram_; }

 private:
  std::unique_ptr<render::VolumeRaycaster> raycaster_;
  int shown_preset_ = -1;
  float shown_level_ = 0, shown_width_ = 1;
  volume::TfEditor editor_;       ///< the shown table: the preset after window/level, then the user's edits
  volume::Histogram histogram_;   ///< of the volume, under the editor
  bool edited_ = false;
};

}  // namespace lancet::viz
