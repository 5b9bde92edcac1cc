// lancet-viz: the visualizer process. Wires the tissue simulation (sim::SceneSim, built from a
// training scenario or the built-in tissue) to lancet-rt through the shared-memory link
// (VizSession), and both to the window (VizApp): each frame the drained ToolSamples drive the
// scene, the scene's patch around the tool is published, what changed is drawn. Keeps running (and
// says so on screen) when lancet-rt is absent or goes away. With --replay, a recording drives the
// same frame instead of lancet-rt.
//
// This file is the start and the end: the command line (app/viz_cli), the simulation or the
// replay, the window; the frame loop is app/viz_app.

#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <memory>
#include <string>
#include <utility>

#include "app/sample_trace.hpp"
#include "app/station.hpp"
#include "app/viz_app.hpp"
#include "app/viz_cli.hpp"
#include "recording/hdf5_io.hpp"
#include "record/replay.hpp"
#include "render/window.hpp"
#include "sim/scene_sim.hpp"

namespace {

std::atomic<bool> g_stop{false};
extern "C" void on_signal(int) { g_stop.store(true, std::memory_order_relaxed); }

// The recording to replay, and the replay of it (which points into the recording: it stays put).
struct Replaying {
  std::unique_ptr<lancet::record::Recording> recording;
  std::unique_ptr<lancet::record::Replay> replay;
};

// --replay FILE: read and checked; the error says what is wrong with the file.
lancet::Result<Replaying> open_replay(const std::string& path) {
  Replaying r;
  auto read = lancet::record::read_recording(path);
  if (!read.ok()) return lancet::Error{read.error().code, "--replay: " + read.error().message};
  r.recording = std::make_unique<lancet::record::Recording>(std::move(read).value());
  auto made = lancet::record::Replay::create(*r.recording);
  if (!made.ok()) return lancet::Error{made.error().code, "--replay " + path + ": " + made.error().message};
  r.replay = std::move(made).value();
  const lancet::record::Recording& rec = *r.recording;
  std::printf("lancet-viz: replaying %s: %zu ticks, %zu frames, %.1f s, recorded %s by lancet %s%s\n", path.c_str(),
              rec.samples.size(), rec.frames.size(), r.replay->duration_s(), rec.created.c_str(), rec.lancet_version.c_str(),
              rec.cut_short ? " (cut short: the recorder never finished it)" : "");
  return r;
}

// The live simulation the command line describes (a scenario's tissue, or the built-in one).
lancet::Result<std::unique_ptr<lancet::sim::SceneSim>> build_sim(const lancet::viz::VizOptions& o) {
  lancet::sim::SceneSetup setup;
  setup.tissue = o.tissue;
  setup.volume_path = o.volume_path;
  setup.patch_radius = o.patch_radius_mm * 1e-3;
  if (!o.scenario_path.empty()) {
    auto text = lancet::scenario::read_scenario_text(o.scenario_path);
    if (!text.ok()) return lancet::Error{lancet::ErrorCode::kInvalid, text.error().message};  // the user's to fix
    setup.scenario_toml = std::move(text).value();
    setup.scenario_file = o.scenario_path;
  }
  std::printf("lancet-viz: building the tissue (%s)\n", o.scenario_path.empty() ? o.tissue.c_str() : o.scenario_path.c_str());
  std::fflush(stdout);
  return lancet::sim::SceneSim::create(setup);
}

}  // namespace

int main(int argc, char** argv) {
  lancet::viz::VizOptions o;
  if (const auto code = lancet::viz::parse_viz_cli(argc, argv, o)) return *code;
  // At once, before the tissue is built (a second or more): a Ctrl-C during start-up ends the run
  // (at its first frame), and so does a SIGINT sent to a viz started in the background, where the
  // shell left SIGINT ignored.
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);
  std::signal(SIGHUP, on_signal);

  lancet::viz::VizSources sources;
  // --trainee: the station (the trainee checked, what waits delivered); without --record each
  // attempt is recorded into its outbox.
  std::unique_ptr<lancet::viz::Station> station;
  if (!o.trainee.empty()) {
    auto s = lancet::viz::Station::start({o.trainee, o.db, o.outbox, LANCET_VERSION});
    if (!s.ok()) {
      std::fprintf(stderr, "lancet-viz: %s\n", s.error().message.c_str());
      return 2;
    }
    station = std::move(s).value();
    if (o.record_path.empty()) o.record_path = station->recording_path();
    sources.station = station.get();
  }
  if (!o.trace_path.empty()) {
    auto trace = lancet::viz::SampleTrace::create(o.trace_path);
    if (!trace.ok()) {
      std::fprintf(stderr, "lancet-viz: %s\n", trace.error().message.c_str());
      return 2;
    }
    sources.trace = std::move(trace).value();
  }

  // The simulation: the replay's (built as the recording says), or our own.
  Replaying replaying;
  if (!o.replay_path.empty()) {
    auto r = open_replay(o.replay_path);
    if (!r.ok()) {
      std::fprintf(stderr, "lancet-viz: %s\n", r.error().message.c_str());
      return 2;
    }
    replaying = std::move(r).value();
    sources.replay = std::move(replaying.replay);
  } else {
    auto made = build_sim(o);
    if (!made.ok()) {
      std::fprintf(stderr, "lancet-viz: %s\n", made.error().message.c_str());
      return made.error().code == lancet::ErrorCode::kInvalid ? 2 : 3;
    }
    sources.sim = std::move(made).value();
  }
  const lancet::sim::SceneSim& sim = sources.replay ? sources.replay->sim() : *sources.sim;
  const lancet::scenario::Scenario* scenario = sim.scenario();
  // The tool picked when connected: --tool, else the scenario's; "none" leaves it to lancet-rt.
  sources.tool = o.tool;
  if (scenario != nullptr && o.tool.empty()) sources.tool = lancet::tool_name(scenario->start_tool);
  if (sources.tool == "none") sources.tool.clear();
  if (scenario != nullptr)
    std::printf("lancet-viz: scenario %s (%s): %s\n", scenario->name.c_str(), scenario->file.c_str(), scenario->description.c_str());

  auto window = lancet::render::Window::create({o.width, o.height, !o.headless, "Lancet"});
  if (!window) {
    std::fprintf(stderr, "lancet-viz: %s\n", window.error().message.c_str());
    return 3;
  }
  lancet::render::Window& win = *window.value();
  std::printf("lancet-viz: %s\n", win.gl_description().c_str());

  lancet::viz::VizApp app(o, win, std::move(sources), LANCET_VERSION);
  const int exit_code = app.run(g_stop);
  const int code = app.finish(exit_code);
  // The last attempt's delivery: a bounded wait, then it stays in the outbox.
  if (station) station->finish(std::chrono::seconds(5));
  return code;
}
