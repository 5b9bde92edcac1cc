#pragma once
// From a training scenario (host_viz/scenarios) to what the visualizer runs: the scene's
// description (loading the CT a file scenario names, or the one given on the command line). The
// task measured on the scene is score/task_monitor.hpp's.

#include <string>

#include "tissue/tissue_scene.hpp"
#include "lancet/shared_model/result.hpp"
#include "scenarios/scenario.hpp"
#include "volume/volume.hpp"

namespace lancet::tissue {

/// Loads a CT: a DICOM series (a directory), MetaImage (.mhd, .mha) or NRRD (.nrrd, .nhdr).
/// Errors name the path and what is wrong with it.
[[nodiscard]] Result<volume::Volume> load_ct(const std::string& path);

/// The scene a scenario describes. volume_override (the command line's --volume) replaces the
/// file's path and is required when a file scenario names none; it is refused for a phantom or
/// block scenario (it would be silently ignored).
[[nodiscard]] Result<SceneDescription> scene_description(const scenario::Scenario& s, const std::string& volume_override = {});

}  // namespace lancet::tissue
