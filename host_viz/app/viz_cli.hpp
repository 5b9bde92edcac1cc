#pragma once
// lancet-viz's command line: every option, its checks and its default, in one struct.

#include <cmath>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "lancet/shared_model/shared_state.hpp"

namespace lancet::viz {

/// What the command line asked for (units as named; lengths in mm as typed).
struct VizOptions {
  std::string shm = kDefaultShmName;  ///< lancet-rt's shared-memory segment
  bool headless = false;              ///< offscreen (EGL), no window
  double duration = 0;                ///< s to run; 0: until the window closes (headless: 5 s)
  std::string screenshot;             ///< PNG of the last frame, written on exit ("" none)
  std::string stats;                  ///< JSON summary, written on exit ("" none)
  int width = 1280, height = 720;     ///< pixels
  double patch_radius_mm = 40;        ///< radius of the tissue patch sent to lancet-rt (a replay uses the recording's)
  double fps = 60;                    ///< frame-rate cap
  std::string scenario_path;          ///< --scenario ("" none)
  std::string volume_path;            ///< --volume ("" none)
  std::string tissue = "block";       ///< without a scenario: block or phantom
  std::string tool;                   ///< --tool ("" not given; "none": leave it to lancet-rt)
  int view = 0;                       ///< 0 mesh, 1 composite, 2 volume
  bool show_patch = false;            ///< draw the patch sent to lancet-rt (wireframe), as T does
  int screenshot_view = -1;           ///< the last frame's view (-1: as the run's)
  float clip_mm = std::numeric_limits<float>::quiet_NaN();  ///< volume clipped above (world z); NaN: not
  int preset = 1;                     ///< index into volume::kTfPresets
  std::string trace_path;             ///< CSV of every ToolSample ("" none)
  std::string record_path;            ///< --record ("" none)
  std::string replay_path;            ///< --replay ("" none)
  double replay_speed = 1;            ///< multiple of real time
  std::string trainee;                ///< --trainee: each recording is this trainee's attempt ("" none)
  std::string db;                     ///< --db: the records ("" records::default_database_path())
  std::string outbox;                 ///< --outbox ("" records::default_outbox_path(db))
};

/// The names of the views (--view, --screenshot-view), by view number.
inline constexpr const char* kViewNames[] = {"mesh", "composite", "volume"};

/// Parses argv into `out`. Returns the exit code when the program should end now (--help: 0;
/// a bad option or --record with --replay: 2, with the message printed), nothing to run on.
[[nodiscard]] std::optional<int> parse_viz_cli(int argc, char** argv, VizOptions& out);

}  // namespace lancet::viz
