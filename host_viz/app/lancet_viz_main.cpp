// lancet-viz: the visualizer process. Wires the tissue scene (hybrid::TissueScene, built from a
// training scenario or the built-in tissue) to lancet-rt through the shared-memory link
// (VizSession), and both to the window (SceneRenderer, Overlay): each frame the drained
// ToolSamples drive the scene, the scene's patch around the tool is published, what changed is
// drawn. Keeps running (and says so on screen) when lancet-rt is absent or goes away.

#include <epoxy/gl.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <deque>
#include <filesystem>
#include <limits>
#include <map>
#include <memory>
#include <numeric>
#include <optional>
#include <span>
#include <thread>
#include <utility>
#include <vector>

#include "app/viz_session.hpp"
#include "record/hdf5_io.hpp"
#include "record/replay.hpp"
#include "hybrid/bleeding.hpp"
#include "hybrid/scenario_scene.hpp"
#include "hybrid/tissue_scene.hpp"
#include "render/overlay.hpp"
#include "render/scene_renderer.hpp"
#include "render/volume_raycaster.hpp"
#include "render/window.hpp"
#include "volume/tf_editor.hpp"

namespace {

std::atomic<bool> g_stop{false};
extern "C" void on_signal(int) { g_stop.store(true, std::memory_order_relaxed); }

// Mouse and keyboard state of the interactive window.
struct Interaction {
  bool mouse_drives_stylus = false;
  double depth_mm = 3.0;       // how far below the surface the mouse-driven stylus is pushed
  bool rotating = false, windowing = false;
  double last_x = 0, last_y = 0;
  int view = 0;               // 0 mesh, 1 mesh with the volume composited, 2 the volume alone
  int preset = 1;             // index into volume::kTfPresets
  float level = 0, width = 1; // window/level: HU shift and width scale of the preset
  bool clip = false;          // the volume cut away above clip_mm (world z)
  float clip_mm = -10;
  float yaw = 0.6f, pitch = 0.55f, distance = 0.26f;
};
Interaction* g_ui = nullptr;

void on_scroll(GLFWwindow*, double, double dy) {
  if (g_ui == nullptr) return;
  if (g_ui->mouse_drives_stylus) {
    g_ui->depth_mm = std::clamp(g_ui->depth_mm + dy, -10.0, 15.0);
  } else {
    g_ui->distance = std::clamp(g_ui->distance * static_cast<float>(std::pow(0.9, dy)), 0.05f, 1.0f);
  }
}

struct VizOptions {
  std::string shm = lancet::kDefaultShmName;
  bool headless = false;
  double duration = 0;
  std::string screenshot;
  std::string stats;
  int width = 1280, height = 720;
  double patch_radius_mm = 30;
  double fps = 60;
  std::string scenario_name;  ///< for the stats
};

bool write_stats(const VizOptions& o, const lancet::viz::VizSession& s, std::uint64_t frames, double variance,
                 const lancet::hybrid::TissueScene& scene, const lancet::hybrid::TaskStatus* task,
                 const lancet::hybrid::Bleeding* blood, double blood_ms_per_frame) {
  std::FILE* f = std::fopen(o.stats.c_str(), "w");
  if (f == nullptr) return false;
  const auto& st = s.stats();
  const auto& ev = scene.events();
  const auto cuts = scene.cut_figures();
  const auto grooves = scene.grooves();
  const lancet::hybrid::BloodFigures bf = blood != nullptr ? blood->figures() : lancet::hybrid::BloodFigures{};
  lancet::hybrid::GrooveFigures groove{};  // the widest
  for (const auto& g : grooves)
    if (g.top_gap >= groove.top_gap) groove = g;
  std::fprintf(f,
               "{\n  \"frames\": %llu,\n  \"connections\": %u,\n  \"rt_losses\": %u,\n  \"link\": \"%s\",\n"
               "  \"samples_received\": %llu,\n  \"samples_total\": %llu,\n  \"first_seq\": %llu,\n  \"last_seq\": %llu,\n"
               "  \"lost\": %llu,\n  \"out_of_order\": %llu,\n  \"discarded_on_attach\": %llu,\n  \"max_batch\": %llu,\n"
               "  \"patches_published\": %llu,\n  \"samples_rejected\": %llu,\n  \"sample_ring_resets\": %llu,\n"
               "  \"status_rejected\": %llu,\n  \"drill_removals\": %llu,\n  \"voxels_drilled\": %llu,\n  \"bone_updates\": %llu,\n"
               "  \"cuts\": %zu,\n  \"longest_cut_mm\": %.2f,\n"
               "  \"cut_opening_mm\": %.2f,\n  \"cut_from_mm\": [%.2f, %.2f, %.2f],\n  \"cut_to_mm\": [%.2f, %.2f, %.2f],\n"
               "  \"grooves\": %zu,\n  \"groove_width_mm\": %.2f,\n  \"groove_depth_mm\": %.2f,\n  \"groove_faces\": %zu,\n"
               "  \"contacts\": %llu,\n  \"contact_ends\": %llu,\n  \"ruptures\": %llu,\n  \"cut_steps\": %llu,\n"
               "  \"grabs\": %llu,\n  \"releases\": %llu,\n  \"pulls\": %llu,\n"
               "  \"clamped_ticks\": %llu,\n  \"faded_ticks\": %llu,\n  \"fault_ticks\": %llu,\n"
               "  \"scenario\": \"%s\",\n  \"task_progress\": %.3f,\n  \"task_damaged\": %zu,\n"
               "  \"blood_lost_ml\": %.4f,\n  \"blood_on_tissue_ml\": %.4f,\n  \"blood_swabbed_ml\": %.4f,\n"
               "  \"vessel_bleeding\": %s,\n  \"blood_ledger_error\": %.3g,\n  \"blood_cells\": %zu,\n  \"blood_ms_per_frame\": %.3f,\n"
               "  \"screenshot\": \"%s\",\n  \"screenshot_variance\": %.3f\n}\n",
               static_cast<unsigned long long>(frames), s.connections(), s.rt_losses(),
               s.link() == lancet::viz::Link::kConnected ? "connected"
               : s.link() == lancet::viz::Link::kLost   ? "lost"
                                                        : "waiting",
               static_cast<unsigned long long>(st.received), static_cast<unsigned long long>(s.samples_total()),
               static_cast<unsigned long long>(st.first_seq), static_cast<unsigned long long>(st.last_seq),
               static_cast<unsigned long long>(st.lost), static_cast<unsigned long long>(st.out_of_order),
               static_cast<unsigned long long>(st.discarded), static_cast<unsigned long long>(st.max_batch),
               static_cast<unsigned long long>(s.patches_published()), static_cast<unsigned long long>(st.rejected),
               static_cast<unsigned long long>(st.ring_resets), static_cast<unsigned long long>(st.status_rejected),
               static_cast<unsigned long long>(ev.drill_removals), static_cast<unsigned long long>(ev.voxels_drilled),
               static_cast<unsigned long long>(ev.bone_updates), cuts.cuts, cuts.longest * 1e3, cuts.opening * 1e3,
               cuts.from.x * 1e3, cuts.from.y * 1e3, cuts.from.z * 1e3, cuts.to.x * 1e3, cuts.to.y * 1e3, cuts.to.z * 1e3,
               grooves.size(), groove.top_gap * 1e3, groove.depth * 1e3, groove.faces,
               static_cast<unsigned long long>(ev.contacts), static_cast<unsigned long long>(ev.contact_ends),
               static_cast<unsigned long long>(ev.ruptures), static_cast<unsigned long long>(ev.cut_steps),
               static_cast<unsigned long long>(ev.grabs), static_cast<unsigned long long>(ev.releases),
               static_cast<unsigned long long>(ev.pulls),
               static_cast<unsigned long long>(ev.clamped_ticks), static_cast<unsigned long long>(ev.faded_ticks),
               static_cast<unsigned long long>(ev.fault_ticks), o.scenario_name.c_str(), task ? task->progress : 0.0,
               task ? task->damaged.size() : std::size_t{0}, bf.lost_ml, bf.on_tissue_ml, bf.swabbed_ml,
               bf.vessel_bleeding ? "true" : "false", bf.ledger_error, bf.cells, blood_ms_per_frame,
               o.screenshot.c_str(), std::isfinite(variance) ? variance : -1.0);
  return std::fclose(f) == 0;
}

std::vector<lancet::render::OverlayLine> status_lines(const lancet::viz::VizSession& s, const Interaction& ui,
                                                      bool headless, const lancet::hybrid::SceneEvents& events,
                                                      const lancet::scenario::Scenario* scenario,
                                                      const lancet::hybrid::TaskStatus* task, const std::string& keys) {
  using lancet::render::OverlayLine;
  std::vector<OverlayLine> lines;
  if (scenario != nullptr) {
    lines.push_back({"scenario " + scenario->name + ": " + scenario->description});
    if (task != nullptr) lines.push_back({task->line, !task->damaged.empty()});
  }
  lines.push_back({s.link_message(), s.link() != lancet::viz::Link::kConnected});
  char buf[256];
  if (const auto& st = s.rt_status(); st && s.link() == lancet::viz::Link::kConnected) {
    std::snprintf(buf, sizeof buf, "servo: tick %llu at %.0f Hz%s, missed %llu, wake p50 %.0f us, p99 %.0f us, max %.0f us",
                  static_cast<unsigned long long>(st->tick), 1e9 / static_cast<double>(st->period_ns),
                  st->fifo ? " (SCHED_FIFO)" : " (not real-time)", static_cast<unsigned long long>(st->missed),
                  static_cast<double>(st->wake_p50_ns) / 1e3, static_cast<double>(st->wake_p99_ns) / 1e3,
                  static_cast<double>(st->wake_max_ns) / 1e3);
    lines.push_back({buf});
    if (st->watchdog_tripped) lines.push_back({"WATCHDOG TRIPPED: force held at zero; press W to re-arm", true});
    if (st->has_arm != 0 && st->device_state == lancet::DeviceLifecycle::kFault) {
      std::snprintf(buf, sizeof buf, "ARM FAULT: %s; force held at zero; press W to re-arm%s", st->fault_text,
                    st->link_lost ? " (bus link lost: reconnecting)" : "");
      lines.push_back({buf, true});
    }
    std::snprintf(buf, sizeof buf, "force %.2f N (scale %.2f)%s", lancet::norm(st->force), st->force_scale,
                  st->contact ? "  in contact" : "");
    lines.push_back({buf});
  }
  if (s.has_sample()) {
    const auto& t = s.latest();
    std::snprintf(buf, sizeof buf, "tool %s at (%.1f, %.1f, %.1f) mm", lancet::tool_name(t.mode), t.tool.position.x * 1e3,
                  t.tool.position.y * 1e3, t.tool.position.z * 1e3);
    lines.push_back({buf});
  }
  if (!events.last.empty()) lines.push_back({events.last, events.last_is_warning});
  const auto& st = s.stats();
  std::snprintf(buf, sizeof buf, "samples %llu received, %llu lost, %llu out of order; patch %u triangles",
                static_cast<unsigned long long>(st.received), static_cast<unsigned long long>(st.lost),
                static_cast<unsigned long long>(st.out_of_order), s.patch().n_triangles);
  lines.push_back({buf, st.lost > 0 || st.out_of_order > 0});
  if (st.rejected + st.ring_resets + st.status_rejected > 0) {
    std::snprintf(buf, sizeof buf, "shared segment: %llu samples and %llu status reads rejected, ring reset %llu times (%s)",
                  static_cast<unsigned long long>(st.rejected), static_cast<unsigned long long>(st.status_rejected),
                  static_cast<unsigned long long>(st.ring_resets), st.last_reject != nullptr ? st.last_reject : "-");
    lines.push_back({buf, true});
  }
  if (!headless) {
    lines.push_back({ui.mouse_drives_stylus ? "M: mouse drives the stylus (scroll: depth), M again: script"
                                            : "M: drive the stylus with the mouse; drag: rotate; scroll: zoom"});
    lines.push_back({keys + "   V: volume view   R: reset   W: re-arm watchdog   F9: record   Esc: quit"});
  }
  return lines;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App cli{"lancet-viz: Lancet's visualizer (tissue, tool, link to lancet-rt)"};
  VizOptions o;
  cli.add_option("--shm", o.shm, "shared-memory segment of lancet-rt")->capture_default_str();
  cli.add_flag("--headless", o.headless, "render offscreen without a window (EGL: no X server or DISPLAY needed)");
  cli.add_option("--duration", o.duration, "seconds to run; 0 runs until the window closes (headless default 5)")
      ->check(CLI::NonNegativeNumber);
  cli.add_option("--screenshot", o.screenshot, "write a PNG of the last frame here on exit");
  cli.add_option("--stats", o.stats, "write a JSON summary here on exit");
  cli.add_option("--width", o.width, "image width in pixels")->check(CLI::Range(64, 8192))->capture_default_str();
  cli.add_option("--height", o.height, "image height in pixels")->check(CLI::Range(64, 8192))->capture_default_str();
  cli.add_option("--patch-radius-mm", o.patch_radius_mm, "radius of the tissue patch sent to lancet-rt")
      ->check(CLI::Range(1.0, 200.0))->capture_default_str();
  cli.add_option("--fps", o.fps, "frame-rate cap")->check(CLI::Range(1.0, 1000.0))->capture_default_str();
  std::string scenario_path, volume_path;
  auto* scenario_opt = cli.add_option("--scenario", scenario_path,
                                      "a training scenario (host_viz/scenarios/*.toml): the tissue, the tools, the camera, "
                                      "the task and the structures not to damage");
  cli.add_option("--volume", volume_path, "the CT for a scenario whose tissue is a file (DICOM directory, .mhd, .nrrd)")
      ->needs(scenario_opt);
  std::string tissue = "block";
  cli.add_option("--tissue", tissue, "without --scenario: phantom: the skin of the built-in CT phantom; block: the procedural skin block")
      ->check(CLI::IsMember({"block", "phantom"}))->capture_default_str()->excludes(scenario_opt);
  std::string tool;
  std::vector<std::string> tool_choices(std::begin(lancet::kToolNames), std::end(lancet::kToolNames));
  tool_choices.emplace_back("none");
  cli.add_option("--tool", tool,
                 "pick this tool in lancet-rt when connected (as the keys 1-4 do); default: the scenario's start_tool; "
                 "none: leave it to lancet-rt (a --trajectory that picks its own tools)")
      ->check(CLI::IsMember(tool_choices));
  std::map<std::string, int> views{{"mesh", 0}, {"composite", 1}, {"volume", 2}};
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
  float clip_mm = std::numeric_limits<float>::quiet_NaN();
  cli.add_option("--clip-mm", clip_mm, "cut the volume away above this height (world z, mm; the skin's top is at 0)");
  std::vector<std::string> preset_names;
  for (auto p : lancet::volume::kTfPresets) preset_names.emplace_back(lancet::volume::tf_preset_name(p));
  std::string preset = "CT-Soft-Tissue";
  cli.add_option("--preset", preset, "the volume's transfer function (P cycles them in the window)")
      ->check(CLI::IsMember(preset_names))->capture_default_str();
  std::string trace_path;
  cli.add_option("--trace", trace_path,
                 "write every ToolSample received here as CSV (time, stage, events, tool and proxy in mm, force in N, the "
                 "patch version it used), one line a servo tick");
  std::string record_path, replay_path;
  double replay_speed = 1;
  cli.add_option("--record", record_path,
                 "record the session to this HDF5 file: lancet-rt's servo and the scene start afresh (a reset) and every "
                 "servo tick and frame from then on is written (the Record button, F9, does the same into "
                 "lancet-YYYYmmdd-HHMMSS.h5)");
  auto* replay_opt = cli.add_option("--replay", replay_path,
                                    "replay a recorded session (HDF5) through the same servo step and scene, checking it bit for "
                                    "bit; needs no lancet-rt. Headless: as fast as it goes, then a summary (exit 1 if it differs)")
                         ->excludes(scenario_opt);
  cli.add_option("--replay-speed", replay_speed, "replay at this multiple of real time (space pauses in the window)")
      ->check(CLI::Range(0.01, 1000.0))->capture_default_str()->needs(replay_opt);
  CLI11_PARSE(cli, argc, argv);
  // At once, before the tissue is built (a second or more): a Ctrl-C during start-up ends the run
  // (at its first frame), and so does a SIGINT sent to a viz started in the background, where the
  // shell left SIGINT ignored.
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);
  std::signal(SIGHUP, on_signal);
  if (!record_path.empty() && !replay_path.empty()) {
    std::fprintf(stderr, "lancet-viz: --record and --replay: one at a time\n");
    return 2;
  }
  if (o.headless && o.duration == 0) o.duration = 5;
  const bool tool_given = !tool.empty();
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> trace(nullptr, &std::fclose);
  if (!trace_path.empty()) {
    trace.reset(std::fopen(trace_path.c_str(), "w"));
    if (!trace) {
      std::fprintf(stderr, "lancet-viz: --trace %s: cannot create: %s\n", trace_path.c_str(), std::strerror(errno));
      return 2;
    }
    std::fputs("t_s,stage,events,tool_x_mm,tool_y_mm,tool_z_mm,proxy_x_mm,proxy_y_mm,proxy_z_mm,force_x_n,force_y_n,"
               "force_z_n,patch_version\n",
               trace.get());
  }

  // The tissue: a scenario's, or the built-in one.
  // The visualizer's simulation: the scene, its blood and the task, built the same way live and
  // in a replay (record::SceneSim).
  lancet::record::SceneSetup setup;
  setup.tissue = tissue;
  setup.volume_path = volume_path;
  setup.patch_radius = o.patch_radius_mm * 1e-3;
  std::optional<lancet::record::Recording> recording;  // --replay: the file
  std::unique_ptr<lancet::record::Replay> replay;
  std::unique_ptr<lancet::record::SceneSim> sim_owned;
  if (!replay_path.empty()) {
    auto r = lancet::record::read_recording(replay_path);
    if (!r.ok()) {
      std::fprintf(stderr, "lancet-viz: --replay: %s\n", r.error().message.c_str());
      return 2;
    }
    recording = std::move(r).value();
    auto rp = lancet::record::Replay::create(*recording);
    if (!rp.ok()) {
      std::fprintf(stderr, "lancet-viz: --replay %s: %s\n", replay_path.c_str(), rp.error().message.c_str());
      return 2;
    }
    replay = std::move(rp).value();
    setup = replay->sim().setup();
    std::printf("lancet-viz: replaying %s: %zu ticks, %zu frames, %.1f s, recorded %s by lancet %s%s\n", replay_path.c_str(),
                recording->samples.size(), recording->frames.size(), replay->duration_s(), recording->created.c_str(),
                recording->lancet_version.c_str(), recording->cut_short ? " (cut short: the recorder never finished it)" : "");
  } else {
    if (!scenario_path.empty()) {
      auto text = lancet::scenario::read_scenario_text(scenario_path);
      if (!text.ok()) {
        std::fprintf(stderr, "lancet-viz: %s\n", text.error().message.c_str());
        return 2;
      }
      setup.scenario_toml = std::move(text).value();
      setup.scenario_file = scenario_path;
    }
    std::printf("lancet-viz: building the tissue (%s)\n", scenario_path.empty() ? tissue.c_str() : scenario_path.c_str());
    std::fflush(stdout);
    auto made = lancet::record::SceneSim::create(setup);
    if (!made.ok()) {
      std::fprintf(stderr, "lancet-viz: %s\n", made.error().message.c_str());
      return made.error().code == lancet::ErrorCode::kInvalid ? 2 : 3;
    }
    sim_owned = std::move(made).value();
  }
  // The simulation in use: the replay's, or our own (the Record button makes a fresh one).
  const auto sim = [&]() -> lancet::record::SceneSim& { return replay ? replay->sim() : *sim_owned; };
  const lancet::scenario::Scenario* scenario = sim().scenario();
  if (scenario != nullptr) {
    o.scenario_name = scenario->name;
    if (!tool_given) tool = lancet::tool_name(scenario->start_tool);
  }
  if (tool == "none") tool.clear();
  double blood_ms = 0;  // spent on the blood, all frames
  std::string replay_error;  // why a replay stopped before its end
  std::vector<lancet::Vec3> guide;
  if (scenario != nullptr) {
    if (scenario->task == lancet::scenario::TaskKind::kIncision) guide = sim().scene().drape(scenario->incision.line);
    std::printf("lancet-viz: scenario %s (%s): %s\n", scenario->name.c_str(), scenario->file.c_str(), scenario->description.c_str());
  }
  std::vector<lancet::ToolMode> offered = scenario != nullptr ? scenario->tools
                                                   : std::vector<lancet::ToolMode>{lancet::ToolMode::kProbe, lancet::ToolMode::kScalpel,
                                                                                   lancet::ToolMode::kRetractor, lancet::ToolMode::kDrill,
                                                                                   lancet::ToolMode::kSwab};
  std::string keys;
  for (auto m : offered) {
    keys += keys.empty() ? "" : " / ";
    keys += std::to_string(static_cast<int>(m) + 1) + ": " + lancet::tool_name(m);
  }

  auto window = lancet::render::Window::create({o.width, o.height, !o.headless, "Lancet"});
  if (!window) {
    std::fprintf(stderr, "lancet-viz: %s\n", window.error().message.c_str());
    return 3;
  }
  auto& win = *window.value();
  std::printf("lancet-viz: %s\n", win.gl_description().c_str());

  lancet::viz::VizSessionParams sp;
  sp.shm_name = o.shm;
  lancet::viz::VizSession session(sp);
  // Every drained sample: to the trace, then to the scene (and the task's measure); the patch
  // around the tool comes from the sim().scene().
  // Recording: armed (--record, or the Record button) → the servo's reset is sent → recording
  // from the tick that applied it, with a fresh scene; Stop (or the end) finishes the file.
  enum class Rec { kOff, kArmed, kWaitingReset, kOn };
  Rec rec = record_path.empty() ? Rec::kOff : Rec::kArmed;
  int record_parts = 1;  // --record FILE: attempts recorded so far (a lancet-rt restart starts the next)
  std::uint32_t rt_losses_recorded = 0;  // lancet-rt losses the recording has reacted to
  std::string rec_path = record_path;
  std::unique_ptr<lancet::record::Recorder> recorder;
  std::uint64_t rec_frames = 0, rec_last_seq = 0, rec_frame_ticks = 0;
  std::vector<lancet::record::SceneEvent> scene_events;
  std::string rec_message;
  // While recording is armed: the patches this viz published (newest last, at most 8), for the
  // recording's start: the servo's first recorded ticks may still use one published a frame or two
  // before (the reset is sent only once the servo uses one of them, never a patch of a viz before
  // this one, which the recording could not hold).
  std::deque<std::pair<std::uint64_t, std::unique_ptr<lancet::TissuePatch>>> armed_patches;
  constexpr std::size_t kArmedPatches = 8;
  const auto stop_recording = [&] {
    if (!recorder) return;
    const auto done = recorder->finish();
    std::printf("lancet-viz: recorded %llu servo ticks (%llu lost in %llu gaps) and %llu frames to %s%s%s\n",
                static_cast<unsigned long long>(recorder->samples()), static_cast<unsigned long long>(recorder->samples_lost()),
                static_cast<unsigned long long>(recorder->gaps()), static_cast<unsigned long long>(recorder->frames()),
                recorder->path().c_str(), done.ok() ? "" : ": ", done.ok() ? "" : done.error().message.c_str());
    std::fflush(stdout);
    rec_message = "recorded " + recorder->path();
    recorder.reset();
    rec = Rec::kOff;
  };

  // Every drained sample: to the trace, then kept for the frame's batch (the scene takes one batch
  // a frame, just before the patch around the tool is cut from it, as a replay does).
  std::vector<lancet::ToolSample> frame_batch;
  const auto on_samples = [&, f = trace.get()](std::span<const lancet::ToolSample> batch) {
    if (f != nullptr) {
      for (const lancet::ToolSample& t : batch) {
        const lancet::Vec3 a = t.tool.position * 1e3, b = t.proxy.position * 1e3;
        std::fprintf(f, "%.6f,%u,%u,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.5f,%.5f,%.5f,%llu\n", static_cast<double>(t.t_ns) * 1e-9,
                     static_cast<unsigned>(t.stage), static_cast<unsigned>(t.events), a.x, a.y, a.z, b.x, b.y, b.z,
                     t.force.x, t.force.y, t.force.z, static_cast<unsigned long long>(t.patch_version));
      }
    }
    frame_batch.insert(frame_batch.end(), batch.begin(), batch.end());
  };
  const auto fill_patch = [&](lancet::Vec3 at, lancet::TissuePatch& patch) {
    std::span<const lancet::ToolSample> use(frame_batch);
    // Armed, the fresh scene waits for the session: what the servo sends before its reset (in the
    // frame that connects, before the reset goes out) is not applied to it.
    if (rec == Rec::kArmed) use = {};
    if (rec == Rec::kWaitingReset) {
      // Until the servo has applied the reset, what it sends belongs to no session.
      std::size_t i = 0;
      const auto is_reset = [](const lancet::ToolSample& t) { return t.reset_mode != lancet::kNoReset; };
      while (i < frame_batch.size() && !is_reset(frame_batch[i])) ++i;
      use = use.subspan(i);
      // The reset tick's patch and every newer one this viz published: what the recorded ticks use
      // before the first recorded frame publishes.
      const std::uint64_t reset_patch = use.empty() ? 0 : use.front().patch_version;
      const bool have_patches = reset_patch == 0 || std::any_of(armed_patches.begin(), armed_patches.end(),
                                                                [&](const auto& a) { return a.first == reset_patch; });
      if (!use.empty() && !have_patches) {
        // (Only if the reset took longer than kArmedPatches frames to come back.) Ask again.
        std::fprintf(stderr, "lancet-viz: the servo's reset used patch %llu, no longer kept: sending the reset again\n",
                     static_cast<unsigned long long>(reset_patch));
        rec = Rec::kArmed;
        use = {};
      }
      if (!use.empty()) {
        lancet::record::Recording meta;
        meta.lancet_version = LANCET_VERSION;
        meta.layout_hash = lancet::kSharedLayoutHash;
        meta.protocol = lancet::kProtocolVersion;
        char when[32];
        const std::time_t wall = std::time(nullptr);
        std::strftime(when, sizeof when, "%Y-%m-%dT%H:%M:%SZ", std::gmtime(&wall));
        meta.created = when;
        meta.scenario_name = scenario != nullptr ? scenario->name : "";
        meta.scenario_toml = setup.scenario_toml;
        meta.scenario_file = setup.scenario_file;
        meta.tissue = setup.tissue;
        meta.volume_path = setup.volume_path;
        meta.patch_radius = setup.patch_radius;
        meta.servo_hash_every = static_cast<std::uint32_t>(lancet::servo::kServoHashEvery);
        meta.scene_hash_every = lancet::record::kSceneHashEvery;
        (void)session.read_servo_model(meta.servo_model);
        meta.arm_config = session.read_arm_config();
        meta.period_ns = session.rt_status() ? session.rt_status()->period_ns : 1'000'000;
        for (const auto& [version, kept] : armed_patches) {
          if (reset_patch == 0 || version < reset_patch) continue;
          meta.first_patch_versions.push_back(version);
          meta.first_patches.push_back(*kept);
        }
        auto made = lancet::record::Recorder::create(rec_path, meta);
        if (made.ok()) {
          recorder = std::move(made).value();
          rec = Rec::kOn;
          rec_frames = 0;
          rec_message.clear();
          std::printf("lancet-viz: recording to %s from servo tick %llu\n", rec_path.c_str(),
                      static_cast<unsigned long long>(use.front().seq));
        } else {
          std::fprintf(stderr, "lancet-viz: %s\n", made.error().message.c_str());
          rec_message = made.error().message;
          rec = Rec::kOff;
        }
      }
    }
    sim().apply(use);
    if (rec == Rec::kOn) recorder->add_samples(use);
    if (!use.empty()) rec_last_seq = use.back().seq;
    rec_frame_ticks = rec == Rec::kOn ? use.size() : 0;
    frame_batch.clear();
    (void)sim().export_patch(at, patch);
  };

  int exit_code = 0;
  std::uint64_t frames = 0;
  double variance = -1;
  try {
    lancet::render::SceneRenderer renderer(o.width, o.height);
    lancet::surface::TriangleMesh mesh;
    sim().scene().draw_mesh(mesh);
    renderer.set_mesh(mesh);
    std::uint64_t shown_revision = sim().scene().revision();
    bool shown_walls_off = false;
    lancet::render::Overlay overlay(win.handle(), !o.headless);
    Interaction ui;
    ui.view = views.at(view);
    ui.preset = static_cast<int>(std::find(preset_names.begin(), preset_names.end(), preset) - preset_names.begin());
    if (std::isfinite(clip_mm)) ui.clip = true, ui.clip_mm = clip_mm;
    std::unique_ptr<lancet::render::VolumeRaycaster> raycaster;  // made when the volume is first shown
    int shown_preset = -1;
    float shown_level = 0, shown_width = 1;
    lancet::volume::TfEditor tf_editor;   // the shown table: the preset after window/level, then the user's edits
    lancet::volume::Histogram histogram;  // of the volume, under the editor
    bool tf_edited = false;
    if (scenario) {
      ui.yaw = static_cast<float>(scenario->camera.yaw);
      ui.pitch = static_cast<float>(scenario->camera.pitch);
      ui.distance = static_cast<float>(scenario->camera.distance);
    }
    g_ui = &ui;
    if (!o.headless) glfwSetScrollCallback(win.handle(), on_scroll);

    const auto start = std::chrono::steady_clock::now();
    const auto frame_period = std::chrono::duration<double>(1.0 / o.fps);
    std::string last_message;
    bool key_down[10] = {};
    std::uint32_t tool_sent_for = 0;  // the connection the starting tool was last sent on
    bool screenshot_frame = false;    // the extra frame drawn in --screenshot-view
    bool want_snapshot = false;       // F12 or the panel's button: a PNG of this frame
    bool f12_down = false;
    std::vector<float> force_history, wake_history;
    std::deque<std::pair<std::int64_t, std::array<std::uint64_t, lancet::kWakeBins>>> wake_snapshots;  // (time, RtStatus bins)
    std::vector<float> blood_depth, blood_age;
    lancet::surface::TriangleMesh with_pools;  // the drawn mesh and the grooves' pools
    auto last_frame = std::chrono::steady_clock::now();
    double replay_clock = 0;  // s of the recording shown
    bool replay_paused = false, f9_down = false, space_down = false;
    bool want_record = false;  // F9 or the panel's button
    while (!g_stop.load(std::memory_order_relaxed) && !win.should_close()) {
      const auto frame_start = std::chrono::steady_clock::now();
      if (o.duration > 0 && std::chrono::duration<double>(frame_start - start).count() >= o.duration) {
        // Time is up; with --screenshot-view, one frame more in that view for the screenshot.
        if (screenshot_view.empty() || screenshot_frame) break;
        ui.view = views.at(screenshot_view);
        screenshot_frame = true;
      }
      const std::int64_t now = lancet::monotonic_ns();
      lancet::record::FrameRecord frame_record;
      const std::uint64_t published_before = session.patches_published();
      if (replay) {
        // The recorded frames up to the replay's clock (all of them at once, headless).
        const double wall_dt = std::chrono::duration<double>(frame_start - last_frame).count();
        if (!replay_paused) replay_clock += std::min(wall_dt, 0.1) * replay_speed;
        const auto& rf = replay->recording().frames;
        while (!replay->done() &&
               (o.headless || static_cast<double>(rf[replay->frame()].t_ns - rf.front().t_ns) * 1e-9 <= replay_clock)) {
          auto stepped = replay->step_frame();
          if (!stepped.ok()) {
            std::fprintf(stderr, "lancet-viz: --replay: %s\n", stepped.error().message.c_str());
            replay_error = stepped.error().message;
            exit_code = 1;
            g_stop.store(true);
            break;
          }
        }
        if (o.headless && replay->done()) {  // then one frame drawn (in --screenshot-view, if given) and stop
          if (screenshot_view.empty() || screenshot_frame) {
            g_stop.store(true);
          } else {
            ui.view = views.at(screenshot_view);
            screenshot_frame = true;
          }
        }
      } else {
        session.frame(now, on_samples, fill_patch);
        if ((rec == Rec::kArmed || rec == Rec::kWaitingReset) && session.patches_published() != published_before) {
          std::unique_ptr<lancet::TissuePatch> kept;
          if (armed_patches.size() >= kArmedPatches) {
            kept = std::move(armed_patches.front().second);
            armed_patches.pop_front();
          } else {
            kept = std::make_unique<lancet::TissuePatch>();
          }
          std::memcpy(static_cast<void*>(kept.get()), &session.patch(), lancet::tissue_patch_bytes(session.patch()));
          armed_patches.emplace_back(session.patch_version(), std::move(kept));
        }
        if (rec == Rec::kOff || rec == Rec::kOn) armed_patches.clear();
      }
      // The session's start: the tool (and, when recording is armed, the servo's reset before it,
      // once the servo uses a patch this viz published).
      const bool connected = !replay && session.link() == lancet::viz::Link::kConnected;
      const bool servo_uses_ours = session.has_sample() && !armed_patches.empty() &&
                                   session.latest().patch_version >= armed_patches.front().first;
      if (connected && rec == Rec::kArmed && servo_uses_ours) {
        lancet::Command c{};
        c.kind = lancet::CommandKind::kReset;
        if (session.send(c, now)) {
          rec = Rec::kWaitingReset;  // (the reset keeps the tool in hand)
          frame_batch.clear();
        }
      }
      if (!tool.empty() && connected && tool_sent_for != session.connections()) {
        lancet::Command c{};
        c.kind = lancet::CommandKind::kSetToolMode;
        (void)lancet::tool_from_name(tool, c.mode);  // CLI11 or the scenario admitted only the tools' names
        if (session.send(c, now)) tool_sent_for = session.connections();
      }
      if (rec == Rec::kOn) {
        frame_record.frame = rec_frames;
        frame_record.t_ns = now;
        frame_record.last_seq = rec_last_seq;
        frame_record.ticks = rec_frame_ticks;
        rec_frame_ticks = 0;
        if (session.patches_published() != published_before) {
          const lancet::TissuePatch& p = session.patch();
          frame_record.patch_version = session.patch_version();
          frame_record.patch_seq = p.seq;
          frame_record.patch_t_ns = p.t_ns;
          frame_record.patch_samples_applied = p.samples_applied;
          frame_record.patch_centre = session.latest().tool.position;
        }
      }
      // Redraw only what changed shape; with the volume beneath, the grooves' walls are the
      // volume's to show.
      bool mesh_changed = false;
      if (sim().scene().revision() != shown_revision || (ui.view == 1) != shown_walls_off) {
        shown_revision = sim().scene().revision();
        shown_walls_off = ui.view == 1;
        sim().scene().draw_mesh(mesh, !shown_walls_off);
        mesh_changed = true;
      }
      // The blood: the frame's time simulated (at most 0.1 s after a stall), then onto the mesh,
      // with the pools in the grooves (they change every frame: the mesh with them is sent every
      // frame, only the blocks that differ).
      if (sim().bleeding()) {
        const auto t0 = std::chrono::steady_clock::now();
        const double blood_dt = std::chrono::duration<double>(t0 - last_frame).count();
        if (!replay) sim().bleeding()->advance(sim().scene(), blood_dt);  // (a replay advances it as recorded)
        if (rec == Rec::kOn) frame_record.blood_dt = blood_dt;
        sim().bleeding()->vertex_blood(mesh, blood_depth, blood_age);
        if (sim().bleeding()->groove_cells() > 0) {
          with_pools = mesh;
          sim().bleeding()->append_pools(sim().scene(), with_pools, blood_depth, blood_age);
          renderer.set_mesh(with_pools);
          mesh_changed = false;
        }
        blood_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      }
      if (mesh_changed) renderer.set_mesh(mesh);
      if (sim().bleeding()) {
        const auto t0 = std::chrono::steady_clock::now();
        renderer.set_blood(blood_depth, blood_age);
        blood_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      }
      if (rec == Rec::kOn) {
        sim().figures(frame_record);
        if (rec_frames % lancet::record::kSceneHashEvery == 0) frame_record.scene_hash = sim().hash();
        recorder->add_frame(frame_record);
        scene_events.clear();
        sim().take_events(rec_frames, now, scene_events);
        for (const auto& e : scene_events) recorder->add_event(e);
        ++rec_frames;
      }
      last_frame = frame_start;
      if (!replay && session.link_message() != last_message) {
        last_message = session.link_message();
        std::printf("lancet-viz: %s\n", last_message.c_str());
        std::fflush(stdout);
      }

      int fw = o.width, fh = o.height;
      if (!o.headless) {
        win.framebuffer_size(fw, fh);
        if (fw > 0 && fh > 0) renderer.resize(fw, fh);
        GLFWwindow* h = win.handle();
        if (glfwGetKey(h, GLFW_KEY_ESCAPE) == GLFW_PRESS) break;
        // Edge-triggered keys: M toggles mouse drive, 1-5 pick an offered tool, R resets, W re-arms.
        const int key_codes[10] = {GLFW_KEY_M, GLFW_KEY_1, GLFW_KEY_2, GLFW_KEY_3, GLFW_KEY_4,
                                   GLFW_KEY_R, GLFW_KEY_W, GLFW_KEY_V, GLFW_KEY_P, GLFW_KEY_5};
        for (int k = 0; k < 10; ++k) {
          const bool down = glfwGetKey(h, key_codes[k]) == GLFW_PRESS;
          if (down && !key_down[k]) {
            if (k == 7) {
              ui.view = (ui.view + 1) % 3;
            } else if (k == 8) {
              ui.preset = (ui.preset + 1) % static_cast<int>(preset_names.size());
              ui.level = 0, ui.width = 1;
            } else if (k == 0) {
              ui.mouse_drives_stylus = !ui.mouse_drives_stylus;
              if (!ui.mouse_drives_stylus) session.set_stylus_target(false, {}, now);
            } else if (k == 5 || k == 6) {
              lancet::Command c{};
              c.kind = k == 5 ? lancet::CommandKind::kReset : lancet::CommandKind::kRearm;
              (void)session.send(c, now);
            } else if (const auto mode = static_cast<lancet::ToolMode>(k == 9 ? 4 : k - 1);
                       std::find(offered.begin(), offered.end(), mode) != offered.end()) {
              lancet::Command c{};
              c.kind = lancet::CommandKind::kSetToolMode;
              c.mode = mode;
              (void)session.send(c, now);
            }
          }
          key_down[k] = down;
        }
        const bool f12 = glfwGetKey(h, GLFW_KEY_F12) == GLFW_PRESS;
        if (f12 && !f12_down) want_snapshot = true;
        f12_down = f12;
        const bool f9 = glfwGetKey(h, GLFW_KEY_F9) == GLFW_PRESS;
        if (f9 && !f9_down && !replay) want_record = true;
        f9_down = f9;
        const bool space = glfwGetKey(h, GLFW_KEY_SPACE) == GLFW_PRESS;
        if (space && !space_down && replay) replay_paused = !replay_paused;
        space_down = space;
        double mx = 0, my = 0;
        glfwGetCursorPos(h, &mx, &my);
        const bool left = glfwGetMouseButton(h, GLFW_MOUSE_BUTTON_LEFT) == GLFW_PRESS && !overlay.wants_mouse();
        if (left && ui.rotating) {
          ui.yaw += static_cast<float>(mx - ui.last_x) * 0.005f;
          ui.pitch = std::clamp(ui.pitch + static_cast<float>(my - ui.last_y) * 0.005f, 0.05f, 1.5f);
        }
        // Right drag: window/level, as in 3D Slicer (across: level, up and down: width).
        const bool right = glfwGetMouseButton(h, GLFW_MOUSE_BUTTON_RIGHT) == GLFW_PRESS && !overlay.wants_mouse();
        if (right && ui.windowing) {
          ui.level += static_cast<float>(mx - ui.last_x) * 2.0f;
          ui.width = std::clamp(ui.width * std::pow(1.005f, static_cast<float>(my - ui.last_y)), 0.05f, 20.0f);
        }
        ui.windowing = right;
        ui.rotating = left;
        ui.last_x = mx, ui.last_y = my;
        int ww = 0, wh = 0;
        glfwGetWindowSize(h, &ww, &wh);
        lancet::Vec3 p;
        if (ui.mouse_drives_stylus && renderer.pick_plane(mx, my, ww, wh, p)) {
          // Pushed depth_mm below the surface under the cursor (or below z = 0 off the tissue).
          const auto top = sim().scene().surface_below(p.x, p.y);
          p.z = (top ? top->z : 0.0) - ui.depth_mm * 1e-3;
          session.set_stylus_target(true, p, now);
        }
      }

      lancet::render::SceneInput in;
      // The tool and the patch: lancet-rt's, or the replay's.
      const lancet::ToolSample* latest = replay ? replay->latest() : session.has_sample() ? &session.latest() : nullptr;
      in.has_tool = latest != nullptr;
      if (in.has_tool) {
        in.tool = latest->tool.position;
        in.proxy = latest->proxy.position;
        in.force = latest->force;
      }
      in.patch = replay ? replay->patch() : session.patches_published() > 0 ? &session.patch() : nullptr;
      in.camera_yaw = ui.yaw, in.camera_pitch = ui.pitch, in.camera_distance = ui.distance;
      if (scenario) in.camera_target = scenario->camera.target;
      in.guide = guide.empty() ? nullptr : &guide;
      // The volume: made and uploaded when first shown, its drilled voxels sent as they change.
      const lancet::volume::VoxelBox changed = sim().scene().take_volume_changes();
      if (ui.view != 0) {
        if (!raycaster) {
          raycaster = std::make_unique<lancet::render::VolumeRaycaster>();
          raycaster->set_volume(sim().scene().render_volume());
          shown_preset = -1;
          const lancet::volume::TfSpec range = lancet::volume::tf_preset_spec(lancet::volume::kTfPresets[0]);
          histogram = lancet::volume::histogram(sim().scene().render_volume(), range.lo, range.hi, 128);
        } else if (!changed.empty()) {
          raycaster->update_region(sim().scene().render_volume(), changed);
        }
        if (shown_preset != ui.preset || shown_level != ui.level || shown_width != ui.width) {
          // A preset or a window/level drag starts the editor afresh from the preset's points.
          tf_editor = lancet::volume::TfEditor(lancet::volume::tf_preset_spec(lancet::volume::kTfPresets[ui.preset], ui.level, ui.width));
          shown_preset = ui.preset, shown_level = ui.level, shown_width = ui.width;
          tf_edited = true;
        }
        if (tf_edited) raycaster->set_transfer_function(tf_editor.table());
        tf_edited = false;
        in.volume = raycaster.get();
        in.volume_to_world = sim().scene().volume_to_world();
        in.volume_params.step = 1.0f;  // a voxel a sample: interactive on llvmpipe
        if (ui.clip) {  // keep world z <= clip_mm, as a plane in the volume's frame
          const auto m = in.volume_to_world;
          in.volume_params.clip = true;
          in.volume_params.clip_plane = {m[2], m[6], m[10], m[14] - ui.clip_mm * 1e-3f};
        }
        in.draw_surface = ui.view == 1;
      } else if (raycaster && !changed.empty()) {
        raycaster->update_region(sim().scene().render_volume(), changed);
      }
      renderer.render(in);
      auto lines = status_lines(session, ui, o.headless, sim().scene().events(), scenario,
                                sim().task() ? &sim().task()->status() : nullptr, keys);
      if (replay) {  // no lancet-rt: the replay's line instead of the link's
        std::erase_if(lines, [&](const lancet::render::OverlayLine& l) {
          return l.text == session.link_message() || l.text.rfind("samples ", 0) == 0;  // no link: its figures say nothing
        });
        char buf[160];
        std::snprintf(buf, sizeof buf, "REPLAY %s  %.1f / %.1f s at %gx%s; patch %u triangles", replay_path.c_str(), replay->time_s(),
                      replay->duration_s(), replay_speed, replay_paused ? " (paused: space)" : "",
                      replay->patch() != nullptr ? replay->patch()->n_triangles : 0u);
        lines.insert(lines.begin(), {buf});
      }
      if (ui.view != 0) {
        char buf[160];
        std::snprintf(buf, sizeof buf, "volume: %s, level %+.0f HU, width x%.2f%s", preset_names[static_cast<std::size_t>(ui.preset)].c_str(),
                      static_cast<double>(ui.level), static_cast<double>(ui.width),
                      o.headless ? "" : "   V: view, P: preset, right drag: window/level");
        lines.push_back({buf});
      }
      // The controls panel: task, tools, the force and the servo over the last seconds, the volume.
      force_history.push_back(latest != nullptr ? static_cast<float>(lancet::norm(latest->force)) : 0.0f);
      const auto& rs = session.rt_status();
      wake_history.push_back(rs ? static_cast<float>(rs->wake_p99_ns) * 1e-3f : 0.0f);
      for (auto* h : {&force_history, &wake_history})
        if (h->size() > 300) h->erase(h->begin(), h->begin() + static_cast<std::ptrdiff_t>(h->size() - 300));
      // The latency histogram over the last seconds: today's counts less those of a snapshot
      // at least kWakeWindow old (RtStatus counts since lancet-rt started).
      std::vector<std::uint64_t> wake_recent;
      float wake_window_s = 0;
      if (rs) {
        std::array<std::uint64_t, lancet::kWakeBins> bins{};
        std::copy(std::begin(rs->wake_histogram), std::end(rs->wake_histogram), bins.begin());
        const auto total = [](const auto& b) { return std::accumulate(b.begin(), b.end(), std::uint64_t{0}); };
        if (!wake_snapshots.empty() && total(bins) < total(wake_snapshots.back().second)) wake_snapshots.clear();  // lancet-rt restarted
        wake_snapshots.emplace_back(now, bins);
        constexpr std::int64_t kWakeWindow = 5'000'000'000;
        while (wake_snapshots.size() > 1 && now - wake_snapshots[1].first >= kWakeWindow) wake_snapshots.pop_front();
        const auto& old = wake_snapshots.front();
        wake_recent.resize(lancet::kWakeBins);
        for (std::size_t i = 0; i < lancet::kWakeBins; ++i) wake_recent[i] = bins[i] >= old.second[i] ? bins[i] - old.second[i] : 0;
        wake_window_s = static_cast<float>(static_cast<double>(now - old.first) * 1e-9);
        if (wake_snapshots.size() == 1) wake_recent.assign(bins.begin(), bins.end()), wake_window_s = 0;
      } else {
        wake_snapshots.clear();
      }
      lancet::render::PanelState panel;
      if (sim().task()) {
        panel.task_progress = static_cast<float>(sim().task()->status().progress);
        panel.task_label = scenario->task == lancet::scenario::TaskKind::kIncision ? "incision along the line" : "drill the window";
      }
      for (auto m : offered) {
        panel.tools.emplace_back(lancet::tool_name(m));
        panel.tool_keys.push_back(static_cast<int>(m));
      }
      panel.tool = latest != nullptr ? static_cast<int>(latest->mode) : -1;
      panel.force_history = force_history;
      panel.wake_p99_history = wake_history;
      panel.wake_bins = wake_recent;
      panel.wake_window_s = wake_window_s;
      panel.watchdog_tripped = rs && rs->watchdog_tripped != 0;
      panel.connected = session.link() == lancet::viz::Link::kConnected;
      panel.can_record = !replay;
      panel.recording = rec != Rec::kOff;
      if (rec == Rec::kOn) {
        char buf[200];
        std::snprintf(buf, sizeof buf, "REC %s: %llu ticks, %llu lost", rec_path.c_str(),
                      static_cast<unsigned long long>(recorder->samples()), static_cast<unsigned long long>(recorder->samples_lost()));
        panel.record_line = buf;
      } else if (rec != Rec::kOff) {
        panel.record_line = "recording: waiting for lancet-rt's reset";
      } else {
        panel.record_line = rec_message;
      }
      if (replay) {
        const lancet::record::ReplayCheck& ck = replay->check();
        char buf[200];
        std::snprintf(buf, sizeof buf, "replay: %llu ticks, %llu frames, %s", static_cast<unsigned long long>(ck.ticks),
                      static_cast<unsigned long long>(ck.frames),
                      ck.exact() ? "bit-exact so far" : "DIFFERS from the recording");
        panel.record_line = buf;
        panel.replay_duration_s = static_cast<float>(replay->duration_s());
        panel.replay_position = panel.replay_duration_s > 0 ? static_cast<float>(replay->time_s() / replay->duration_s()) : 1.0f;
        panel.replay_paused = replay_paused;
        panel.replay_speed = static_cast<float>(replay_speed);
      }
      panel.view = ui.view;
      panel.presets = preset_names;
      panel.preset = ui.preset;
      panel.level = ui.level, panel.width = ui.width;
      panel.clip = ui.clip, panel.clip_mm = ui.clip_mm;
      if (raycaster) panel.tf_editor = &tf_editor, panel.histogram = &histogram;
      if (sim().bleeding()) {
        const lancet::hybrid::BloodFigures bf = sim().bleeding()->figures();
        char buf[160];
        std::snprintf(buf, sizeof buf, "blood lost %.2f mL (on the tissue %.2f, swabbed %.2f)", bf.lost_ml, bf.on_tissue_ml,
                      bf.swabbed_ml);
        panel.blood.push_back({buf, false});
        for (const auto& src : sim().bleeding()->sources()) {
          if (src.kind != lancet::hybrid::BloodSource::Kind::kVessel) continue;
          std::snprintf(buf, sizeof buf, "%s: %s", src.name.c_str(),
                        src.stopped ? "stopped" : src.pressed_s > 0 ? "pressed..." : "BLEEDING: press it 3 s with the probe");
          panel.blood.push_back({buf, !src.stopped});
        }
      }
      // ImGui sizes a panel from the frame before: the screenshot's extra frame (a line more) is
      // laid out once before it is drawn.
      if (screenshot_frame) overlay.layout("Lancet", lines, renderer.width(), renderer.height(), &panel);
      const lancet::render::PanelActions act = overlay.draw("Lancet", lines, renderer.width(), renderer.height(), &panel);
      if (act.tool >= 0) {
        lancet::Command c{};
        c.kind = lancet::CommandKind::kSetToolMode;
        c.mode = static_cast<lancet::ToolMode>(act.tool);
        (void)session.send(c, now);
      }
      if (act.rearm || act.reset) {
        lancet::Command c{};
        c.kind = act.reset ? lancet::CommandKind::kReset : lancet::CommandKind::kRearm;
        (void)session.send(c, now);
      }
      if (act.view >= 0) ui.view = act.view;
      if (act.preset >= 0) ui.preset = act.preset, ui.level = 0, ui.width = 1;
      if (act.window_changed) ui.level = act.level, ui.width = act.width;
      if (act.clip_changed) ui.clip = act.clip, ui.clip_mm = act.clip_mm;
      if (act.tf_edited) tf_edited = true;
      if (act.screenshot) want_snapshot = true;
      if (act.replay_pause) replay_paused = !replay_paused;
      if (act.replay_speed > 0) replay_speed = act.replay_speed;
      if (act.record) want_record = true;
      // Arms a recording to `name` on a fresh scene (an attempt starts from untouched tissue).
      const auto arm_recording = [&](const std::string& name) {
        auto fresh = lancet::record::SceneSim::create(setup);
        if (fresh.ok()) {
          sim_owned = std::move(fresh).value();
          scenario = sim().scenario();  // the old sim's went with it
          shown_revision = ~std::uint64_t{0};
          raycaster.reset();
          rec_path = name;
          rec = Rec::kArmed;
        } else {
          rec_message = fresh.error().message;
        }
      };
      if (want_record) {  // Record: a fresh scene and the servo's reset; Stop: finish the file
        want_record = false;
        if (rec != Rec::kOff) {
          stop_recording();  // (armed and waiting for the reset: nothing was written yet)
          rec = Rec::kOff;
        } else {
          char name[64];
          const std::time_t wall = std::time(nullptr);
          std::strftime(name, sizeof name, "lancet-%Y%m%d-%H%M%S.h5", std::localtime(&wall));
          arm_recording(name);
        }
      }
      // lancet-rt went away while recording: its servo's state went with it, so the attempt (and its
      // recording) ends here. With --record, the next attempt is recorded once lancet-rt is back,
      // on a fresh scene, to FILE-2.h5, FILE-3.h5, ...
      const bool rt_lost = !replay && session.rt_losses() != rt_losses_recorded;
      if (rt_lost) rt_losses_recorded = session.rt_losses();
      if (rt_lost && rec != Rec::kOff) {
        const bool was_recording = rec == Rec::kOn;
        stop_recording();
        rec = Rec::kOff;
        if (was_recording) std::printf("lancet-viz: lancet-rt went away: the recording ends there\n");
        if (!record_path.empty()) {
          const std::filesystem::path base(record_path);
          const std::string next = (base.parent_path() / (base.stem().string() + "-" + std::to_string(++record_parts) + base.extension().string())).string();
          std::printf("lancet-viz: the next attempt will be recorded to %s once lancet-rt is back\n", next.c_str());
          arm_recording(next);
        }
        std::fflush(stdout);
      }
      if (want_snapshot) {  // lancet-YYYYmmdd-HHMMSS.png in the working directory
        want_snapshot = false;
        char name[64];
        const std::time_t wall = std::time(nullptr);
        std::strftime(name, sizeof name, "lancet-%Y%m%d-%H%M%S.png", std::localtime(&wall));
        const lancet::render::Image img = renderer.read_back();
        std::printf("lancet-viz: %s %s\n", lancet::render::write_png(name, img) ? "wrote" : "cannot write", name);
      }
      if (!o.headless) renderer.present(fw, fh);
      win.swap_and_poll();
      ++frames;
      std::this_thread::sleep_until(frame_start + frame_period);
    }

    if (!o.screenshot.empty()) {
      const lancet::render::Image img = renderer.read_back();
      variance = lancet::render::luminance_variance(img);
      if (!lancet::render::write_png(o.screenshot, img)) {
        std::fprintf(stderr, "lancet-viz: cannot write screenshot %s\n", o.screenshot.c_str());
        exit_code = 1;
      } else {
        std::printf("lancet-viz: wrote %s (%dx%d, luminance variance %.1f)\n", o.screenshot.c_str(), img.width,
                    img.height, variance);
      }
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "lancet-viz: %s\n", e.what());
    exit_code = 4;
  }
  g_ui = nullptr;
  stop_recording();
  if (replay) {
    const lancet::record::ReplayCheck& ck = replay->check();
    // A verdict only for what was checked: a replay that stopped early says so, and one that
    // checked nothing is no evidence of anything.
    const bool all = replay_error.empty() && replay->done();
    const char* verdict = !ck.exact()          ? "DIFFERS"
                          : ck.ticks == 0      ? "nothing replayed"
                          : !all               ? "bit-exact as far as it went"
                                               : "bit-exact";
    std::printf("lancet-viz: replay of %s: %llu of %zu ticks and %llu of %zu frames; servo state hashes %llu checked, %llu differ; "
                "samples differing %llu; scene hashes %llu checked, %llu differ: %s\n",
                replay_path.c_str(), static_cast<unsigned long long>(ck.ticks), recording->samples.size(),
                static_cast<unsigned long long>(ck.frames), recording->frames.size(), static_cast<unsigned long long>(ck.servo_hashes),
                static_cast<unsigned long long>(ck.servo_hash_mismatches), static_cast<unsigned long long>(ck.sample_mismatches),
                static_cast<unsigned long long>(ck.scene_hashes), static_cast<unsigned long long>(ck.scene_hash_mismatches), verdict);
    if (recording->cut_short)
      std::printf("lancet-viz: the recording was cut short (its recorder never finished it: the viz was killed or the power "
                  "lost): replayed up to where the file ends\n");
    if (ck.gap_seq != 0)
      std::printf("lancet-viz: %llu servo ticks are missing before tick %llu (the viz stalled longer than the sample ring holds): "
                  "the servo was checked up to there, the scene throughout (%llu ticks after the gap drove it as recorded)\n",
                  static_cast<unsigned long long>(ck.ticks_lost), static_cast<unsigned long long>(ck.gap_seq),
                  static_cast<unsigned long long>(ck.ticks_unchecked));
    if (!replay_error.empty()) std::printf("lancet-viz: the replay stopped: %s\n", replay_error.c_str());
    if (!replay_error.empty() || (o.headless && (!all || ck.ticks == 0))) exit_code = exit_code ? exit_code : 1;
    if (!ck.exact()) {
      std::printf("lancet-viz: the first difference: servo tick %llu, frame %llu\n", static_cast<unsigned long long>(ck.first_bad_seq),
                  static_cast<unsigned long long>(ck.first_bad_frame > 0 ? ck.first_bad_frame - 1 : 0));
      exit_code = exit_code ? exit_code : 1;
    }
  }
  if (!replay) {
    std::printf("lancet-viz: %llu frames, %llu samples received (%llu lost), %llu patches published\n",
                static_cast<unsigned long long>(frames), static_cast<unsigned long long>(session.samples_total()),
                static_cast<unsigned long long>(session.stats().lost),
                static_cast<unsigned long long>(session.patches_published()));
  }
  if (sim().task()) std::printf("lancet-viz: %s\n", sim().task()->status().line.c_str());
  if (!o.stats.empty() &&
      !write_stats(o, session, frames, variance, sim().scene(), sim().task() ? &sim().task()->status() : nullptr, sim().bleeding(),
                   frames > 0 ? blood_ms / static_cast<double>(frames) : 0.0)) {
    std::fprintf(stderr, "lancet-viz: cannot write stats to %s\n", o.stats.c_str());
    exit_code = exit_code ? exit_code : 1;
  }
  return exit_code;
}
