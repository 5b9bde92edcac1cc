#include "app/viz_cli.hpp"

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cstdio>
#include <iterator>

#include "lancet/shared_model/messages.hpp"
#include "volume/tf_editor.hpp"

namespace lancet::viz {

namespace {

int view_number(const std::string& name) {
  return static_cast<int>(std::find_if(std::begin(kViewNames), std::end(kViewNames), [&](const char* v) { return name == v; }) -
                          std::begin(kViewNames));
}

}  // namespace

std::optional<int> parse_viz_cli(int argc, char** argv, VizOptions& o) {
  CLI::App cli{"lancet-viz: Lancet's visualizer (tissue, tool, link to lancet-rt)"};
  cli.add_option("--shm", o.shm, "shared-memory segment of lancet-rt")->capture_default_str();
  cli.add_flag("--headless", o.headless, "render offscreen without a window (EGL: no X server or DISPLAY needed)");
  cli.add_option("--duration", o.duration, "seconds to run; 0 runs until the window closes (headless default 5)")
      ->check(CLI::NonNegativeNumber);
  cli.add_option("--screenshot", o.screenshot, "write a PNG of the last frame here on exit");
  cli.add_option("--stats", o.stats, "write a JSON summary here on exit");
  cli.add_option("--width", o.width, "image width in pixels")->check(CLI::Range(64, 8192))->capture_default_str();
  cli.add_option("--height", o.height, "image height in pixels")->check(CLI::Range(64, 8192))->capture_default_str();
  cli.add_option("--patch-radius-mm", o.patch_radius_mm, "radius of the tissue patch sent to lancet-rt (a replay uses the recording's)")
      ->check(CLI::Range(1.0, 200.0))->capture_default_str();
  cli.add_option("--fps", o.fps, "frame-rate cap")->check(CLI::Range(1.0, 1000.0))->capture_default_str();
  auto* scenario_opt = cli.add_option("--scenario", o.scenario_path,
                                      "a training scenario (host_viz/scenarios/*.toml): the tissue, the tools, the camera, "
                                      "the task and the structures not to damage");
  cli.add_option("--volume", o.volume_path, "the CT for a scenario whose tissue is a file (DICOM directory, .mhd, .nrrd)")
      ->needs(scenario_opt);
  cli.add_option("--tissue", o.tissue, "without --scenario: phantom: the skin of the built-in CT phantom; block: the procedural skin block")
      ->check(CLI::IsMember({"block", "phantom"}))->capture_default_str()->excludes(scenario_opt);
  std::vector<std::string> tool_choices(std::begin(kToolNames), std::end(kToolNames));
  tool_choices.emplace_back("none");
  cli.add_option("--tool", o.tool,
                 "pick this tool in lancet-rt when connected (as the keys 1-4 do); default: the scenario's start_tool; "
                 "none: leave it to lancet-rt (a --trajectory that picks its own tools)")
      ->check(CLI::IsMember(tool_choices));
  std::string view = "mesh";
  cli.add_option("--view", view,
                 "mesh: the surfaces; composite: with the volume ray cast where no surface is in front; volume: the "
                 "volume alone (V cycles them in the window)")
      ->check(CLI::IsMember({"mesh", "composite", "volume"}))->capture_default_str();
  std::string screenshot_view;
  cli.add_option("--screenshot-view", screenshot_view,
                 "draw the last frame (the screenshot's, with --duration) in this view instead: e.g. composite, to show the "
                 "volume beneath an opened incision while the run itself stays fast")
      ->check(CLI::IsMember({"mesh", "composite", "volume"}));
  cli.add_flag("--show-patch", o.show_patch,
               "draw the tissue patch sent to lancet-rt as a cyan wireframe (a developer's view; T toggles it in the window)");
  cli.add_option("--clip-mm", o.clip_mm, "cut the volume away above this height (world z, mm; the skin's top is at 0)");
  std::vector<std::string> preset_names;
  for (auto p : volume::kTfPresets) preset_names.emplace_back(volume::tf_preset_name(p));
  std::string preset = "CT-Soft-Tissue";
  cli.add_option("--preset", preset, "the volume's transfer function (P cycles them in the window)")
      ->check(CLI::IsMember(preset_names))->capture_default_str();
  cli.add_option("--trace", o.trace_path,
                 "write every ToolSample received here as CSV (time, stage, events, tool and proxy in mm, force in N, the "
                 "patch version it used, the hand), one line a servo tick and hand");
  cli.add_option("--record", o.record_path,
                 "record the session to this HDF5 file: lancet-rt's servo and the scene start afresh (a reset) and every "
                 "servo tick and frame from then on is written (the Record button, F9, does the same into "
                 "lancet-YYYYmmdd-HHMMSS.h5)");
  auto* replay_opt = cli.add_option("--replay", o.replay_path,
                                    "replay a recorded session (HDF5) through the same servo step and scene, checking it bit for "
                                    "bit; needs no lancet-rt. Headless: as fast as it goes, then a summary (exit 1 if it differs)")
                         ->excludes(scenario_opt);
  cli.add_option("--replay-speed", o.replay_speed, "replay at this multiple of real time (space pauses in the window)")
      ->check(CLI::Range(0.01, 1000.0))->capture_default_str()->needs(replay_opt);
  auto* trainee_opt = cli.add_option("--trainee", o.trainee,
                                     "record each attempt as this trainee's (without --record, into the outbox), score it and store it "
                                     "in the records; the panel shows where the trainee stands in the curriculum (docs/RECORDS.md)")
                          ->excludes(replay_opt);
  cli.add_option("--db", o.db, "with --trainee: the records, an SQLite file or a postgresql:// URL (default: as lancet-records')")
      ->needs(trainee_opt);
  cli.add_option("--outbox", o.outbox,
                 "with --trainee: where attempts wait until stored (default: beside an SQLite --db, else ~/.local/share/lancet/outbox)")
      ->needs(trainee_opt);
  try {
    cli.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return cli.exit(e);
  }
  if (!o.record_path.empty() && !o.replay_path.empty()) {
    std::fprintf(stderr, "lancet-viz: --record and --replay: one at a time\n");
    return 2;
  }
  if (o.headless && o.duration == 0) o.duration = 5;
  o.view = view_number(view);
  o.screenshot_view = screenshot_view.empty() ? -1 : view_number(screenshot_view);
  o.preset = static_cast<int>(std::find(preset_names.begin(), preset_names.end(), preset) - preset_names.begin());
  return std::nullopt;
}

}  // namespace lancet::viz
