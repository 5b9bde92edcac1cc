#include "app/volume_view.hpp"

namespace lancet::viz {

void VolumeView::prepare(const Interaction& ui, tissue::TissueScene& scene, const volume::VoxelBox& changed,
                         render::SceneInput& in) {
  if (ui.view == 0) {
    if (raycaster_ && !changed.empty()) raycaster_->update_region(scene.render_volume(), changed);
    return;
  }
  if (!raycaster_) {
    raycaster_ = std::make_unique<render::VolumeRaycaster>();
    raycaster_->set_volume(scene.render_volume());
    shown_preset_ = -1;
    const volume::TfSpec range = volume::tf_preset_spec(volume::kTfPresets[0]);
    histogram_ = volume::histogram(scene.render_volume(), range.lo, range.hi, 128);
  } else if (!changed.empty()) {
    raycaster_->update_region(scene.render_volume(), changed);
  }
  if (shown_preset_ != ui.preset || shown_level_ != ui.level || shown_width_ != ui.width) {
    // A preset or a window/level drag starts the editor afresh from the preset's points.
    editor_ = volume::TfEditor(volume::tf_preset_spec(volume::kTfPresets[ui.preset], ui.level, ui.width));
    shown_preset_ = ui.preset, shown_level_ = ui.level, shown_width_ = ui.width;
    edited_ = true;
  }
  if (edited_) raycaster_->set_transfer_function(editor_.table());
  edited_ = false;
  in.volume = raycaster_.get();
  in.volume_to_world = scene.volume_to_world();
  in.volume_params.step = 1.0f;  // a voxel a sample: interactive on llvmpipe
  if (ui.clip) {  // keep world z <= clip_mm, as a plane in the volume's frame
    const auto m = in.volume_to_world;
    in.volume_params.clip = true;
    in.volume_params.clip_plane = {m[2], m[6], m[10], m[14] - ui.clip_mm * 1e-3f};
  }
  in.draw_surface = ui.view == 1;
}

}  // namespace lancet::viz
